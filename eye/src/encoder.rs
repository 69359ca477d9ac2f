//! Encoder counts <-> link angles, and start-up homing on the shared code wheel
//! (`shared/spec/conventions.md`, Encoders).
//!
//! # Counts
//! A 1448-line wheel read with x4 quadrature and x16 interpolation: [`COUNTS_PER_REV`] =
//! 92672 counts per revolution, 64 per line. `theta_i = 360 * (count_i - home_i) / 92672` deg.
//!
//! # Homing model (our design decision, consistent with conventions.md)
//! - The code wheel is fixed to the base; link i carries read head i. The wheel has three
//!   zero markers, at [`MARKER_COUNTS`] = lines 0, 40 and 724 (0, 9.9448 and 180 deg; the
//!   spec's "9.944 deg" is line 40, as markers sit on lines).
//! - At home (all theta = 0) head i sits exactly on marker i, so head i is at wheel position
//!   `s_i + theta_i` with `s = MARKER_COUNTS`.
//! - A head emits an index pulse whenever it passes ANY of the three markers. The drive board
//!   latches the count at the index edge and reports it in the sample carrying the rising
//!   edge; a run of consecutive `true` flags on one head is one pulse, located at the count of
//!   its first sample. A run already under way in the very first sample has no edge we saw
//!   and is ignored.
//! - At start-up the three links turn together in the + direction (a pure roll, far from any
//!   singularity): their start angles agree pairwise within a tolerance (default 2 deg, plus
//!   [`INDEX_SLACK_COUNTS`] for read noise) and they advance by the same amount up to small
//!   noise; their travels may differ by no more than that either.
//!
//! In terms of the common roll t the events are (deg): 0 {1,2,3}, 9.94 {1}, 170.06 {2},
//! 180 {1,3}, 189.94 {3}, 350.06 {2}. {2} alone occurs twice, so it is ambiguous until the
//! next event; from any start, within 180 deg of travel (plus the tolerance) the pattern is
//! unique and every head has seen at least one of its own pulses.
//!
//! # Decoding
//! Each head's first pulse pins its start angle to one of three values (which marker it
//! was). A hypothesis is one such choice per pulsed link; it must (a) put the pulsed links'
//! start angles within the tolerance of each other, (b) predict every pulse seen and see
//! every pulse it predicts (within [`INDEX_SLACK_COUNTS`]), and (c) leave room for the
//! still silent links to have passed no marker so far. No surviving hypothesis is an error
//! (never a guess); several keep homing pending; one, once all three heads have pulsed, is
//! the answer. Each home count then comes from that link's OWN latched pulse count, in
//! integers, so it is exact; of the values one turn apart, the one that puts theta_i in
//! (-180, 180] deg at the deciding sample. A stream still undecided past 180 deg + twice the
//! tolerance of travel is refused. Work is done only on pulses and at the travel where some
//! hypothesis expects a pulse, which keeps [`Homing::push`] cheap per sample.
use crate::error::{EyeError, Result};

/// 1448 lines x4 quadrature x16 interpolation.
pub const COUNTS_PER_REV: i64 = 92672;
pub const LINES_PER_REV: i64 = 1448;
pub const COUNTS_PER_LINE: i64 = COUNTS_PER_REV / LINES_PER_REV;
/// The three zero markers on the shared wheel, as counts from marker 1: 0, line 40
/// (= 9.9448 deg, the spec's "9.944 deg"; markers sit on lines), line 724 (= 180 deg).
pub const MARKER_COUNTS: [i64; 3] = [0, 40 * 64, 724 * 64];
/// Default pairwise tolerance on the links' start angles (and on their travel difference):
/// 2 deg, rounded to counts.
pub const DEFAULT_TOLERANCE_COUNTS: i64 = (2 * COUNTS_PER_REV + 180) / 360;
/// How far a latched pulse may sit from where a hypothesis puts the marker, how far past an
/// expected marker a head must be before the missing pulse counts, and the read-noise margin
/// added to the tolerance (half a line).
pub const INDEX_SLACK_COUNTS: i64 = COUNTS_PER_LINE / 2;
/// Backward steps up to this are read noise, not motion.
pub const JITTER_COUNTS: i64 = 16;
/// Largest step between two samples: a head must not pass two markers (>= 40 lines apart)
/// between samples, since one flag can report only one.
pub const MAX_STEP_COUNTS: i64 = 1024;

const N: i64 = COUNTS_PER_REV;
const HALF: i64 = COUNTS_PER_REV / 2;
/// Re-check silent links this often (counts of travel) when nothing else happens.
const RECHECK_COUNTS: i64 = 256;

/// Angle (deg) of a raw count given the link's home count.
pub fn counts_to_deg(count: i64, home_count: i64) -> f64 {
    // i128: no overflow for any pair of raw counts.
    (count as i128 - home_count as i128) as f64 * 360.0 / N as f64
}

/// Nearest raw count for an angle (deg) given the link's home count.
pub fn deg_to_counts(deg: f64, home_count: i64) -> i64 {
    home_count + (deg * N as f64 / 360.0).round() as i64
}

/// Snaps an angle (deg) to the encoder grid (a multiple of 360/92672 deg): what the encoder
/// reads when the motor servoes to `deg`.
pub fn quantize_deg(deg: f64) -> f64 {
    counts_to_deg(deg_to_counts(deg, 0), 0)
}

fn c2d(c: i64) -> f64 {
    counts_to_deg(c, 0)
}

/// Circular difference a - b in (-N/2, N/2].
fn circ(d: i64) -> i64 {
    let r = d.rem_euclid(N);
    if r > HALF {
        r - N
    } else {
        r
    }
}

/// One sample of the homing stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomingSample {
    /// raw incremental counts (arbitrary origin per link); on the sample carrying an index
    /// rising edge, the count the board latched at the edge
    pub counts: [i64; 3],
    /// index-pulse flags at that sample
    pub index: [bool; 3],
}

/// The raw count at which each link is at theta_i = 0; theta_i = counts_to_deg(count_i, home_i).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomeCounts(pub [i64; 3]);

impl HomeCounts {
    /// Link angles (deg) for raw counts.
    pub fn theta_deg(&self, counts: [i64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|i| counts_to_deg(counts[i], self.0[i]))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HomingStatus {
    Pending,
    Done(HomeCounts),
}

#[derive(Debug, Clone)]
enum State {
    Pending,
    Done(HomeCounts),
    Failed(String),
}

/// Why a hypothesis was refused; `spread` ranks the start-angle refusals (closest first).
struct Refusal {
    by_pulses: bool,
    spread: i64,
    msg: String,
}

/// Incremental homing: feed samples with [`Homing::push`] until it reports `Done`.
#[derive(Debug, Clone)]
pub struct Homing {
    tol: i64,
    /// counts at the first sample (travel is measured from there)
    start: Option<[i64; 3]>,
    last: [i64; 3],
    /// largest travel reached per link (counts)
    max_u: [i64; 3],
    prev_index: [bool; 3],
    /// travel (counts) of each link's pulses, at their rising edges
    pulses: [Vec<i64>; 3],
    /// re-evaluate once a link's travel reaches this
    next_eval: [i64; 3],
    /// hypotheses alive at the last evaluation
    alive: usize,
    state: State,
}

impl Default for Homing {
    fn default() -> Self {
        Homing::new()
    }
}

impl Homing {
    /// Homing with the default start tolerance ([`DEFAULT_TOLERANCE_COUNTS`], 2 deg).
    pub fn new() -> Self {
        Homing::with_tolerance_counts(DEFAULT_TOLERANCE_COUNTS)
    }

    /// `tol`: largest difference between two links' start angles, and between their travels.
    /// Clamped to [0, 20 lines] (~5 deg): wider, starts one marker gap (9.94 deg) apart could
    /// no longer be told apart.
    pub fn with_tolerance_counts(tol: i64) -> Self {
        Homing {
            tol: tol.clamp(0, COUNTS_PER_LINE * 20),
            start: None,
            last: [0; 3],
            max_u: [0; 3],
            prev_index: [false; 3],
            pulses: Default::default(),
            next_eval: [i64::MAX; 3],
            alive: 0,
            state: State::Pending,
        }
    }

    /// Travel so far (deg), mean of the three links.
    pub fn travel_deg(&self) -> f64 {
        c2d(self.travel_counts())
    }

    fn travel_counts(&self) -> i64 {
        match self.start {
            None => 0,
            Some(s) => (0..3).map(|i| self.last[i] - s[i]).sum::<i64>() / 3,
        }
    }

    /// Feeds the next sample. `Err` (and every later call) when the stream fits no hypothesis.
    pub fn push(&mut self, s: HomingSample) -> Result<HomingStatus> {
        match &self.state {
            State::Done(h) => return Ok(HomingStatus::Done(*h)),
            State::Failed(m) => return Err(EyeError::Homing(m.clone())),
            State::Pending => {}
        }
        match self.step(s) {
            Ok(st) => Ok(st),
            Err(m) => {
                self.state = State::Failed(m.clone());
                Err(EyeError::Homing(m))
            }
        }
    }

    fn step(&mut self, s: HomingSample) -> std::result::Result<HomingStatus, String> {
        let Some(start) = self.start else {
            self.start = Some(s.counts);
            self.last = s.counts;
            self.prev_index = s.index;
            return Ok(HomingStatus::Pending);
        };
        let mut u = [0i64; 3];
        for i in 0..3 {
            let d = s.counts[i] - self.last[i];
            if d < -JITTER_COUNTS {
                return Err(format!(
                    "link {} moved backwards: count {} -> {} ({:.3} deg) after {:.3} deg of travel",
                    i + 1,
                    self.last[i],
                    s.counts[i],
                    c2d(d),
                    self.travel_deg()
                ));
            }
            if d > MAX_STEP_COUNTS {
                return Err(format!(
                    "link {} moved {:.3} deg between two samples (at most {:.3}): sample faster",
                    i + 1,
                    c2d(d),
                    c2d(MAX_STEP_COUNTS)
                ));
            }
            u[i] = s.counts[i] - start[i];
        }
        self.last = s.counts;
        // Plain loops: this runs for every sample, also in unoptimised test builds.
        let mut edge = [false; 3];
        let (mut lo, mut hi) = (i64::MAX, i64::MIN);
        for i in 0..3 {
            edge[i] = s.index[i] && !self.prev_index[i];
            // A latched count lags the head by up to one step: judge togetherness on the others.
            if !edge[i] {
                lo = lo.min(u[i]);
                hi = hi.max(u[i]);
            }
        }
        if lo <= hi && hi - lo > self.tol + INDEX_SLACK_COUNTS {
            return Err(format!(
                "links do not move together: travel {:.3}, {:.3}, {:.3} deg differ by more than \
                 the tolerance {:.3} deg",
                c2d(u[0]),
                c2d(u[1]),
                c2d(u[2]),
                c2d(self.tol)
            ));
        }
        let mut changed = false;
        for i in 0..3 {
            if u[i] > self.max_u[i] {
                self.max_u[i] = u[i];
            }
            if edge[i] {
                self.pulses[i].push(u[i]);
                changed = true;
            }
            changed |= self.max_u[i] >= self.next_eval[i];
        }
        self.prev_index = s.index;
        if !changed {
            if u[0] + u[1] + u[2] > 3 * self.travel_limit() {
                return Err(self.undecided_message());
            }
            return Ok(HomingStatus::Pending);
        }
        let status = self.evaluate()?;
        if status == HomingStatus::Pending && self.travel_counts() > self.travel_limit() {
            return Err(self.undecided_message());
        }
        if let HomingStatus::Done(h) = status {
            self.state = State::Done(h);
        }
        Ok(status)
    }

    fn undecided_message(&self) -> String {
        format!(
            "no decision after {:.3} deg of travel (homing decides within 180 deg + the \
             tolerance): {} hypotheses fit the pulses seen: {}",
            self.travel_deg(),
            self.alive,
            self.pulses_seen()
        )
    }

    /// Past this mean travel a valid stream has always decided; the margin covers links that
    /// lag within the tolerance.
    fn travel_limit(&self) -> i64 {
        HALF + 2 * self.tol + 2 * INDEX_SLACK_COUNTS
    }

    /// Checks every hypothesis against everything seen so far.
    fn evaluate(&mut self) -> std::result::Result<HomingStatus, String> {
        let pulsed = [0, 1, 2].map(|i| !self.pulses[i].is_empty());
        if !pulsed.iter().any(|&p| p) {
            self.next_eval = self.max_u.map(|u| u + RECHECK_COUNTS);
            self.alive = 0;
            return Ok(HomingStatus::Pending);
        }
        // Start angle (counts at the first sample, in [0, N)) if pulse i is on marker k.
        let cand = |i: usize, k: usize| (MARKER_COUNTS[k] - MARKER_COUNTS[i] - self.pulses[i][0]).rem_euclid(N);
        let n_k = pulsed.map(|p| if p { 3 } else { 1 });
        let mut alive = 0usize;
        let mut winner = [0i64; 3];
        let mut next = [i64::MAX; 3];
        let mut refusals: Vec<Refusal> = Vec::new();
        for k0 in 0..n_k[0] {
            for k1 in 0..n_k[1] {
                for k2 in 0..n_k[2] {
                    let ks = [k0, k1, k2];
                    let phi: [Option<i64>; 3] = [0, 1, 2].map(|i| pulsed[i].then(|| cand(i, ks[i])));
                    match self.check(&phi) {
                        Ok(n) => {
                            alive += 1;
                            winner = phi.map(|p| p.unwrap_or(0));
                            for i in 0..3 {
                                next[i] = next[i].min(n[i]);
                            }
                        }
                        Err(r) => refusals.push(r),
                    }
                }
            }
        }
        self.alive = alive;
        if alive == 0 {
            return Err(self.no_fit_message(refusals));
        }
        self.next_eval = next;
        if alive == 1 && pulsed.iter().all(|&p| p) {
            let start = self.start.unwrap_or_default();
            let home = [0, 1, 2].map(|i| {
                // home_i = pulse count - (marker - s_i) mod N: from link i's own latched count.
                let home = start[i] - winner[i];
                // Representative: theta in (-180, 180] deg at the end of homing.
                let mut theta = (self.last[i] - home).rem_euclid(N);
                if theta > HALF {
                    theta -= N;
                }
                self.last[i] - theta
            });
            return Ok(HomingStatus::Done(HomeCounts(home)));
        }
        Ok(HomingStatus::Pending)
    }

    /// One hypothesis (start angle per pulsed link); `Ok` gives the travel per link at which
    /// it must be checked again.
    fn check(&self, phi: &[Option<i64>; 3]) -> std::result::Result<[i64; 3], Refusal> {
        let slack = INDEX_SLACK_COUNTS;
        for i in 0..3 {
            for j in i + 1..3 {
                if let (Some(a), Some(b)) = (phi[i], phi[j]) {
                    let d = circ(a - b).abs();
                    if d > self.tol + INDEX_SLACK_COUNTS {
                        return Err(Refusal {
                            by_pulses: false,
                            spread: d,
                            msg: format!(
                                "the pulses of links {} and {} imply start angles {:.3} and \
                                 {:.3} deg, {:.3} deg apart (tolerance {:.3} deg)",
                                i + 1,
                                j + 1,
                                c2d(a),
                                c2d(b),
                                c2d(d),
                                c2d(self.tol)
                            ),
                        });
                    }
                }
            }
        }
        let refuse = |msg: String| Refusal { by_pulses: true, spread: 0, msg };
        let mut next = [i64::MAX; 3];
        let reference = phi.iter().flatten().next().copied();
        for i in 0..3 {
            let umax = self.max_u[i];
            let Some(p) = phi[i] else {
                if let Some(r) = reference {
                    if !self.silent_link_fits(i, r, phi) {
                        return Err(refuse(format!(
                            "link {} saw no index pulse in {:.3} deg of travel, yet with a start \
                             within the tolerance of the other links (start {:.3} deg) it \
                             would have passed a marker",
                            i + 1,
                            c2d(umax),
                            c2d(r)
                        )));
                    }
                }
                next[i] = umax + RECHECK_COUNTS;
                continue;
            };
            // Travel at which head i is on marker k: (m_k - s_i - phi) mod N, and one turn
            // earlier for a marker just behind the start.
            let mut predicted = [0i64; 6];
            for k in 0..3 {
                let v = (MARKER_COUNTS[k] - MARKER_COUNTS[i] - p).rem_euclid(N);
                predicted[2 * k] = v;
                predicted[2 * k + 1] = v - N;
            }
            for &q in &self.pulses[i] {
                if !predicted.iter().any(|v| (q - v).abs() <= slack) {
                    return Err(refuse(format!(
                        "link {}: index pulse at {:+.3} deg of travel where no marker can be \
                         (start {:.3} deg)",
                        i + 1,
                        c2d(q),
                        c2d(p)
                    )));
                }
            }
            for (j, &v) in predicted.iter().enumerate() {
                if v > slack && v <= umax - slack {
                    if !self.pulses[i].iter().any(|q| (q - v).abs() <= slack) {
                        return Err(refuse(format!(
                            "link {}: expected index pulse of marker {} at {:+.3} deg of travel \
                             not seen (start {:.3} deg)",
                            i + 1,
                            j / 2 + 1,
                            c2d(v),
                            c2d(p)
                        )));
                    }
                } else if v > umax - slack {
                    next[i] = next[i].min(v + slack + 1);
                }
            }
        }
        Ok(next)
    }

    /// Whether silent link i can have a start angle within the tolerance of every pulsed
    /// link's (hypothesis `phi`, `reference` one of them) and have passed no marker so far.
    fn silent_link_fits(&self, i: usize, reference: i64, phi: &[Option<i64>; 3]) -> bool {
        let slack = INDEX_SLACK_COUNTS;
        // Window of start angles, as offsets from `reference` (the spread check has passed,
        // so the unwrapped offsets are consistent).
        let offs = phi.iter().flatten().map(|&p| circ(p - reference));
        let tol = self.tol + INDEX_SLACK_COUNTS;
        let lo = offs.clone().max().unwrap_or(0) - tol;
        let hi = offs.min().unwrap_or(0) + tol;
        let width = hi - lo;
        // A marker is required (seen or refused) when it falls in travel (slack, umax-slack],
        // i.e. for starts in [m - s_i - (umax - slack), m - s_i - slack - 1].
        let len = self.max_u[i] - 2 * slack;
        if len <= 0 {
            return true;
        }
        if len >= N {
            return false;
        }
        let mut covered: Vec<(i64, i64)> = Vec::with_capacity(6);
        for m in MARKER_COUNTS {
            let first = m - MARKER_COUNTS[i] - (self.max_u[i] - slack);
            let a = (first - (reference + lo)).rem_euclid(N);
            let b = a + len - 1;
            covered.push((a, b.min(N - 1)));
            if b >= N {
                covered.push((0, b - N));
            }
        }
        covered.sort_unstable();
        let mut pos = 0;
        for (a, b) in covered {
            if a > pos {
                break;
            }
            pos = pos.max(b + 1);
        }
        pos <= width
    }

    fn pulses_seen(&self) -> String {
        let mut all: Vec<(i64, usize)> = (0..3).flat_map(|i| self.pulses[i].iter().map(move |&u| (u, i))).collect();
        if all.is_empty() {
            return "none".into();
        }
        all.sort_unstable();
        let mut v: Vec<String> =
            all.iter().take(12).map(|(u, i)| format!("link {} at {:+.3} deg", i + 1, c2d(*u))).collect();
        if all.len() > 12 {
            v.push(format!("... ({} in all)", all.len()));
        }
        v.join(", ")
    }

    fn no_fit_message(&self, mut refusals: Vec<Refusal>) -> String {
        // Evidence from pulses says more than a start-angle mismatch; show the closest ones.
        refusals.sort_by_key(|r| (!r.by_pulses, r.spread));
        let mut reasons: Vec<&str> = Vec::new();
        for r in &refusals {
            if reasons.len() == 3 {
                break;
            }
            if !reasons.contains(&r.msg.as_str()) {
                reasons.push(&r.msg);
            }
        }
        format!(
            "no marker hypothesis fits the index pulses seen ({}) after {:.3} deg of travel: {}",
            self.pulses_seen(),
            self.travel_deg(),
            reasons.join("; ")
        )
    }

    /// Why homing is still pending (for the batch error).
    fn pending_message(&self) -> String {
        if self.pulses.iter().all(Vec::is_empty) {
            format!("ambiguous: no index pulse after {:.3} deg of travel; need more travel", self.travel_deg())
        } else {
            format!(
                "ambiguous: {} after {:.3} deg of travel (pulses seen: {}); need more travel",
                if self.pulses.iter().any(Vec::is_empty) {
                    "not every link has seen an index pulse yet".to_string()
                } else {
                    format!("{} marker hypotheses still fit", self.alive)
                },
                self.travel_deg(),
                self.pulses_seen()
            )
        }
    }
}

/// Batch homing over a recorded stream; errors if the stream is inconsistent or ends before
/// homing is decided.
pub fn home_from_stream(samples: &[HomingSample]) -> Result<HomeCounts> {
    let mut h = Homing::new();
    for s in samples {
        if let HomingStatus::Done(home) = h.push(*s)? {
            return Ok(home);
        }
    }
    Err(EyeError::Homing(h.pending_message()))
}

/// The drive board during the start-up roll (a simulator, for tests and `abvs sim board`).
/// Link i starts at theta_i = `start[i]` counts and all links advance `step` counts per sample;
/// `origin[i]` is the raw count at theta_i = 0, so the true home counts are `origin` modulo one
/// turn. Reported counts carry +-`noise` read noise, except on the sample with an index rising
/// edge, which carries the exact count latched at the edge. The index line stays high while the
/// head is within `width` counts past a marker.
#[derive(Clone, Debug)]
pub struct StartupRoll {
    pub start: [i64; 3],
    pub origin: [i64; 3],
    pub step: i64,
    pub noise: i64,
    pub width: i64,
}

/// The sample stream of a [`StartupRoll`] (stateful, so that a sample costs little even unoptimised).
pub struct RollStream<'a> {
    roll: &'a StartupRoll,
    n: i64,
    /// theta (counts) at which each head next reaches a marker, and where it last did
    next_edge: [i64; 3],
    last_edge: [i64; 3],
    noise: u64,
}

/// Theta (counts) > p at which head i next reaches a marker: s_i + q = m (mod N).
fn next_marker(i: usize, p: i64) -> i64 {
    let n = COUNTS_PER_REV;
    let mut best = i64::MAX;
    for m in MARKER_COUNTS {
        best = best.min(p + 1 + (m - MARKER_COUNTS[i] - p - 1).rem_euclid(n));
    }
    best
}

impl StartupRoll {
    /// The samples, endless; `seed` drives the read noise.
    pub fn stream(&self, seed: u64) -> RollStream<'_> {
        RollStream { roll: self, n: 0, next_edge: [0; 3], last_edge: [0; 3], noise: seed | 1 }
    }

    /// Theta (counts) of link i at sample n, without noise.
    pub fn theta_counts(&self, i: usize, n: i64) -> i64 {
        self.start[i] + n * self.step
    }

    /// The home counts homing must report, given the counts of the deciding sample: the
    /// origin, shifted by whole turns so that theta lies in (-180, 180] deg.
    pub fn expected(&self, last: [i64; 3]) -> HomeCounts {
        let n = COUNTS_PER_REV;
        HomeCounts([0, 1, 2].map(|i| {
            let mut th = (last[i] - self.origin[i]).rem_euclid(n);
            if th > n / 2 {
                th -= n;
            }
            last[i] - th
        }))
    }
}

impl Iterator for RollStream<'_> {
    type Item = HomingSample;
    fn next(&mut self) -> Option<HomingSample> {
        let b = self.roll;
        let mut counts = [0; 3];
        let mut index = [false; 3];
        for i in 0..3 {
            let p = b.theta_counts(i, self.n);
            if self.n == 0 {
                // Already on a marker at start-up: the index line is high, no edge seen.
                let back = next_marker(i, p - b.width);
                self.last_edge[i] = if back <= p { back } else { i64::MIN / 2 };
                self.next_edge[i] = next_marker(i, p);
            }
            if self.n > 0 && self.next_edge[i] <= p {
                // The board latches the exact count at the rising edge.
                let q = self.next_edge[i];
                counts[i] = b.origin[i] + q;
                index[i] = true;
                self.last_edge[i] = q;
                self.next_edge[i] = next_marker(i, q);
            } else {
                // xorshift: cheap read noise in [-noise, noise].
                self.noise ^= self.noise << 13;
                self.noise ^= self.noise >> 7;
                self.noise ^= self.noise << 17;
                let jitter = (self.noise % (2 * b.noise as u64 + 1)) as i64 - b.noise;
                counts[i] = b.origin[i] + p + jitter;
                index[i] |= p - self.last_edge[i] < b.width;
            }
        }
        self.n += 1;
        Some(HomingSample { counts, index })
    }
}
