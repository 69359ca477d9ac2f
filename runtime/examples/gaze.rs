//! Points the eyes from a process of one's own through the running runtime's gaze handle: look at a point,
//! pursue one, hold, go home, and read the state of the latest frame. The guide's Rust lines
//! (docs/gaze.md, "Point the eyes from your process") are lines of this file, which the tests build and run.
//!
//! On the shipped fixture (a replay) there is no drive board to move: every goal is refused with the reason
//! `no_board` and the eyes hold, which this example prints; on the live eyes the same calls move them.
//!
//! ```text
//! cargo run -p abvs-runtime --example gaze
//! ```
use std::time::Duration;

use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::RuntimeConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut config = RuntimeConfig::load(&shipped("config/fixture.toml"))?;
    config.disparity.width = 320;
    config.disparity.height = 240;
    config.source.frames = Some(12);
    config.bridges.iceoryx.enabled = false;

    let handle = Runtime::from_config(&config)?.spawn()?;
    let gaze = handle.gaze();
    let id = gaze.look_at([0.1, -0.05, 0.8]);
    // goals are taken at the next frame: wait for the state that answers this one
    let mut answered = None;
    while answered.is_none() && !handle.is_finished() {
        std::thread::sleep(Duration::from_millis(20));
        answered = gaze.state().filter(|s| s.goal_id == id);
    }
    gaze.pursue([-0.1, 0.0, 0.8], [0.2, 0.0, 0.0]);
    gaze.hold();
    gaze.home();
    let state = gaze.state(); // Option<GazeState>: the latest frame's
    let report = handle.join()?;
    match answered {
        Some(s) => println!("goal {id}: phase {} reason {}", s.phase.name(), s.reason.map_or("-", |r| r.name())),
        None => println!("goal {id}: no state answered it"),
    }
    println!("latest state: {state:?}");
    println!("frames_published {}", report.stats.frames_published);
    Ok(())
}
