//! [`crate::tracker::EncoderTracker`] on its own thread, reading a port until stopped or the port fails,
//! and the homing and liveness it saw for other threads ([`crate::watch::EncoderWatch`]).
use std::io::{ErrorKind, Read};
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use crossbeam_channel::{Receiver, Sender, TrySendError};

use crate::commands::CommandPort;
use crate::error::BoardError;
use crate::tracker::{EncoderStats, EncoderTracker, HomedSample};
use crate::watch::EncoderWatch;

/// CLOCK_MONOTONIC now (ns): the receive time of the bytes read (the runtime's frame clock).
// (time_t and c_long are 32-bit on 32-bit targets: the casts are not no-ops everywhere)
#[allow(clippy::unnecessary_cast)]
pub fn monotonic_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as i64 * 1_000_000_000 + ts.tv_nsec as i64
}

/// [`EncoderTracker`] on its own thread, reading a port until stopped or the port fails.
pub struct EncoderStream {
    rx: Receiver<HomedSample>,
    shared: Arc<Mutex<(EncoderStats, [bool; 2])>>,
    last_ns: Arc<AtomicI64>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), BoardError>>>,
    /// The same port for writing (the drive board's commands), when it was given one.
    commands: Option<(Box<dyn std::io::Write + Send>, String)>,
}

impl EncoderStream {
    /// Starts reading. `name` (the port path) goes into errors. The reader should time out now
    /// and then (a serial port's timeout) so that the thread notices [`EncoderStream::finish`].
    pub fn spawn<R: Read + Send + 'static>(mut reader: R, name: String, capacity: usize) -> Self {
        let (tx, rx): (Sender<HomedSample>, _) = crossbeam_channel::bounded(capacity.max(1));
        let shared = Arc::new(Mutex::new((EncoderStats::default(), [false; 2])));
        let stop = Arc::new(AtomicBool::new(false));
        let last_ns = Arc::new(AtomicI64::new(i64::MIN));
        let (sh, st, last) = (shared.clone(), stop.clone(), last_ns.clone());
        let thread = std::thread::Builder::new()
            .name("encoders".into())
            .spawn(move || {
                let mut tracker = EncoderTracker::new();
                let mut buf = vec![0u8; 4096];
                let mut out = Vec::with_capacity(256);
                let mut overflow = 0u64;
                let result = loop {
                    if st.load(Ordering::Relaxed) {
                        break Ok(());
                    }
                    let n = match reader.read(&mut buf) {
                        Ok(0) => break Err(BoardError::EndOfStream { port: name }),
                        Ok(n) => n,
                        Err(e)
                            if matches!(
                                e.kind(),
                                ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                            ) =>
                        {
                            continue
                        }
                        Err(source) => break Err(BoardError::Read { port: name, source }),
                    };
                    let rx_ns = monotonic_ns();
                    tracker.feed(&buf[..n], rx_ns, &mut out);
                    if !out.is_empty() {
                        last.store(rx_ns, Ordering::Relaxed);
                    }
                    for r in out.drain(..) {
                        if let Err(TrySendError::Full(_)) = tx.try_send(r) {
                            overflow += 1;
                        }
                    }
                    let mut s = sh.lock().expect("encoder stats lock");
                    *s = (EncoderStats { overflow, ..tracker.stats() }, tracker.homed());
                };
                let mut s = sh.lock().expect("encoder stats lock");
                *s = (EncoderStats { overflow, ..tracker.stats() }, tracker.homed());
                result
            })
            .expect("spawning the encoder thread");
        EncoderStream { rx, shared, last_ns, stop, thread: Some(thread), commands: None }
    }

    /// The same port for writing: the drive board's commands ([`CommandPort`]).
    pub fn with_commands(mut self, writer: Box<dyn std::io::Write + Send>, name: String) -> Self {
        self.commands = Some((writer, name));
        self
    }

    /// Homing and liveness, for another thread.
    pub fn watch(&self) -> EncoderWatch {
        EncoderWatch { shared: self.shared.clone(), last_ns: self.last_ns.clone() }
    }

    /// The command side of the port, once (`None` without one).
    pub fn take_commands(&mut self) -> Option<CommandPort> {
        let (w, name) = self.commands.take()?;
        Some(CommandPort::new(w, self.watch(), name))
    }

    /// Homed samples, in arrival order.
    pub fn records(&self) -> &Receiver<HomedSample> {
        &self.rx
    }

    /// What the tracker saw so far.
    pub fn stats(&self) -> EncoderStats {
        self.shared.lock().expect("encoder stats lock").0.clone()
    }

    /// Whether each eye is homed (it may un-home after a board reset).
    pub fn homed(&self) -> [bool; 2] {
        self.shared.lock().expect("encoder stats lock").1
    }

    /// True once the reading thread ended (port error or end of stream).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Stops reading; returns the final counts and the port error that ended the stream, if any.
    pub fn finish(mut self) -> (EncoderStats, Option<BoardError>) {
        self.stop.store(true, Ordering::Relaxed);
        let err = match self.thread.take().map(|t| t.join()) {
            Some(Ok(Ok(()))) | None => None,
            Some(Ok(Err(e))) => Some(e),
            Some(Err(_)) => Some(BoardError::ThreadPanicked),
        };
        (self.stats(), err)
    }
}

impl Drop for EncoderStream {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
