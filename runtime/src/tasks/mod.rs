//! Tasks: the processing stages between sources and sinks, in data-flow order:
//! [`align`] (encoder angles at each frame's mid-exposure) -> [`kinematics`] (per-eye FK, moving extrinsic) ->
//! [`rectify`] (per-frame rectification maps and remap) -> [`disparity`] (the stage around an engine of the
//! `abvs_disparity` crate, with its left-right check and validity mask) ->
//! [`depth`] (depth map and point cloud in the left home camera frame); [`fovea`] (a window at the raw
//! frames' native scale around the fixation point, its own lane between disparity and output).
pub mod align;
pub mod depth;
pub mod disparity;
pub mod fovea;
pub mod kinematics;
pub mod motion;
pub mod rectify;
