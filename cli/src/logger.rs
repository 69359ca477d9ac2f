//! The program's logger: what the libraries report through `log` goes to stderr as
//! `warning: ...` / `error: ...` (the wording the libraries used to print themselves).
//! `ABVS_LOG` (error, warn, info, debug, trace, off) sets the level; warnings by default.
use log::{Level, LevelFilter, Log, Metadata, Record};
use std::io::Write;

struct Stderr;

impl Log for Stderr {
    fn enabled(&self, m: &Metadata) -> bool {
        m.level() <= log::max_level()
    }

    fn log(&self, r: &Record) {
        if !self.enabled(r.metadata()) {
            return;
        }
        let tag = match r.level() {
            Level::Error => "error",
            Level::Warn => "warning",
            Level::Info => "info",
            Level::Debug => "debug",
            Level::Trace => "trace",
        };
        // One write per line, so that lines from several threads do not interleave.
        let _ = std::io::stderr().lock().write_all(format!("{tag}: {}\n", r.args()).as_bytes());
    }

    fn flush(&self) {}
}

/// Installs the logger (once, at start-up).
pub fn init() {
    let level = std::env::var("ABVS_LOG").ok().and_then(|v| v.parse::<LevelFilter>().ok()).unwrap_or(LevelFilter::Warn);
    if log::set_logger(&Stderr).is_ok() {
        log::set_max_level(level);
    }
}
