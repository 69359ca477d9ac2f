//! Simulated drive boards (tests and `abvs sim board`): the encoder stream's frames
//! (`abvs_board::protocol`) from a synthetic link roll with injected faults
//! ([`BoardSim`]), or from a recorded session after a start-up roll through the index markers
//! ([`SessionBoard`]). Offline: the runtime only decodes what a board sends.
use abvs_runtime_core::session::EncoderRecord;

/// Why a session cannot be scripted as a board's frame stream.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ScriptError {
    #[error("the session has no encoder samples")]
    NoEncoderSamples,
    /// A count (origin + session count, or the roll's) does not fit the wire's i32.
    #[error("{what}: raw count {value} exceeds i32")]
    CountOverflow { what: &'static str, value: i64 },
    /// An encoder row names an eye the board has no origin for.
    #[error("eye {0} in the session")]
    UnknownEye(u8),
}
use abvs_board::protocol::BoardFrame;

/// What a simulated board sends (for tests and `abvs sim board`).
#[derive(Debug, Clone)]
pub struct BoardSim {
    pub frames: usize,
    pub rate_hz: f64,
    /// Every n-th frame gets a flipped byte (0 = never).
    pub corrupt_every: usize,
    /// Every n-th frame is not sent (0 = never).
    pub drop_every: usize,
    /// The board restarts after this many frames (None = never).
    pub reset_after: Option<usize>,
}

impl BoardSim {
    /// The byte stream, frame by frame (a slow link roll on all three links).
    pub fn frames(&self) -> Vec<Vec<u8>> {
        let mut out = vec![];
        let mut seq = 0u16;
        let mut t0 = 0usize;
        for k in 0..self.frames {
            if Some(k) == self.reset_after {
                seq = 0;
                t0 = k;
            }
            let t_us = ((k - t0) as f64 * 1e6 / self.rate_hz) as u64 + 1000;
            let c = (k as i32) * 7;
            let f = BoardFrame { seq, board_time_us: t_us, eye: 0, counts: [c, c + 1, c + 2], index: 0 };
            seq = seq.wrapping_add(1);
            out.extend(impair(k, f.encode().to_vec(), self.corrupt_every, self.drop_every));
        }
        out
    }
}

/// A simulated link's faults: every `drop_every`-th frame is not sent, every `corrupt_every`-th
/// gets a flipped bit in its counts (0 = never).
fn impair(k: usize, mut bytes: Vec<u8>, corrupt_every: usize, drop_every: usize) -> Option<Vec<u8>> {
    if drop_every > 0 && k % drop_every == drop_every - 1 {
        return None;
    }
    if corrupt_every > 0 && k % corrupt_every == corrupt_every - 1 {
        bytes[20] ^= 0x40;
    }
    Some(bytes)
}

/// A simulated drive board replaying a session's encoder stream (for tests and `abvs sim board
/// --session`): each eye first rolls its links together through the index markers, as at
/// start-up (`abvs_eye::encoder::StartupRoll`), then sends the session's samples as raw counts,
/// `origin + homed count`. Index flags are sent during the roll only (the runtime reads them
/// only while homing).
#[derive(Debug, Clone)]
pub struct SessionBoard {
    /// Raw count of each link at theta = 0, `[eye][link]` (what homing must find).
    pub origin: [[i64; 3]; 2],
    /// Roll start angle of each eye, deg (the links start within the homing tolerance of it).
    pub roll_start_deg: [f64; 2],
    /// Roll length, deg (homing decides within 180 deg + the tolerance).
    pub roll_deg: f64,
    /// Roll speed, counts per sample; samples are sent at `rate_hz` per eye.
    pub step_counts: i64,
    /// Time the links rest at the end of the roll before the session starts (s).
    pub settle_s: f64,
    pub rate_hz: f64,
    pub corrupt_every: usize,
    pub drop_every: usize,
}

impl SessionBoard {
    /// A board with origins and roll starts drawn from `seed`.
    pub fn from_seed(seed: u64) -> Self {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        SessionBoard {
            origin: [0; 2].map(|_| [0; 3].map(|_| rng.gen_range(-1_000_000_000i64..1_000_000_000))),
            // Rolls that stay within (-180, 180] deg, so the decided home is the origin itself.
            roll_start_deg: [0; 2].map(|_| rng.gen_range(-175.0..-165.0)),
            roll_deg: 200.0,
            step_counts: 64,
            settle_s: 0.25,
            rate_hz: 1000.0,
            corrupt_every: 0,
            drop_every: 0,
        }
    }

    /// The frames to send, each with its send time on the session's clock (ns), in time order:
    /// the roll, then `settle_s` at rest, then the session's samples. Board time counts from 1 ms
    /// before the first frame.
    pub fn script(&self, encoders: &[EncoderRecord]) -> Result<Vec<(i64, Vec<u8>)>, ScriptError> {
        use abvs_eye::encoder::{deg_to_counts, StartupRoll, DEFAULT_TOLERANCE_COUNTS};
        let t_first = encoders.iter().map(|r| r.t_ns).min().ok_or(ScriptError::NoEncoderSamples)?;
        let period_ns = (1e9 / self.rate_hz).round() as i64;
        let n_roll = deg_to_counts(self.roll_deg, 0) / self.step_counts.max(1);
        let n_settle = (self.settle_s * self.rate_hz).round() as i64;
        let t0 = t_first - (n_roll + n_settle + 1) * period_ns;
        let raw =
            |v: i64, what: &'static str| i32::try_from(v).map_err(|_| ScriptError::CountOverflow { what, value: v });
        let mut timed: Vec<(i64, u8, [i32; 3], u8)> = vec![];
        for eye in 0..2 {
            let s = deg_to_counts(self.roll_start_deg[eye], 0);
            // Start angles spread by a third of the homing tolerance, as real links settle.
            let d = DEFAULT_TOLERANCE_COUNTS / 3;
            let roll = StartupRoll {
                start: [s, s + d, s - d],
                origin: self.origin[eye],
                step: self.step_counts,
                noise: 1,
                width: 16,
            };
            let mut last = ([0; 3], 0);
            for (k, h) in roll.stream(eye as u64 + 1).take(n_roll as usize).enumerate() {
                let counts = [raw(h.counts[0], "roll")?, raw(h.counts[1], "roll")?, raw(h.counts[2], "roll")?];
                let index = (0..3).fold(0u8, |m, i| m | (u8::from(h.index[i]) << i));
                timed.push((t0 + k as i64 * period_ns, eye as u8, counts, index));
                last = (counts, index);
            }
            for k in n_roll..n_roll + n_settle {
                timed.push((t0 + k * period_ns, eye as u8, last.0, last.1));
            }
        }
        for r in encoders {
            let o = self.origin.get(usize::from(r.eye)).ok_or(ScriptError::UnknownEye(r.eye))?;
            let counts =
                [raw(o[0] + r.count1, "session")?, raw(o[1] + r.count2, "session")?, raw(o[2] + r.count3, "session")?];
            timed.push((r.t_ns, r.eye, counts, 0));
        }
        timed.sort_by_key(|x| (x.0, x.1));
        let board_zero = t0 - 1_000_000;
        let mut out = Vec::with_capacity(timed.len());
        for (k, (t, eye, counts, index)) in timed.into_iter().enumerate() {
            let f = BoardFrame { seq: k as u16, board_time_us: ((t - board_zero) / 1000) as u64, eye, counts, index };
            out.extend(impair(k, f.encode().to_vec(), self.corrupt_every, self.drop_every).map(|b| (t, b)));
        }
        Ok(out)
    }
}

/// Sends `frames` to `port`, one every `period` (`abvs sim board`'s plain roll); the frames sent.
pub fn send_paced<W: std::io::Write + ?Sized>(
    port: &mut W,
    frames: &[Vec<u8>],
    period: std::time::Duration,
) -> std::io::Result<usize> {
    for f in frames {
        port.write_all(f)?;
        std::thread::sleep(period);
    }
    port.flush()?;
    Ok(frames.len())
}

/// What to add to a [`SessionBoard::script`]'s times to get CLOCK_MONOTONIC send times: the session's first
/// encoder sample at `start_ns`, or (without it) the roll's first frame 1 ms from now.
pub fn clock_shift(script: &[(i64, Vec<u8>)], encoders: &[EncoderRecord], start_ns: Option<i64>) -> i64 {
    let t_first = encoders.iter().map(|r| r.t_ns).min().unwrap_or(0);
    match start_ns {
        Some(s) => s - t_first,
        None => abvs_runtime_core::messages::monotonic_ns() + 1_000_000 - script.first().map_or(t_first, |x| x.0),
    }
}

/// Sends each frame of `script` when CLOCK_MONOTONIC reaches its time plus `shift` (ns), in real time
/// (`abvs sim board --session`); the frames sent.
pub fn send_timed<W: std::io::Write + ?Sized>(
    port: &mut W,
    script: &[(i64, Vec<u8>)],
    shift: i64,
) -> std::io::Result<usize> {
    use abvs_runtime_core::messages::monotonic_ns;
    for (t, bytes) in script {
        let wait = t + shift - monotonic_ns();
        if wait > 0 {
            std::thread::sleep(std::time::Duration::from_nanos(wait as u64));
        }
        port.write_all(bytes)?;
    }
    port.flush()?;
    Ok(script.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timed_frames_go_out_in_order_at_their_times() {
        let script = vec![(0i64, vec![1u8, 2]), (2_000_000, vec![3]), (4_000_000, vec![4, 5])];
        let mut out = Vec::new();
        let t0 = abvs_runtime_core::messages::monotonic_ns();
        // the first frame is due now, the last 4 ms later
        let sent = send_timed(&mut out, &script, t0).unwrap();
        assert_eq!((sent, out), (3, vec![1, 2, 3, 4, 5]));
        assert!(abvs_runtime_core::messages::monotonic_ns() - t0 >= 4_000_000);
        let enc = [EncoderRecord { t_ns: 500, eye: 0, count1: 0, count2: 0, count3: 0 }];
        assert_eq!(clock_shift(&script, &enc, Some(10_500)), 10_000);
        let mut out = Vec::new();
        assert_eq!(send_paced(&mut out, &[vec![7], vec![8]], std::time::Duration::ZERO).unwrap(), 2);
        assert_eq!(out, vec![7, 8]);
    }
}
