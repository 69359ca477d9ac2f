//! The settings each part of the pipeline runs with, as plain data with their defaults: motion
//! ([`MotionConfig`]), the left-right check ([`CheckConfig`]), the validity mask's threshold, the fovea
//! ([`FoveaConfig`]), the self-check ([`SelfCheckConfig`]) and the gaze goals' rate limit ([`RateLimit`]).
//! The deployment file ([`crate::config`]) fills them; the stages that use them live in the runtime.
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::error::{Result, RuntimeError};
use crate::messages::MAX_ROW_BANDS;

/// Default motion gate (rectified pixels of blur). 3 px at 640x480 (4.7 px/deg at the centre) is
/// 0.64 deg of blur: 160 deg/s at a 4 ms exposure, so smooth pursuit (up to ~100 deg/s) is kept and
/// saccades (200-1561 deg/s) are gated. The per-speed error table in runtime/BENCHMARKS.md shows depth
/// falling apart beyond this (the network was trained on sharp images).
pub const DEFAULT_GATE_BLUR_PX: f64 = 3.0;

/// What the runtime does about motion during an exposure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionConfig {
    /// Correct each row with the eye's pose when it exposed (when the frames have a readout).
    pub rolling_shutter: bool,
    /// Row bands of the per-row correction (nodes = bands + 1).
    pub bands: usize,
    /// Frames whose blur exceeds this many rectified pixels are gated (infinity: never).
    pub gate_blur_px: f64,
    /// encoder_time_offset of each eye (s), overriding their FK models' (effects.md; `None`: the models').
    pub time_offset_s: Option<[f64; 2]>,
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig { rolling_shutter: true, bands: 8, gate_blur_px: DEFAULT_GATE_BLUR_PX, time_offset_s: None }
    }
}

impl MotionConfig {
    /// Row bands used for a frame of `readout_ns` (0: the frame is corrected as a whole).
    pub fn bands_for(&self, readout_ns: i64) -> usize {
        if self.rolling_shutter && readout_ns > 0 {
            self.bands.clamp(1, MAX_ROW_BANDS)
        } else {
            0
        }
    }
}

/// Largest `max_diff` accepted (px): beyond it exp(-diff) comes close to f32's underflow, and a check that
/// loose checks nothing.
pub const MAX_DIFF_LIMIT: f32 = 50.0;

/// What the left-right check does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckConfig {
    /// Write the confidence into each frame ([`crate::messages::Work::confidence`], published by the bridges).
    pub confidence: bool,
    /// Set the disparity of every pixel of confidence 0 to NaN (depth and cloud drop it).
    pub invalidate: bool,
    /// Largest left/right disagreement (px) of a consistent match.
    pub max_diff: f32,
}

impl Default for CheckConfig {
    fn default() -> Self {
        CheckConfig { confidence: false, invalidate: false, max_diff: 1.0 }
    }
}

impl CheckConfig {
    /// Whether the check runs at all (it has something to produce).
    pub fn enabled(&self) -> bool {
        self.confidence || self.invalidate
    }

    /// Refuses a `max_diff` outside (0, [`MAX_DIFF_LIMIT`]].
    pub fn check(&self) -> Result<()> {
        if !(self.max_diff > 0.0 && self.max_diff <= MAX_DIFF_LIMIT) {
            return Err(RuntimeError::Invalid(format!(
                "left-right check: max_diff {} px must be in (0, {MAX_DIFF_LIMIT}]",
                self.max_diff
            )));
        }
        Ok(())
    }
}

/// The default threshold of the validity mask (`[disparity] min_confidence`, `--min-confidence`): published
/// depth is NaN where the confidence is below it. 0 keeps every pixel (the dense output, bit for bit).
/// Chosen on Aloe at 640x480 (`abvs disparity-eval --resolution 640x480 --json`, `own_confidence.mask_curve`)
/// among the thresholds that publish at least 5 points more than SGBM_3WAY's density (0.725) at no more than
/// its bad-2 (3.85 %): 0.65 to 0.725 when it was chosen; with the match cost in the confidence (docs/depth.md)
/// 0.6 to 0.75 (0.7 chosen); with the cost's curvature too (session 28) 0.55 to 0.75, and the middle, 0.65, gives
/// 0.794 / 2.76 % (0.55: 0.810 / 3.71 %; 0.75: 0.775 / 1.98 %).
pub const DEFAULT_MIN_CONFIDENCE: f32 = 0.65;

/// What the fovea computes and where it looks by default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoveaConfig {
    /// Window width (px at the raw frames' scale).
    pub width: u32,
    /// Window height (px).
    pub height: u32,
    /// Widest disparity search (px at the fovea's scale; a multiple of 16).
    pub max_range_px: u32,
    /// Fixations nearer than this (m, from the midpoint of the optical centres) are not used.
    pub min_distance_m: f64,
    /// Fixations farther than this (nearly parallel axes: the meeting point is noise) are not used.
    pub max_distance_m: f64,
    /// Distance along the image centre's ray used without a usable fixation (m).
    pub default_distance_m: f64,
    /// Behind (a newer frame already waits for the fovea's lane), let the frame go on without its fovea
    /// instead of holding up the frames behind it, which the queue would drop whole (`Stage::shed`).
    pub shed_when_behind: bool,
}

impl Default for FoveaConfig {
    fn default() -> Self {
        FoveaConfig {
            width: 320,
            height: 240,
            max_range_px: 96,
            min_distance_m: 0.15,
            max_distance_m: 3.0,
            default_distance_m: 1.0,
            shed_when_behind: true,
        }
    }
}

/// How the self-check runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCheckConfig {
    /// Check every n-th frame (by `seq`; 1 = every frame). 5 by default: 5 checks a second at 25 fps, a
    /// fifth of the worker's CPU time (10 ms a check at 320x240, release) for the same drift detection.
    pub every: u64,
    /// Half-height of the band of rows searched for a match (px).
    pub band_px: f32,
    /// Nearest depth matched (m): the disparity range is f B / min_depth.
    pub min_depth_m: f64,
    /// Corners searched per frame (at most).
    pub features: usize,
    /// Warn when the rotation error (median of the last `warn_frames` checked frames) exceeds this (deg).
    pub threshold_deg: f64,
    /// Window of the warning (checked frames).
    pub warn_frames: u32,
    /// Per-frame CSV log.
    pub log: Option<PathBuf>,
    /// Wait for the worker instead of skipping frames (offline, reproducible; costs the output stage the wait).
    pub blocking: bool,
    /// Run the worker only on otherwise idle CPU time (Linux SCHED_IDLE; nice 19 where refused), so it never
    /// takes a core from the pipeline's stages; false keeps the pipeline's priority.
    pub background: bool,
    /// The run's identity, on every row of both logs and in `<log>.run.toml` (the runtime's `sinks::self_check::new_run_id`; 0 = none), so
    /// that `abvs calib self-check` refuses logs and configurations of different runs.
    pub run_id: u64,
}

impl Default for SelfCheckConfig {
    fn default() -> Self {
        SelfCheckConfig {
            every: 5,
            band_px: 4.0,
            min_depth_m: 0.15,
            features: 300,
            threshold_deg: 0.1,
            warn_frames: 25,
            log: None,
            blocking: false,
            background: true,
            run_id: 0,
        }
    }
}

/// The goals the controller executes per second, whoever sends them (`[gaze] max_goals_per_s`, `goal_burst`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RateLimit {
    /// Sustained goals per second. 20: a person makes 3-4 saccades a second, and a pursuit target updated at
    /// the camera's 25 fps still fits with the burst.
    pub max_goals_per_s: f64,
    /// Goals that may come back to back (the bucket's size).
    pub goal_burst: u32,
}

impl Default for RateLimit {
    fn default() -> Self {
        RateLimit { max_goals_per_s: 20.0, goal_burst: 4 }
    }
}

impl RateLimit {
    /// Values the limit cannot run with, named by their `[gaze]` field.
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // refuses NaN too
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(self.max_goals_per_s > 0.0 && self.max_goals_per_s <= 10_000.0) {
            return Err(format!("gaze.max_goals_per_s: {} must be in (0, 10000]", self.max_goals_per_s));
        }
        if !(1..=1000).contains(&self.goal_burst) {
            return Err(format!("gaze.goal_burst: {} must be in 1..=1000", self.goal_burst));
        }
        Ok(())
    }

    /// The most goals it lets through in `seconds` (starting full).
    pub fn most_in(&self, seconds: f64) -> u64 {
        (self.max_goals_per_s * seconds).floor() as u64 + u64::from(self.goal_burst)
    }
}
