//! `--dump DIR`: writes each frame's rectified pair and a depth image as PNG, to look at what the pipeline
//! saw and made (debugging, reports). Allocates per frame: not for the real-time path.
use std::path::PathBuf;

use crate::error::{Result, RuntimeError};
use crate::messages::Published;
use crate::sinks::Sink;

/// Writes `frame_{seq}.png` per frame: rectified left, rectified right and depth side by side.
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
        // left | right side by side, then depth (near = bright, invalid = black)
        let mut img = image::GrayImage::new(w * 3, h);
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
        let p = self.dir.join(format!("frame_{:06}.png", out.seq));
        img.save(&p).map_err(|e| err(&p, &e))
    }
}
