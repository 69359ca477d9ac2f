//! The self-check logs as the timing fit reads them: per frame the motion and the timing the run applied,
//! per match its timing evidence, and the checks that a frame log and its match log are of one run.
use std::path::Path;

use abvs_runtime::sinks::self_check::log_record::{read_log, FrameRecord, MatchRecord};

use crate::error::{Result, SelfCheckError};

/// One logged frame's timing context.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTiming {
    /// Pipeline sequence number.
    pub seq: u64,
    /// Each camera's angular speed (deg/s).
    pub speed: [f64; 2],
    /// Change of each camera's mean angular velocity across the frame instant (deg/s).
    pub accel: [f64; 2],
    /// The readout the run applied (ms).
    pub readout_ms: f64,
    /// The row fraction the stamps fix.
    pub anchor: f64,
    /// The encoder offsets the run applied (ms).
    pub offset_ms: [f64; 2],
    /// |rotation error| the self-check measured on the frame (deg); NaN without a fit.
    pub error_deg: f64,
    /// Row bands of the rolling-shutter correction (0: the frame corrected as a whole); `None` in older logs.
    pub row_bands: Option<u64>,
    /// The run's identity (`run_id`); `None` in older logs.
    pub run_id: Option<u64>,
}

/// One match's timing evidence (the runtime's match log).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchEvidence {
    /// The frame.
    pub seq: u64,
    /// Raw row fraction of the left and right point.
    pub row: [f64; 2],
    /// Vertical disparity (px).
    pub dy: f64,
    /// Design row of the static rotation (px/rad).
    pub j: [f64; 3],
    /// d(dy)/d(eps) per eye (px/ms).
    pub s: [f64; 2],
    /// Parallax of each camera's optical centre moving for a millisecond (px/ms).
    pub u: [f64; 2],
}

/// The per-frame log's timing (`None` when the log predates the timing columns).
pub fn read_frames(path: &Path) -> Result<Option<Vec<FrameTiming>>> {
    let log = read_log::<FrameRecord>(path)?;
    if !log.has_column(FrameRecord::TIMING_COLUMN) {
        return Ok(None);
    }
    let mut out = Vec::with_capacity(log.lines.len());
    for l in &log.lines {
        let r = &l.record;
        let timing = [
            r.speed_l_deg_s,
            r.speed_r_deg_s,
            r.accel_l_deg_s,
            r.accel_r_deg_s,
            r.readout_ms,
            r.readout_anchor,
            r.offset_l_ms,
            r.offset_r_ms,
        ];
        if timing.iter().any(|x| !x.is_finite()) {
            return Err(SelfCheckError::TimingNotNumbers { path: path.to_path_buf(), line: l.line });
        }
        out.push(FrameTiming {
            seq: r.seq,
            speed: [r.speed_l_deg_s, r.speed_r_deg_s],
            accel: [r.accel_l_deg_s, r.accel_r_deg_s],
            readout_ms: r.readout_ms,
            anchor: r.readout_anchor,
            offset_ms: [r.offset_l_ms, r.offset_r_ms],
            error_deg: (r.rot_x_deg * r.rot_x_deg + r.rot_y_deg * r.rot_y_deg + r.rot_z_deg * r.rot_z_deg).sqrt(),
            row_bands: r.row_bands,
            run_id: r.run_id,
        });
    }
    Ok(Some(out))
}

/// The per-frame log's timing, where it must have it (a `--before` log, a round's log).
pub fn read_frames_with_timing(path: &Path) -> Result<Vec<FrameTiming>> {
    read_frames(path)?.ok_or_else(|| SelfCheckError::NoTimingColumns { path: path.to_path_buf() })
}

/// The one run identity of a log's rows (`None`: the log predates it); an error when its rows mix runs.
pub fn run_id_of(path: &Path, ids: impl Iterator<Item = Option<u64>>) -> Result<Option<u64>> {
    let mut one = None;
    for id in ids.flatten() {
        match one {
            None => one = Some(id),
            Some(o) if o != id => {
                return Err(SelfCheckError::MixedRuns { path: path.to_path_buf(), first: o, second: id })
            }
            _ => {}
        }
    }
    Ok(one)
}

/// The match log (`<log>.matches.csv`).
pub fn read_matches(path: &Path) -> Result<Vec<MatchEvidence>> {
    Ok(read_matches_of_run(path)?.0)
}

/// The match log (`<log>.matches.csv`) and the run it names (`None` in older logs).
pub fn read_matches_of_run(path: &Path) -> Result<(Vec<MatchEvidence>, Option<u64>)> {
    let log = read_log::<MatchRecord>(path)?;
    let run = run_id_of(path, log.records().map(|r| r.run_id))?;
    let m = log
        .records()
        .map(|r| MatchEvidence {
            seq: r.seq,
            row: [r.row_l, r.row_r],
            dy: r.dy_px,
            j: [r.j_x, r.j_y, r.j_z],
            s: [r.s_l_px_per_ms, r.s_r_px_per_ms],
            u: [r.u_l_px_per_ms, r.u_r_px_per_ms],
        })
        .collect();
    Ok((m, run))
}

/// The run of a frame log and its match log; an error naming both when they are of different runs.
pub fn same_run(log: &Path, frames: &[FrameTiming], mpath: &Path, mrun: Option<u64>) -> Result<Option<u64>> {
    let run = run_id_of(log, frames.iter().map(|f| f.run_id))?;
    if let (Some(a), Some(b)) = (run, mrun) {
        if a != b {
            return Err(SelfCheckError::DifferentRuns {
                match_log: mpath.to_path_buf(),
                match_run: b,
                frame_log: log.to_path_buf(),
                frame_run: a,
            });
        }
    }
    Ok(run)
}

/// A frame's motion was steady enough for the first-order model: its mean angular velocity changed by at
/// most a quarter of its speed across the instant (or by 2 deg/s when slower than 8 deg/s).
pub fn steady(f: &FrameTiming) -> bool {
    (0..2).all(|e| f.accel[e] <= (0.25 * f.speed[e]).max(2.0))
}

/// Why the log's run cannot be fitted as it was applied: frames the rolling-shutter correction left whole
/// although the cameras have a readout (the fit models a per-row correction).
pub fn not_as_applied(frames: &[FrameTiming]) -> Option<String> {
    let whole = frames.iter().filter(|f| f.row_bands == Some(0) && f.readout_ms > 0.0 && steady(f)).count();
    (whole > 0).then(|| {
        format!(
            "the run rectified {whole} moving frames as a whole, at their instant (the rolling-shutter correction \
             was off: `--rolling-shutter off`, `[motion] rolling_shutter = false`), while the fit models a run that \
             reads each row at its own time: replay with the correction on and fit that log"
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_runtime::sinks::self_check::log_record::LogRecord;

    #[test]
    fn a_damaged_match_log_names_file_line_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.matches.csv");
        let head = MatchRecord::header();
        std::fs::write(
            &p,
            format!(
                "{head}\n0,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,7\n0,1,2,3,4,0.1,0.2,oops,1,2,3,0.01,0.02,0,0,7\n"
            ),
        )
        .unwrap();
        let e = read_matches(&p).unwrap_err().to_string();
        assert!(e.contains("x.matches.csv:3") && e.contains("dy_px") && e.contains("oops"), "{e}");
        std::fs::write(&p, "seq,xl\n1,2\n").unwrap();
        let e = read_matches(&p).unwrap_err().to_string();
        assert!(e.contains("no column `yl`"), "{e}");
        std::fs::write(
            &p,
            format!(
                "{head}\n0,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,7\n1,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,8\n"
            ),
        )
        .unwrap();
        let e = read_matches(&p).unwrap_err().to_string();
        assert!(e.contains("rows of two runs (7 and 8)"), "{e}");
    }
}
