//! `abvs sim`: draw a unit, simulate a data-collection session.
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::Effect;
use abvs_eye::UnitModel;
use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum SimCmd {
    /// Draw a plausible unit (effects.md magnitudes) and write its TOML.
    Unit(UnitArgs),
    /// Reproduce the paper's data collection on a unit and write a dataset CSV.
    Dataset(DatasetArgs),
    /// Render an AprilGrid image session (four boards, OV8856 fisheye) with ground truth.
    AprilgridSession(crate::camcal::SimSessionArgs),
    /// Render a stereo calibration session at home (AprilGrid pairs) for a known pair of cameras.
    StereoSession(crate::camcal::SimStereoArgs),
    /// Act as a drive board: stream encoder frames to a serial port (e.g. a pseudo-terminal).
    Board(BoardArgs),
    /// Render a stereo session with ground truth (textured scene, two units, saccades and pursuit).
    Session(SessionArgs),
    /// ISO 9283 repeatability protocol: 30 approaches from random starts to each target.
    Repeatability(crate::repeat::SimRepeatArgs),
}

#[derive(Args)]
pub struct SessionArgs {
    /// Session directory to write (session.toml, frames.csv, encoders.csv, frames/, calib/, truth/).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the scene, the units and the eye movements.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of stereo frames to render (1 to 100000).
    #[arg(long, default_value_t = 50, value_parser = crate::args::count(1usize, 100_000))]
    frames: usize,
    /// Frame rate (Hz, above 0 up to 200).
    #[arg(long, default_value_t = 25.0, value_parser = crate::args::positive_up_to(200.0))]
    fps: f64,
    /// Frame width (px, 16 to 8192; the OV8856 binned 2x2 by default; the lens is scaled).
    #[arg(long, default_value_t = 800, value_parser = crate::args::count(16u32, 8192))]
    width: u32,
    /// Frame height (px, 16 to 8192).
    #[arg(long, default_value_t = 600, value_parser = crate::args::count(16u32, 8192))]
    height: u32,
    /// FK calibration method fitted for each eye on a simulated calibration dataset.
    #[arg(long, value_enum, default_value_t = abvs_calib::methods::Method::Hybrid)]
    fk_method: abvs_calib::methods::Method,
    /// Grid step (deg, 1 to 30) of that calibration dataset.
    #[arg(long, default_value_t = 6.0, value_parser = crate::args::finite_in(1.0, 30.0))]
    calib_step_deg: f64,
    /// Anti-aliasing samples per pixel side (1 to 8).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1u32, 8))]
    supersample: u32,
    /// Rolling-shutter readout (ms, 0 up to one frame period - 4 ms: 36 at 25 fps): first row's start of
    /// exposure to the last row's (the OV8856 binned mode: ~32 ms); 0 = global shutter.
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::finite_in(0.0, 1000.0))]
    readout_ms: f64,
    /// Exposure of each row (ms, 0 up to one frame period: 40 at 25 fps); every row integrates it (motion
    /// blur); 0 = an instant.
    #[arg(long, default_value_t = 4.0, value_parser = crate::args::finite_in(0.0, 1000.0))]
    exposure_ms: f64,
    /// Peak angular speed of the smooth pursuits (deg/s, 0 to 500); the targets also move in depth (the eyes
    /// verge); 0 = fixations and saccades only.
    #[arg(long, default_value_t = 30.0, value_parser = crate::args::finite_in(0.0, 500.0))]
    pursuit_deg_s: f64,
    /// Depth range of the gaze targets, NEAR..FAR (m, along the left home camera's axis; 0.2 <= NEAR < FAR
    /// <= 5): where the eyes fixate and verge. The default draws exactly what sessions always drew.
    #[arg(long, default_value = "0.55..1.3", value_parser = parse_depth_range)]
    fixation_m: [f64; 2],
    /// encoder_time_offset of both eyes (ms, 0 to 10): the encoder stream is stamped this much later than the
    /// camera clock (effects.md) [default: each simulated unit's own, 0.1-5 ms].
    #[arg(long, value_parser = crate::args::finite_in(0.0, 10.0))]
    time_offset_ms: Option<f64>,
    /// Write over an existing, non-empty --out: the session there (frames/, calib/, truth/, session.toml,
    /// frames.csv, encoders.csv) is removed first, so no frame of it is left behind; other files stay.
    #[arg(long)]
    force: bool,
}

/// What `abvs sim session` writes into its directory: all of it is removed before a --force render.
const SESSION_ENTRIES: [&str; 6] = ["frames", "calib", "truth", "session.toml", "frames.csv", "encoders.csv"];

impl SessionArgs {
    /// --out before any work: a new or empty directory, or with --force any directory (a session there
    /// would otherwise be overwritten in part, its extra frames left behind).
    pub fn check(&self) -> anyhow::Result<()> {
        // the timing against the frame period, by flag, before the directory is looked at
        let period_ms = 1e3 / self.fps;
        if self.exposure_ms > period_ms {
            bail!(
                "--exposure-ms {}: longer than one frame period ({period_ms:.3} ms at --fps {})",
                self.exposure_ms,
                self.fps
            );
        }
        // every row's mid-exposure, and 1 ms either side, within the encoder stream's loop (SessionSpec)
        if self.readout_ms > period_ms - 4.0 {
            bail!(
                "--readout-ms {}: outside [0, {:.3}] ms (one frame period - 4 ms at --fps {})",
                self.readout_ms,
                (period_ms - 4.0).max(0.0),
                self.fps
            );
        }
        abvs_runtime::outputs::check_dir_creatable("--out", &self.out)?;
        let nonempty = self.out.is_dir()
            && std::fs::read_dir(&self.out)
                .with_context(|| format!("--out {}: reading the directory", self.out.display()))?
                .next()
                .is_some();
        if nonempty && !self.force {
            bail!(
                "--out {}: the directory exists and is not empty (a session there would be overwritten in part); \
                 choose a new directory, or add --force to replace it",
                self.out.display()
            );
        }
        Ok(())
    }

    /// With --force: the earlier session's entries removed (the render then starts from an empty session).
    fn clear_earlier(&self) -> anyhow::Result<()> {
        if !self.force {
            return Ok(());
        }
        for name in SESSION_ENTRIES {
            let p = self.out.join(name);
            let r = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
            match r {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(e).with_context(|| format!("--force: removing {}", p.display()))
                }
                _ => {}
            }
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct BoardArgs {
    /// Serial device to write to (a /dev/pts/N for tests).
    #[arg(long)]
    port: String,
    /// Encoder frames to send (plain roll; 1 to 1e9).
    #[arg(long, default_value_t = 1000, value_parser = crate::args::count(1usize, 1_000_000_000))]
    frames: usize,
    /// Encoder frame rate (Hz, up to 100000).
    #[arg(long, default_value_t = 1000.0, value_parser = crate::args::positive_up_to(100_000.0))]
    rate_hz: f64,
    /// Flip a byte in every n-th frame (0: never).
    #[arg(long, default_value_t = 0, value_parser = crate::args::count(0usize, 1_000_000_000))]
    corrupt_every: usize,
    /// Leave out every n-th frame (0: never).
    #[arg(long, default_value_t = 0, value_parser = crate::args::count(0usize, 1_000_000_000))]
    drop_every: usize,
    /// Restart the board (sequence and clock from zero) after this many frames.
    #[arg(long, value_parser = crate::args::count(1usize, 1_000_000_000))]
    reset_after: Option<usize>,
    /// Replay this session's encoder stream instead of a plain roll: each eye first rolls through its
    /// index markers (start-up homing), then sends the session's samples as raw counts, in real time.
    #[arg(long)]
    session: Option<PathBuf>,
    /// With --session: CLOCK_MONOTONIC time (ns) at which the session's first encoder sample is sent
    /// (default: right after the roll, which starts now). Other processes replaying the same session's
    /// frames use the same anchor.
    #[arg(long, value_parser = crate::args::count(0i64, i64::MAX / 2))]
    start_ns: Option<i64>,
    /// With --session: draws the links' raw-count origins and roll starts.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Execute move commands read from the port (after the start-up roll, both eyes streamed at
    /// --rate-hz) for --seconds; `abvs gaze saccade` drives it.
    #[arg(long)]
    serve: bool,
    /// With --serve: how long to serve (s, above 0 up to 1e9).
    #[arg(long, default_value_t = 10.0, value_parser = crate::args::seconds())]
    seconds: f64,
}

#[derive(Args)]
pub struct UnitArgs {
    /// Seed of the drawn effect sizes.
    #[arg(long)]
    seed: u64,
    /// Unit model file to write (TOML).
    #[arg(long)]
    out: PathBuf,
    /// Comma-separated effect names to switch on, or "all".
    #[arg(long, default_value = "all")]
    effects: String,
    /// Unit name stored in the file (default sim-<seed>).
    #[arg(long)]
    name: Option<String>,
}

#[derive(Args)]
#[command(group(clap::ArgGroup::new("grid").required(true).args(["step_deg", "grid_n"])))]
pub struct DatasetArgs {
    /// Unit model to simulate (TOML).
    #[arg(long)]
    unit: PathBuf,
    /// Grid step of the commanded Fick grid (deg; the grid may hold at most 2e6 poses).
    #[arg(long, value_parser = crate::args::positive_up_to(90.0))]
    step_deg: Option<f64>,
    /// Instead of a step: n values per axis (the paper's n^3 fine-tuning sets; 2 to 125).
    #[arg(long, value_parser = crate::args::count(2usize, 125))]
    grid_n: Option<usize>,
    /// Keep N commanded poses drawn at random, visited in random order (1 to 2e6).
    #[arg(long, value_parser = crate::args::count(1usize, 2_000_000))]
    random: Option<usize>,
    /// Seed of the noise, dropouts and random subset.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Probability in [0, 0.99] that a measurement fails and the sample is absent.
    #[arg(long, default_value_t = 0.05, value_parser = crate::args::finite_in(0.0, 0.99))]
    dropout: f64,
    /// Gravity direction in B, "gx,gy,gz", a unit vector (default head upright: 0,1,0).
    #[arg(long, default_value = "0,1,0", value_parser = crate::args::gravity, allow_hyphen_values = true)]
    gravity: [f64; 3],
    /// Half-ranges of alpha, beta, gamma (deg, each in (0, 90]), "a,b,g" (default the paper's 30,15,30).
    #[arg(long, default_value = "30,15,30", value_parser = crate::args::half_ranges)]
    range: [f64; 3],
    /// Dataset CSV to write (docs/spec/dataset.md).
    #[arg(long)]
    out: PathBuf,
}

impl DatasetArgs {
    /// The commanded grid's size before any work.
    pub fn check(&self) -> anyhow::Result<()> {
        if let Some(s) = self.step_deg {
            crate::args::check_grid("--step-deg", self.range, s)?;
        }
        Ok(abvs_runtime::outputs::check_file_writable("--out", &self.out)?)
    }
}

/// `abvs sim board --session`: the session's encoder stream sent in real time, each frame when
/// CLOCK_MONOTONIC reaches its time (board time is the process's own clock, from its start).
fn session_board(a: BoardArgs) -> anyhow::Result<ExitCode> {
    let dir = a.session.as_ref().expect("checked by the caller");
    let session =
        abvs_runtime_core::session::Session::open(dir).with_context(|| format!("opening {}", dir.display()))?;
    let board = abvs_sim::board::SessionBoard {
        rate_hz: a.rate_hz,
        corrupt_every: a.corrupt_every,
        drop_every: a.drop_every,
        ..abvs_sim::board::SessionBoard::from_seed(a.seed)
    };
    let script = board.script(&session.encoders)?;
    let shift = abvs_sim::board::clock_shift(&script, &session.encoders, a.start_ns);
    let mut port = abvs_board::port::open_port(&a.port, 1_000_000)?;
    let sent =
        abvs_sim::board::send_timed(&mut port, &script, shift).with_context(|| format!("writing to {}", a.port))?;
    eprintln!("sent {sent} frames to {} (session {})", a.port, dir.display());
    Ok(ExitCode::SUCCESS)
}

pub fn run(cmd: SimCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        SimCmd::AprilgridSession(a) => crate::camcal::sim_session(a),
        SimCmd::StereoSession(a) => crate::camcal::sim_stereo(a),
        SimCmd::Repeatability(a) => crate::repeat::sim(a),
        SimCmd::Board(a) if a.serve => {
            eprintln!("{}", abvs_sim::board_server::serve_board(&a.port, a.seed, a.rate_hz, a.seconds)?);
            Ok(ExitCode::SUCCESS)
        }
        SimCmd::Board(a) if a.session.is_some() => session_board(a),
        SimCmd::Board(a) => {
            let sim = abvs_sim::board::BoardSim {
                frames: a.frames,
                rate_hz: a.rate_hz,
                corrupt_every: a.corrupt_every,
                drop_every: a.drop_every,
                reset_after: a.reset_after,
            };
            let mut port = abvs_board::port::open_port(&a.port, 1_000_000)?;
            let period = std::time::Duration::from_secs_f64(1.0 / a.rate_hz.max(1.0));
            let sent = abvs_sim::board::send_paced(&mut port, &sim.frames(), period)
                .with_context(|| format!("writing to {}", a.port))?;
            eprintln!("sent {sent} frames to {}", a.port);
            Ok(ExitCode::SUCCESS)
        }
        SimCmd::Session(a) => {
            let spec = abvs_sim::synth::SessionSpec {
                seed: a.seed,
                frames: a.frames,
                fps: a.fps,
                width: a.width,
                height: a.height,
                fk_method: a.fk_method,
                calib_step_deg: a.calib_step_deg,
                supersample: a.supersample,
                readout_ms: a.readout_ms,
                exposure_ms: a.exposure_ms,
                pursuit_deg_s: a.pursuit_deg_s,
                fixation_m: a.fixation_m,
                time_offset_ms: a.time_offset_ms,
                ..Default::default()
            };
            // refused before any work (a session takes minutes to render)
            spec.validate()?;
            a.check()?;
            a.clear_earlier()?;
            let pb = crate::progress_bar(a.frames as u64, "render");
            abvs_sim::synth::generate(&spec, &a.out, &mut |stage, done, total| {
                pb.set_message(stage.to_string());
                pb.set_length(total as u64);
                pb.set_position(done as u64);
            })?;
            pb.finish_and_clear();
            eprintln!("wrote session {} ({} frames)", a.out.display(), a.frames);
            Ok(ExitCode::SUCCESS)
        }
        SimCmd::Unit(a) => {
            let mut u = draw_unit(a.seed, &Effect::parse_list(&a.effects)?);
            if let Some(n) = a.name {
                u.name = n;
            }
            u.save(&a.out)?;
            eprintln!("wrote {} ({} effects on)", a.out.display(), u.enabled_effects().len());
            Ok(ExitCode::SUCCESS)
        }
        SimCmd::Dataset(a) => {
            let unit = UnitModel::load(&a.unit)?;
            let commanded = match (a.step_deg, a.grid_n) {
                (Some(s), None) => Commanded::Step(s),
                (None, Some(n)) => Commanded::PerAxis(n),
                _ => bail!("give --step-deg S or --grid-n N"),
            };
            let spec = SimSpec {
                commanded,
                range_deg: a.range,
                random: a.random,
                seed: a.seed,
                dropout: a.dropout,
                gravity: a.gravity,
            };
            let t0 = std::time::Instant::now();
            let pb = crate::progress_bar(0, "simulating");
            let (data, stats) = simulate_dataset(&unit, &spec, crate::progress_to(&pb))?;
            pb.finish_and_clear();
            data.write(&a.out)?;
            eprintln!(
                "wrote {}: {} samples of {} commanded ({} unreachable nominally, {} for this unit, {} failed measurements); \
                 max ideal-vs-measured deviation {:.2} deg, {:.2} mm; {:.2} s",
                a.out.display(),
                stats.written,
                stats.commanded,
                stats.unreachable_nominal,
                stats.unreachable_unit,
                stats.failed_measurement,
                stats.max_dev_rot_deg,
                stats.max_dev_trans_mm,
                t0.elapsed().as_secs_f64()
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `NEAR..FAR` in metres (e.g. `0.5..2`), 0.2 <= NEAR < FAR <= 5.
fn parse_depth_range(s: &str) -> Result<[f64; 2], String> {
    let bad = || format!("`{s}` is not NEAR..FAR in metres (e.g. 0.5..2)");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let (near, far): (f64, f64) = (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
    if !(0.2..=5.0).contains(&near) || !(0.2..=5.0).contains(&far) || near >= far {
        return Err(format!("{s}: need 0.2 <= NEAR < FAR <= 5 (m)"));
    }
    Ok([near, far])
}
