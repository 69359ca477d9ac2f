//! # abvs-disparity: stereo disparity engines
//!
//! Left-view disparity of rectified 8-bit gray pairs, by four engines behind one interface
//! ([`engine::DisparityEngine`], built by name by [`factory::engine`]):
//!
//! - [`onnx::OnnxEngine`]: a HITNet-style stereo network through ONNX Runtime (loaded at run time);
//! - [`sgbm::SgbmEngine`]: OpenCV's StereoSGBM in its parallel SGBM_3WAY mode;
//! - [`census::CensusRefineEngine`]: the network refined by a census search around its answer, with SGBM's
//!   checked matches where the images are larger than the network (the runtime's default), scoring each
//!   pixel as it goes ([`census_confidence`]);
//! - [`fused::FusedEngine`]: SGBM where its own checks accept a match, the network elsewhere (the default of
//!   `abvs disparity`).
//!
//! Around them: the one left-right check and validity mask ([`confidence`]), model manifests and the one rule
//! that picks a shipped model ([`manifest`]), resampling between resolutions ([`resample`]), one engine's
//! answer on a pair of any size ([`estimate`]), PFM files ([`pfm`]), scoring against ground truth
//! ([`score`]), the engines scored side by side ([`eval`]) and the fovea's matching core, native scale around a
//! coarser map's answer ([`fovea`], scored on a pair with ground truth by [`fovea_eval`]). The crate has no
//! pipeline stage: `abvs-runtime` wraps an engine in one, and `abvs disparity`, `abvs disparity-eval` and
//! `abvs run` all call this crate.
//!
//! Layers, each module importing only from those above it in this list (no circle): [`error`];
//! [`engine`]; [`resample`], [`confidence`], [`census_confidence`], [`manifest`], [`pfm`]; [`onnx`], [`sgbm`];
//! [`census`], [`fused`], [`fovea`]; [`factory`]; [`estimate`], [`score`]; [`eval`], [`fovea_eval`].
#![warn(missing_docs)]
pub mod census;
pub mod census_confidence;
pub mod confidence;
pub mod engine;
pub mod error;
pub mod estimate;
pub mod eval;
pub mod factory;
pub mod fovea;
pub mod fovea_eval;
pub mod fused;
pub mod manifest;
pub mod match_cost;
pub mod onnx;
pub mod pfm;
pub mod resample;
pub mod score;
pub mod sgbm;

pub use error::{DisparityError, Result};
