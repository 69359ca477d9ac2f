//! CPU time of the run, per lane and per thread, from the kernel's per-thread clocks.
//!
//! Why: on the robot's few cores the frame rate a run holds depends on how fast the machine is that day,
//! and latency under overload is queueing, not work. CPU time per frame is the work itself: it says how
//! much of the machine a frame needs (two cores at 25 fps give 80 ms per frame), on any day.
//!
//! Lanes measure their own thread (`CLOCK_THREAD_CPUTIME_ID`); every other thread of the process (the
//! engine's helpers, ONNX Runtime's and OpenCV's workers, the replay's decoder, the side lanes) is read by
//! its thread id through the clock Linux gives each thread (`thread_clock`), before and after the run.
use std::collections::BTreeMap;

/// CPU time (ns) the calling thread has used.
pub fn thread_cpu_ns() -> i64 {
    clock_ns(libc::CLOCK_THREAD_CPUTIME_ID).unwrap_or(0)
}

/// CPU time (ns) the whole process has used, every thread included.
pub fn process_cpu_ns() -> i64 {
    clock_ns(libc::CLOCK_PROCESS_CPUTIME_ID).unwrap_or(0)
}

/// The calling thread's kernel id.
pub fn thread_id() -> i32 {
    // SAFETY: gettid has no preconditions.
    unsafe { libc::gettid() }
}

fn clock_ns(id: libc::clockid_t) -> Option<i64> {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `t` is a valid timespec to write to.
    (unsafe { libc::clock_gettime(id, &mut t) } == 0).then(|| t.tv_sec * 1_000_000_000 + t.tv_nsec)
}

/// The CPU clock of thread `tid` of this process: Linux's ABI (`MAKE_THREAD_CPUCLOCK(tid, CPUCLOCK_SCHED)`,
/// what glibc's `pthread_getcpuclockid` returns), usable for any thread of the calling process.
fn thread_clock(tid: i32) -> libc::clockid_t {
    ((!tid) << 3) | 6
}

/// One thread of this process, read by [`threads`].
#[derive(Debug, Clone)]
pub struct ThreadCpu {
    /// Its name (`comm`; unnamed threads carry the process's).
    pub name: String,
    /// CPU time it has used (ns).
    pub ns: i64,
    /// Whether it runs at idle priority (SCHED_IDLE, or nice 19 where that was refused): it only takes CPU
    /// time nothing else wants, as the side lanes do.
    pub idle: bool,
}

/// Every thread of this process now, by thread id. Threads that end while this reads are left out.
pub fn threads() -> BTreeMap<i32, ThreadCpu> {
    let mut out = BTreeMap::new();
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else { return out };
    for e in dir.flatten() {
        let Some(tid) = e.file_name().to_str().and_then(|s| s.parse::<i32>().ok()) else { continue };
        let Some(ns) = clock_ns(thread_clock(tid)) else { continue };
        let name = std::fs::read_to_string(e.path().join("comm")).unwrap_or_default().trim().to_string();
        // SAFETY: plain system calls about a thread of this process (a thread gone meanwhile gives -1).
        let idle = unsafe {
            libc::sched_getscheduler(tid) == libc::SCHED_IDLE
                || libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t) == 19
        };
        out.insert(tid, ThreadCpu { name, ns, idle });
    }
    out
}

/// The CPU a run used: its lanes' own threads, the process, and the other threads by name.
#[derive(Debug, Clone, Default)]
pub struct RunCpu {
    /// Each lane's thread (the source's first), ns.
    pub lanes: Vec<(&'static str, i64)>,
    /// The whole process over the run, ns.
    pub process_ns: i64,
    /// Threads other than the lanes that ran during the run, grouped by name, ns.
    pub others: BTreeMap<String, i64>,
    /// The part of `others` that ran at idle priority (the side lanes), ns.
    pub idle_ns: i64,
}

impl RunCpu {
    /// The threads that are not lanes (`lane_tids`): CPU used between two [`threads`] readings, by name
    /// (unnamed threads, which take the process's name, are reported as `workers`), and the part of it
    /// used by threads at idle priority.
    pub fn others_between(
        before: &BTreeMap<i32, ThreadCpu>,
        after: &BTreeMap<i32, ThreadCpu>,
        lane_tids: &[i32],
        process_name: &str,
    ) -> (BTreeMap<String, i64>, i64) {
        let (mut out, mut idle) = (BTreeMap::new(), 0);
        for (tid, t) in after {
            if lane_tids.contains(tid) {
                continue;
            }
            let used = t.ns - before.get(tid).map_or(0, |b| b.ns);
            if used <= 0 {
                continue;
            }
            let key = if t.name.is_empty() || t.name == process_name { "workers".to_string() } else { t.name.clone() };
            *out.entry(key).or_default() += used;
            if t.idle {
                idle += used;
            }
        }
        (out, idle)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Works until this thread has used `ms` of CPU (not wall) time.
    fn spin(ms: i64) {
        let t = thread_cpu_ns();
        let mut x = 0u64;
        while thread_cpu_ns() - t < ms * 1_000_000 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
    }

    #[test]
    fn another_threads_clock_reads_its_work_and_a_sleeping_thread_reads_none() {
        let (tx, rx) = std::sync::mpsc::channel();
        let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
        let busy = std::thread::Builder::new()
            .name("cpu-test-busy".into())
            .spawn(move || {
                // at idle priority, as the side lanes run (nice 19 where SCHED_IDLE is refused)
                // SAFETY: plain system calls on the calling thread.
                unsafe {
                    let param = libc::sched_param { sched_priority: 0 };
                    if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
                        libc::setpriority(libc::PRIO_PROCESS, 0, 19);
                    }
                }
                tx.send(thread_id()).unwrap();
                go_rx.recv().unwrap();
                spin(60);
                go_rx.recv().unwrap();
            })
            .unwrap();
        let tid = rx.recv().unwrap();
        let before = threads();
        assert_eq!(before[&tid].name, "cpu-test-busy");
        assert!(before[&tid].idle, "the thread runs at idle priority");
        assert!(!before[&thread_id()].idle, "this one does not");
        go_tx.send(()).unwrap();
        let mut after = threads();
        while after[&tid].ns - before[&tid].ns < 55_000_000 {
            std::thread::sleep(std::time::Duration::from_millis(10));
            after = threads();
        }
        let me = thread_id();
        let (others, idle) = RunCpu::others_between(&before, &after, &[me], "never-this");
        let used = others["cpu-test-busy"];
        assert!((55_000_000..2_000_000_000).contains(&used), "{used} ns");
        // the idle-priority part holds that thread's work (and whatever else of this test binary idles)
        assert!(idle >= used, "{idle} < {used}");
        go_tx.send(()).unwrap();
        busy.join().unwrap();
        // the excluded thread (a lane's) is not among the others; a thread's own clock is the one read by id
        assert!(!others.contains_key(&after[&me].name));
        let (own, by_id) = (thread_cpu_ns(), clock_ns(thread_clock(me)).unwrap());
        assert!((by_id - own).abs() < 50_000_000, "{own} vs {by_id}");
        assert!(process_cpu_ns() >= own);
    }
}
