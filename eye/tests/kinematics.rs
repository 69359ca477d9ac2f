//! Kinematics over the whole workspace, checked against an independent formulation.
use abvs_eye::pose::Fick;
use abvs_eye::psc::grid;
use abvs_eye::spm::{LegParams, SpmGeometry};
use abvs_eye::EyeError;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// FK(IK(P)) = P to 1e-9 deg over the paper's whole 1 deg grid (115,351 poses), warm-started
/// along the serpentine acquisition order as the runtime does, plus a cold start every 97th pose.
#[test]
fn fk_of_ik_is_identity_over_the_1deg_grid() {
    let g = SpmGeometry::nominal();
    let spec = abvs_eye::sim::SimSpec { commanded: abvs_eye::sim::Commanded::Step(1.0), ..Default::default() };
    let poses = abvs_eye::sim::commanded_poses(&spec);
    assert_eq!(poses.len(), 115_351);
    let mut warm = Matrix3::identity();
    let mut worst: f64 = 0.0;
    for (k, p) in poses.iter().enumerate() {
        let r = Fick::from_deg(*p).to_matrix();
        let th = g.ik_checked(&r).unwrap_or_else(|e| panic!("IK at {p:?}: {e}"));
        let sol = if k % 97 == 0 { g.fk_cold(&th) } else { g.fk_from(&th, &warm) }
            .unwrap_or_else(|e| panic!("FK at {p:?}: {e}"));
        assert!(sol.residual < 1e-12);
        warm = sol.r;
        let back = Fick::from_matrix(&sol.r).to_deg();
        for i in 0..3 {
            worst = worst.max((back[i] - p[i]).abs());
        }
    }
    assert!(worst < 1e-9, "worst |FK(IK(P)) - P| = {worst:e} deg");
}

#[test]
fn equal_link_motion_is_pure_roll_over_a_full_turn() {
    let g = SpmGeometry::nominal();
    let mut warm = Matrix3::identity();
    for t in grid(-180.0, 179.0, 1.0) {
        let th = [t.to_radians(); 3];
        let sol = g.fk_from(&th, &warm).or_else(|_| g.fk_cold(&th)).unwrap();
        warm = sol.r;
        let want = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), t.to_radians()).into_inner();
        assert!((sol.r - want).amax() < 1e-12, "roll {t}");
    }
}

/// A second formulation: unknowns are platform-joint axes v_1, v_2 (6 numbers) with
/// |v_1| = |v_2| = 1, v_1 . v_2 = v_10 . v_20 (rigid platform), v_3 carried rigidly by them
/// (v_3 = a v_1 + b v_2 + c v_1 x v_2 with a, b, c from home), and w_i . v_i = cos d2;
/// solved by Newton (finite-difference Jacobian) along a continuation path. The orientation is
/// recovered from the triad. (Three coplanar axes with all pairwise dots as unknowns would make
/// the Jacobian singular, hence the rigid third axis.)
fn fk_by_platform_vectors(g: &SpmGeometry, theta: &[f64; 3]) -> Matrix3<f64> {
    let v0: Vec<Vector3<f64>> = g.legs.iter().map(|l| l.v0).collect();
    let basis = |a: Vector3<f64>, b: Vector3<f64>| Matrix3::from_columns(&[a, b, a.cross(&b)]);
    let coef = basis(v0[0], v0[1]).try_inverse().unwrap() * v0[2];
    let unpack = |x: &SVector<f64, 6>| {
        let v1 = Vector3::new(x[0], x[1], x[2]);
        let v2 = Vector3::new(x[3], x[4], x[5]);
        (v1, v2, basis(v1, v2) * coef)
    };
    let mut x = SVector::<f64, 6>::zeros();
    x.fixed_rows_mut::<3>(0).copy_from(&v0[0]);
    x.fixed_rows_mut::<3>(3).copy_from(&v0[1]);
    let steps = 20;
    for s in 1..=steps {
        let w: Vec<Vector3<f64>> = (0..3).map(|i| g.w(i, theta[i] * s as f64 / steps as f64)).collect();
        let f = |x: &SVector<f64, 6>| {
            let (v1, v2, v3) = unpack(x);
            SVector::<f64, 6>::from_column_slice(&[
                v1.dot(&v1) - 1.0,
                v2.dot(&v2) - 1.0,
                v1.dot(&v2) - v0[0].dot(&v0[1]),
                w[0].dot(&v1) - g.legs[0].cos_d2,
                w[1].dot(&v2) - g.legs[1].cos_d2,
                w[2].dot(&v3) - g.legs[2].cos_d2,
            ])
        };
        for _ in 0..60 {
            let fx = f(&x);
            if fx.amax() < 1e-15 {
                break;
            }
            let mut j = SMatrix::<f64, 6, 6>::zeros();
            for k in 0..6 {
                let mut xp = x;
                let mut xm = x;
                xp[k] += 1e-7;
                xm[k] -= 1e-7;
                j.set_column(k, &((f(&xp) - f(&xm)) / 2e-7));
            }
            x -= j.lu().solve(&fx).expect("regular");
        }
    }
    let (v1, v2, _) = unpack(&x);
    let triad = |a: Vector3<f64>, b: Vector3<f64>| {
        let e1 = a.normalize();
        let e3 = a.cross(&b).normalize();
        Matrix3::from_columns(&[e1, e3.cross(&e1), e3])
    };
    triad(v1, v2) * triad(v0[0], v0[1]).transpose()
}

#[test]
fn fk_agrees_with_platform_vector_formulation() {
    let perturbed = SpmGeometry::from_params(&[
        LegParams { d1_deg: 60.4, axis_tilt_deg: [0.2, -0.1], platform_axis_deg: [0.3, -0.2], ..LegParams::nominal(0) },
        LegParams { d2_deg: 89.6, ..LegParams::nominal(1) },
        LegParams { d1_deg: 59.7, d2_deg: 90.3, axis_tilt_deg: [-0.1, 0.15], ..LegParams::nominal(2) },
    ]);
    for g in [SpmGeometry::nominal(), perturbed] {
        for p in [[0.0, 0.0, 0.0], [30.0, 15.0, 30.0], [-30.0, -15.0, -30.0], [12.0, -7.0, -26.0], [-25.0, 9.0, 18.0]] {
            let th = g.ik(&Fick::from_deg(p).to_matrix()).unwrap();
            let a = g.fk_cold(&th).unwrap().r;
            let b = fk_by_platform_vectors(&g, &th);
            assert!(
                (a - b).amax() < 1e-12,
                "at {p:?}: {} res a {:e} res b {:e} orth b {:e}",
                (a - b).amax(),
                g.constraints(&a, &th).amax(),
                g.constraints(&b, &th).amax(),
                (b.transpose() * b - Matrix3::identity()).amax()
            );
        }
    }
}

#[test]
fn cold_start_refuses_instead_of_switching_branch() {
    let g = SpmGeometry::nominal();
    // Link angles far outside the workspace drive the straight path through a singularity.
    match g.fk_cold(&[80f64, -80.0, 80.0].map(f64::to_radians)) {
        Err(EyeError::NearSingular { .. }) | Err(EyeError::FkFailed(_)) => {}
        Ok(sol) => {
            // If it does solve, it must be the working-mode branch: IK gives the input back.
            let th = g.ik(&sol.r).unwrap();
            assert!((th[0].to_degrees() - 80.0).abs() < 1e-6, "{th:?}");
        }
        Err(e) => panic!("unexpected {e}"),
    }
}
