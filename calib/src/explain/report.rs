//! The discrepancy report: summary.json (machine-readable) and report.md (for people), plus the
//! evidence line of each named effect.
use super::structure::periodic;
use super::{CandidateScore, ExplainResult};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, MotionHistory};

/// The variable that shows an effect best, for evidence and plots.
pub fn explaining_variable(e: Effect) -> &'static str {
    match e {
        Effect::HingeBacklash => "direction of approach",
        Effect::CodeWheelEccentricity => "link angle (once per revolution)",
        Effect::EncoderScale | Effect::EncoderZeroOffset => "link angle",
        Effect::GravitySag => "gravity direction in the platform frame",
        _ => "workspace position (alpha x gamma)",
    }
}

pub(super) fn evidence(e: Effect, data: &Dataset, before: &[[f64; 6]], after: &[[f64; 6]]) -> String {
    let rot = |r: &[f64; 6]| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    match e {
        Effect::HingeBacklash => {
            // Mean rotation residual for samples approached from + vs - on each link.
            let mut hist = MotionHistory::new();
            let mut txt = vec![];
            let dirs: Vec<[f64; 3]> = data.samples.iter().map(|s| hist.update(&s.theta_deg)).collect();
            for l in 0..3 {
                let mean = |sign: f64, res: &[[f64; 6]]| {
                    let v: Vec<f64> =
                        dirs.iter().zip(res).filter(|(d, _)| d[l] == sign).map(|(_, r)| r[0] + r[1] + r[2]).collect();
                    v.iter().sum::<f64>() / v.len().max(1) as f64
                };
                txt.push(format!(
                    "link {}: mean residual + vs - approach {:+.4} / {:+.4} deg before, {:+.4} / {:+.4} after",
                    l + 1,
                    mean(1.0, before),
                    mean(-1.0, before),
                    mean(1.0, after),
                    mean(-1.0, after)
                ));
            }
            format!("residual depends on the direction of approach ({})", txt.join("; "))
        }
        Effect::CodeWheelEccentricity | Effect::EncoderScale | Effect::EncoderZeroOffset => {
            let (b, a) = (periodic(data, before, 1), periodic(data, after, 1));
            format!("residual vs link angle: once-per-revolution component {:.4} deg before, {:.4} deg after", b.0, a.0)
        }
        _ => {
            let (b, a): (f64, f64) =
                (before.iter().map(rot).fold(0.0, f64::max), after.iter().map(rot).fold(0.0, f64::max));
            format!(
                "structured residual over the {}: max held-out rotation residual {:.4} deg before, {:.4} deg after",
                explaining_variable(e),
                b,
                a
            )
        }
    }
}

/// summary.json.
pub fn summary_json(r: &ExplainResult) -> serde_json::Value {
    serde_json::json!({
        "noise_floor": {"rot_deg": r.noise_floor_rot_deg, "trans_mm": r.noise_floor_trans_mm, "method": r.noise_method},
        "start": {"default": r.default_start, "known_model": r.known_model, "notes": r.start_notes},
        "initial": {"rms_rot_deg": r.initial_rms.0, "rms_trans_mm": r.initial_rms.1},
        "final": {
            "rms_rot_deg": r.final_rms.0,
            "rms_trans_mm": r.final_rms.1,
            "rot_vs_floor": r.final_rms.0 / r.noise_floor_rot_deg,
            "trans_vs_floor": r.final_rms.1 / r.noise_floor_trans_mm,
        },
        "named": r.steps.iter().map(|s| s.effect.clone()).collect::<Vec<_>>(),
        "steps": r.steps.iter().map(|s| serde_json::json!({
            "effect": s.effect,
            "form": s.form,
            "params": s.params,
            "std_errors": s.std_errors,
            "score": s.score,
            "joint_with": s.joint_with,
            "signature_rms_rot_deg": s.signature_rms_rot_deg,
            "rms_rot_deg_before": s.rms_rot_deg_before,
            "rms_rot_deg_after": s.rms_rot_deg_after,
            "rms_trans_mm_before": s.rms_trans_mm_before,
            "rms_trans_mm_after": s.rms_trans_mm_after,
            "evidence": s.evidence,
            "candidates": s.candidates,
        })).collect::<Vec<_>>(),
        "ambiguous": r.ambiguous,
        "at_bounds": r.at_bounds,
        "final_candidates": r.final_candidates,
        "unexplained": r.unexplained,
        "held_parameters": r.held,
    })
}

fn table(cands: &[CandidateScore]) -> String {
    let mut t = String::from(
        "| effect | params | score alone | share of structured misfit alone | named | note |\n| --- | --- | --- | --- | --- | --- |\n",
    );
    for c in cands {
        t += &format!(
            "| {} | {} | {:.4} | {:.0}% | {} | {} |\n",
            c.effect,
            c.params_added,
            c.score,
            100.0 * c.excess_fraction,
            if c.significant { "yes" } else { "no" },
            c.note
        );
    }
    t
}

/// report.md: what was found, with the numbers and the plots' file names.
pub fn report_markdown(r: &ExplainResult, data_name: &str, plots: &[(String, String)]) -> String {
    let mut s = format!(
        "# Discrepancy report: {data_name}\n\n\
         Noise floor (per-sample RMS of the measurement noise): {:.4} deg, {:.4} mm ({}).\n\n",
        r.noise_floor_rot_deg, r.noise_floor_trans_mm, r.noise_method
    );
    s += &format!("## Start\n\nKnown model: {}.\n\n", r.known_model.join(", "));
    for n in &r.start_notes {
        s += &format!("- {n}\n");
    }
    s += &format!(
        "\nHeld-out RMS of the known model (3-fold cross-validation): {:.4} deg, {:.4} mm.\n\n",
        r.initial_rms.0, r.initial_rms.1
    );
    if r.steps.is_empty() && r.ambiguous.is_empty() {
        s += "No effect of the library explains a significant part of the held-out residual: nothing was added.\n\n";
    }
    for (i, st) in r.steps.iter().enumerate() {
        s += &format!("## Step {}: {}\n\n", i + 1, st.effect);
        if let Some(f) = &st.form {
            s += &format!("Fitted as {f} (the form the held-out data support best).\n\n");
        }
        if let Some(w) = &st.warning {
            s += &format!("**Warning:** {w}.\n\n");
        }
        if !st.joint_with.is_empty() {
            s += &format!("Named jointly with {} (the set was chosen as a whole).\n\n", st.joint_with.join(", "));
        }
        s += &format!(
            "Held-out RMS {:.4} -> {:.4} deg, {:.4} -> {:.4} mm; the effect contributes {:.4} deg rms over the dataset.\n\nEvidence: {}\n\n",
            st.rms_rot_deg_before,
            st.rms_rot_deg_after,
            st.rms_trans_mm_before,
            st.rms_trans_mm_after,
            st.signature_rms_rot_deg,
            st.evidence
        );
        s += "| parameter | value | std. error |\n| --- | --- | --- |\n";
        for (k, v) in &st.params {
            s += &format!("| {k} | {v:.5} | {:.5} |\n", st.std_errors.get(k).copied().unwrap_or(f64::NAN));
        }
        s += "\nCandidates (held-out cross-validation, linearised around the model of this round):\n\n";
        s += &table(&st.candidates);
        for (title, file) in plots.iter().filter(|p| p.0.starts_with(&format!("step {}:", i + 1))) {
            s += &format!("\n![{title}]({file})\n");
        }
        s += "\n";
    }
    for a in &r.ambiguous {
        s += &format!("## Ambiguous between {}\n\n{}\n\n", a.effects.join(" and "), a.evidence);
        s += &format!(
            "The model carries {} for now. To separate them, measure where their predictions differ most:\n\n\
             | commanded alpha, beta, gamma (deg) | approach | gravity in B | difference (deg) |\n| --- | --- | --- | --- |\n",
            a.effects[0]
        );
        for p in &a.separating {
            s += &format!(
                "| {:.0}, {:.0}, {:.0} | {} | {:.2}, {:.2}, {:.2} | {:.4} |\n",
                p.cmd_deg[0],
                p.cmd_deg[1],
                p.cmd_deg[2],
                p.approach,
                p.gravity[0],
                p.gravity[1],
                p.gravity[2],
                p.difference_deg
            );
        }
        s += "\n";
    }
    s += "## Last round\n\n";
    s += &table(&r.final_candidates);
    s += &format!(
        "\nFinal held-out RMS {:.4} deg ({:.2}x the floor), {:.4} mm ({:.2}x).\n\n",
        r.final_rms.0,
        r.final_rms.0 / r.noise_floor_rot_deg,
        r.final_rms.1,
        r.final_rms.1 / r.noise_floor_trans_mm
    );
    if !r.at_bounds.is_empty() {
        s += "## Parameters at a plausibility bound\n\n| parameter | value | bound | probably absorbing |\n| --- | --- | --- | --- |\n";
        for b in &r.at_bounds {
            s += &format!("| {} | {:.4} | {:.4} | {} |\n", b.param, b.value, b.bound, b.absorbing);
        }
        s += "\n";
    }
    if !r.unexplained.is_empty() {
        s += "## Unexplained structure\n\n";
        for u in &r.unexplained {
            s += &format!("- {} (held-out rotation RMS {:.4} deg)\n", u.description, u.rms_rot_deg);
        }
        s += "\nNo effect of the library fits this pattern; it is reported, not forced onto a name.\n\n";
    }
    if !r.held.is_empty() {
        s +=
            &format!("Parameters the data cannot separate (held at their starting values): {}.\n\n", r.held.join(", "));
    }
    for (title, file) in plots.iter().filter(|p| !p.0.starts_with("step ")) {
        s += &format!("![{title}]({file})\n\n");
    }
    s += "The final unit model is `unit.toml` (loadable by `abvs kin fk --unit`, `abvs sim dataset --unit`).\n";
    s
}
