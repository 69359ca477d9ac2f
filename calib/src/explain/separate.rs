//! The experiment that separates two effects the data cannot tell apart: both alternative
//! models (each fitted to the same data) are evaluated over poses, approach directions and
//! head orientations the dataset may lack; where their predictions differ most is where a
//! new measurement decides between them.
use abvs_eye::pose::{rotation_angle_deg, Fick, Pose};
use abvs_eye::spm::SpmGeometry;
use abvs_eye::unit::{Conditions, UnitModel};

#[derive(Debug, Clone, serde::Serialize)]
pub struct SeparatingPose {
    /// Commanded Fick angles [alpha, beta, gamma] (deg), reached by nominal IK.
    pub cmd_deg: [f64; 3],
    /// Direction the links approach the pose from.
    pub approach: &'static str,
    /// Gravity in the base frame (the head's orientation).
    pub gravity: [f64; 3],
    /// Rotation between the two models' predictions (deg).
    pub difference_deg: f64,
}

/// The `n` conditions where models `a` and `b` disagree most (distinct commanded poses).
pub fn separating_poses(a: &UnitModel, b: &UnitModel, n: usize) -> Vec<SeparatingPose> {
    let (Ok(fa), Ok(fb)) = (a.compile(), b.compile()) else { return vec![] };
    let nominal = SpmGeometry::nominal();
    let tilt = 40f64.to_radians();
    let gravities = [[0.0, 1.0, 0.0], [tilt.sin(), tilt.cos(), 0.0], [0.0, tilt.cos(), tilt.sin()]];
    let approaches: [(&str, f64); 2] = [("+ (every link moving up)", 1.0), ("- (every link moving down)", -1.0)];
    let mut out: Vec<SeparatingPose> = vec![];
    let axis = |r: f64| (0..=10).map(move |i| -r + 2.0 * r * i as f64 / 10.0);
    for al in axis(30.0) {
        for be in axis(15.0) {
            for ga in axis(30.0) {
                let cmd = [al, be, ga];
                let Ok(th) = nominal.ik_checked(&Fick::from_deg(cmd).to_matrix()) else { continue };
                let reading = th.map(f64::to_degrees);
                let mut best: Option<SeparatingPose> = None;
                for g in gravities {
                    for (name, s) in approaches {
                        let cond = Conditions { dir: [s; 3], gravity: g, platform_dir: [0.0, 0.0, s] };
                        let (Ok(pa), Ok(pb)) = (fa.p6(&reading, &cond), fb.p6(&reading, &cond)) else { continue };
                        let d = rotation_angle_deg(&Pose::from_p6(&pa).r, &Pose::from_p6(&pb).r);
                        if best.as_ref().is_none_or(|x| d > x.difference_deg) {
                            best = Some(SeparatingPose { cmd_deg: cmd, approach: name, gravity: g, difference_deg: d });
                        }
                    }
                }
                out.extend(best);
            }
        }
    }
    out.sort_by(|x, y| y.difference_deg.total_cmp(&x.difference_deg));
    out.truncate(n);
    out
}
