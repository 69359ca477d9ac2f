//! What `abvs run` prints at the end of a run (unless `--quiet`): the source, the engine, the latency table,
//! and a line for each sink that reported (the truth's side lane, the self-check, depth error by confidence
//! and by eye speed, the ROS 2 outputs).
use abvs_runtime::config::RuntimeConfig;
use abvs_runtime::Report;

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
            let hi = b["deg_s"][1].as_f64().map_or("inf".to_string(), |h| format!("{h:.0}"));
            println!(
                "  [{:>3.0}, {hi:>3}): {:>3} / {:>3}  {:>6.2} %  {:>6.1} mm",
                b["deg_s"][0].as_f64().unwrap_or(0.0),
                b["frames"].as_u64().unwrap_or(0),
                b["gated"].as_u64().unwrap_or(0),
                b["abs_rel"].as_f64().unwrap_or(f64::NAN) * 100.0,
                b["point_mm_p50"].as_f64().unwrap_or(f64::NAN)
            );
        }
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
