//! Receives the runtime's depth maps, their confidence and the point clouds in another process, over iceoryx2
//! shared memory: the typed header ([`FrameHeader`]: seq, times, poses, intrinsics) and the payload read in
//! place, the same layout the Python module (`python/abvs_iceoryx2.py`) reads.
//!
//! A robot runs `abvs run` (or its own process embedding the runtime) and this beside it, both with the same
//! configuration: the subscriber's services must have the publisher's settings
//! ([`RuntimeConfig::bridge_config`]). So that the example runs alone, it starts its own publisher: itself
//! again, as a child process (`--publish`) embedding the runtime on the fixture.
//!
//! ```text
//! cargo run -p abvs-runtime --example subscribe [FRAMES]
//! ```
use std::collections::BTreeSet;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use abvs_runtime::bridges::iceoryx::{
    BridgeConfig, BridgePayload, CloudSubscriber, DepthSubscriber, FrameHeader, Subscriber,
};
use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::RuntimeConfig;

/// The deployment both processes share: the fixture at 320x240, paced at its recorded 25 fps as a camera
/// would deliver it, with the confidence, published under a prefix of this run's own.
fn config(prefix: &str, frames: u64) -> Result<RuntimeConfig, Box<dyn std::error::Error>> {
    let mut c = RuntimeConfig::load(&shipped("config/fixture.toml"))?;
    c.disparity.width = 320;
    c.disparity.height = 240;
    c.disparity.confidence = true;
    c.source.frames = Some(frames);
    c.bridges.iceoryx.service_prefix = prefix.to_string();
    Ok(c)
}

/// The seqs received on one topic, each sample checked against its header.
struct Topic<T: BridgePayload> {
    sub: Subscriber<T>,
    seqs: BTreeSet<u64>,
}

impl<T: BridgePayload> Topic<T> {
    fn new(sub: Subscriber<T>) -> Self {
        Topic { sub, seqs: BTreeSet::new() }
    }

    /// Takes every sample waiting; `wait` long for the first.
    fn drain(&mut self, wait: Duration) -> Result<(), Box<dyn std::error::Error>> {
        let mut next = self.sub.wait(wait)?;
        while let Some(sample) = next {
            let h: &FrameHeader = sample.header();
            let organised = (h.width * h.height) as usize;
            // depth and confidence: the whole organised map; a cloud: its valid points only
            let n = if T::TRIM_TO_VALID { h.valid as usize } else { organised };
            if sample.data().len() != n || (h.width, h.height) != (320, 240) || h.frame_id_str() != "left_home_camera" {
                return Err(format!("{}: seq {}: {} elements for {h:?}", self.sub.service_name(), h.seq, n).into());
            }
            self.seqs.insert(h.seq);
            drop(sample);
            next = self.sub.try_receive()?;
        }
        Ok(())
    }
}

fn publish(prefix: &str, frames: u64) -> Result<(), Box<dyn std::error::Error>> {
    let report = Runtime::from_config(&config(prefix, frames)?)?.run()?;
    println!("publisher frames_published {}", report.stats.frames_published);
    Ok(())
}

fn subscribe(frames: u64) -> Result<(), Box<dyn std::error::Error>> {
    let prefix = format!("abvs-example-{}", std::process::id());
    let bridge = BridgeConfig::for_deployment(&config(&prefix, frames)?);
    // subscribed before the publisher starts: it sends to every subscriber there
    let mut depth = Topic::new(DepthSubscriber::new(&bridge)?);
    let mut confidence = Topic::new(Subscriber::<f32>::confidence(&bridge)?);
    let mut cloud = Topic::new(CloudSubscriber::new(&bridge)?);
    let exe = std::env::current_exe()?;
    let mut child: Child = Command::new(exe).args(["--publish", &prefix, &frames.to_string()]).spawn()?;
    let deadline = Instant::now() + Duration::from_secs(120);
    let status = loop {
        depth.drain(Duration::from_millis(100))?;
        confidence.drain(Duration::ZERO)?;
        cloud.drain(Duration::ZERO)?;
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if Instant::now() > deadline {
            child.kill()?;
            return Err("the publisher did not finish within 120 s".into());
        }
    };
    // what the publisher sent before it ended
    depth.drain(Duration::from_millis(200))?;
    confidence.drain(Duration::ZERO)?;
    cloud.drain(Duration::ZERO)?;
    if !status.success() {
        return Err(format!("the publisher failed: {status}").into());
    }
    let seqs = |s: &BTreeSet<u64>| s.iter().map(u64::to_string).collect::<Vec<_>>().join(",");
    println!("subscriber depth {} seqs {}", depth.seqs.len(), seqs(&depth.seqs));
    println!("subscriber confidence {} seqs {}", confidence.seqs.len(), seqs(&confidence.seqs));
    println!("subscriber cloud {} seqs {}", cloud.seqs.len(), seqs(&cloud.seqs));
    println!("subscriber seq_gaps {} malformed {}", depth.sub.stats().seq_gaps, depth.sub.stats().malformed);
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let count = |a: Option<&String>| -> Result<u64, String> {
        a.map_or(Ok(20), |a| a.parse().map_err(|e| format!("FRAMES `{a}`: {e}")))
    };
    match args.first().map(String::as_str) {
        Some("--publish") => {
            let prefix = args.get(1).ok_or("--publish PREFIX [FRAMES]")?;
            publish(prefix, count(args.get(2))?)
        }
        _ => subscribe(count(args.first())?),
    }
}
