//! Adds a sink of one's own to the runtime: it receives every frame's depth map (and everything else the
//! frame published: cloud, poses, the rectified pair) on the pipeline's output lane.
//!
//! This one checks what it receives: frames in order, none missing, and an FNV-1a hash over every depth
//! value, the same hash as the runtime's `output_digest`, so the two must agree.
//!
//! ```text
//! cargo run -p abvs-runtime --example custom_sink [FRAMES]
//! ```
use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::RuntimeConfig;
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// Counts frames and valid depth pixels, hashes the depth. `consume` runs on the pipeline's critical path:
/// it must not block, and should not allocate (the runtime allocates nothing per frame).
struct DepthSink {
    frames: u64,
    next_seq: Option<u64>,
    out_of_order: u64,
    valid_pixels: u64,
    digest: u64,
}

impl Sink for DepthSink {
    fn name(&self) -> &'static str {
        "depth example"
    }

    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        if self.next_seq.is_some_and(|s| s != out.seq) {
            self.out_of_order += 1;
        }
        self.next_seq = Some(out.seq + 1);
        self.frames += 1;
        // row-major metres, width x height of the rectified left camera, NaN where there is no depth
        let depth = &out.depth.depth;
        debug_assert_eq!(depth.len(), (out.cam.width * out.cam.height) as usize);
        self.valid_pixels += depth.iter().filter(|z| z.is_finite()).count() as u64;
        for z in depth {
            for b in z.to_bits().to_le_bytes() {
                self.digest = (self.digest ^ b as u64).wrapping_mul(0x100000001b3);
            }
        }
        Ok(())
    }

    /// Called once after the last frame: what the sink measured goes into the run's statistics.
    fn finish(&mut self, stats: &mut RunStats) {
        stats.extra.insert(
            "depth_example".into(),
            serde_json::json!({
                "frames": self.frames,
                "out_of_order": self.out_of_order,
                "valid_pixels": self.valid_pixels,
                "digest": format!("{:016x}", self.digest),
            }),
        );
    }
}

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

    let mut runtime = Runtime::from_config(&config)?;
    let sink = DepthSink { frames: 0, next_seq: None, out_of_order: 0, valid_pixels: 0, digest: 0xcbf29ce484222325 };
    runtime.add_sink(Box::new(sink));
    let report = runtime.run()?;
    let s = &report.stats;
    let mine = &s.extra["depth_example"];
    println!(
        "sink frames {} out_of_order {} valid_pixels {} digest {}",
        mine["frames"],
        mine["out_of_order"],
        mine["valid_pixels"],
        mine["digest"].as_str().unwrap_or("?")
    );
    println!(
        "runtime frames_published {} output_digest {:016x}",
        s.frames_published,
        s.output_digest.expect("a lossless run is digested")
    );
    Ok(())
}
