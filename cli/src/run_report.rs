//! What `abvs run` prints at the end of a run (unless `--quiet`): the source, the engine, the latency table,
//! and a line for each sink that reported (the truth's side lane, the self-check, depth error by confidence
//! and by eye speed, the ROS 2 outputs).
use abvs_runtime::Report;
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
    if let Some(hint) = stats.cpu_json(r.elapsed_s).and_then(|cpu| overload_hint(&cpu, stats.frames_dropped, &r.engine))
    {
        println!("{hint}");
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

/// Share of the cores a run kept busy (idle priority aside) above which dropped frames mean the computer is
/// short of CPU, not that a frame met a passing hiccup. Lanes that hand frames to each other cannot use
/// every cycle: the default at 640x480 dropped 11-22 of 125 frames at 1.73-1.8 of 2 cores on this project's
/// 2-core VM (2026-11-26), census-refine on hitnet-s none at 1.2.
const SATURATED: f64 = 0.8;

/// What to tell a user whose run dropped frames because the computer could not do a frame's work in a frame
/// period (`cpu`: the stats JSON's `cpu`), with the lighter settings it has; `None` otherwise.
fn overload_hint(cpu: &serde_json::Value, dropped: u64, engine: &str) -> Option<String> {
    // the idle-priority side lanes only fill what the pipeline leaves: not a shortage
    let busy = cpu["cores_busy_without_idle_priority"].as_f64()?;
    let cores = cpu["cores"].as_u64()? as f64;
    if dropped == 0 || busy < SATURATED * cores {
        return None;
    }
    let lighter = if engine.starts_with("census-refine") && !engine.starts_with("census-refine:hitnet-s") {
        "no `--model` (the default: hitnet-s and SGBM at 320x240, about half the disparity stage's CPU) or \
         `--resolution 320x240`"
    } else {
        "`--resolution 320x240`"
    };
    Some(format!(
        "CPU-bound: {dropped} frames dropped with {busy:.2} of {cores} cores busy, idle-priority side lanes aside \
         ({:.1} ms of CPU per frame in all): \
         this computer cannot do this setting's work at this frame rate; lighter: {lighter} \
         (runtime/BENCHMARKS.md, \"Real time on 2 cores\")",
        cpu["ms_per_frame"].as_f64().unwrap_or(f64::NAN)
    ))
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
    fn the_hint_speaks_only_of_runs_that_dropped_frames_with_the_cores_busy() {
        let cpu =
            |busy: f64| serde_json::json!({"cores_busy_without_idle_priority": busy, "cores": 2, "ms_per_frame": 78.0});
        let hint = overload_hint(&cpu(1.95), 12, "census-refine:hitnet-m4").expect("saturated and dropping");
        assert!(hint.contains("12 frames dropped") && hint.contains("1.95 of 2 cores") && hint.contains("78.0 ms"));
        assert!(hint.contains("no `--model`") && hint.contains("320x240"), "{hint}");
        // already the light network: only the resolution is left
        let light = overload_hint(&cpu(1.95), 3, "census-refine:hitnet-s+sgbm").unwrap();
        assert!(!light.contains("--model") && light.contains("320x240"), "{light}");
        // nothing dropped, or frames dropped with CPU to spare (a hiccup, not a shortage): no hint
        assert_eq!(overload_hint(&cpu(1.95), 0, "census-refine:hitnet-m4"), None);
        assert_eq!(overload_hint(&cpu(1.2), 5, "census-refine:hitnet-m4"), None);
        assert_eq!(overload_hint(&serde_json::json!({}), 5, "sgbm"), None);
    }
}
