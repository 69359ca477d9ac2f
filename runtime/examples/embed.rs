//! Embeds the abvs runtime in a process of one's own: a deployment's configuration in, one call to a
//! running runtime, its statistics out. The runtime runs on a thread of its own; this process reads its
//! counts while it goes and its report at the end.
//!
//! Here the configuration is the shipped fixture's (`config/fixture.toml`), made small: 320x240, every frame
//! processed (`lossless`), no iceoryx2 publishing.
//!
//! ```text
//! cargo run -p abvs-runtime --example embed [FRAMES]
//! ```
use std::time::Duration;

use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::RuntimeConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let frames: u64 = match std::env::args().nth(1) {
        Some(a) => a.parse().map_err(|e| format!("FRAMES `{a}`: {e}"))?,
        None => 10,
    };
    let mut config = RuntimeConfig::load(&shipped("config/fixture.toml"))?;
    config.disparity.width = 320;
    config.disparity.height = 240;
    config.source.frames = Some(frames);
    config.source.lossless = true;
    config.bridges.iceoryx.enabled = false;

    // Opens the session, loads the calibration and the FK models, builds the engine: every error is here.
    let runtime = Runtime::from_config(&config)?;
    println!("engine {} at {}x{}", runtime.engine_name(), config.disparity.width, config.disparity.height);
    let handle = runtime.spawn()?;
    while !handle.is_finished() {
        // the robot's own work goes on here; `handle.stop()` would end the run early
        std::thread::sleep(Duration::from_millis(100));
    }
    let counts = handle.stats();
    let report = handle.join()?;
    let s = &report.stats;
    println!(
        "frames_in {} frames_published {} frames_dropped {} (handle: {} / {} / {})",
        s.frames_in,
        s.frames_published,
        s.frames_dropped,
        counts.frames_in,
        counts.frames_published,
        counts.frames_dropped
    );
    if s.latency_measured {
        println!("latency_ms p50 {:.1} p99 {:.1}", s.end_to_end.ms(0.5), s.end_to_end.ms(0.99));
    } else {
        println!("latency_ms n/a (an unpaced replay takes frames ahead of their times)");
    }
    println!("output_digest {:016x}", s.output_digest.expect("a lossless run is digested"));
    Ok(())
}
