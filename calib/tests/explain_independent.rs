//! The discrepancy workflow on data the project did not make: hidden-effect datasets of an
//! independent simulator written from shared/spec alone (`calib/tests/independent/`, Python and
//! numpy, its own kinematics and its own forms of the effects: read heads 120 deg apart on the
//! wheel, one common encoder scale, backlash as a platform lag, a 3-cycle reading ripple outside
//! the library). Family `dev` was used while developing the workflow; family `final` was held out
//! of every choice and run once at the end (README, "Discrepancy workflow"). Round 2 (`dev2`,
//! held-out `final2`, see the generator's README) adds larger ripples of any cycle count,
//! backlash in each link's reading, sizes beyond effects.md's range and three effects together.
//! Round 3 (`dev3`, held-out `final3`, run once at the end) adds backlash as the platform settling
//! about each leg's hinge axis, a ripple with its second harmonic, a drift of the measured
//! orientation, and a library effect under a drift. CI runs `final2` and `final3`.
//!
//! Each set: 4,851 samples on the paper's 3 deg grid, noise 0.01 deg / 0.05 mm, explained from
//! the default start (nothing given), except `link_angle_error_hidden`, which starts from the
//! other geometric effects so that the hidden one can be searched.
use abvs_calib::explain::{explain, ExplainOptions, ExplainResult, KNOWN_GEOMETRIC};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, UnitModel};
use std::path::PathBuf;

fn dir(family: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/independent/data").join(family)
}

/// The generator's truth.json of a family (a missing file fails).
fn truth_json(family: &str) -> serde_json::Value {
    let path = dir(family).join("truth.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap()
}

/// The hidden effects of a set.
fn hidden(family: &str, set: &str) -> (Vec<String>, Option<String>) {
    let t = truth_json(family);
    let s = &t["sets"][set];
    assert!(s.is_object(), "{set} missing from {family}/truth.json");
    let names = s["hidden"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_string()).collect();
    (names, s["hidden_geometric"].as_str().map(String::from))
}

fn run(family: &str, set: &str) -> (Vec<String>, Option<String>, ExplainResult) {
    let (names, geometric) = hidden(family, set);
    let data = Dataset::read(&dir(family).join(format!("{set}.csv"))).unwrap();
    assert_eq!(data.len(), 4851, "{set}");
    let mut start = UnitModel::nominal();
    if let Some(g) = &geometric {
        let g = Effect::from_name(g).unwrap();
        for e in KNOWN_GEOMETRIC.iter().filter(|e| **e != g) {
            start.set_enabled(*e, true);
        }
    }
    let verbose = std::env::var_os("ABVS_PROGRESS").is_some();
    let t0 = std::time::Instant::now();
    let r = explain(&start, &data, &ExplainOptions::default(), &mut |m| {
        if verbose {
            eprintln!("  {m}")
        }
    })
    .unwrap();
    let secs = t0.elapsed().as_secs_f64();
    // Sizes as pose signatures (RMS rotation each effect contributes, deg): the generator's own
    // parameterisations differ from ours, the pose change they cause does not.
    let truth = truth_json(family);
    let per = &truth["sets"][set]["hidden_effect_pose_change_per_effect"];
    let named: Vec<String> = r
        .steps
        .iter()
        .map(|s| {
            let t = per[s.effect.as_str()]["rms_rot_deg"]
                .as_f64()
                .or_else(|| truth["sets"][set]["hidden_effect_pose_change"]["rms_rot_deg"].as_f64())
                .unwrap_or(f64::NAN);
            let form = s.form.as_deref().map(|f| format!(" as {f}")).unwrap_or_default();
            format!("{}{form} (signature {:.4} deg, truth {:.4})", s.effect, s.signature_rms_rot_deg, t)
        })
        .collect();
    eprintln!(
        "{family}/{set}: hidden {names:?} {geometric:?} named {named:?} ambiguous {:?} unexplained {:?} held-out rot {:.4} -> {:.4} deg, floor {:.4} ({:.2}x), {secs:.1} s",
        r.ambiguous.iter().map(|a| &a.effects).collect::<Vec<_>>(),
        r.unexplained.iter().map(|u| &u.description).collect::<Vec<_>>(),
        r.initial_rms.0,
        r.final_rms.0,
        r.noise_floor_rot_deg,
        r.final_rms.0 / r.noise_floor_rot_deg
    );
    (names, geometric, r)
}

/// Every hidden library effect named, nothing else named, no ambiguity, the held-out rotation
/// residual within 1.2x of the floor.
fn assert_named(family: &str, set: &str) {
    let (names, geometric, r) = run(family, set);
    let mut want: Vec<String> = names.into_iter().chain(geometric).collect();
    want.sort();
    want.dedup();
    let mut got: Vec<String> = r.steps.iter().map(|s| s.effect.clone()).collect();
    got.sort();
    assert_eq!(got, want, "{family}/{set}: ambiguous {:?}", r.ambiguous.iter().map(|a| &a.effects).collect::<Vec<_>>());
    assert!(r.ambiguous.is_empty(), "{family}/{set}: {:?}", r.ambiguous.iter().map(|a| &a.effects).collect::<Vec<_>>());
    assert!(
        r.final_rms.0 < 1.2 * r.noise_floor_rot_deg,
        "{family}/{set}: {} vs floor {}",
        r.final_rms.0,
        r.noise_floor_rot_deg
    );
    assert!(
        r.unexplained.is_empty(),
        "{family}/{set}: {:?}",
        r.unexplained.iter().map(|u| &u.description).collect::<Vec<_>>()
    );
}

fn assert_null(family: &str) {
    let (_, _, r) = run(family, "null");
    assert!(r.steps.is_empty() && r.ambiguous.is_empty() && r.unexplained.is_empty());
    assert!(r.final_rms.0 < 1.2 * r.noise_floor_rot_deg);
}

/// The 3-cycle reading ripple is outside the library: nothing is named, the structure is
/// reported as periodic in the rippled link.
fn assert_outside(family: &str) {
    let (_, _, r) = run(family, "ripple3");
    let t = truth_json(family);
    let link = t["sets"]["ripple3"]["hidden_effects"]["outside:ripple3"]["link"].as_u64().unwrap();
    assert!(r.steps.is_empty(), "{family}: named {:?}", r.steps.iter().map(|s| &s.effect).collect::<Vec<_>>());
    assert_eq!(r.unexplained.len(), 1, "{family}");
    let d = &r.unexplained[0].description;
    assert!(d.contains(&format!("periodic in theta{link}")), "{family}: {d}");
}

/// A common encoder scale hidden with the eccentricity: the per-head eccentricity (free head
/// phases) absorbs a common scale up to a cubic term the data barely show, so the pair is not
/// always separated. What must hold: nothing is named that is not hidden, and what is not named
/// is reported (ambiguity or unexplained structure), never silently dropped.
fn assert_no_false_name(family: &str, set: &str) {
    let (names, _, r) = run(family, set);
    for s in &r.steps {
        assert!(names.contains(&s.effect), "{family}/{set}: {} named, hidden {names:?}", s.effect);
    }
    if r.steps.len() < names.len() {
        assert!(!r.ambiguous.is_empty() || !r.unexplained.is_empty(), "{family}/{set}: a hidden effect vanished");
    }
}

macro_rules! family {
    ($m:ident, $f:literal $(, #[$a:meta])?) => {
        mod $m {
            use super::*;
            #[test]
            $(#[$a])?
            fn null_adds_nothing() {
                assert_null($f);
            }
            #[test]
            $(#[$a])?
            fn input_axis_tilt() {
                assert_named($f, "input_axis_tilt");
            }
            #[test]
            $(#[$a])?
            fn code_wheel_eccentricity() {
                assert_named($f, "code_wheel_eccentricity");
            }
            #[test]
            $(#[$a])?
            fn encoder_scale() {
                assert_named($f, "encoder_scale");
            }
            #[test]
            $(#[$a])?
            fn hinge_backlash_as_platform_lag() {
                assert_named($f, "hinge_backlash");
            }
            #[test]
            $(#[$a])?
            fn gravity_sag() {
                assert_named($f, "gravity_sag");
            }
            #[test]
            $(#[$a])?
            fn link_angle_error_from_a_start_without_it() {
                assert_named($f, "link_angle_error_hidden");
            }
            #[test]
            $(#[$a])?
            fn eccentricity_and_sag_together() {
                assert_named($f, "eccentricity_plus_sag");
            }
            #[test]
            $(#[$a])?
            fn backlash_and_tilt_together() {
                assert_named($f, "backlash_plus_tilt");
            }
            #[test]
            $(#[$a])?
            fn ripple_outside_the_library_is_unexplained() {
                assert_outside($f);
            }
            #[test]
            $(#[$a])?
            fn scale_and_eccentricity_together_name_nothing_false() {
                assert_no_false_name($f, "scale_plus_eccentricity");
            }
        }
    };
}

// The development families were tuned on; CI runs the newest held-out ones (a clean CI's time is
// bounded): run these by hand with `cargo test --release -p abvs-calib --test explain_independent -- --ignored`.
family!(dev, "dev", #[ignore = "development family (tuned on): run by hand with --ignored"]);
// Round 1's held-out family made room in CI for round 3's. Its cases stay in CI through final2, final3
// and explain.rs (the null unit, a hidden link_angle_error), except the generator's platform-lag
// backlash, which dev and final keep covering by hand.
family!(held_out_final, "final", #[ignore = "oldest held-out family, out of CI for time: run by hand with --ignored"]);

/// Round 2 (families `dev2`, `final2`): larger outside ripples of any cycle count, backlash in
/// each link's reading, sizes beyond effects.md's range, three effects together. Every hidden
/// library effect named, nothing else named or left ambiguous, an outside ripple reported with
/// its link and cycle count (amplitude within 30%), the floor reached (1.2x) where everything
/// hidden is in the library.
fn assert_round2(family: &str, set: &str) -> ExplainResult {
    let (names, _, r) = run(family, set);
    let library: Vec<&String> = names.iter().filter(|n| !n.starts_with("outside:")).collect();
    let mut got: Vec<&String> = r.steps.iter().map(|s| &s.effect).collect();
    got.sort();
    let mut want = library.clone();
    want.sort();
    let amb: Vec<&Vec<String>> = r.ambiguous.iter().map(|a| &a.effects).collect();
    assert_eq!(got, want, "{family}/{set}: ambiguous {amb:?}");
    assert!(amb.is_empty(), "{family}/{set}: ambiguous {amb:?}");
    let t = truth_json(family);
    let outside: Vec<&serde_json::Value> =
        names.iter().filter(|n| n.starts_with("outside:")).map(|n| &t["sets"][set]["hidden_effects"][n]).collect();
    // Ripples: link, cycle count (the fundamental's), amplitude; drifts are checked by round 3.
    for o in outside.iter().filter(|o| o["link"].is_u64()) {
        let (link, cycles, amp) = (
            o["link"].as_u64().unwrap() as usize,
            o["cycles_per_rev"].as_u64().unwrap() as usize,
            o["size"].as_f64().unwrap(),
        );
        let h = r.unexplained.iter().find_map(|u| u.ripple);
        let h = h.unwrap_or_else(|| panic!("{family}/{set}: no ripple reported: {:?}", r.unexplained));
        assert_eq!((h.link + 1, h.cycles), (link, cycles), "{family}/{set}");
        assert!((h.amplitude_deg / amp - 1.0).abs() < 0.3, "{family}/{set}: amplitude {} vs {amp}", h.amplitude_deg);
    }
    if outside.is_empty() {
        assert!(
            r.final_rms.0 < 1.2 * r.noise_floor_rot_deg,
            "{family}/{set}: {} vs floor {}",
            r.final_rms.0,
            r.noise_floor_rot_deg
        );
        assert!(r.unexplained.is_empty(), "{family}/{set}: {:?}", r.unexplained);
    }
    r
}

/// A size beyond effects.md's range is named with a warning (not dropped, not left ambiguous).
fn assert_beyond_range(family: &str, set: &str) {
    let r = assert_round2(family, set);
    assert!(r.steps.iter().any(|s| s.warning.is_some()), "{family}/{set}: no warning");
}

macro_rules! family2 {
    ($m:ident, $f:literal $(, #[$a:meta])?) => {
        mod $m {
            use super::*;
            #[test]
            $(#[$a])?
            fn large_ripple_names_nothing_and_is_reported() {
                assert_round2($f, "ripple_large");
            }
            #[test]
            $(#[$a])?
            fn backlash_in_each_link_reading() {
                assert_round2($f, "link_backlash");
            }
            #[test]
            $(#[$a])?
            fn scale_beyond_the_range_named_with_a_warning() {
                assert_beyond_range($f, "scale_beyond_range");
            }
            #[test]
            $(#[$a])?
            fn scale_and_eccentricity_separated() {
                assert_round2($f, "scale_plus_eccentricity");
            }
            #[test]
            $(#[$a])?
            fn tilt_eccentricity_and_sag() {
                assert_round2($f, "tilt_eccentricity_sag");
            }
            #[test]
            $(#[$a])?
            fn backlash_scale_and_tilt() {
                assert_round2($f, "backlash_scale_tilt");
            }
            #[test]
            $(#[$a])?
            fn ripple_on_top_of_a_tilt() {
                assert_round2($f, "ripple_plus_tilt");
            }
        }
    };
}

family2!(dev2, "dev2", #[ignore = "development family (tuned on): run by hand with --ignored"]);
family2!(held_out_final2, "final2");

/// Round 3 (families `dev3`, `final3`): backlash as the platform settling about each leg's hinge
/// axis, a ripple with its second harmonic, a drift of the measured orientation over the session,
/// three effects with the hinge form, a library effect under a drift. As round 2, and: the
/// hinge_backlash form fitted is the one hidden; a ripple's second harmonic and a drift are
/// reported with their sizes (within 30%).
fn assert_round3(family: &str, set: &str) {
    let r = assert_round2(family, set);
    let (names, _) = hidden(family, set);
    let t = truth_json(family);
    let h = &t["sets"][set]["hidden_effects"];
    if names.iter().any(|n| n == "hinge_backlash") {
        assert_eq!(h["hinge_backlash"]["model"], "hinge_lag");
        let s = r.steps.iter().find(|s| s.effect == "hinge_backlash").expect("named");
        let form = s.form.as_deref().unwrap_or("");
        assert!(form.contains("hinge_lag_deg"), "{family}/{set}: fitted as {form}");
    }
    if names.iter().any(|n| n == "outside:ripple_harmonic") {
        let want = h["outside:ripple_harmonic"]["harmonic"]["amplitude_deg"].as_f64().unwrap();
        let got = r.unexplained.iter().find_map(|u| u.ripple).and_then(|h| h.second_harmonic_deg);
        let got = got.unwrap_or_else(|| panic!("{family}/{set}: no second harmonic reported: {:?}", r.unexplained));
        assert!((got / want - 1.0).abs() < 0.3, "{family}/{set}: second harmonic {got} vs {want}");
    }
    if names.iter().any(|n| n == "outside:drift") {
        let want = h["outside:drift"]["size"].as_f64().unwrap();
        let got = r.unexplained.iter().find_map(|u| u.drift_deg);
        let got = got.unwrap_or_else(|| panic!("{family}/{set}: no drift reported: {:?}", r.unexplained));
        assert!((got / want - 1.0).abs() < 0.3, "{family}/{set}: drift {got} vs {want} deg");
    }
}

macro_rules! family3 {
    ($m:ident, $f:literal $(, #[$a:meta])?) => {
        mod $m {
            use super::*;
            #[test]
            $(#[$a])?
            fn backlash_at_the_platform_hinges() {
                assert_round3($f, "hinge_backlash_at_hinges");
            }
            #[test]
            $(#[$a])?
            fn ripple_with_its_second_harmonic() {
                assert_round3($f, "ripple_with_harmonic");
            }
            #[test]
            $(#[$a])?
            fn drift_names_nothing_and_is_reported() {
                assert_round3($f, "drift");
            }
            #[test]
            $(#[$a])?
            fn hinge_backlash_eccentricity_and_sag() {
                assert_round3($f, "hinge_backlash_eccentricity_sag");
            }
            #[test]
            $(#[$a])?
            fn scale_under_a_drift() {
                assert_round3($f, "scale_under_drift");
            }
        }
    };
}

family3!(dev3, "dev3", #[ignore = "development family (tuned on): run by hand with --ignored"]);
family3!(held_out_final3, "final3");
