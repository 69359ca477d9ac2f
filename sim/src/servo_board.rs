//! A simulated drive board that executes commands (`abvs sim board --serve`): at power-up each
//! eye rolls its links together through the index markers (start-up homing, as
//! [`crate::board::SessionBoard`] does), then the links rest and the board streams both eyes'
//! encoder frames while it executes the move commands it receives (`abvs_board::protocol`'s
//! command frame): from where the links are, a minimum-jerk profile in link space
//! ([`abvs_eye::saccade::MinJerk`]) to the target counts over the commanded duration. The motors
//! track the profile to the count (the encoders read it rounded to counts).
use crate::board::SessionBoard;
use abvs_board::protocol::{CommandFrame, COMMAND_MOVE};
use abvs_eye::encoder::{deg_to_counts, StartupRoll, DEFAULT_TOLERANCE_COUNTS};
use abvs_eye::saccade::MinJerk;

#[derive(Debug, Clone, Copy)]
struct EyeServo {
    /// Raw counts where the links are when no move is under way.
    rest: [f64; 3],
    /// The move under way (raw counts) and its start (board time, us).
    mv: Option<(MinJerk, u64)>,
}

/// One executed command, for the board's log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Executed {
    pub seq: u16,
    pub eye: u8,
    pub start_us: u64,
    pub duration_us: u32,
    /// Largest link travel of the move (counts).
    pub travel_counts: f64,
}

/// The board: its start-up roll and the servo state of both eyes.
#[derive(Debug, Clone)]
pub struct ServoBoard {
    /// Origins (raw count at theta = 0) and roll parameters.
    pub roll: SessionBoard,
    eyes: [EyeServo; 2],
    pub executed: Vec<Executed>,
    /// Commands refused (eye other than 0 or 1, or a target beyond i32).
    pub refused: u64,
}

/// A frame's content before sequencing: board time (us), eye, raw counts, index flags.
pub type Sample = (u64, u8, [i32; 3], u8);

impl ServoBoard {
    /// A board with origins and roll starts drawn from `seed` (as [`SessionBoard::from_seed`]).
    pub fn from_seed(seed: u64) -> Self {
        ServoBoard {
            roll: SessionBoard::from_seed(seed),
            eyes: [EyeServo { rest: [0.0; 3], mv: None }; 2],
            executed: vec![],
            refused: 0,
        }
    }

    /// The start-up roll of both eyes (interleaved, one sample per eye every 1/rate_hz from
    /// board time `t0_us`), then `settle_s` at rest; the links rest where the roll ended.
    #[allow(clippy::needless_range_loop)] // eye-indexed: roll parameters, state and output
    pub fn startup(&mut self, t0_us: u64) -> Vec<Sample> {
        let r = &self.roll;
        let period_us = 1e6 / r.rate_hz;
        let n_roll = deg_to_counts(r.roll_deg, 0) / r.step_counts.max(1);
        let n_settle = (r.settle_s * r.rate_hz).round() as i64;
        let mut out = vec![];
        let mut last = [([0i32; 3], 0u8); 2];
        for eye in 0..2 {
            let s = deg_to_counts(r.roll_start_deg[eye], 0);
            let d = DEFAULT_TOLERANCE_COUNTS / 3;
            let roll = StartupRoll {
                start: [s, s + d, s - d],
                origin: r.origin[eye],
                step: r.step_counts,
                noise: 1,
                width: 16,
            };
            for (k, h) in roll.stream(eye as u64 + 1).take(n_roll as usize).enumerate() {
                let counts = h.counts.map(|c| c as i32);
                let index = (0..3).fold(0u8, |m, i| m | (u8::from(h.index[i]) << i));
                out.push((t0_us + (k as f64 * period_us) as u64, eye as u8, counts, index));
                last[eye] = (counts, index);
            }
            // The links rest where the roll ended (its last noiseless position).
            self.eyes[eye].rest = std::array::from_fn(|i| (r.origin[eye][i] + roll.theta_counts(i, n_roll - 1)) as f64);
            for k in n_roll..n_roll + n_settle {
                out.push((t0_us + (k as f64 * period_us) as u64, eye as u8, last[eye].0, last[eye].1));
            }
        }
        out.sort_by_key(|x| (x.0, x.1));
        out
    }

    /// Board time (us) at which the start-up sequence from `t0_us` ends.
    pub fn startup_end_us(&self, t0_us: u64) -> u64 {
        let r = &self.roll;
        let n = deg_to_counts(r.roll_deg, 0) / r.step_counts.max(1) + (r.settle_s * r.rate_hz).round() as i64;
        t0_us + (n as f64 * 1e6 / r.rate_hz) as u64
    }

    /// Where eye's links are at board time `now_us` (raw counts, continuous).
    fn position(&mut self, eye: usize, now_us: u64) -> [f64; 3] {
        let e = &mut self.eyes[eye];
        match e.mv {
            Some((m, t0)) => {
                let t = now_us.saturating_sub(t0) as f64 * 1e-6;
                if t >= m.duration_s {
                    e.rest = m.to;
                    e.mv = None;
                    m.to
                } else {
                    m.at(t)
                }
            }
            None => e.rest,
        }
    }

    /// Executes a command received at board time `now_us`: the move starts from where the links
    /// are (a move under way is replaced).
    pub fn command(&mut self, c: &CommandFrame, now_us: u64) {
        let eye = usize::from(c.eye);
        if eye > 1 || c.kind != COMMAND_MOVE {
            self.refused += 1;
            return;
        }
        let from = self.position(eye, now_us);
        let to = c.target_counts.map(f64::from);
        let m = MinJerk { from, to, duration_s: c.duration_us as f64 * 1e-6 };
        self.eyes[eye].mv = Some((m, now_us));
        self.executed.push(Executed {
            seq: c.seq,
            eye: c.eye,
            start_us: now_us,
            duration_us: c.duration_us,
            travel_counts: (0..3).map(|i| (to[i] - from[i]).abs()).fold(0.0, f64::max),
        });
    }

    /// The encoder sample of `eye` at board time `now_us` (counts rounded, no index flags).
    pub fn sample(&mut self, eye: u8, now_us: u64) -> Sample {
        let p = self.position(usize::from(eye), now_us);
        (now_us, eye, p.map(|c| c.round() as i32), 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_board::protocol::BoardFrame;
    use abvs_board::tracker::{EncoderTracker, HomedSample};
    use abvs_eye::saccade::{MinJerk, PEAK_SPEED_DEG_S};

    #[test]
    fn homes_then_executes_a_minimum_jerk_move() {
        let mut b = ServoBoard::from_seed(3);
        let mut bytes = vec![];
        let mut seq = 0u16;
        let mut push = |s: Sample, bytes: &mut Vec<u8>| {
            bytes.extend(BoardFrame { seq, board_time_us: s.0, eye: s.1, counts: s.2, index: s.3 }.encode());
            seq = seq.wrapping_add(1);
        };
        for s in b.startup(1000) {
            push(s, &mut bytes);
        }
        let t_end = b.startup_end_us(1000);
        // A 30 deg move of link 1 of the left eye at the paper's peak speed.
        let rest = b.sample(0, t_end).2;
        let target = [rest[0] + deg_to_counts(30.0, 0) as i32, rest[1], rest[2]];
        let m = MinJerk::with_peak_speed([0.0; 3], [30.0, 0.0, 0.0], PEAK_SPEED_DEG_S);
        let dur_us = (m.duration_s * 1e6).ceil() as u32;
        let cmd = CommandFrame { seq: 0, eye: 0, kind: COMMAND_MOVE, target_counts: target, duration_us: dur_us };
        b.command(&cmd, t_end + 10_000);
        for k in 0..100 {
            let t = t_end + k * 1000;
            push(b.sample(0, t), &mut bytes);
            push(b.sample(1, t), &mut bytes);
        }
        let mut tr = EncoderTracker::new();
        let mut out: Vec<HomedSample> = vec![];
        for (k, chunk) in bytes.chunks(29).enumerate() {
            tr.feed(chunk, 1_000_000 + k as i64 * 500_000, &mut out);
        }
        assert_eq!(tr.homed(), [true, true]);
        assert_eq!(tr.stats().home_counts, [Some(b.roll.origin[0]), Some(b.roll.origin[1])]);
        let left: Vec<&HomedSample> = out.iter().filter(|r| r.eye == 0).collect();
        let last = left.last().unwrap();
        assert_eq!(last.counts[0] + b.roll.origin[0][0], i64::from(target[0]));
        // Moving frames span the minimum-jerk duration (1 ms samples).
        let after = &left[left.len() - 100..];
        let moving = after.windows(2).filter(|w| w[0].counts[0] != w[1].counts[0]).count() as f64;
        assert!((moving - m.duration_s * 1e3).abs() <= 2.0, "{moving} vs {}", m.duration_s * 1e3);
        assert_eq!(b.executed.len(), 1);
    }
}
