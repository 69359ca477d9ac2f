//! Physics identification on simulated units: the fit reaches the noise floor, recovers what the
//! data determine, and holds (does not fit to noise) what they cannot.
use abvs_calib::identify::{fit_unit, residuals, rms, static_effects, FitOptions};
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::{Effect, UnitModel};

#[test]
fn hand_eye_fits_camera_mount_exactly_when_that_is_all_there_is() {
    let mut unit = draw_unit(5, &[Effect::CameraMount, Effect::MeasurementNoise]);
    unit.effects.measurement_noise.rot_deg = 0.01;
    unit.effects.measurement_noise.trans_mm = 0.05;
    let spec = SimSpec { commanded: Commanded::PerAxis(5), dropout: 0.0, ..Default::default() };
    let (data, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let fit = fit_unit(&UnitModel::nominal(), &[Effect::CameraMount], &data, &FitOptions::default()).unwrap();
    assert!(fit.held.is_empty(), "{:?}", fit.held);
    let got = fit.unit.params(Effect::CameraMount);
    let want = unit.params(Effect::CameraMount);
    for k in 0..6 {
        assert!(
            (got[k] - want[k]).abs() < 5.0 * fit.std_error[k] + 1e-3,
            "{k}: {got:?} vs {want:?} (se {:?})",
            fit.std_error
        );
    }
    assert!(fit.rms_rot_deg < 0.02 && fit.rms_trans_mm < 0.1, "{} {}", fit.rms_rot_deg, fit.rms_trans_mm);
}

#[test]
fn full_physics_reaches_the_noise_floor_from_343_samples() {
    let unit = UnitModel::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../fixtures/units/c1.toml")))
        .unwrap();
    let spec = SimSpec { commanded: Commanded::PerAxis(7), dropout: 0.0, ..Default::default() };
    let (data, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let start = rms(&residuals(&UnitModel::nominal(), &data).unwrap());
    let fit = fit_unit(&UnitModel::nominal(), &static_effects(), &data, &FitOptions::default()).unwrap();
    let floor =
        (3f64.sqrt() * unit.effects.measurement_noise.rot_deg, 3f64.sqrt() * unit.effects.measurement_noise.trans_mm);
    eprintln!(
        "start {start:?} -> fit ({}, {}), floor {floor:?}, held {}",
        fit.rms_rot_deg,
        fit.rms_trans_mm,
        fit.held.len()
    );
    for h in &fit.held {
        eprintln!("held {} (se {:.3e}) with {:?}", h.name, h.std_error, h.confounded_with);
    }
    assert!(!fit.held.is_empty(), "a 38-parameter model has confounded parameters");
    assert!(fit.rms_rot_deg < 1.3 * floor.0 && fit.rms_trans_mm < 1.3 * floor.1);
}
