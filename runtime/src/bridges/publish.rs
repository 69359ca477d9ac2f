//! The pipeline's publishing sink: each finished frame goes out as a depth map, its confidence (when the run
//! computes one and the sink was made [`PublishSink::with_confidence`]) and a point cloud on the iceoryx2
//! services of [`crate::bridges::iceoryx`], written straight into the loaned shared memory.
use abvs_eye::Pose;

use crate::bridges::iceoryx::{check_shm_space, BridgeConfig, CloudPoint, FrameHeader, Publisher, CONFIDENCE_TOPIC};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// Publishes every finished frame on the iceoryx2 services (see the module docs).
pub struct PublishSink {
    depth: Publisher<f32>,
    confidence: Option<Publisher<f32>>,
    cloud: Publisher<CloudPoint>,
    /// The services' configuration (a subscriber opens them with the same).
    pub config: BridgeConfig,
    /// The fovea's depth and cloud (`{prefix}/fovea/...`), when the run computes one.
    fovea: Option<(Publisher<f32>, Publisher<CloudPoint>)>,
}

impl PublishSink {
    /// Depth and cloud.
    pub fn new(config: BridgeConfig) -> Result<PublishSink> {
        Self::open(config, false)
    }

    /// Depth, confidence and cloud: every frame must carry a confidence (the pipeline's
    /// `PipelineConfig::check` with `confidence`), a frame without one fails this sink.
    pub fn with_confidence(config: BridgeConfig) -> Result<PublishSink> {
        Self::open(config, true)
    }

    fn open(config: BridgeConfig, confidence: bool) -> Result<PublishSink> {
        let err = |e: crate::bridges::iceoryx::BridgeError| RuntimeError::Ipc(Box::new(e));
        // every topic's shared memory at once (each publisher checks its own as it is created)
        let maps = if confidence { 2 } else { 1 };
        let all = maps * config.publisher_bytes::<f32>() + config.publisher_bytes::<CloudPoint>();
        let mut names = vec![config.service_name("depth"), config.service_name("cloud")];
        if confidence {
            names.insert(1, config.service_name(CONFIDENCE_TOPIC));
        }
        check_shm_space(&names.join(", "), all).map_err(err)?;
        Ok(PublishSink {
            depth: Publisher::new(&config).map_err(err)?,
            confidence: if confidence { Some(Publisher::confidence(&config).map_err(err)?) } else { None },
            cloud: Publisher::new(&config).map_err(err)?,
            config,
            fovea: None,
        })
    }

    /// Also the fovea's depth and cloud, on services sized for its `width` x `height` window.
    pub fn with_fovea(mut self, width: u32, height: u32) -> Result<PublishSink> {
        let err = |e: crate::bridges::iceoryx::BridgeError| RuntimeError::Ipc(Box::new(e));
        let cfg = BridgeConfig { max_width: width, max_height: height, ..self.config.clone() };
        self.fovea = Some((Publisher::fovea(&cfg).map_err(err)?, Publisher::fovea(&cfg).map_err(err)?));
        Ok(self)
    }
}

/// The cloud's points as the service's (the same 16 bytes: gray as 0xffGGGGGG).
fn cloud_points(pts: &[abvs_runtime_core::messages::CloudPoint]) -> impl Iterator<Item = CloudPoint> + '_ {
    pts.iter().map(|p| CloudPoint { x: p.x, y: p.y, z: p.z, rgba: p.rgb })
}

/// P = [alpha, beta, gamma (deg), x, y, z (mm)] of a runtime pose (metres).
fn p6(p: &Pose) -> [f64; 6] {
    Pose::new(p.r, p.t * 1000.0).to_p6()
}

impl Sink for PublishSink {
    fn name(&self) -> &'static str {
        "iceoryx2"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        let err = |e: crate::bridges::iceoryx::BridgeError| RuntimeError::Ipc(Box::new(e));
        let mut h = FrameHeader::new_left_home();
        h.seq = out.seq;
        h.t_frame_ns = out.t_frame_ns;
        h.pose_left = p6(&out.pose.rel_left);
        h.pose_right = p6(&out.pose.rel_right);
        h.intrinsics = [out.cam.f, out.cam.f, out.cam.cx, out.cam.cy];
        h.width = out.cam.width;
        h.height = out.cam.height;
        h.baseline_m = out.rect.baseline_m;
        h.valid = out.depth.n_points as u32;
        if out.motion.gated {
            h.flags |= crate::bridges::iceoryx::FLAG_MOTION_GATED;
        }
        let depth = &out.depth.depth;
        self.depth.publish_depth(&h, |s| s.extend_from_slice(depth)).map_err(err)?;
        if let Some(p) = &mut self.confidence {
            let c = out.confidence.ok_or_else(|| {
                RuntimeError::Invalid(format!("frame {}: no confidence to publish (the run computes none)", out.seq))
            })?;
            p.publish_depth(&h, |s| s.extend_from_slice(c)).map_err(err)?;
        }
        let n = out.depth.n_points;
        let pts = &out.depth.cloud[..n];
        self.cloud
            .publish_cloud(&h, n, |s| {
                for p in cloud_points(pts) {
                    s.push(p);
                }
            })
            .map_err(err)?;
        if let (Some((depth, cloud)), Some(f)) = (&mut self.fovea, out.fovea) {
            h.intrinsics = [f.cam.f, f.cam.f, f.cam.cx, f.cam.cy];
            (h.width, h.height, h.valid) = (f.cam.width, f.cam.height, f.depth.n_points as u32);
            if !f.measured {
                h.flags |= crate::bridges::iceoryx::FLAG_FOVEA_DEFAULT_FIXATION;
            }
            depth.publish_depth(&h, |s| s.extend_from_slice(&f.depth.depth)).map_err(err)?;
            let n = f.depth.n_points;
            let pts = &f.depth.cloud[..n];
            cloud
                .publish_cloud(&h, n, |s| {
                    for p in cloud_points(pts) {
                        s.push(p);
                    }
                })
                .map_err(err)?;
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let (d, c) = (self.depth.stats(), self.cloud.stats());
        let mut p = serde_json::json!({ "depth": d, "cloud": c });
        if let Some(k) = &self.confidence {
            p["confidence"] = serde_json::json!(k.stats());
        }
        if let Some((d, c)) = &self.fovea {
            p["fovea"] = serde_json::json!({ "depth": d.stats(), "cloud": c.stats() });
        }
        stats.extra.insert("publish".into(), p);
    }
}
