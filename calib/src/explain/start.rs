//! The starting model. Without one, every real unit has the geometric effects
//! (encoder_zero_offset, link_angle_error, platform_axis_error, camera_mount): they are the
//! known model, fitted before any search. Good starting values come in stages: the hand-eye
//! part (camera_mount) first, on the nominal mechanism, then all the geometry from there; where
//! the joint fit fails, a continuation adds the effects one at a time, each from the last.
use crate::error::{CalibError, Result};
use crate::identify::{fit_params, params_of, FitOptions, FitResult, Param};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, UnitModel};

/// The effects every real unit has, fitted as the known model when none is given.
pub const KNOWN_GEOMETRIC: [Effect; 4] =
    [Effect::EncoderZeroOffset, Effect::LinkAngleError, Effect::PlatformAxisError, Effect::CameraMount];

pub struct Start {
    pub unit: UnitModel,
    /// Identifiable parameters of the known model.
    pub free: Vec<Param>,
    pub known: Vec<Effect>,
    pub default_start: bool,
    /// How the start was reached, for the report.
    pub notes: Vec<String>,
}

fn opts(sigma: (f64, f64), max_iter: usize, fit_all: bool) -> FitOptions {
    FitOptions { sigma_rot_deg: sigma.0, sigma_trans_mm: sigma.1, max_iter, fit_all, ..FitOptions::default() }
}

fn fmt_fit(f: &FitResult) -> String {
    format!("{:.4} deg, {:.4} mm rms", f.rms_rot_deg, f.rms_trans_mm)
}

pub fn fit_start(
    start: &UnitModel,
    data: &Dataset,
    sigma: (f64, f64),
    progress: &mut dyn FnMut(&str),
) -> Result<Start> {
    let mut unit = start.clone();
    let mut known: Vec<Effect> = unit.enabled_effects().into_iter().filter(|e| e.is_kinematic()).collect();
    let default_start = known.is_empty();
    let mut notes = vec![];
    if default_start {
        known = KNOWN_GEOMETRIC.to_vec();
        for e in known.iter() {
            unit.set_params(*e, &vec![0.0; e.param_names().len()])?;
            unit.set_enabled(*e, true);
        }
        notes.push(format!(
            "no starting model given: started from the nominal unit with the geometric effects every real unit has ({}) as the known model",
            known.iter().map(|e| e.name()).collect::<Vec<_>>().join(", ")
        ));
    }
    // Stage 1: hand-eye on the nominal (or given) mechanism, when the mount is to be fitted
    // and starts at zero: it carries most of a unit's deviation (degrees, millimetres).
    if known.contains(&Effect::CameraMount) && unit.params(Effect::CameraMount).iter().all(|v| *v == 0.0) {
        progress("start: hand-eye (camera_mount) on the nominal mechanism");
        match fit_params(&unit, &params_of(&[Effect::CameraMount]), data, &opts(sigma, 30, false)) {
            Ok(f) => {
                notes.push(format!("hand-eye first (camera_mount): {}", fmt_fit(&f)));
                unit = f.unit;
            }
            Err(e) => notes.push(format!("hand-eye stage failed ({e}); starting the geometry from zero")),
        }
    }
    // Stage 2: the whole known model from there (identifiable parameters only).
    progress(&format!("start: fitting the known model ({} effects)", known.len()));
    let joint = fit_params(&unit, &params_of(&known), data, &opts(sigma, 60, false));
    let fit = match joint {
        Ok(f) => f,
        Err(e) => {
            // Continuation: one effect at a time, each fitted from the previous state.
            notes.push(format!("joint fit of the known model failed ({e}); continued one effect at a time"));
            let mut cur = unit.clone();
            let mut on: Vec<Effect> = vec![];
            let mut last: Option<FitResult> = None;
            for &e in &known {
                on.push(e);
                progress(&format!("start: continuation, + {e}"));
                match fit_params(&cur, &params_of(&on), data, &opts(sigma, 40, false)) {
                    Ok(f) => {
                        cur = f.unit.clone();
                        last = Some(f);
                    }
                    Err(err) => {
                        on.pop();
                        notes.push(format!(
                            "{e} could not be fitted from this start ({err}); left out of the known model"
                        ));
                    }
                }
            }
            last.ok_or_else(|| {
                CalibError::Data(format!("the known model ({known:?}) cannot be fitted to these data from any start"))
            })?
        }
    };
    if !fit.held.is_empty() {
        notes.push(format!(
            "held at their starting values (not determined by these data): {}",
            fit.held.iter().map(|h| h.name.clone()).collect::<Vec<_>>().join(", ")
        ));
    }
    notes.push(format!("known model fitted: {}", fmt_fit(&fit)));
    Ok(Start { unit: fit.unit, free: fit.free, known, default_start, notes })
}
