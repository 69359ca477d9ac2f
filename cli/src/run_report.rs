//! What `abvs run` prints at the end of a run (unless `--quiet`): the source, the engine, the latency table,
//! and a line for each sink that reported (the truth's side lane, the self-check, depth error by confidence
//! and by eye speed, the ROS 2 outputs).
use abvs_runtime::{Overload, Report};
use abvs_runtime_core::config::RuntimeConfig;

/// Prints the run's report on stdout.
pub fn print(c: &RuntimeConfig, r: &Report) {
    let stats = &r.stats;
    println!("session {} ({})", r.source, r.description);
    let d = &c.disparity;
    let check = match (d.confidence, d.lr_check) {
        (false, false) => String::new(),
        (conf, lr) => format!(
            ", left-right check ({}{}{}, {} px)",
            if conf { "confidence" } else { "" },
            if conf && lr { " + " } else { "" },
            if lr { "inconsistent pixels dropped" } else { "" },
            d.lr_max_diff
        ),
    };
    println!("engine {} at {}x{}{check}, fk {}", r.engine, d.width, d.height, c.calibration.fk.as_str());
    print!("{}", r.table());
    if let Some(o) = r.overload() {
        println!("{}", overload_hint(&o, &r.engine));
    }
    if let Some(v) = stats.extra.get("fovea") {
        let n = |f: &str| v[f].as_u64().unwrap_or(0);
        println!(
            "fovea {}x{}: on {} frames ({} gated), {} shed (its lane behind: published without a fovea)",
            v["window"][0].as_u64().unwrap_or(0),
            v["window"][1].as_u64().unwrap_or(0),
            n("frames"),
            n("gated"),
            n("shed_behind")
        );
    }
    if let Some(v) = stats.extra.get("truth_side_lane") {
        let n = |f: &str| v[f].as_u64().unwrap_or(0);
        println!(
            "depth error scored on {} of {} published frames (side lane at idle priority: {} skipped, {} \
             scored after the run)",
            n("frames_consumed"),
            n("frames_in"),
            n("frames_skipped"),
            n("drained_at_finish")
        );
    }
    if let Some(v) = stats.extra.get("self_check") {
        println!("{}", abvs_runtime::sinks::self_check::summary_line(v));
    }
    if let Some(v) = stats.extra.get("depth_error_by_confidence") {
        let part = |p: &serde_json::Value| {
            format!(
                "abs rel {:.2} %, rmse {:.1} mm ({} points)",
                p["abs_rel"].as_f64().unwrap_or(f64::NAN) * 100.0,
                p["rmse_m"].as_f64().unwrap_or(f64::NAN) * 1000.0,
                p["points"].as_u64().unwrap_or(0)
            )
        };
        let t = v["threshold"].as_f64().unwrap_or(f64::NAN);
        println!(
            "depth error vs truth by confidence: > {t:.1}: {}; <= {t:.1}: {}",
            part(&v["above"]),
            part(&v["at_most"])
        );
    }
    if let Some(serde_json::Value::Array(bands)) = stats.extra.get("depth_error_by_speed") {
        println!("depth error vs truth by eye speed (deg/s): frames scored / gated, abs rel, point error p50");
        for b in bands.iter().filter(|b| b["frames"].as_u64().unwrap_or(0) + b["gated"].as_u64().unwrap_or(0) > 0) {
            println!("{}", band_line(b));
        }
    }
    if let Some(g) = stats.extra.get("gaze").filter(|g| g.get("fixation_error_deg").is_some()) {
        let f = |k: &str, q: &str| g[k][q].as_f64().map_or("-".to_string(), |x| format!("{x:.4}"));
        let refused: u64 = g["refused"].as_object().map_or(0, |r| r.values().filter_map(|v| v.as_u64()).sum());
        println!(
            "gaze vs truth: {} goals ({} refused, {} settled), fixation error p50 {} max {} deg, settle p50 {} max {} \
             ms, pursuit error p50 {} max {} deg, {} frames gated for saccades",
            g["goals"].as_u64().unwrap_or(0),
            refused,
            g["settled"].as_u64().unwrap_or(0),
            f("fixation_error_deg", "p50"),
            f("fixation_error_deg", "max"),
            f("settle_ms", "p50"),
            f("settle_ms", "max"),
            f("pursuit_error_deg", "p50"),
            f("pursuit_error_deg", "max"),
            g["frames_gated_saccade"].as_u64().unwrap_or(0),
        );
    }
    for k in ["zenoh", "mcap"] {
        if let Some(v) = stats.extra.get(k) {
            let n = |f: &str| v[f].as_u64().unwrap_or(0);
            let err = v["last_error"].as_str().map(|e| format!(", first error: {e}")).unwrap_or_default();
            println!(
                "{k}: {} of {} frames written, {} dropped (queue full), {} failed{err}",
                n("frames_written"),
                n("frames_in"),
                n("frames_dropped"),
                n("frames_failed")
            );
        }
    }
}

/// One speed band of `depth_error_by_speed`: frames scored / gated, abs rel, point error p50; "-" where the
/// band scored no point (only gated frames): an empty band has no error, not a NaN one.
fn band_line(b: &serde_json::Value) -> String {
    let hi = b["deg_s"][1].as_f64().map_or("inf".to_string(), |h| format!("{h:.0}"));
    let num = |k: &str, scale: f64, unit: &str| match b[k].as_f64().filter(|x| x.is_finite()) {
        Some(x) => format!("{:>6.prec$} {unit}", x * scale, prec = if unit == "%" { 2 } else { 1 }),
        None => format!("{:>6} {unit}", "-"),
    };
    format!(
        "  [{:>3.0}, {hi:>3}): {:>3} / {:>3}  {}  {}",
        b["deg_s"][0].as_f64().unwrap_or(0.0),
        b["frames"].as_u64().unwrap_or(0),
        b["gated"].as_u64().unwrap_or(0),
        num("abs_rel", 100.0, "%"),
        num("point_mm_p50", 1.0, "mm")
    )
}

/// What to tell a user whose run dropped frames because the computer could not do a frame's work in a frame
/// period, with the lighter settings it has.
fn overload_hint(o: &Overload, engine: &str) -> String {
    format!(
        "CPU-bound: {} frames dropped with {:.2} of {} cores busy, idle-priority side lanes aside \
         ({:.1} ms of CPU per frame in all): \
         this computer cannot do this setting's work at this frame rate; lighter: {} \
         (runtime/BENCHMARKS.md, \"Real time on 2 cores\")",
        o.dropped,
        o.cores_busy,
        o.cores,
        o.ms_per_frame,
        Overload::lighter(engine)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_speed_band_prints_a_dash_not_nan() {
        // a band with only gated frames: no point scored, so no error (the JSON has nulls)
        let gated = serde_json::json!({"deg_s": [100.0, 300.0], "frames": 0, "gated": 4, "abs_rel": null,
                                       "point_mm_p50": null});
        let line = band_line(&gated);
        assert!(!line.contains("NaN") && line.contains("- %") && line.contains("- mm"), "{line}");
        let scored = serde_json::json!({"deg_s": [0.0, 5.0], "frames": 7, "gated": 0, "abs_rel": 0.01234,
                                        "point_mm_p50": 3.21});
        let line = band_line(&scored);
        assert!(line.contains("1.23 %") && line.contains("3.2 mm") && line.contains("  7 /   0"), "{line}");
    }

    #[test]
    fn the_hint_names_the_drops_the_cores_and_a_lighter_setting() {
        let o = Overload { dropped: 12, cores_busy: 1.95, cores: 2.0, ms_per_frame: 78.0 };
        let hint = overload_hint(&o, "census-refine:hitnet-m4");
        assert!(hint.contains("12 frames dropped") && hint.contains("1.95 of 2 cores") && hint.contains("78.0 ms"));
        assert!(hint.contains("no `--model`") && hint.contains("320x240"), "{hint}");
    }
}
