//! `abvs sim board --serve` (a simulated drive board executing move commands) and
//! `abvs gaze saccade` (home from the board's stream, solve the calibrated IK of each target,
//! send minimum-jerk moves as command frames, watch the encoders arrive).
use abvs_calib::gaze::{Binocular, Torsion, YokedSaccade};
use abvs_calib::ik::CalibratedIk;
use abvs_calib::model::{FkModel, FkState};
use abvs_camera::StereoCalibration;
use abvs_eye::encoder::counts_to_deg;
use abvs_eye::pose::Pose;
use abvs_eye::saccade::PEAK_SPEED_DEG_S;
use abvs_runtime::sources::encoder_link::{
    open_port, BoardFrame, CommandDecoder, CommandFrame, Decoder, LinkEvent, COMMAND_MOVE,
};
use abvs_runtime::sources::encoder_stream::EncoderTracker;
use abvs_runtime_core::messages::monotonic_ns;
use abvs_runtime_core::session::EncoderRecord;
use abvs_sim::servo_board::{Sample, ServoBoard};
use anyhow::{bail, Context};
use clap::Args;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// `abvs sim board --serve`: the start-up roll, then both eyes' encoder frames at `rate_hz`
/// while executing the move commands read from the same port, for `seconds`.
pub fn serve_board(port_name: &str, seed: u64, rate_hz: f64, seconds: f64) -> anyhow::Result<ExitCode> {
    let mut port = open_port(port_name, 1_000_000).map_err(anyhow::Error::msg)?;
    port.set_timeout(Duration::from_millis(1))?;
    let mut board = ServoBoard::from_seed(seed);
    board.roll.rate_hz = rate_hz;
    let t0 = monotonic_ns();
    let now_us = || ((monotonic_ns() - t0) / 1000) as u64 + 1000;
    let mut decoder = CommandDecoder::new();
    let mut seq = 0u16;
    let mut buf = [0u8; 1024];
    let mut dropped = 0u64;
    // A frame the wire cannot take now is lost (counted), as on a UART; other errors end the run.
    let mut send = |port: &mut Box<dyn serialport::SerialPort>, s: Sample| -> std::io::Result<()> {
        let f = BoardFrame { seq, board_time_us: s.0, eye: s.1, counts: s.2, index: s.3 };
        seq = seq.wrapping_add(1);
        match port.write_all(&f.encode()) {
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => {
                dropped += 1;
                Ok(())
            }
            r => r,
        }
    };
    let mut poll = |port: &mut Box<dyn serialport::SerialPort>, board: &mut ServoBoard| -> std::io::Result<()> {
        if port.bytes_to_read().unwrap_or(0) > 0 {
            let n =
                port.read(&mut buf)
                    .or_else(|e| if e.kind() == std::io::ErrorKind::TimedOut { Ok(0) } else { Err(e) })?;
            for c in decoder.feed(&buf[..n]) {
                board.command(&c, now_us());
            }
        }
        Ok(())
    };
    let wait_until = |t_us: u64| {
        let now = now_us();
        if t_us > now {
            std::thread::sleep(Duration::from_micros((t_us - now).min(2000)));
        }
    };
    let end_us = (seconds * 1e6) as u64 + 1000;
    let mut ended = None;
    let startup = board.startup(1000);
    for s in startup {
        while now_us() < s.0 {
            wait_until(s.0);
        }
        if let Err(e) = send(&mut port, s) {
            ended = Some(e);
            break;
        }
    }
    let period_us = (1e6 / rate_hz).round().max(1.0) as u64;
    let mut next = board.startup_end_us(1000);
    while ended.is_none() && next < end_us {
        while now_us() < next {
            wait_until(next);
        }
        if let Err(e) = poll(&mut port, &mut board) {
            ended = Some(e);
            break;
        }
        for eye in 0..2 {
            let s = board.sample(eye, next);
            if let Err(e) = send(&mut port, s) {
                ended = Some(e);
                break;
            }
        }
        next += period_us;
    }
    let _ = port.flush();
    eprintln!(
        "board: {} moves executed, {} refused; {dropped} frames the wire did not take; commands: {} ok, {} CRC errors, {} unsupported{}",
        board.executed.len(),
        board.refused,
        decoder.stats.commands,
        decoder.stats.crc_errors,
        decoder.stats.unsupported,
        ended.map(|e| format!("; port closed ({e})")).unwrap_or_default()
    );
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct SaccadeArgs {
    /// The drive board's serial port (a /dev/pts/N for the simulated board).
    #[arg(long)]
    port: String,
    /// Calibration directory: stereo.yaml and eye0, eye1 (FK models).
    #[arg(long)]
    calib: PathBuf,
    /// Targets in order, "alpha,beta,gamma;..." (deg): both eyes to that orientation.
    #[arg(long, allow_hyphen_values = true)]
    orientation: Option<String>,
    /// Targets in order, "x,y,z;..." (m, left home camera frame): both eyes fixate each point.
    #[arg(long, allow_hyphen_values = true)]
    point: Option<String>,
    /// Torsion rule for --point: listing or zero-fick.
    #[arg(long, value_enum, default_value_t = Torsion::Listing)]
    torsion: Torsion,
    /// Peak link speed of the minimum-jerk moves (deg/s, up to 5000).
    #[arg(long, default_value_t = PEAK_SPEED_DEG_S, value_parser = crate::args::positive_up_to(5000.0))]
    peak_deg_s: f64,
    /// Give up waiting for homing or for an arrival after this long (s, up to 1e9).
    #[arg(long, default_value_t = 10.0, value_parser = crate::args::seconds())]
    timeout_s: f64,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

/// What one saccade did, measured on the encoder stream.
#[derive(Debug)]
struct Report {
    target: [f64; 3],
    /// Per eye: link angles before and after (deg), target counts (homed).
    from_deg: [[f64; 3]; 2],
    to_deg: [[f64; 3]; 2],
    target_counts: [[i64; 3]; 2],
    /// Largest link travel over both eyes (deg).
    travel_deg: f64,
    planned_ms: f64,
    /// From the first moving sample to the first sample at the target (board time), per eye.
    measured_ms: [f64; 2],
    /// Largest link speed between consecutive samples (deg/s), per eye.
    peak_deg_s: [f64; 2],
    arrived: bool,
}

impl Report {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "target": self.target,
            "from_deg": self.from_deg,
            "to_deg": self.to_deg,
            "target_counts": self.target_counts,
            "travel_deg": self.travel_deg,
            "planned_ms": self.planned_ms,
            "measured_ms": self.measured_ms,
            "peak_deg_s": self.peak_deg_s,
            "arrived": self.arrived,
        })
    }
}

fn parse_list(s: &str) -> anyhow::Result<Vec<[f64; 3]>> {
    s.split(';').map(|t| crate::parse3(t.trim()).map_err(anyhow::Error::msg)).collect()
}

/// A homed sample on the board's clock.
#[derive(Debug, Clone, Copy)]
struct Timed {
    board_us: u64,
    eye: usize,
    /// Homed counts.
    counts: [i64; 3],
}

impl Timed {
    fn deg(&self) -> [f64; 3] {
        self.counts.map(|c| counts_to_deg(c, 0))
    }
}

/// The board's stream as `gaze saccade` reads it: the runtime's tracker (homing, clock mapping,
/// homed records: what the runtime consumes) and, beside it, each frame's board time, which
/// times the moves without the host's scheduling.
struct Link {
    port: Box<dyn serialport::SerialPort>,
    tracker: EncoderTracker,
    frames: Decoder,
    records: Vec<EncoderRecord>,
    homed_records: u64,
    buf: Vec<u8>,
}

impl Link {
    fn new(mut port: Box<dyn serialport::SerialPort>) -> Self {
        let _ = port.set_timeout(Duration::from_millis(20));
        Link {
            port,
            tracker: EncoderTracker::new(),
            frames: Decoder::new(),
            records: vec![],
            homed_records: 0,
            buf: vec![0; 1 << 14],
        }
    }

    /// Reads what arrived: homed samples of frames after homing, on board time.
    fn poll(&mut self) -> std::io::Result<Vec<Timed>> {
        let n = match self.port.read(&mut self.buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => 0,
            Err(e) => return Err(e),
        };
        let bytes = &self.buf[..n];
        self.tracker.feed(bytes, monotonic_ns(), &mut self.records);
        self.homed_records += self.records.len() as u64;
        self.records.clear();
        let home = self.tracker.stats().home_counts;
        let mut out = vec![];
        for ev in self.frames.feed(bytes) {
            let f = match ev {
                LinkEvent::Frame(f) | LinkEvent::Reset(f) => f,
            };
            let eye = usize::from(f.eye);
            if let Some(Some(h)) = home.get(eye) {
                let counts = std::array::from_fn(|i| i64::from(f.counts[i]) - h[i]);
                out.push(Timed { board_us: f.board_time_us, eye, counts });
            }
        }
        Ok(out)
    }
}

pub fn saccade(a: SaccadeArgs) -> anyhow::Result<ExitCode> {
    let targets = match (&a.orientation, &a.point) {
        (Some(o), None) => parse_list(o)?,
        (None, Some(p)) => parse_list(p)?,
        _ => bail!("give exactly one of --orientation and --point"),
    };
    let torsion = a.torsion;
    let stereo = StereoCalibration::read_yaml(a.calib.join("stereo.yaml"))?;
    let load = |e: &str| FkModel::load(&a.calib.join(e)).with_context(|| format!("{}: FK model", a.calib.display()));
    let models = [load("eye0")?, load("eye1")?];
    let bino = Binocular {
        left: CalibratedIk::new(&models[0]),
        right: CalibratedIk::new(&models[1]),
        left_to_right: Pose::new(stereo.rotation, stereo.translation_mm),
        torsion,
    };
    let port = open_port(&a.port, 1_000_000).map_err(anyhow::Error::msg)?;
    let mut writer = port.try_clone().with_context(|| format!("{}: cannot clone the port", a.port))?;
    let mut link = Link::new(port);
    let timeout = Duration::from_secs_f64(a.timeout_s);
    let mut latest: [Option<Timed>; 2] = [None, None];
    // Homing decides during the start-up roll; then wait until the links rest (50 equal samples).
    let t_wait = std::time::Instant::now();
    let mut rest = [0usize; 2];
    while rest.iter().any(|&n| n < 50) {
        for t in link.poll().with_context(|| format!("reading {}", a.port))? {
            let same = latest[t.eye].is_some_and(|p| p.counts == t.counts);
            rest[t.eye] = if same { rest[t.eye] + 1 } else { 0 };
            latest[t.eye] = Some(t);
        }
        if t_wait.elapsed() > timeout {
            bail!(
                "{}: both eyes not homed and at rest after {:.1} s ({:?})",
                a.port,
                a.timeout_s,
                link.tracker.stats()
            );
        }
    }
    let home = link.tracker.stats().home_counts.map(|h| h.expect("homed"));
    eprintln!("homed: home counts {home:?}");
    // The models' motion history starts where the links are.
    let mut st: [FkState; 2] = [models[0].state(), models[1].state()];
    for e in 0..2 {
        let th = latest[e].expect("a sample").deg();
        models[e].eval(&mut st[e], &th, [0.0, 1.0, 0.0])?;
    }
    let mut reports = vec![];
    let mut seq = 0u16;
    for target in targets {
        let sol: [[f64; 3]; 2] = match &a.point {
            Some(_) => {
                let [l, r] = &mut st;
                let f = bino.fixate_and_move([l, r], target.map(|v| v * 1000.0), [[0.0, 1.0, 0.0]; 2])?;
                [f.left.ik.theta_deg, f.right.ik.theta_deg]
            }
            None => {
                let mut out = [[0.0; 3]; 2];
                for (e, ik) in [&bino.left, &bino.right].into_iter().enumerate() {
                    out[e] = ik.solve_and_move(&mut st[e], target, [0.0, 1.0, 0.0])?.theta_deg;
                }
                out
            }
        };
        let from: [[f64; 3]; 2] = [0, 1].map(|e| latest[e].expect("a sample").deg());
        // Both eyes move together (yoked): the slower eye's duration for both.
        let plan = YokedSaccade::plan(from, sol, a.peak_deg_s);
        let (to, target_counts, duration_us) = (plan.to_deg, plan.target_counts, plan.duration_us);
        for e in 0..2 {
            let raw: [i32; 3] = std::array::from_fn(|i| (home[e][i] + target_counts[e][i]) as i32);
            let c = CommandFrame { seq, eye: e as u8, kind: COMMAND_MOVE, target_counts: raw, duration_us };
            seq = seq.wrapping_add(1);
            writer.write_all(&c.encode()).with_context(|| format!("writing to {}", a.port))?;
        }
        writer.flush()?;
        // Watch the stream until both eyes sit at their targets for 10 samples (board time).
        let (mut moved_at, mut arrived_at) = ([None::<u64>; 2], [None::<u64>; 2]);
        let mut peak = [0.0f64; 2];
        let mut still = [0usize; 2];
        let start_counts = [0, 1].map(|e| latest[e].expect("a sample").counts);
        let t_send = std::time::Instant::now();
        while still.iter().any(|&n| n < 10) && t_send.elapsed() < timeout {
            for t in link.poll().with_context(|| format!("reading {}", a.port))? {
                let e = t.eye;
                if let Some(prev) = latest[e] {
                    let dt = t.board_us.saturating_sub(prev.board_us) as f64 * 1e-6;
                    if dt > 0.0 {
                        for i in 0..3 {
                            peak[e] = peak[e].max(counts_to_deg((t.counts[i] - prev.counts[i]).abs(), 0) / dt);
                        }
                    }
                }
                if moved_at[e].is_none() && t.counts != start_counts[e] {
                    moved_at[e] = Some(t.board_us);
                }
                if t.counts == target_counts[e] {
                    arrived_at[e].get_or_insert(t.board_us);
                    still[e] += 1;
                } else {
                    arrived_at[e] = None;
                    still[e] = 0;
                }
                latest[e] = Some(t);
            }
        }
        let arrived = still.iter().all(|&n| n >= 10);
        let measured_ms = [0, 1].map(|e| match (moved_at[e], arrived_at[e]) {
            (Some(m), Some(a)) => a.saturating_sub(m) as f64 * 1e-3,
            (None, Some(_)) => 0.0,
            _ => f64::NAN,
        });
        let travel_deg = plan.travel_deg();
        let rep = Report {
            target,
            from_deg: from,
            to_deg: to,
            target_counts,
            travel_deg,
            planned_ms: duration_us as f64 * 1e-3,
            measured_ms,
            peak_deg_s: peak,
            arrived,
        };
        if !a.json {
            println!(
                "saccade to [{:.3}, {:.3}, {:.3}]: link travel {:.2} deg, planned {:.2} ms (minimum jerk, peak {:.0} deg/s); \
                 measured {:.2} / {:.2} ms, peak {:.0} / {:.0} deg/s (left / right){}",
                target[0],
                target[1],
                target[2],
                travel_deg,
                rep.planned_ms,
                a.peak_deg_s,
                measured_ms[0],
                measured_ms[1],
                peak[0],
                peak[1],
                if arrived { "" } else { "; NOT ARRIVED" }
            );
        }
        reports.push(rep);
    }
    let stats = link.tracker.stats();
    eprintln!(
        "encoder stream: {} homed samples consumed (left {}, right {}), {} frames, {} CRC errors, {} lost",
        link.homed_records,
        stats.samples[0],
        stats.samples[1],
        stats.link.frames,
        stats.link.crc_errors,
        stats.link.lost_frames
    );
    if a.json {
        let v = serde_json::json!({
            "saccades": reports.iter().map(Report::json).collect::<Vec<_>>(),
            "encoders": stats,
            "homed_samples": link.homed_records,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(if reports.iter().all(|r| r.arrived) { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
