//! Textures: gray (optionally RGB) radiance in [0, 1] over texture coordinates (u, v) in [0, 1]^2,
//! u to the right along the texture's rows, v down along its columns (image order).

use std::path::Path;
use std::sync::Arc;

use crate::{RenderError, Result};

/// How a raster texture is sampled between texel centres.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    /// Bilinear between texel centres: photographs and smooth textures.
    Bilinear,
    /// Nearest texel, so edges stay perfectly sharp: binary boards (AprilGrid, chessboard)
    /// whose edges must sit exactly on texel boundaries; anti-aliasing then comes from the
    /// renderer's supersampling (and optional blur), as in a real camera.
    Nearest,
}

type ProcFn = dyn Fn(f64, f64) -> f32 + Send + Sync;

#[derive(Clone)]
enum Kind {
    Raster { width: usize, height: usize, gray: Vec<f32>, rgb: Option<Vec<[f32; 3]>> },
    Procedural(Arc<ProcFn>),
}

/// A texture. Raster texel `(i, j)` (column, row) covers `u` in `[i, i+1) / width` and `v` in
/// `[j, j+1) / height`: texel centres are at half-integers, so a board of `k` texels per square
/// has its square edges exactly at `u = n k / width`.
///
/// By default a texture is stretched over the whole face it is put on; with
/// [`Texture::with_metric_size`] it instead spans `W x H` metres and repeats (tiles).
#[derive(Clone)]
pub struct Texture {
    kind: Kind,
    filter: Filter,
    metric_size: Option<[f64; 2]>,
}

impl std::fmt::Debug for Texture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = match &self.kind {
            Kind::Raster { width, height, rgb, .. } => {
                format!("raster {width}x{height}{}", if rgb.is_some() { " rgb" } else { "" })
            }
            Kind::Procedural(_) => "procedural".to_string(),
        };
        f.debug_struct("Texture")
            .field("kind", &kind)
            .field("filter", &self.filter)
            .field("metric_size", &self.metric_size)
            .finish()
    }
}

/// ITU-R BT.601 luma, the gray value of an RGB texel.
fn luma(c: [f32; 3]) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

impl Texture {
    /// A uniform texture.
    pub fn constant(value: f32) -> Texture {
        Texture::procedural(move |_, _| value)
    }

    /// A gray raster texture from a row-major buffer of values in [0, 1].
    pub fn from_gray(width: usize, height: usize, gray: Vec<f32>) -> Result<Texture> {
        check_dims(width, height, gray.len())?;
        Ok(Texture {
            kind: Kind::Raster { width, height, gray, rgb: None },
            filter: Filter::Bilinear,
            metric_size: None,
        })
    }

    /// An RGB raster texture from a row-major buffer of values in [0, 1]; the gray channel is
    /// its luma.
    pub fn from_rgb(width: usize, height: usize, rgb: Vec<[f32; 3]>) -> Result<Texture> {
        check_dims(width, height, rgb.len())?;
        let gray = rgb.iter().map(|&c| luma(c)).collect();
        Ok(Texture {
            kind: Kind::Raster { width, height, gray, rgb: Some(rgb) },
            filter: Filter::Bilinear,
            metric_size: None,
        })
    }

    /// A gray raster texture with texel `(column, row)` = `f(column, row)`.
    pub fn from_texel_fn(width: usize, height: usize, f: impl Fn(usize, usize) -> f32) -> Result<Texture> {
        let gray = (0..height).flat_map(|j| (0..width).map(move |i| (i, j))).map(|(i, j)| f(i, j)).collect();
        Texture::from_gray(width, height, gray)
    }

    /// A procedural gray texture `f(u, v)`, evaluated exactly at every ray hit (no texels, so
    /// no resampling error at all): analytic blobs, ramps, gratings.
    pub fn procedural(f: impl Fn(f64, f64) -> f32 + Send + Sync + 'static) -> Texture {
        Texture { kind: Kind::Procedural(Arc::new(f)), filter: Filter::Bilinear, metric_size: None }
    }

    /// A binary checkerboard of `cols x rows` squares (the top-left one black), one texel per
    /// square, sampled with [`Filter::Nearest`]: its inner corners are exactly at
    /// `(i / cols, j / rows)`.
    pub fn checkerboard(cols: usize, rows: usize) -> Result<Texture> {
        Ok(Texture::from_texel_fn(cols, rows, |i, j| ((i + j) % 2) as f32)?.with_filter(Filter::Nearest))
    }

    /// Loads an image file (PNG; gray or colour, 8 or 16 bit). Colour images keep their RGB.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Texture> {
        let path = path.as_ref();
        let err = |source| RenderError::TextureFile { path: path.to_path_buf(), source };
        let img = image::ImageReader::open(path)
            .map_err(|e| err(image::ImageError::IoError(e)))?
            .with_guessed_format()
            .map_err(|e| err(image::ImageError::IoError(e)))?
            .decode()
            .map_err(err)?;
        Texture::from_image(&img)
    }

    /// Converts a decoded image (gray stays gray, anything with colour keeps RGB).
    pub fn from_image(img: &image::DynamicImage) -> Result<Texture> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        if img.color().has_color() {
            let rgb = img.to_rgb32f();
            Texture::from_rgb(w, h, rgb.pixels().map(|p| p.0).collect())
        } else {
            let gray = img.to_luma32f();
            Texture::from_gray(w, h, gray.pixels().map(|p| p.0[0]).collect())
        }
    }

    /// Sets the sampling filter of a raster texture (procedural textures ignore it).
    pub fn with_filter(mut self, filter: Filter) -> Texture {
        self.filter = filter;
        self
    }

    /// Makes the texture span `width x height` metres and repeat, instead of being stretched
    /// over the face: floors, walls and boxes keep a physical texture scale whatever their size.
    pub fn with_metric_size(mut self, width: f64, height: f64) -> Result<Texture> {
        if !(width.is_finite() && height.is_finite() && width > 0.0 && height > 0.0) {
            return Err(RenderError::InvalidTexture(format!("metric size {width} x {height} m must be positive")));
        }
        self.metric_size = Some([width, height]);
        Ok(self)
    }

    /// The metric size set by [`Texture::with_metric_size`], if any.
    pub fn metric_size(&self) -> Option<[f64; 2]> {
        self.metric_size
    }

    /// Raster size in texels (`None` for procedural textures).
    pub fn texels(&self) -> Option<(usize, usize)> {
        match &self.kind {
            Kind::Raster { width, height, .. } => Some((*width, *height)),
            Kind::Procedural(_) => None,
        }
    }

    /// Whether the texture carries colour.
    pub fn is_rgb(&self) -> bool {
        matches!(&self.kind, Kind::Raster { rgb: Some(_), .. })
    }

    /// Texture coordinates of a point `(x, y)` metres from the corner of a `face_w x face_h` face.
    #[inline]
    pub(crate) fn uv_on_face(&self, x: f64, y: f64, face_w: f64, face_h: f64) -> (f64, f64) {
        match self.metric_size {
            None => (x / face_w, y / face_h),
            Some([w, h]) => ((x / w).rem_euclid(1.0), (y / h).rem_euclid(1.0)),
        }
    }

    /// Gray value at `(u, v)`; coordinates outside [0, 1] clamp to the border texels.
    #[inline]
    pub fn sample(&self, u: f64, v: f64) -> f32 {
        match &self.kind {
            Kind::Procedural(f) => f(u, v),
            Kind::Raster { width, height, gray, .. } => {
                self.sample_raster(*width, *height, u, v, |i| gray[i], |a, b, t| a + (b - a) * t)
            }
        }
    }

    /// RGB value at `(u, v)` (gray textures give gray).
    #[inline]
    pub fn sample_rgb(&self, u: f64, v: f64) -> [f32; 3] {
        match &self.kind {
            Kind::Raster { width, height, rgb: Some(rgb), .. } => self.sample_raster(
                *width,
                *height,
                u,
                v,
                |i| rgb[i],
                |a, b, t| [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t],
            ),
            _ => {
                let g = self.sample(u, v);
                [g, g, g]
            }
        }
    }

    #[inline]
    fn sample_raster<T: Copy>(
        &self,
        w: usize,
        h: usize,
        u: f64,
        v: f64,
        at: impl Fn(usize) -> T,
        lerp: impl Fn(T, T, f32) -> T,
    ) -> T {
        match self.filter {
            Filter::Nearest => {
                let i = ((u * w as f64).floor().max(0.0) as usize).min(w - 1);
                let j = ((v * h as f64).floor().max(0.0) as usize).min(h - 1);
                at(j * w + i)
            }
            Filter::Bilinear => {
                let x = (u * w as f64 - 0.5).clamp(0.0, (w - 1) as f64);
                let y = (v * h as f64 - 0.5).clamp(0.0, (h - 1) as f64);
                let (i0, j0) = (x.floor() as usize, y.floor() as usize);
                let (i1, j1) = ((i0 + 1).min(w - 1), (j0 + 1).min(h - 1));
                let (tx, ty) = ((x - i0 as f64) as f32, (y - j0 as f64) as f32);
                let top = lerp(at(j0 * w + i0), at(j0 * w + i1), tx);
                let bottom = lerp(at(j1 * w + i0), at(j1 * w + i1), tx);
                lerp(top, bottom, ty)
            }
        }
    }
}

fn check_dims(width: usize, height: usize, len: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(RenderError::InvalidTexture(format!("texture of {width} x {height} texels has no pixels")));
    }
    if width.checked_mul(height) != Some(len) {
        return Err(RenderError::InvalidTexture(format!(
            "buffer of {len} values does not match {width} x {height} texels"
        )));
    }
    Ok(())
}
