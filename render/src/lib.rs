//! Deterministic ray-casting renderer of textured 3D scenes through the abvs camera models.
//!
//! Why: calibration and the stereo runtime need synthetic images whose geometry is known
//! exactly (board corners to well under 0.1 px, per-pixel ground-truth depth). A ray caster
//! over a few analytic surfaces gives both, through the very lens model (`abvs_camera::Camera`)
//! that the rest of abvs uses, so no second camera model can drift from the real one.
//!
//! Pipeline: [`RayTable`] (per-pixel camera rays, computed once per camera because the lens
//! unprojection is the slow part) -> [`render_with_rays`] casts `n x n` stratified rays per pixel
//! into a [`Scene`] of [`Surface`]s carrying [`Texture`]s, then applies blur, vignetting,
//! gain/offset and seeded noise ([`RenderOptions`]) and quantises to 8 bits ([`Rendered`]).
//!
//! Frames: OpenCV camera frame (x right, y down, z forward), `world_from_camera` poses, metres.

mod error;
mod rays;
mod render;
mod scene;
mod texture;

pub use abvs_camera::Camera;
pub use error::RenderError;
pub use rays::RayTable;
pub use render::{render, render_moving, render_with_rays, RenderOptions, Rendered, MAX_TIME_SAMPLES};
pub use scene::{BoxTextures, Hit, Scene, Surface};
pub use texture::{Filter, Texture};

/// Result type of this crate.
pub type Result<T> = std::result::Result<T, RenderError>;
