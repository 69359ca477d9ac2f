//! The run's statistics (every role adds to them, so they belong to none): latency statistics of the pipeline: a histogram per stage and end to end (HdrHistogram, allocated at
//! start-up so recording never allocates), counters of frames in / published / dropped, printed at exit and
//! written as JSON.
use std::collections::BTreeMap;
use std::time::Instant;

use hdrhistogram::Histogram;

use crate::cpu::RunCpu;
use serde_json::{json, Value};

/// Latency histogram in microseconds (1 us .. 60 s, 3 significant digits).
pub struct Latency(Histogram<u64>);

impl Default for Latency {
    fn default() -> Self {
        Latency(Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds"))
    }
}

impl Latency {
    /// Records one latency (ns; under 1 us counts as 1 us).
    pub fn record_ns(&mut self, ns: i64) {
        let us = (ns.max(1000) / 1000) as u64;
        self.0.saturating_record(us);
    }
    /// Values recorded.
    pub fn count(&self) -> u64 {
        self.0.len()
    }
    /// Quantile in milliseconds (NaN when empty).
    pub fn ms(&self, q: f64) -> f64 {
        if self.0.is_empty() {
            f64::NAN
        } else {
            self.0.value_at_quantile(q) as f64 / 1000.0
        }
    }
    /// Largest value in milliseconds (NaN when empty).
    pub fn max_ms(&self) -> f64 {
        if self.0.is_empty() {
            f64::NAN
        } else {
            self.0.max() as f64 / 1000.0
        }
    }
    /// Empties the histogram (keeps its buffers: does not allocate).
    pub fn reset(&mut self) {
        self.0.reset();
    }
    /// Adds another histogram's values.
    pub fn merge(&mut self, other: &Latency) {
        let _ = self.0.add(&other.0);
    }
    fn json(&self) -> Value {
        json!({ "p50": round3(self.ms(0.5)), "p99": round3(self.ms(0.99)), "mean": round3(self.0.mean() / 1000.0),
                "max": round3(self.0.max() as f64 / 1000.0), "count": self.count() })
    }
}

fn finite(x: f64) -> Value {
    if x.is_finite() {
        json!(x)
    } else {
        Value::Null
    }
}

fn round3(x: f64) -> Value {
    if x.is_finite() {
        json!((x * 1000.0).round() / 1000.0)
    } else {
        Value::Null
    }
}

/// Resident set size of this process (bytes), from /proc/self/statm; `None` where there is none. Reads into a
/// stack buffer: it does not allocate (the output stage calls it once per statistics window).
pub fn rss_bytes() -> Option<u64> {
    use std::io::Read;
    let mut buf = [0u8; 128];
    let n = std::fs::File::open("/proc/self/statm").and_then(|mut f| f.read(&mut buf)).ok()?;
    // "size resident shared text lib data dt", in pages
    let text = std::str::from_utf8(&buf[..n]).ok()?;
    let pages: u64 = text.split_ascii_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf has no preconditions.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * if page > 0 { page as u64 } else { 4096 })
}

/// One statistics window of a run (a minute by default): what a soak test looks at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// End of the window, seconds since the run started.
    pub t_s: f64,
    /// Frames the source delivered, published, dropped under overload in the window.
    pub frames_in: u64,
    /// Frames published in the window.
    pub frames_published: u64,
    /// Frames dropped under overload in the window.
    pub frames_dropped: u64,
    /// End-to-end latency of the window's published frames (ms; NaN without frames).
    pub p50_ms: f64,
    /// p99 of the same (ms).
    pub p99_ms: f64,
    /// Largest of the same (ms).
    pub max_ms: f64,
    /// Resident set size at the end of the window (bytes; 0 where unknown).
    pub rss_bytes: u64,
}

/// The most windows a run keeps: at this many, neighbours are merged in pairs and the window doubles, so a run
/// of any length with any window holds a fixed list (256 kB, reserved and written at the start).
pub const MAX_WINDOWS: usize = 4096;

impl Window {
    /// `self` and the window after it as one: counts summed, the later end and resident memory, p50 the mean
    /// of the two weighted by frames published, p99 and max the larger (p99 then an upper bound).
    pub fn merged(&self, next: &Window) -> Window {
        let (a, b) = (self.frames_published as f64, next.frames_published as f64);
        let p50 = match (self.p50_ms.is_finite(), next.p50_ms.is_finite()) {
            (true, true) if a + b > 0.0 => (self.p50_ms * a + next.p50_ms * b) / (a + b),
            (true, _) => self.p50_ms,
            _ => next.p50_ms,
        };
        let big = |x: f64, y: f64| {
            if x.is_nan() {
                y
            } else if y.is_nan() {
                x
            } else {
                x.max(y)
            }
        };
        Window {
            t_s: next.t_s,
            frames_in: self.frames_in + next.frames_in,
            frames_published: self.frames_published + next.frames_published,
            frames_dropped: self.frames_dropped + next.frames_dropped,
            p50_ms: p50,
            p99_ms: big(self.p99_ms, next.p99_ms),
            max_ms: big(self.max_ms, next.max_ms),
            rss_bytes: next.rss_bytes,
        }
    }

    fn json(&self) -> Value {
        json!({
            "t_s": round3(self.t_s),
            "frames_in": self.frames_in,
            "frames_published": self.frames_published,
            "frames_dropped": self.frames_dropped,
            "p50_ms": round3(self.p50_ms),
            "p99_ms": round3(self.p99_ms),
            "max_ms": round3(self.max_ms),
            "rss_mb": round3(self.rss_bytes as f64 / 1048576.0),
        })
    }
}

/// Least-squares slope of y over x (NaN with fewer than two points).
fn slope(pts: &[(f64, f64)]) -> f64 {
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return f64::NAN;
    }
    let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if sxx > 0.0 {
        sxy / sxx
    } else {
        f64::NAN
    }
}

/// Depth accuracy against ground truth (synthetic sessions).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DepthError {
    /// Sum of |r_est - r_true| / r_true over valid points.
    pub abs_rel_sum: f64,
    /// Sum of squared 3D point errors (m^2).
    pub sq_sum: f64,
    /// Points scored.
    pub points: u64,
    /// Pixels looked at (valid or not).
    pub pixels: u64,
}

impl DepthError {
    /// Errors are null when no point was scored: nothing scored is not a perfect score.
    pub fn json(&self) -> Value {
        let n = self.points as f64;
        let scored = |v: f64| if self.points > 0 { json!(v) } else { Value::Null };
        json!({
            "abs_rel": scored(self.abs_rel_sum / n),
            "rmse_m": scored((self.sq_sum / n).sqrt()),
            "valid_fraction": self.points as f64 / self.pixels.max(1) as f64,
            "points": self.points,
        })
    }
}

/// Everything `abvs run` reports.
pub struct RunStats {
    /// When the statistics were made (the run's start).
    pub started: Instant,
    /// Frames taken from the source.
    pub frames_in: u64,
    /// Frames that reached the sinks.
    pub frames_published: u64,
    /// Dropped under overload (oldest first) at each queue.
    pub frames_dropped: u64,
    /// Frames a stage refused (bad frame file, encoders out of span, FK failure...), by reason.
    pub frames_failed: BTreeMap<String, u64>,
    /// Published with depth invalid because the eyes moved too fast during the exposure (the motion gate).
    pub frames_motion_gated: u64,
    /// Frames a sink failed to take (a full disk under --dump, ...), by sink: that sink's failure,
    /// not the frame's; the frame still counts as published to the others.
    pub sink_failures: BTreeMap<String, u64>,
    /// Latency of each lane (the source's first), by name.
    pub stages: Vec<(&'static str, Latency)>,
    /// From the moment a frame exists (its last row's exposure ended, as a camera delivers it) to its
    /// publication.
    pub end_to_end: Latency,
    /// Whether `end_to_end` measures latency: live frames and paced replays. An unpaced replay (lossless,
    /// offline) takes frames ahead of their times, so its "latency" reads 0 and is reported as not
    /// applicable (null in the JSON, "n/a" in the table).
    pub latency_measured: bool,
    /// Depth error against ground truth (synthetic sessions scored by a truth sink).
    pub depth_error: Option<DepthError>,
    /// Valid points over every published frame.
    pub points_total: u64,
    /// FNV-1a over every published depth map of a lossless run (`None` otherwise): equal across runs of the
    /// same input. A lossy run's frames depend on timing (which ones drop), so it is not digested: hashing a
    /// 640x480 map a byte at a time took 1.7 ms of the output thread's every frame (runtime/BENCHMARKS.md).
    pub output_digest: Option<u64>,
    /// Length of a statistics window (s) and the run's windows, in order (the last one may be shorter).
    pub window_s: f64,
    /// The windows, in order.
    pub windows: Vec<Window>,
    /// What stages, sinks and the embedding program added, by name (in the JSON at the top level).
    pub extra: BTreeMap<String, Value>,
    /// CPU time the run used, per lane and per other thread (`None` until a run ends).
    pub cpu: Option<RunCpu>,
}

impl RunStats {
    /// Empty statistics for a graph of these lanes (the source's first).
    pub fn new(stage_names: &[&'static str]) -> Self {
        RunStats {
            started: Instant::now(),
            frames_in: 0,
            frames_published: 0,
            frames_dropped: 0,
            frames_failed: BTreeMap::new(),
            frames_motion_gated: 0,
            sink_failures: BTreeMap::new(),
            stages: stage_names.iter().map(|n| (*n, Latency::default())).collect(),
            end_to_end: Latency::default(),
            latency_measured: true,
            depth_error: None,
            points_total: 0,
            output_digest: None,
            window_s: 60.0,
            windows: Vec::new(),
            extra: BTreeMap::new(),
            cpu: None,
        }
    }

    /// A lane's latency histogram (panics on an unknown name: the names are the graph's).
    pub fn stage_mut(&mut self, name: &str) -> &mut Latency {
        &mut self.stages.iter_mut().find(|(n, _)| *n == name).expect("known stage").1
    }

    /// Counts a frame refused for `reason`.
    pub fn fail(&mut self, reason: &str) {
        *self.frames_failed.entry(reason.to_string()).or_default() += 1;
    }

    /// Adds a depth map to [`RunStats::output_digest`] (the first one starts it).
    pub fn digest(&mut self, data: &[f32]) {
        let mut h = self.output_digest.unwrap_or(0xcbf29ce484222325);
        for v in data {
            for b in v.to_bits().to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x100000001b3);
            }
        }
        self.output_digest = Some(h);
    }

    /// Everything as JSON, rates over `elapsed_s` (what the stats JSON file holds).
    pub fn json(&self, elapsed_s: f64) -> Value {
        let mut stages = serde_json::Map::new();
        for (n, l) in &self.stages {
            stages.insert(n.to_string(), l.json());
        }
        let mut v = json!({
            "frames_in": self.frames_in,
            "frames_published": self.frames_published,
            "frames_dropped": self.frames_dropped,
            "frames_failed": self.frames_failed,
            "frames_motion_gated": self.frames_motion_gated,
            "sink_failures": self.sink_failures,
            "fps": if elapsed_s > 0.0 { self.frames_published as f64 / elapsed_s } else { 0.0 },
            "elapsed_s": elapsed_s,
            "latency_ms": if self.latency_measured { self.end_to_end.json() } else { Value::Null },
            "stages": stages,
            "points_mean": self.points_total as f64 / self.frames_published.max(1) as f64,
            "output_digest": self.output_digest.map(|h| format!("{h:016x}")),
        });
        if let Some(e) = &self.depth_error {
            v["depth_error"] = e.json();
        }
        v["window_s"] = json!(self.window_s);
        v["windows"] = Value::Array(self.windows.iter().map(Window::json).collect());
        v["rss"] = self.rss_summary();
        if let Some(c) = self.cpu_json(elapsed_s) {
            v["cpu"] = c;
        }
        for (k, x) in &self.extra {
            v[k] = x.clone();
        }
        v
    }

    /// CPU per frame taken from the source (ms): the whole process, each lane and the other threads by name,
    /// with the cores busy on average over the run and the cores the machine has.
    pub fn cpu_json(&self, elapsed_s: f64) -> Option<Value> {
        let c = self.cpu.as_ref()?;
        let per = |ns: i64| round3(ns as f64 * 1e-6 / self.frames_in.max(1) as f64);
        let lanes: serde_json::Map<String, Value> = c.lanes.iter().map(|(n, ns)| (n.to_string(), per(*ns))).collect();
        let others: serde_json::Map<String, Value> = c.others.iter().map(|(n, ns)| (n.clone(), per(*ns))).collect();
        let lane_sum: i64 = c.lanes.iter().map(|l| l.1).sum();
        Some(json!({
            "frames": self.frames_in,
            "ms_per_frame": per(c.process_ns),
            "lanes_ms_per_frame": lanes,
            "other_threads_ms_per_frame": per(c.process_ns - lane_sum),
            "other_threads_by_name_ms_per_frame": others,
            "idle_priority_ms_per_frame": per(c.idle_ns),
            "cores_busy": round3(c.process_ns as f64 * 1e-9 / elapsed_s.max(1e-9)),
            "cores_busy_without_idle_priority": round3((c.process_ns - c.idle_ns) as f64 * 1e-9 / elapsed_s.max(1e-9)),
            "cores": std::thread::available_parallelism().map_or(1, |n| n.get()),
        }))
    }

    /// Resident memory over the run's windows: first, last and highest (MB), and the least-squares slope (MB
    /// per minute) and relative spread ((max - min) / min) over every complete window after the first (the
    /// first holds start-up: loading models, first-touch of buffers).
    pub fn rss_summary(&self) -> Value {
        let mb = |w: &Window| w.rss_bytes as f64 / 1048576.0;
        let full: Vec<&Window> = self.windows.iter().filter(|w| w.rss_bytes > 0).collect();
        let (Some(first), Some(last)) = (full.first(), full.last()) else { return Value::Null };
        // complete windows after the first (the last one of a run is usually cut short)
        let n = full.len();
        let steady: Vec<&Window> = full
            .iter()
            .copied()
            .enumerate()
            .filter(|(i, _)| *i > 0 && (*i + 1 < n || n <= 2))
            .map(|(_, w)| w)
            .collect();
        let pts: Vec<(f64, f64)> = steady.iter().map(|w| (w.t_s / 60.0, mb(w))).collect();
        let (lo, hi) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
        json!({
            "first_mb": round3(mb(first)),
            "last_mb": round3(mb(last)),
            "max_mb": round3(full.iter().map(|w| mb(w)).fold(0.0, f64::max)),
            "steady_windows": pts.len(),
            "steady_slope_mb_per_min": finite(slope(&pts)),
            "steady_spread": if pts.is_empty() { Value::Null } else { finite((hi - lo) / lo) },
        })
    }

    /// The latency table printed at exit.
    pub fn table(&self, elapsed_s: f64) -> String {
        let mut s = String::new();
        s += &format!(
            "frames in {}  published {} (motion-gated {})  dropped {}  failed {}  ({:.1} fps over {:.1} s)\n",
            self.frames_in,
            self.frames_published,
            self.frames_motion_gated,
            self.frames_dropped,
            self.frames_failed.values().sum::<u64>(),
            self.frames_published as f64 / elapsed_s.max(1e-9),
            elapsed_s
        );
        for (reason, n) in &self.frames_failed {
            s += &format!("  failed: {reason}: {n}\n");
        }
        for (sink, n) in &self.sink_failures {
            s += &format!("  sink {sink} failed on {n} frames\n");
        }
        s += &format!("{:<22} {:>9} {:>9} {:>9} {:>7}\n", "stage (ms)", "p50", "p99", "max", "count");
        for (n, l) in self.stages.iter().map(|(n, l)| (*n, l)).chain(std::iter::once(("end to end", &self.end_to_end)))
        {
            if n == "end to end" && !self.latency_measured {
                s += &format!(
                    "{:<22} {:>9} {:>9} {:>9} {:>7}  (unpaced replay: not applicable)\n",
                    n, "-", "-", "-", "-"
                );
                continue;
            }
            s += &format!(
                "{:<22} {:>9.2} {:>9.2} {:>9.2} {:>7}\n",
                n,
                l.ms(0.5),
                l.ms(0.99),
                l.0.max() as f64 / 1000.0,
                l.count()
            );
        }
        if self.windows.len() > 1 {
            s += &format!(
                "{:<10} {:>7} {:>7} {:>9} {:>7} {:>9} {:>9} {:>9}\n",
                "window", "end (s)", "in", "published", "dropped", "p50 (ms)", "p99 (ms)", "rss (MB)"
            );
            for (i, w) in self.windows.iter().enumerate() {
                s += &format!(
                    "{:<10} {:>7.1} {:>7} {:>9} {:>7} {:>9.2} {:>9.2} {:>9.1}\n",
                    i + 1,
                    w.t_s,
                    w.frames_in,
                    w.frames_published,
                    w.frames_dropped,
                    w.p50_ms,
                    w.p99_ms,
                    w.rss_bytes as f64 / 1048576.0
                );
            }
        }
        if let Some(c) = self.cpu_json(elapsed_s) {
            let f = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
            let list = |m: &Value| {
                m.as_object().map_or(String::new(), |m| {
                    m.iter().map(|(n, v)| format!("{n} {:.1}", f(v))).collect::<Vec<_>>().join(", ")
                })
            };
            s += &format!(
                "CPU per frame: {:.1} ms ({:.2} of {} cores busy); lanes: {}; other threads {:.1} ({}; {:.1} of it \
                 at idle priority)\n",
                f(&c["ms_per_frame"]),
                f(&c["cores_busy"]),
                c["cores"],
                list(&c["lanes_ms_per_frame"]),
                f(&c["other_threads_ms_per_frame"]),
                list(&c["other_threads_by_name_ms_per_frame"]),
                f(&c["idle_priority_ms_per_frame"])
            );
        }
        if let Some(e) = self.depth_error.filter(|e| e.points == 0) {
            s += &format!("depth error vs truth: nothing scored (0 of {} pixels had a valid depth)\n", e.pixels);
        } else if let Some(e) = &self.depth_error {
            let j = e.json();
            s += &format!(
                "depth error vs truth: abs_rel {:.4}  rmse {:.4} m  valid {:.3}\n",
                j["abs_rel"].as_f64().unwrap_or(f64::NAN),
                j["rmse_m"].as_f64().unwrap_or(f64::NAN),
                j["valid_fraction"].as_f64().unwrap_or(0.0)
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_of_an_unpaced_replay_is_reported_as_not_applicable() {
        let mut s = RunStats::new(&["source"]);
        // an unpaced replay: frames taken ahead of their times record the 1 us floor (read as "0.00 ms")
        for _ in 0..10 {
            s.end_to_end.record_ns(-5_000_000);
        }
        s.latency_measured = false;
        let j = s.json(1.0);
        assert!(j["latency_ms"].is_null(), "{j}");
        let t = s.table(1.0);
        let row = t.lines().find(|l| l.starts_with("end to end")).unwrap();
        assert!(row.contains("not applicable") && !row.contains("0.00"), "{row}");
        // measured (live, paced): the numbers
        s.latency_measured = true;
        assert_eq!(s.json(1.0)["latency_ms"]["count"], 10);
        assert!(s.table(1.0).lines().any(|l| l.starts_with("end to end") && l.contains("0.00")));
    }
}
