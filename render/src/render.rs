//! Rendering a scene through a camera: supersampled ray casting, then the photometric chain
//! (blur, vignetting, gain/offset, noise) and 8-bit quantisation.

use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::rays::par_rows;
use crate::scene::Frame;
use crate::{Camera, RayTable, RenderError, Result, Scene};

/// How to render. `Default` is one ray per pixel centre, no blur, vignetting or noise, unit gain.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOptions {
    /// `n`: `n x n` samples per pixel, averaged (box filter over the pixel). With `n > 1` the
    /// samples are multi-jittered (Chiu, Shirley & Wang 1994): one per cell of the `n x n` grid
    /// *and* one per each of the `n^2` columns and rows, positions from a hash of the pixel
    /// (deterministic). A regular grid would snap axis-aligned edges to 1/n px and bias board
    /// corners by up to 1/(2n) px; this pattern leaves ~1/(2n^2) per pixel, uncorrelated between
    /// pixels. Use >= 4 for calibration boards.
    pub supersample: u32,
    /// Gaussian blur sigma in pixels (lens PSF), applied to the supersampled radiance; 0 = none.
    pub blur_sigma: f64,
    /// Vignetting strength `s` in [0, 1]: relative illumination `(1 - s) + s cos^4(theta)`,
    /// theta the field angle of the pixel's ray (the natural cos^4 fall-off at `s = 1`).
    pub vignetting: f64,
    /// Multiplies the radiance (exposure / sensor gain difference between eyes).
    pub gain: f64,
    /// Added after the gain, in 8-bit grey levels (black level difference between eyes).
    pub offset: f64,
    /// Standard deviation of additive Gaussian noise, in 8-bit grey levels; 0 = none.
    pub noise_sigma: f64,
    /// Noise seed: same seed, same bytes (on any machine and thread count).
    pub seed: u64,
    /// Also return the gray image before rounding and clipping ([`Rendered::linear`]), for
    /// measurements that must not be limited by 8-bit quantisation.
    pub keep_linear: bool,
    /// Worker threads; 0 = one per core (at most 8). The output does not depend on it.
    pub threads: usize,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            supersample: 1,
            blur_sigma: 0.0,
            vignetting: 0.0,
            gain: 1.0,
            offset: 0.0,
            noise_sigma: 0.0,
            seed: 0,
            keep_linear: false,
            threads: 0,
        }
    }
}

impl RenderOptions {
    fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(RenderError::InvalidOptions(m));
        if self.supersample == 0 || self.supersample > 64 {
            return bad(format!("supersample {} must be in 1..=64", self.supersample));
        }
        if !(self.blur_sigma.is_finite() && self.blur_sigma >= 0.0) {
            return bad(format!("blur sigma {} px must be >= 0", self.blur_sigma));
        }
        if !(0.0..=1.0).contains(&self.vignetting) {
            return bad(format!("vignetting strength {} must be in [0, 1]", self.vignetting));
        }
        if !(self.gain.is_finite() && self.offset.is_finite()) {
            return bad(format!("gain {} / offset {} must be finite", self.gain, self.offset));
        }
        if !(self.noise_sigma.is_finite() && self.noise_sigma >= 0.0) {
            return bad(format!("noise sigma {} must be >= 0", self.noise_sigma));
        }
        Ok(())
    }
}

/// A rendered image. Row-major, `width * height` entries (RGB: 3 per pixel).
#[derive(Debug, Clone, PartialEq)]
pub struct Rendered {
    pub width: usize,
    pub height: usize,
    /// 8-bit gray image.
    pub gray: Vec<u8>,
    /// 8-bit RGB image (interleaved), when any texture in the scene is RGB.
    pub rgb: Option<Vec<u8>>,
    /// Ground-truth depth: z in the camera frame (metres) of the hit of the pixel-centre ray,
    /// whatever the supersampling; `f32::INFINITY` where it hits nothing (background) or the
    /// pixel is outside the lens's valid range.
    pub depth: Vec<f32>,
    /// Gray in grey levels before rounding and clipping, if `keep_linear`.
    pub linear: Option<Vec<f32>>,
}

impl Rendered {
    /// The 8-bit gray image as an `image` buffer (e.g. to save as PNG).
    pub fn gray_image(&self) -> image::GrayImage {
        image::GrayImage::from_raw(self.width as u32, self.height as u32, self.gray.clone())
            .expect("gray buffer has width * height bytes")
    }

    /// The RGB image as an `image` buffer, if the render has colour.
    pub fn rgb_image(&self) -> Option<image::RgbImage> {
        let rgb = self.rgb.as_ref()?;
        image::RgbImage::from_raw(self.width as u32, self.height as u32, rgb.clone())
    }
}

/// Renders `scene` through `camera` at `world_from_camera` (builds the [`RayTable`]; to render
/// several frames through one camera build the table once and use [`render_with_rays`]).
pub fn render(
    scene: &Scene,
    camera: &Camera,
    world_from_camera: &Isometry3<f64>,
    opts: &RenderOptions,
) -> Result<Rendered> {
    render_with_rays(scene, &RayTable::new(camera)?, world_from_camera, opts)
}

/// Renders `scene` through the camera of `rays` at `world_from_camera`.
pub fn render_with_rays(
    scene: &Scene,
    rays: &RayTable,
    world_from_camera: &Isometry3<f64>,
    opts: &RenderOptions,
) -> Result<Rendered> {
    render_moving(scene, rays, &|_, _| *world_from_camera, 1, opts)
}

/// Most time samples a pixel integrates (a saccade's blur at 1561 deg/s over a long exposure is
/// tens of pixels; past this the caller's frame is unusable anyway).
pub const MAX_TIME_SAMPLES: usize = 256;

/// Renders `scene` through the camera of `rays` with a pose per row and time sample: pixel row `y`
/// integrates `time_samples` poses `world_from_camera(y, k)`, k = 0..time_samples (the caller spaces
/// them over that row's exposure, so a rolling shutter and motion blur are both the caller's
/// timing). Each time sample takes one of the pixel's spatial samples in turn (distributed ray
/// tracing: `max(time_samples, n^2)` rays a pixel, not their product). Depth comes from the pixel
/// centre at the middle time sample. `time_samples = 1` with a constant pose is
/// [`render_with_rays`].
pub fn render_moving(
    scene: &Scene,
    rays: &RayTable,
    world_from_camera: &(dyn Fn(usize, usize) -> Isometry3<f64> + Sync),
    time_samples: usize,
    opts: &RenderOptions,
) -> Result<Rendered> {
    opts.validate()?;
    scene.validate()?;
    if time_samples == 0 || time_samples > MAX_TIME_SAMPLES {
        return Err(RenderError::InvalidOptions(format!(
            "time samples {time_samples} must be in 1..={MAX_TIME_SAMPLES}"
        )));
    }
    let (w, h) = (rays.width(), rays.height());
    let with_rgb = scene.has_rgb();
    let n = opts.supersample as usize;
    let spatial = n * n;
    let samples = spatial.max(time_samples);
    let weight = 1.0 / samples as f32;
    let bg = scene.background;

    struct Row {
        gray: Vec<f32>,
        rgb: Vec<[f32; 3]>,
        depth: Vec<f32>,
    }
    let rows = par_rows(h, opts.threads, |y| {
        let mut row = Row {
            gray: vec![bg; w],
            rgb: if with_rgb { vec![[bg; 3]; w] } else { Vec::new() },
            depth: vec![f32::INFINITY; w],
        };
        // The scene prepared for each instant of this row (a few surfaces each: cheap).
        let frames: Vec<Frame> = (0..time_samples).map(|k| Frame::new(scene, &world_from_camera(y, k))).collect();
        let mid = &frames[time_samples / 2];
        let mut offsets = Vec::with_capacity(spatial);
        for x in 0..w {
            let Some(centre) = rays.centre_ray(x, y) else { continue };
            let (mut g, mut c) = (0.0f32, [0.0f32; 3]);
            sample_offsets(x, y, n, &mut offsets);
            for j in 0..samples {
                // sample j: spatial offset j mod n^2, instant j (or spread evenly when n^2 > K)
                let (dx, dy) = offsets[j % spatial];
                let frame = &frames[if time_samples >= spatial { j } else { j * time_samples / spatial }];
                let ray = rays.ray(x, y, dx, dy).unwrap_or(centre);
                match frame.trace(&ray) {
                    Some((i, t, aux)) if with_rgb => {
                        let (sg, sc) = frame.shade_rgb(i, &ray, t, aux);
                        g += sg;
                        c = [c[0] + sc[0], c[1] + sc[1], c[2] + sc[2]];
                    }
                    Some((i, t, aux)) => g += frame.shade(i, &ray, t, aux),
                    None => {
                        g += bg;
                        c = [c[0] + bg, c[1] + bg, c[2] + bg];
                    }
                }
            }
            row.gray[x] = g * weight;
            if with_rgb {
                row.rgb[x] = [c[0] * weight, c[1] * weight, c[2] * weight];
            }
            // Depth from the exact pixel-centre ray (with n = 1 it is the one sample).
            if let Some((_, t, _)) = mid.trace(&centre) {
                row.depth[x] = (t * centre.z) as f32;
            }
        }
        row
    });

    let mut gray = Vec::with_capacity(w * h);
    let mut rgb = Vec::with_capacity(if with_rgb { w * h } else { 0 });
    let mut depth = Vec::with_capacity(w * h);
    for r in rows {
        gray.extend_from_slice(&r.gray);
        rgb.extend_from_slice(&r.rgb);
        depth.extend_from_slice(&r.depth);
    }

    // Photometric chain on planes of f32 (gray, then R, G, B): blur -> vignetting -> gain,
    // offset -> noise. Each plane gets its own noise stream.
    let mut planes = vec![gray];
    if with_rgb {
        for ch in 0..3 {
            planes.push(rgb.iter().map(|c| c[ch]).collect());
        }
    }
    let illumination: Option<Vec<f32>> = (opts.vignetting > 0.0).then(|| {
        let s = opts.vignetting;
        (0..w * h)
            .map(|k| {
                let cos = rays.centre_ray(k % w, k / w).map_or(1.0, |r| r.z.max(0.0));
                ((1.0 - s) + s * cos.powi(4)) as f32
            })
            .collect()
    });
    let out: Vec<Vec<f32>> = planes
        .into_iter()
        .enumerate()
        .map(|(p, mut plane)| {
            if opts.blur_sigma > 0.0 {
                plane = gaussian_blur(&plane, w, h, opts.blur_sigma, opts.threads);
            }
            if let Some(ill) = &illumination {
                plane.iter_mut().zip(ill).for_each(|(v, i)| *v *= i);
            }
            let (gain, offset) = ((opts.gain * 255.0) as f32, opts.offset as f32);
            plane.iter_mut().for_each(|v| *v = *v * gain + offset);
            if opts.noise_sigma > 0.0 {
                add_noise(&mut plane, w, opts.noise_sigma, opts.seed, p as u64);
            }
            plane
        })
        .collect();

    let quantise = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    let gray8 = out[0].iter().map(|&v| quantise(v)).collect();
    let rgb8 = with_rgb
        .then(|| (0..w * h).flat_map(|k| (1..4).map(move |p| (p, k))).map(|(p, k)| quantise(out[p][k])).collect());
    let linear = opts.keep_linear.then(|| out.into_iter().next().expect("gray plane"));
    Ok(Rendered { width: w, height: h, gray: gray8, rgb: rgb8, depth, linear })
}

/// Sub-pixel sample offsets (in [-0.5, 0.5]^2) of pixel `(px, py)`: the pixel centre for
/// `n = 1`, else a multi-jittered pattern (n-rooks and n x n stratified) from a hash of the pixel.
fn sample_offsets(px: usize, py: usize, n: usize, out: &mut Vec<(f64, f64)>) {
    out.clear();
    if n == 1 {
        out.push((0.0, 0.0));
        return;
    }
    let mut state = (px as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (py as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    let mut next = || {
        // SplitMix64.
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let unit = |r: u64| (r >> 11) as f64 / (1u64 << 53) as f64;
    // Canonical arrangement: cell (i, j) holds x sub-column j and y sub-row i.
    let nf = n as f64;
    let mut sx: Vec<usize> = (0..n * n).map(|k| k / n).collect(); // sx[j * n + i] = sub-column of cell (i, j)
    let mut sy: Vec<usize> = (0..n * n).map(|k| k % n).collect(); // sy[j * n + i] = sub-row of cell (i, j)
                                                                  // Shuffle sub-columns within each column i, sub-rows within each row j: keeps both properties.
    for i in 0..n {
        for j in 0..n - 1 {
            let k = j + (next() % (n - j) as u64) as usize;
            sx.swap(j * n + i, k * n + i);
        }
    }
    for j in 0..n {
        for i in 0..n - 1 {
            let k = i + (next() % (n - i) as u64) as usize;
            sy.swap(j * n + i, j * n + k);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let x = (i as f64 + (sx[j * n + i] as f64 + unit(next())) / nf) / nf;
            let y = (j as f64 + (sy[j * n + i] as f64 + unit(next())) / nf) / nf;
            out.push((x - 0.5, y - 0.5));
        }
    }
}

/// Adds N(0, sigma^2) noise; each row has its own ChaCha stream, so the result depends only on
/// (seed, plane), never on how rows are scheduled.
fn add_noise(plane: &mut [f32], w: usize, sigma: f64, seed: u64, plane_index: u64) {
    for (y, row) in plane.chunks_mut(w).enumerate() {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(((y as u64) << 2) | plane_index);
        for v in row {
            let z: f64 = StandardNormal.sample(&mut rng);
            *v += (z * sigma) as f32;
        }
    }
}

/// Separable Gaussian blur with clamp-to-edge borders, kernel radius ceil(3 sigma).
fn gaussian_blur(src: &[f32], w: usize, h: usize, sigma: f64, threads: usize) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    let clampi = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let tmp: Vec<f32> = par_rows(h, threads, |y| {
        let row = &src[y * w..(y + 1) * w];
        (0..w as isize)
            .map(|x| k.iter().enumerate().map(|(j, kv)| kv * row[clampi(x + j as isize - r, w)]).sum::<f32>())
            .collect::<Vec<_>>()
    })
    .concat();
    par_rows(h, threads, |y| {
        (0..w)
            .map(|x| {
                k.iter()
                    .enumerate()
                    .map(|(j, kv)| kv * tmp[clampi(y as isize + j as isize - r, h) * w + x])
                    .sum::<f32>()
            })
            .collect::<Vec<_>>()
    })
    .concat()
}
