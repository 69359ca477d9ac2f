use std::path::PathBuf;

/// Everything that can go wrong when building a scene or rendering it.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// A texture image could not be opened or decoded.
    #[error("cannot read texture file {path}: {source}")]
    TextureFile {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    /// A texture with no pixels, a pixel buffer of the wrong length, or a bad metric size.
    #[error("invalid texture: {0}")]
    InvalidTexture(String),
    /// A surface of zero, negative or non-finite size, or a non-finite pose.
    #[error("invalid surface #{index} ({kind}): {reason}")]
    InvalidSurface { index: usize, kind: &'static str, reason: String },
    /// Render options out of range (e.g. zero supersampling, negative blur).
    #[error("invalid render options: {0}")]
    InvalidOptions(String),
    /// The camera has no pixels, or none of its pixels unprojects.
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
}
