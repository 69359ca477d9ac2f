//! Homing and liveness of a running [`crate::stream::EncoderStream`], shared with other threads (the gaze
//! controller's command side, [`crate::commands::CommandPort`]).
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex};

use crate::tracker::EncoderStats;

/// Homing and liveness of an [`crate::stream::EncoderStream`], for another thread (the gaze controller's).
#[derive(Clone)]
pub struct EncoderWatch {
    pub(crate) shared: Arc<Mutex<(EncoderStats, [bool; 2])>>,
    pub(crate) last_ns: Arc<AtomicI64>,
}

impl EncoderWatch {
    /// Both eyes' home counts once both are homed.
    pub fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        let s = self.shared.lock().expect("encoder stats lock");
        match (s.1, s.0.home_counts) {
            ([true, true], [Some(l), Some(r)]) => Some([l, r]),
            _ => None,
        }
    }

    /// CLOCK_MONOTONIC ns at which the newest homed record arrived.
    pub fn last_record_ns(&self) -> Option<i64> {
        Some(self.last_ns.load(Ordering::Relaxed)).filter(|&t| t != i64::MIN)
    }
}
