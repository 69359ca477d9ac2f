//! # abvs-sim: offline simulation for the runtime
//!
//! What the runtime is tested and measured with, never what runs on the robot: synthetic
//! sessions with ground truth ([`synth`]: simulated units moving through saccades and pursuit in
//! a rendered scene, with their calibration) and the depth error of a run against that truth
//! ([`truth`], a sink of the runtime's pipeline), and simulated drive boards ([`board`]; [`servo_board`]
//! executes move commands), and the closed-loop simulation of the whole head ([`head`]: `abvs run --source
//! sim`), its gaze scripts ([`gaze_script`]) and its gaze scored against the truth ([`gaze_score`]); the
//! runtime assembled with them ([`head_run`]).
//! `abvs sim session`, `abvs sim board` and `abvs run` use them.
pub mod board;
pub mod board_server;
pub mod gaze_plan;
pub mod gaze_score;
pub mod gaze_script;
pub mod head;
pub mod head_run;
pub mod servo_board;
pub mod synth;
pub mod truth;
