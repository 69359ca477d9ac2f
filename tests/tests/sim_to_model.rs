//! Across crates and files: a simulated session written to disk, read back, and explained by the
//! same unit model that generated it, down to the measurement noise and no further.
use abvs_eye::dataset::Dataset;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{Pose, UnitModel};
use std::path::Path;

fn fixture(name: &str) -> UnitModel {
    UnitModel::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/units").join(name)).unwrap()
}

#[test]
fn residual_of_the_true_model_is_the_measurement_noise() {
    let unit = fixture("c2.toml");
    // No dropout: a failed measurement leaves no row, so the direction a link approached the next
    // sample from (hinge_backlash) is then only known up to the missing pose.
    let spec = SimSpec { commanded: Commanded::Step(4.0), seed: 11, dropout: 0.0, ..Default::default() };
    let (data, stats) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c2.csv");
    data.write(&path).unwrap();
    let back = Dataset::read(&path).unwrap();
    assert_eq!(back, data, "dataset must round-trip exactly");
    assert_eq!(back.content_hash(), data.content_hash());
    assert_eq!(stats.written, back.len());

    let pred = unit.compile().unwrap().predict_dataset(&back).unwrap();
    let (mut rot2, mut tr2) = (0.0, 0.0);
    for (p, s) in pred.iter().zip(&back.samples) {
        let (a, b) = (Pose::from_p6(p), Pose::from_p6(&s.pose));
        rot2 += rotation_angle_deg(&a.r, &b.r).powi(2);
        tr2 += (a.t - b.t).norm_squared();
    }
    let n = back.len() as f64;
    let (rms_rot, rms_tr) = ((rot2 / n).sqrt(), (tr2 / n).sqrt());
    // Isotropic 3-axis noise: the rms of the norm is sqrt(3) sigma (within sampling error).
    let (sr, st) = (unit.effects.measurement_noise.rot_deg, unit.effects.measurement_noise.trans_mm);
    let want_r = 3f64.sqrt() * sr;
    let want_t = 3f64.sqrt() * st;
    assert!((rms_rot / want_r - 1.0).abs() < 0.1, "rot rms {rms_rot} vs {want_r}");
    assert!((rms_tr / want_t - 1.0).abs() < 0.1, "trans rms {rms_tr} vs {want_t}");

    // The nominal model misses the unit by far more than the noise.
    let nominal = UnitModel::nominal().compile().unwrap().predict_dataset(&back).unwrap();
    let worst = nominal
        .iter()
        .zip(&back.samples)
        .map(|(p, s)| rotation_angle_deg(&Pose::from_p6(p).r, &Pose::from_p6(&s.pose).r))
        .fold(0.0, f64::max);
    assert!(worst > 50.0 * want_r, "{worst}");
}
