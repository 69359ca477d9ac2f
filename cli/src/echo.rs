//! `abvs echo depth|confidence|cloud`: subscribes to the runtime's iceoryx2 bridge and prints rate and end-to-end
//! latency (now - t_frame_ns, CLOCK_MONOTONIC).
use std::process::ExitCode;
use std::time::{Duration, Instant};

use abvs_runtime::bridges::iceoryx::receive_stats::ReceiveStats;
use abvs_runtime::bridges::iceoryx::{BridgeConfig, BridgeError, BridgePayload, CloudPoint, Subscriber};
use abvs_runtime_core::messages::monotonic_ns;
use clap::{Args, ValueEnum};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Topic {
    /// The depth maps (m per pixel).
    Depth,
    /// The depth's per-pixel confidence (published by `abvs run --confidence`).
    Confidence,
    /// The point clouds (left home camera frame, m).
    Cloud,
}

#[derive(Args)]
pub struct EchoArgs {
    /// What to receive: depth maps, their confidence, or point clouds.
    topic: Topic,
    /// Exit after this many samples (at least 1).
    #[arg(long, value_parser = crate::args::count(1u64, u64::MAX))]
    count: Option<u64>,
    /// Print one JSON object at the end (received, fps, latency_ms {p50, p99}, points_mean, and the
    /// subscriber's counts: seq_gaps, seq_restarts, dead_nodes_cleaned, malformed) instead of the periodic
    /// lines (those go to stderr then).
    #[arg(long)]
    json: bool,
    /// Fail if no sample arrives for this long (s, up to 1e9).
    #[arg(long, default_value_t = 10.0, value_parser = crate::args::seconds())]
    timeout_s: f64,
    /// Service name prefix (the runtime's BridgeConfig prefix).
    #[arg(long, default_value = "abvs")]
    prefix: String,
    /// Testing: abort the process right after receiving K samples, still holding the last one.
    #[arg(long, hide = true, value_parser = crate::args::count(1u64, u64::MAX))]
    abort_after: Option<u64>,
    /// Testing: after K samples, keep the last two borrowed (the most a subscriber may hold), say
    /// "holding" on stderr and sleep until killed.
    #[arg(long, hide = true, value_parser = crate::args::count(1u64, u64::MAX))]
    hold_after: Option<u64>,
}

pub fn run(a: EchoArgs) -> anyhow::Result<ExitCode> {
    match a.topic {
        Topic::Depth => echo(&a, Subscriber::<f32>::new),
        Topic::Confidence => echo(&a, Subscriber::<f32>::confidence),
        Topic::Cloud => echo(&a, Subscriber::<CloudPoint>::new),
    }
}

fn echo<T: BridgePayload>(
    a: &EchoArgs,
    open: fn(&BridgeConfig) -> Result<Subscriber<T>, BridgeError>,
) -> anyhow::Result<ExitCode> {
    if !(a.timeout_s > 0.0 && a.timeout_s.is_finite()) {
        anyhow::bail!("--timeout-s must be a positive number of seconds");
    }
    let cfg = BridgeConfig::default().with_prefix(a.prefix.clone());
    let mut sub = open(&cfg)?;
    let service = sub.service_name().to_string();
    let timeout = Duration::from_secs_f64(a.timeout_s);
    let mut stats = ReceiveStats::default();
    let mut failure = None;
    let mut held = Vec::new();

    loop {
        let received = stats.received();
        if a.count.is_some_and(|n| received >= n) {
            break;
        }
        let Some(r) = sub.wait(timeout)? else {
            failure = Some(format!(
                "no sample on {service} within {} s (received {received}); is the abvs runtime publishing with prefix '{}'?",
                a.timeout_s, a.prefix
            ));
            break;
        };
        let now = Instant::now();
        stats.record(r.header(), monotonic_ns(), now);
        let received = stats.received();
        if a.abort_after == Some(received) {
            // simulate a crashing subscriber: die while the sample is still borrowed
            let _held = r;
            std::process::abort();
        }
        if a.hold_after.is_some_and(|k| received + 1 >= k) {
            held.push(r);
            if held.len() == 2 {
                use std::io::Write;
                let mut e = std::io::stderr();
                let _ = writeln!(e, "holding {} samples", held.len());
                let _ = e.flush();
                loop {
                    std::thread::sleep(Duration::from_secs(3600));
                }
            }
            continue;
        }
        drop(r);
        if let Some(w) = stats.window_done(now) {
            let line = format!(
                "{service}: {:.1} Hz, latency p50 {:.2} ms p99 {:.2} ms, {} {:.0} per sample ({received} received)",
                w.hz,
                w.p50_ms,
                w.p99_ms,
                if T::TRIM_TO_VALID { "points" } else { "valid pixels" },
                w.valid_mean,
            );
            if a.json {
                eprintln!("{line}");
            } else {
                println!("{line}");
            }
        }
    }

    let s = stats.summary();
    let (received, fps, p50, p99, points_mean, motion_gated) =
        (s.received, s.hz, s.p50_ms, s.p99_ms, s.valid_mean, s.motion_gated);
    if a.json {
        let num = |v: f64| if v.is_finite() { serde_json::json!(v) } else { serde_json::Value::Null };
        let st = sub.stats();
        let o = serde_json::json!({
            "received": received,
            "fps": num(fps),
            "latency_ms": { "p50": num(p50), "p99": num(p99) },
            "points_mean": num(points_mean),
            "motion_gated": motion_gated,
            "seq_gaps": st.seq_gaps,
            "seq_restarts": st.seq_restarts,
            "dead_nodes_cleaned": st.dead_nodes_cleaned,
            "malformed": st.malformed,
        });
        println!("{o}");
    } else {
        println!(
            "{service}: {received} received ({motion_gated} motion-gated), {fps:.1} Hz, latency p50 {p50:.2} ms p99 {p99:.2} ms, \
             mean {points_mean:.0} {} per sample",
            if T::TRIM_TO_VALID { "points" } else { "valid pixels" }
        );
    }
    if let Some(f) = failure {
        eprintln!("error: {f}");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}
