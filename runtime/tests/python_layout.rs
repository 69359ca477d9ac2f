//! The Python subscriber's and gaze client's ctypes structures (python/abvs_iceoryx2.py) against the Rust `#[repr(C)]` types
//! of the iceoryx2 services: type names, sizes, alignments and every field's offset, so a layout change on
//! one side cannot drift from the other. Needs the Python environment of scripts/setup.sh (.deps/python, or
//! the interpreter in ABVS_PYTHON): missing, the test fails (CI installs it).
use std::collections::BTreeMap;
use std::mem::{align_of, offset_of, size_of};
use std::process::Command;

use abvs_runtime::bridges::iceoryx::gaze::{GazeGoalWire, GazeStateWire};
use abvs_runtime::bridges::iceoryx::{CloudPoint, FrameHeader};
use iceoryx2::prelude::ZeroCopySend;

#[path = "../../tests/support/python_env.rs"]
mod python_env;
use python_env::{python, repo};

#[test]
fn python_ctypes_match_the_rust_layout() {
    macro_rules! fields {
        ($t:ty; $($f:ident),*) => {{
            let mut m = BTreeMap::new();
            $( m.insert(stringify!($f).to_string(), offset_of!($t, $f)); )*
            m
        }};
    }
    let header = fields!(FrameHeader; seq, t_frame_ns, t_publish_ns, frame_id, pose_left, pose_right, intrinsics,
        width, height, baseline_m, valid, flags);
    let point = fields!(CloudPoint; x, y, z, rgba);
    let goal = fields!(GazeGoalWire; id, kind, reserved, point_m, velocity_m_s);
    let state = fields!(GazeStateWire; seq, t_frame_ns, goal_id, phase, reason, commanded_m, measured_m, vergence_m,
        planned_ms, flags, reserved);
    // SAFETY: type_name only returns the #[type_name] attribute's string.
    let (hn, pn, gn, sn) = unsafe {
        (
            <FrameHeader as ZeroCopySend>::type_name(),
            <CloudPoint as ZeroCopySend>::type_name(),
            <GazeGoalWire as ZeroCopySend>::type_name(),
            <GazeStateWire as ZeroCopySend>::type_name(),
        )
    };
    let rust = serde_json::json!({
        hn: { "size": size_of::<FrameHeader>(), "align": align_of::<FrameHeader>(), "fields": header },
        pn: { "size": size_of::<CloudPoint>(), "align": align_of::<CloudPoint>(), "fields": point },
        gn: { "size": size_of::<GazeGoalWire>(), "align": align_of::<GazeGoalWire>(), "fields": goal },
        sn: { "size": size_of::<GazeStateWire>(), "align": align_of::<GazeStateWire>(), "fields": state },
    });
    let o = Command::new(python())
        .arg(repo().join("python/tests/abvs_check.py"))
        .arg("layout")
        .output()
        .expect("running python");
    assert!(o.status.success(), "python: {}", String::from_utf8_lossy(&o.stderr));
    let py: serde_json::Value = serde_json::from_slice(&o.stdout).expect("python prints JSON");
    assert_eq!(py, rust, "Python's ctypes layout (left) differs from the Rust one (right)");
    // the struct must have a field per Rust field: a field added in Rust and not listed above would pass
    assert_eq!(size_of::<FrameHeader>(), 8 * 3 + 32 + 8 * 16 + 4 * 2 + 8 + 4 * 2);
    assert_eq!(size_of::<GazeGoalWire>(), 8 + 4 * 2 + 8 * 6);
    assert_eq!(size_of::<GazeStateWire>(), 8 * 3 + 4 * 2 + 8 * 8 + 4 * 2);
}
