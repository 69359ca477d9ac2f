//! Disparity model directories: the manifest (`manifest.json`, "abvs-disparity-model/1": layout,
//! resolution, max disparity, training recipe, metrics), the network census-refine runs in a model's place,
//! and the one rule that picks a shipped model for an image size ([`default_model_for`]), used by
//! `abvs disparity`, `abvs disparity-eval` and `abvs run` alike.
use std::path::{Component, Path, PathBuf};

use abvs_runtime_core::session::check_inside;

use serde::{Deserialize, Serialize};

use crate::error::{DisparityError, Result};

/// The format tag of a disparity model's manifest.json.
pub const DISPARITY_FORMAT: &str = "abvs-disparity-model/1";

/// manifest.json of a disparity model directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DisparityManifest {
    /// The format tag, [`DISPARITY_FORMAT`].
    pub format: String,
    /// The model's name (e.g. `hitnet-s`).
    pub variant: String,
    /// The ONNX file, relative to the model directory.
    pub file: String,
    /// The network's input tensor.
    pub input_name: String,
    /// "gray2" (`[1,2,H,W]`) or "rgb6" (`[1,6,H,W]`).
    pub input_layout: String,
    /// Input scale: pixel levels are multiplied by this.
    pub input_scale: f64,
    /// Input width the network was exported at (px).
    pub width: u32,
    /// Input height (px).
    pub height: u32,
    /// Largest disparity the network outputs (px).
    pub max_disparity: f64,
    /// The network's output tensor.
    pub output_name: String,
    /// What the model scored at training (free form).
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// How the model was trained (free form).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Hex SHA-256 of the model file, checked on load (a damaged model would silently change the depth).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub onnx_sha256: Option<String>,
    /// The network census-refine runs in this one's place (a sibling directory's name). The shipped hitnet-m
    /// names `hitnet-s`: at 640x480, hitnet-s and SGBM at its 320x240, refined there, beat hitnet-m's weights
    /// refined at 640x480 on real pairs at half the CPU (models/hitnet/README.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refine_base: Option<String>,
}

impl DisparityManifest {
    /// Reads and parses the manifest file `path` (its format tag is checked by [`DisparityManifest::load`]).
    pub fn read(path: &Path) -> Result<DisparityManifest> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| DisparityError::Read { path: path.to_path_buf(), source })?;
        serde_json::from_str(&text).map_err(|source| DisparityError::Manifest { path: path.to_path_buf(), source })
    }

    /// The manifest of the model directory `dir`, its format tag and its file's name checked.
    pub fn load(dir: &Path) -> Result<DisparityManifest> {
        let mp = dir.join("manifest.json");
        let m = Self::read(&mp)?;
        if m.format != DISPARITY_FORMAT {
            return Err(DisparityError::Model {
                path: mp,
                msg: format!("format `{}`, expected `{DISPARITY_FORMAT}`", m.format),
            });
        }
        // the model file is named relative to the manifest and stays in its directory
        check_inside(&m.file)
            .map_err(|e| DisparityError::Model { path: mp.clone(), msg: format!("bad manifest: `file`: {e}") })?;
        Ok(m)
    }
}

/// The network census-refine runs for the model at `path`: the sibling its manifest names as `refine_base`,
/// else the model itself (an .onnx file, or a manifest without one).
pub fn refine_base(path: &Path) -> Result<PathBuf> {
    let mp = path.join("manifest.json");
    if !path.is_dir() || !mp.is_file() {
        return Ok(path.to_path_buf());
    }
    let m = DisparityManifest::read(&mp)?;
    match m.refine_base {
        None => Ok(path.to_path_buf()),
        Some(name) => {
            let mut parts = Path::new(&name).components();
            match (parts.next(), parts.next()) {
                (Some(Component::Normal(_)), None) => {}
                _ => {
                    return Err(DisparityError::Model {
                        path: mp,
                        msg: format!("bad manifest: `refine_base` `{name}`: must be a sibling directory's name"),
                    })
                }
            }
            // `path` may end in a separator or be relative without a parent: go through its file name
            let dir = std::path::absolute(path).map_err(|source| DisparityError::Read { path: mp.clone(), source })?;
            Ok(dir.parent().unwrap_or(Path::new("/")).join(name))
        }
    }
}

/// The shipped models (`models/hitnet/` of the checkout) that may be chosen by [`default_model_for`].
pub const SHIPPED: [&str; 2] = ["hitnet-s", "hitnet-m"];

/// The checkout's `models/hitnet/{variant}`: next to the executable's checkout (up to four directories above
/// it: `target/<profile>/examples/`), else in the source tree this crate was built from.
pub fn shipped(variant: &str) -> PathBuf {
    let rel = Path::new("models/hitnet").join(variant);
    let mut candidates = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        for a in exe.ancestors().skip(1).take(4) {
            candidates.push(a.join(&rel));
        }
    }
    candidates.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(&rel));
    candidates.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| candidates.pop().expect("one candidate"))
}

/// The shipped models ([`SHIPPED`]) that are present.
pub fn default_models() -> Vec<PathBuf> {
    SHIPPED.iter().map(|v| shipped(v)).filter(|p| p.join("manifest.json").exists()).collect()
}

/// The shipped model for images of `w` x `h`: the largest resolution at most 1.5x the images' on each axis
/// (more detail and a wider disparity range, without inventing much by upsampling: 427x320 and up get
/// hitnet-m (640x480), a 320x240 image hitnet-s); the smallest when none qualifies. The one rule of
/// `abvs disparity`, `abvs disparity-eval` and the runtime (`[disparity] model` unset).
pub fn default_model_for(w: u32, h: u32) -> PathBuf {
    let size = |p: &PathBuf| DisparityManifest::read(&p.join("manifest.json")).ok().map(|m| (m.width, m.height));
    let mut shipped_: Vec<(PathBuf, (u32, u32))> =
        default_models().into_iter().filter_map(|p| size(&p).map(|s| (p, s))).collect();
    shipped_.sort_by_key(|(_, (mw, mh))| mw * mh);
    let fits = shipped_.iter().rev().find(|(_, (mw, mh))| 2 * *mw <= 3 * w && 2 * *mh <= 3 * h);
    match fits.or(shipped_.first()) {
        Some((p, _)) => p.clone(),
        // none readable: the error names the expected path when it is loaded
        None => shipped("hitnet-s"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_model_is_the_largest_within_one_and_a_half_times_the_image() {
        let name = |w, h| default_model_for(w, h).file_name().unwrap().to_string_lossy().into_owned();
        // the runtime's two resolutions, and the bound either side of 1.5x
        assert_eq!(name(640, 480), "hitnet-m");
        assert_eq!(name(320, 240), "hitnet-s");
        assert_eq!(name(427, 320), "hitnet-m");
        assert_eq!(name(426, 320), "hitnet-s");
        assert_eq!(name(1282, 1110), "hitnet-m");
        // nothing fits: the smallest
        assert_eq!(name(160, 120), "hitnet-s");
    }

    #[test]
    fn a_manifest_file_outside_its_directory_is_refused() {
        assert!(check_inside("model.onnx").is_ok());
        assert!(check_inside("../x.onnx").unwrap_err().contains("leaves its directory"));
        assert!(check_inside("/tmp/x.onnx").unwrap_err().contains("absolute"));
        assert!(check_inside("").is_err());
    }
}
