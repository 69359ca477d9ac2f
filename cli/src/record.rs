//! `abvs record`: records a session from the two eye cameras (V4L2) and the drive board's encoder
//! stream (serial), homing both eyes first, in the format `abvs run --session` replays.
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use abvs_runtime::record::{record, RecordConfig, RecordStats};
use abvs_runtime::sinks::session_writer::{CalibFiles, SessionWriter};
use abvs_runtime::sources::devices::open_devices;
use abvs_runtime_core::config::LiveConfig;
use anyhow::Context;
use clap::Args;

/// The eye cameras and the drive board (shared by `abvs record` and `abvs run --live`).
#[derive(Args, Clone)]
pub struct DeviceArgs {
    /// Left eye camera.
    #[arg(long, default_value = "/dev/video0")]
    pub left: PathBuf,
    /// Right eye camera.
    #[arg(long, default_value = "/dev/video2")]
    pub right: PathBuf,
    /// Serial port of the drive board's encoder stream.
    #[arg(long, default_value = "/dev/ttyACM0")]
    pub encoders: String,
    /// Serial baud rate of the encoder stream (1200 to 20000000).
    #[arg(long, default_value_t = 1_000_000, value_parser = crate::args::count(1200u32, 20_000_000))]
    pub baud: u32,
    /// Capture width (px, 16 to 8192).
    #[arg(long, default_value_t = 1600, value_parser = crate::args::count(16u32, 8192))]
    pub width: u32,
    /// Capture height (px, 16 to 8192).
    #[arg(long, default_value_t = 1200, value_parser = crate::args::count(16u32, 8192))]
    pub height: u32,
    /// Camera frame rate (Hz, 1 to 1000; `run --source sim`: up to 200).
    #[arg(long, default_value_t = 25, value_parser = crate::args::count(1u32, 1000))]
    pub fps: u32,
    /// V4L2 FourCC to ask for: pgAA (RAW10 MIPI-packed GRBG, the OV8856 default), BA10, YUYV, NV12, ...
    #[arg(long, default_value = "pgAA")]
    pub fourcc: String,
    /// The cameras' exposure (ms, above 0 up to one frame period: 40 at 25 fps; the flag takes up to 1000 and
    /// the run checks it against the rate) [default: read once from the camera (exposure must be manual)].
    #[arg(long, value_parser = crate::args::positive_up_to(1000.0))]
    pub exposure_ms: Option<f64>,
    /// Rolling-shutter readout (ms, 0 up to one frame period: 40 at 25 fps; the flag takes up to 1000 and the
    /// run checks it against the rate), to move end-of-frame timestamps to the start of exposure; for `run`
    /// also the per-row correction's [default: 30 live and for `record`; a replay: the session's readout_ms].
    #[arg(long, default_value_t = 30.0, hide_default_value = true, value_parser = crate::args::finite_in(0.0, 1000.0))]
    pub readout_ms: f64,
    /// Largest left/right start-of-exposure difference of a pair (ms, up to 1000).
    #[arg(long, default_value_t = 2.0, value_parser = crate::args::positive_up_to(1000.0))]
    pub pair_tolerance_ms: f64,
    /// Seconds both eyes have to home (s, above 0 up to 1e9; their links roll through the index markers at
    /// start-up).
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::seconds())]
    pub homing_timeout: f64,
}

impl DeviceArgs {
    /// The cameras' timing against their frame period (`record`; `run` checks it against the rate it applies
    /// to, the session's in a replay): the readout at most a period, the exposure above 0 and at most a period.
    pub fn check_timing(&self) -> anyhow::Result<()> {
        let period_ms = 1000.0 / f64::from(self.fps);
        if self.readout_ms > period_ms {
            anyhow::bail!(
                "--readout-ms {}: longer than one frame period ({period_ms:.3} ms at --fps {})",
                self.readout_ms,
                self.fps
            );
        }
        if let Some(e) = self.exposure_ms.filter(|&e| e > period_ms) {
            anyhow::bail!("--exposure-ms {e}: longer than one frame period ({period_ms:.3} ms at --fps {})", self.fps);
        }
        Ok(())
    }
}

impl From<&DeviceArgs> for LiveConfig {
    fn from(d: &DeviceArgs) -> Self {
        LiveConfig {
            left: d.left.clone(),
            right: d.right.clone(),
            encoders: d.encoders.clone(),
            baud: d.baud,
            width: d.width,
            height: d.height,
            fps: d.fps,
            fourcc: d.fourcc.clone(),
            exposure_ms: d.exposure_ms,
            readout_ms: d.readout_ms,
            pair_tolerance_ms: d.pair_tolerance_ms,
            homing_timeout_s: d.homing_timeout,
        }
    }
}

#[derive(Args)]
pub struct RecordArgs {
    #[command(flatten)]
    pub devices: DeviceArgs,
    /// Calibration directory: stereo.yaml (both intrinsics and T_lH^rH) and eye0, eye1 (FK models).
    #[arg(long)]
    pub calib: PathBuf,
    /// Session directory to create (must not exist or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// Stop after this many pairs (at least 1; default: run until --seconds or Ctrl-C).
    #[arg(long, value_parser = crate::args::count(1u64, u64::MAX))]
    pub frames: Option<u64>,
    /// Stop after this many seconds (s, above 0 up to 1e9) [default: until stopped, or --frames].
    #[arg(long, value_parser = crate::args::seconds())]
    pub seconds: Option<f64>,
    /// Write the recording's counts as JSON.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
}

impl RecordArgs {
    /// The outputs before the devices are opened and homed.
    pub fn check(&self) -> anyhow::Result<()> {
        self.devices.check_timing()?;
        abvs_runtime::outputs::check_dir_creatable("--out", &self.out)?;
        match &self.stats_json {
            Some(p) => Ok(abvs_runtime::outputs::check_file_writable("--stats-json", p)?),
            None => Ok(()),
        }
    }
}

/// Prints the counts a user needs to judge a recording.
pub fn summary(s: &RecordStats) -> String {
    let e = &s.encoders;
    let c = &s.capture.pairing;
    format!(
        "pairs: {} in, {} written, {} before homing, {} dropped (writer behind), {} write errors\n\
         capture: {:?} unpaired, {:?} out of order, {:?} dropped by the driver, {:?} bad frames (left, right as [l, r])\n\
         encoders: {} rows; homed after {}; link {} frames, {} CRC errors, {} lost, {} resets; {} homing refusals\n",
        s.pairs_in,
        s.pairs_written,
        s.pairs_before_homing,
        s.pairs_dropped_writer,
        s.write_errors,
        c.unpaired,
        c.out_of_order,
        c.dropped,
        s.capture.errors,
        s.encoder_rows,
        s.homed_after_s.map(|t| format!("{t:.2} s")).unwrap_or_else(|| "never".into()),
        e.link.frames,
        e.link.crc_errors,
        e.link.lost_frames,
        e.link.resets,
        e.homing_failures[0] + e.homing_failures[1],
    )
}

pub fn run(a: RecordArgs) -> anyhow::Result<ExitCode> {
    let calib = CalibFiles::from_dir(&a.calib);
    let d = &a.devices;
    let description = format!(
        "recorded by abvs record {}: cameras {} / {}, encoders {}",
        env!("CARGO_PKG_VERSION"),
        d.left.display(),
        d.right.display(),
        d.encoders
    );
    // Checked before any device is opened (the cheapest mistakes to report), and the session
    // directory is created only once every device is open.
    SessionWriter::check_target(&a.out)?;
    calib.check()?;
    let (mut capture, encoders) = open_devices(&LiveConfig::from(d))?;
    let writer =
        SessionWriter::create(&a.out, &calib, f64::from(d.fps), description)?.with_timing(d.readout_ms, d.exposure_ms);
    let stop = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGINT, stop.clone()).context("installing the Ctrl-C handler")?;
    signal_hook::flag::register(signal_hook::consts::SIGTERM, stop.clone())
        .context("installing the SIGTERM handler")?;
    let rc = RecordConfig {
        frames: a.frames,
        duration: a.seconds.map(Duration::from_secs_f64),
        homing_timeout: Duration::from_secs_f64(d.homing_timeout),
        ..RecordConfig::default()
    };
    let pb = crate::progress_bar(a.frames.unwrap_or(0), "recording");
    let (session, stats) = record(&mut capture, encoders, writer, &rc, &stop, &mut |s| {
        pb.set_position(s.pairs_written);
    });
    pb.finish_and_clear();
    eprint!("{}", summary(&stats));
    if let Some(p) = &a.stats_json {
        std::fs::write(p, serde_json::to_string_pretty(&stats)? + "\n")
            .with_context(|| format!("writing {}", p.display()))?;
    }
    let session = session.with_context(|| format!("recording into {}", a.out.display()))?;
    eprintln!("wrote session {} ({} pairs)", a.out.display(), session.frames.len());
    Ok(ExitCode::SUCCESS)
}
