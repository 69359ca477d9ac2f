//! Runs the discrepancy workflow with the default start on dataset files and prints what it
//! named, for development: `cargo run -p abvs-calib --example explain_probe -- A.csv B.csv`.
use abvs_calib::explain::{explain, ExplainOptions};
use abvs_eye::dataset::Dataset;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::Effect;
use abvs_eye::UnitModel;

/// `sim:effect+effect:seed`: our own simulator's unit with the geometric effects plus these.
fn load(path: &str) -> Dataset {
    let Some(spec) = path.strip_prefix("sim:") else {
        return Dataset::read(std::path::Path::new(path)).expect("dataset");
    };
    let (effs, seed) = spec.rsplit_once(':').expect("sim:effects:seed");
    let mut on = vec![
        Effect::EncoderZeroOffset,
        Effect::LinkAngleError,
        Effect::PlatformAxisError,
        Effect::CameraMount,
        Effect::MeasurementNoise,
    ];
    on.extend(effs.split('+').filter(|s| !s.is_empty()).map(|s| Effect::from_name(s).unwrap()));
    let seed: u64 = seed.parse().unwrap();
    let mut unit = draw_unit(seed, &on);
    unit.effects.measurement_noise.rot_deg = 0.01;
    unit.effects.measurement_noise.trans_mm = 0.05;
    let spec = SimSpec { commanded: Commanded::Step(3.0), dropout: 0.0, seed, ..Default::default() };
    simulate_dataset(&unit, &spec, |_, _| {}).unwrap().0
}

fn main() {
    for path in std::env::args().skip(1) {
        let data = load(&path);
        let t0 = std::time::Instant::now();
        let r = explain(&UnitModel::nominal(), &data, &ExplainOptions::default(), &mut |_| {});
        let r = match r {
            Ok(r) => r,
            Err(e) => {
                println!("{path}: error {e}");
                continue;
            }
        };
        println!(
            "{path}: {:.1}s floor {:.4}/{:.4} initial {:.4}/{:.4} final {:.4}/{:.4} ({:.2}x) named {:?} ambiguous {:?} unexplained {:?} bounds {:?}",
            t0.elapsed().as_secs_f64(),
            r.noise_floor_rot_deg,
            r.noise_floor_trans_mm,
            r.initial_rms.0,
            r.initial_rms.1,
            r.final_rms.0,
            r.final_rms.1,
            r.final_rms.0 / r.noise_floor_rot_deg,
            r.steps.iter().map(|s| (s.effect.clone(), (s.signature_rms_rot_deg * 1e4).round() / 1e4)).collect::<Vec<_>>(),
            r.ambiguous.iter().map(|a| a.effects.clone()).collect::<Vec<_>>(),
            r.unexplained.iter().map(|u| u.description.clone()).collect::<Vec<_>>(),
            r.at_bounds.iter().map(|b| b.param.clone()).collect::<Vec<_>>()
        );
        for n in &r.start_notes {
            println!("   note: {n}");
        }
        for a in &r.ambiguous {
            println!("   ambiguous: {}", a.evidence);
        }
        for c in &r.final_candidates {
            println!(
                "   last: {:<24} k={} score {:.4} share {:.2} {} {}",
                c.effect, c.params_added, c.score, c.excess_fraction, c.significant, c.note
            );
        }
        for s in &r.steps {
            for c in &s.candidates {
                println!(
                    "   step {}: {:<24} k={} score {:.4} share {:.2} {} {}",
                    s.effect, c.effect, c.params_added, c.score, c.excess_fraction, c.significant, c.note
                );
            }
        }
    }
}
