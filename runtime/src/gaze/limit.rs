//! Limits that hold whoever sends a goal: where each goal came from ([`GoalSource`]), and a rate limit on the
//! goals the controller executes ([`RateLimit`], a token bucket), both counted per source.
//!
//! The mailbox already keeps a flood from queueing (latest wins). The rate limit bounds what reaches the
//! motors: a goal taken while the bucket is empty waits (the newest one only, in [`GoalGate`]) until a token
//! comes; one replaced while it waits is counted as `rate_limited` under its source. The controller's
//! refusals then apply to every goal as before, and are counted per source too.
use serde::{Deserialize, Serialize};

use super::{Goal, Mailbox};

/// Where a goal came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum GoalSource {
    /// The running runtime's [`super::GazeHandle`] (the robot's own process).
    Rust = 1,
    /// The iceoryx2 service `{prefix}/gaze/goal` (a process on this machine).
    Iceoryx2 = 2,
    /// `/abvs/gaze/goal` over Zenoh (another machine; off unless `[bridges.zenoh] accept_gaze_goals`).
    Zenoh = 3,
}

impl GoalSource {
    /// Every source, in wire order.
    pub const ALL: [GoalSource; 3] = [GoalSource::Rust, GoalSource::Iceoryx2, GoalSource::Zenoh];

    /// Its name in the statistics and the Zenoh state.
    pub fn name(self) -> &'static str {
        match self {
            GoalSource::Rust => "rust",
            GoalSource::Iceoryx2 => "iceoryx2",
            GoalSource::Zenoh => "zenoh",
        }
    }

    /// Index in [`GoalSource::ALL`].
    pub fn index(self) -> usize {
        self as usize - 1
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
    pub fn check(&self) -> Result<(), String> {
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

/// What the gate counted for one source.
#[derive(Debug, Clone, Copy, Default)]
struct SourceCounts {
    taken: u64,
    rate_limited: u64,
    refused: u64,
}

/// Between the mailbox and the controller: the rate limit, and the counts per source. Allocates nothing.
#[derive(Debug)]
pub struct GoalGate {
    limit: RateLimit,
    tokens: f64,
    last_ns: Option<i64>,
    waiting: Option<(Goal, GoalSource)>,
    counts: [SourceCounts; GoalSource::ALL.len()],
}

impl GoalGate {
    /// A gate with a full bucket.
    pub fn new(limit: RateLimit) -> GoalGate {
        GoalGate {
            limit,
            tokens: f64::from(limit.goal_burst),
            last_ns: None,
            waiting: None,
            counts: [SourceCounts::default(); GoalSource::ALL.len()],
        }
    }

    /// The goal the controller takes at `now_ns`, if any: the newest posted (or the one waiting), when the
    /// bucket has a token.
    pub fn next(&mut self, mailbox: &Mailbox, now_ns: i64) -> Option<(Goal, GoalSource)> {
        let dt = self.last_ns.map_or(0.0, |t| (now_ns - t).max(0) as f64 * 1e-9);
        self.last_ns = Some(now_ns);
        self.tokens = (self.tokens + dt * self.limit.max_goals_per_s).min(f64::from(self.limit.goal_burst));
        if let Some(newer) = mailbox.take_from() {
            if let Some((_, old)) = self.waiting.replace(newer) {
                self.counts[old.index()].rate_limited += 1;
            }
        }
        if self.waiting.is_some() && self.tokens >= 1.0 {
            self.tokens -= 1.0;
            let g = self.waiting.take();
            if let Some((_, s)) = g {
                self.counts[s.index()].taken += 1;
            }
            return g;
        }
        None
    }

    /// Whether a goal waits for a token.
    pub fn waiting(&self) -> bool {
        self.waiting.is_some()
    }

    /// The controller refused the goal it took from `source`.
    pub fn refused(&mut self, source: GoalSource) {
        self.counts[source.index()].refused += 1;
    }

    /// The settings.
    pub fn limit(&self) -> &RateLimit {
        &self.limit
    }

    /// The statistics' `gaze.sources` (with the mailbox's posted and superseded per source) and
    /// `gaze.rate_limit`.
    pub fn json(&self, mailbox: &Mailbox) -> (serde_json::Value, serde_json::Value) {
        let sources: serde_json::Map<String, serde_json::Value> = GoalSource::ALL
            .iter()
            .map(|&s| {
                let (posted, superseded) = mailbox.counts_from(s);
                let c = self.counts[s.index()];
                let j = serde_json::json!({
                    "posted": posted,
                    "superseded": superseded,
                    "rate_limited": c.rate_limited,
                    "taken": c.taken,
                    "refused": c.refused,
                });
                (s.name().to_string(), j)
            })
            .collect();
        let limit = serde_json::json!({
            "max_goals_per_s": self.limit.max_goals_per_s,
            "goal_burst": self.limit.goal_burst,
            "waiting_at_end": self.waiting.is_some(),
        });
        (serde_json::Value::Object(sources), limit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaze::GoalKind;

    fn goal(id: u64) -> Goal {
        Goal { id, kind: GoalKind::LookAt, point_m: [0.0, 0.0, 1.0], velocity_m_s: [0.0; 3] }
    }

    #[test]
    fn a_flood_is_cut_to_the_rate_and_counted_per_source() {
        let limit = RateLimit { max_goals_per_s: 20.0, goal_burst: 4 };
        let mut gate = GoalGate::new(limit);
        let mb = Mailbox::default();
        // 2 s of frames at 100 Hz, 10 goals posted before each (zenoh), one iceoryx2 goal every 10th frame
        let mut taken = 0u64;
        let mut id = 0;
        for f in 0..200i64 {
            for _ in 0..10 {
                id += 1;
                mb.post_from(goal(id), GoalSource::Zenoh);
            }
            if f % 10 == 0 {
                id += 1;
                mb.post_from(goal(id), GoalSource::Iceoryx2);
            }
            if let Some((g, s)) = gate.next(&mb, f * 10_000_000) {
                taken += 1;
                assert!(g.id <= id);
                if f % 10 == 0 {
                    // the newest goal wins, whoever sent it
                    assert_eq!(s, GoalSource::Iceoryx2);
                }
            }
        }
        // 1.99 s of refill after a full bucket of 4
        assert!(taken <= limit.most_in(1.99) && taken >= 40, "{taken}");
        let (j, l) = gate.json(&mb);
        let z = &j["zenoh"];
        let posted = z["posted"].as_u64().unwrap();
        assert_eq!(posted, 2000);
        // every zenoh goal is taken, superseded in the mailbox or replaced while waiting for the limit
        let accounted = ["taken", "superseded", "rate_limited"].iter().map(|k| z[k].as_u64().unwrap()).sum::<u64>()
            + gate.waiting() as u64;
        let i = &j["iceoryx2"];
        let ia = ["taken", "superseded", "rate_limited"].iter().map(|k| i[k].as_u64().unwrap()).sum::<u64>();
        assert_eq!(accounted + ia, posted + 20, "{j}");
        assert!(z["rate_limited"].as_u64().unwrap() > 0, "{j}");
        assert_eq!(j["rust"]["posted"], 0);
        assert_eq!(l["max_goals_per_s"], 20.0);
        assert!(RateLimit { max_goals_per_s: f64::NAN, goal_burst: 1 }.check().is_err());
        assert!(RateLimit { max_goals_per_s: 5.0, goal_burst: 0 }.check().is_err());
    }

    #[test]
    fn goals_within_the_rate_pass_at_once() {
        let mut gate = GoalGate::new(RateLimit::default());
        let mb = Mailbox::default();
        // 10 goals a second, one per 100 ms frame: each taken at its frame, none waits
        for f in 0..30i64 {
            mb.post(goal(f as u64 + 1));
            let (g, s) = gate.next(&mb, f * 100_000_000).expect("taken at once");
            assert_eq!((g.id, s), (f as u64 + 1, GoalSource::Rust));
        }
        assert!(!gate.waiting());
    }
}
