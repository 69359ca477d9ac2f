//! Tasks: the processing stages between sources and sinks, in data-flow order:
//! [`align`] (encoder angles at each frame's mid-exposure) -> [`kinematics`] (per-eye FK, moving extrinsic) ->
//! [`rectify`] (per-frame rectification maps and remap) -> [`disparity`] (ONNX network or SGBM; [`disparity_census`] the network refined by a census search, the
//! runtime's default; [`disparity_fused`] SGBM and the network;
//! [`confidence`]: its left-right check, run by the disparity stage; [`census_confidence`]: census-refine's own
//! confidence, the validity mask's) ->
//! [`depth`] (depth map and point cloud in the left home camera frame); [`fovea`] (a window at the raw
//! frames' native scale around the fixation point, its own lane between disparity and output).
pub mod align;
pub mod census_confidence;
pub mod confidence;
pub mod depth;
pub mod disparity;
pub mod disparity_census;
pub mod disparity_fused;
pub mod fovea;
pub mod kinematics;
pub mod motion;
pub mod rectify;
