//! `--dump DIR`: writes each frame's rectified pair, a depth image and the cloud seen from above as PNG, to
//! look at what the pipeline saw and made (debugging, reports, the README's picture). Allocates per frame:
//! not for the real-time path.
use std::path::PathBuf;

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::sink::Sink;

/// Writes `frame_{seq}.png` per frame: rectified left, rectified right, depth and the cloud's top view side
/// by side.
pub struct DumpSink {
    /// The directory (created when missing).
    pub dir: PathBuf,
    /// Only every n-th frame.
    pub every: u64,
}

impl Sink for DumpSink {
    fn name(&self) -> &'static str {
        "dump"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        if out.seq % self.every.max(1) != 0 {
            return Ok(());
        }
        let (w, h) = (out.cam.width, out.cam.height);
        let err = |p: &PathBuf, e: &dyn std::fmt::Display| RuntimeError::File {
            path: p.clone(),
            line: None,
            msg: e.to_string(),
        };
        std::fs::create_dir_all(&self.dir).map_err(|e| err(&self.dir, &e))?;
        // left | right side by side, then depth (near = bright, invalid = black), then the top view
        let mut img = image::GrayImage::new(w * 4, h);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                img.put_pixel(x, y, image::Luma([out.left_rect[i]]));
                img.put_pixel(x + w, y, image::Luma([out.right_rect[i]]));
                let d = out.depth.depth[i];
                let v = if d.is_finite() { (255.0 * (1.0 - (d - 0.2) / 1.4)).clamp(16.0, 255.0) as u8 } else { 0 };
                img.put_pixel(x + 2 * w, y, image::Luma([v]));
            }
        }
        top_view(&mut img, 3 * w, w, h, out);
        let p = self.dir.join(format!("frame_{:06}.png", out.seq));
        img.save(&p).map_err(|e| err(&p, &e))
    }
}

/// The cloud seen from above in the panel at column `x0` (`w` x `h`): x (left home camera frame, m) across,
/// +-[`TOP_HALF_WIDTH_M`], depth z up the panel from 0 to [`TOP_DEPTH_M`]; brighter = higher (smaller y),
/// so the scene's floor and objects read apart.
fn top_view(img: &mut image::GrayImage, x0: u32, w: u32, h: u32, out: &Published) {
    for y in (0..h).step_by(((h / 8).max(1)) as usize) {
        for x in 0..w {
            img.put_pixel(x0 + x, y, image::Luma([24])); // 0.25 m rulers
        }
    }
    for p in &out.depth.cloud[..out.depth.n_points] {
        let u = ((p.x / TOP_HALF_WIDTH_M + 1.0) * 0.5 * w as f32) as i64;
        let v = ((1.0 - p.z / TOP_DEPTH_M) * h as f32) as i64;
        if (0..w as i64).contains(&u) && (0..h as i64).contains(&v) {
            let shade = (160.0 - 200.0 * p.y).clamp(60.0, 255.0) as u8;
            img.put_pixel(x0 + u as u32, v as u32, image::Luma([shade]));
        }
    }
}

/// Half the width (m) of the top view's field.
const TOP_HALF_WIDTH_M: f32 = 1.0;
/// The top view's depth range (m).
const TOP_DEPTH_M: f32 = 2.0;
