//! Limits that hold whoever sends a goal: where each goal came from ([`GoalSource`]), and a rate limit on the
//! goals the controller executes ([`RateLimit`], a token bucket), both counted per source.
//!
//! The mailbox already keeps a flood from queueing (latest wins). The rate limit bounds what reaches the
//! motors: a goal taken while the bucket is empty waits (the newest one only, in [`GoalGate`]) until a token
//! comes; one replaced while it waits is counted as `rate_limited` under its source. The controller's
//! refusals then apply to every goal as before, and are counted per source too.
use abvs_runtime_core::gaze::GoalSource;
use abvs_runtime_core::params::RateLimit;

use super::{Goal, Mailbox};

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
