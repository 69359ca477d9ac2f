//! Camera buffers -> the runtime's 8-bit gray, into caller-provided memory.
//!
//! The runtime only needs luma (calibration, rectification and disparity all work on gray), so
//! every V4L2 layout the OV8856 pipelines deliver is reduced to one `u8` per pixel at full
//! resolution. A [`GrayConverter`] is built once per stream (it owns the few rows of scratch the
//! Bayer path needs) and then converts every frame without allocating.
//!
//! Bayer -> gray ("demosaic to luma"): every 2x2 window of a Bayer mosaic holds one R, two G and
//! one B, so its luma is `0.299 R + 0.587 (G1 + G2) / 2 + 0.114 B`. The output pixel is the mean of
//! the four windows that contain it, i.e. a 3x3 tent kernel `[1 2 1; 2 4 2; 1 2 1] / 16` over the
//! mosaic with per-colour gains. That is centred on the pixel (a single 2x2 window would shift the
//! image by half a pixel, which calibration would silently absorb into the principal point), is the
//! same at every CFA site, and costs one separable pass. Borders use reflect-101 padding, which keeps
//! the CFA parity. It blurs slightly more than a real demosaic, which is harmless for matching.
//!
//! 10 -> 8 bit: `(v - black).max(0) * 256 / (1024 - black)`, truncated, in fixed point on the luma
//! sum (no table, so the loop vectorises): with black level 0 that is exactly `v >> 2`; with the
//! sensor's pedestal (64 on the OV8856) black goes to 0 and white stays at 255.

/// Pixel layouts the converter accepts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// Packed 4:2:2 `Y0 U Y1 V` (V4L2 `YUYV`): luma is every other byte.
    Yuyv,
    /// Semi-planar 4:2:0 (V4L2 `NV12`): a Y plane, then interleaved UV (ignored).
    Nv12,
    /// 10-bit raw Bayer.
    Bayer10 {
        /// The colour filter's order.
        order: CfaOrder,
        /// How the samples are laid out.
        packing: Bayer10Packing,
    },
}

/// Colour filter order of the top-left 2x2 block, named as V4L2 does (row 0 then row 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CfaOrder {
    /// Blue green / green red.
    Bggr,
    /// Green blue / red green.
    Gbrg,
    /// Green red / blue green (the OV8856).
    Grbg,
    /// Red green / green blue.
    Rggb,
}

/// How 10-bit samples are laid out in memory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bayer10Packing {
    /// One little-endian `u16` per pixel, value in the low 10 bits (`V4L2_PIX_FMT_SBGGR10` etc.).
    Unpacked16Le,
    /// MIPI CSI-2 RAW10: 4 pixels in 5 bytes, bytes 0..4 the high 8 bits, byte 4 the low 2 bits of
    /// each (pixel 0 in bits 1:0) (`V4L2_PIX_FMT_SBGGR10P` etc.).
    MipiPacked,
}

/// Errors of format selection and conversion; each says what was expected and what was given.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PixelError {
    #[error("unsupported pixel format '{fourcc}' (supported: YUYV, NV12, BG10/GB10/BA10/RG10, pBAA/pGAA/pgAA/pRAA)")]
    /// A FourCC the converter does not know.
    UnsupportedFourcc {
        /// The FourCC, as text.
        fourcc: String,
    },
    #[error("{format} {width}x{height}: bytesperline {stride} is below the minimum {min}")]
    /// Rows shorter than the pixels they must hold.
    StrideTooSmall {
        /// The pixel format.
        format: String,
        /// Frame width (px).
        width: u32,
        /// Frame height (px).
        height: u32,
        /// Bytes per row given.
        stride: usize,
        /// Bytes per row needed.
        min: usize,
    },
    #[error("{format} {width}x{height}: {reason}")]
    /// A size the format cannot have (e.g. odd for Bayer).
    BadSize {
        /// The pixel format.
        format: String,
        /// Frame width (px).
        width: u32,
        /// Frame height (px).
        height: u32,
        /// Why.
        reason: &'static str,
    },
    #[error("{format} {width}x{height} (bytesperline {stride}): buffer too short: expected at least {expected} bytes, got {got}")]
    /// A buffer shorter than its format and size need.
    SrcTooShort {
        /// The pixel format.
        format: String,
        /// Frame width (px).
        width: u32,
        /// Frame height (px).
        height: u32,
        /// Bytes per row.
        stride: usize,
        /// Bytes needed.
        expected: usize,
        /// Bytes given.
        got: usize,
    },
    #[error("gray output buffer too short: expected {expected} bytes ({width}x{height}), got {got}")]
    /// A gray output buffer shorter than the frame.
    DstTooShort {
        /// Frame width (px).
        width: u32,
        /// Frame height (px).
        height: u32,
        /// Bytes needed.
        expected: usize,
        /// Bytes given.
        got: usize,
    },
    #[error("black level {black} must be at most 256 (10-bit units)")]
    /// A black level above what 10-bit samples allow.
    BadBlackLevel {
        /// The black level given (10-bit units).
        black: u16,
    },
}

impl From<PixelError> for abvs_runtime_core::error::RuntimeError {
    fn from(e: PixelError) -> Self {
        abvs_runtime_core::error::RuntimeError::Capture(Box::new(e))
    }
}

/// A FourCC as printable text (non-printable bytes escaped), for error messages.
pub fn fourcc_string(code: [u8; 4]) -> String {
    code.iter().flat_map(|b| std::ascii::escape_default(*b)).map(char::from).collect()
}

impl PixelFormat {
    /// All formats the converter accepts, in the order a capture prefers them (raw first: the
    /// OV8856 delivers RAW10 and any ISP conversion costs latency).
    pub const ALL: [PixelFormat; 10] = [
        Self::bayer(CfaOrder::Bggr, Bayer10Packing::MipiPacked),
        Self::bayer(CfaOrder::Gbrg, Bayer10Packing::MipiPacked),
        Self::bayer(CfaOrder::Grbg, Bayer10Packing::MipiPacked),
        Self::bayer(CfaOrder::Rggb, Bayer10Packing::MipiPacked),
        Self::bayer(CfaOrder::Bggr, Bayer10Packing::Unpacked16Le),
        Self::bayer(CfaOrder::Gbrg, Bayer10Packing::Unpacked16Le),
        Self::bayer(CfaOrder::Grbg, Bayer10Packing::Unpacked16Le),
        Self::bayer(CfaOrder::Rggb, Bayer10Packing::Unpacked16Le),
        PixelFormat::Yuyv,
        PixelFormat::Nv12,
    ];

    const fn bayer(order: CfaOrder, packing: Bayer10Packing) -> Self {
        PixelFormat::Bayer10 { order, packing }
    }

    /// The V4L2 FourCC of this layout.
    pub const fn fourcc(self) -> [u8; 4] {
        use Bayer10Packing::*;
        use CfaOrder::*;
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Nv12 => *b"NV12",
            PixelFormat::Bayer10 { order, packing: Unpacked16Le } => match order {
                Bggr => *b"BG10",
                Gbrg => *b"GB10",
                Grbg => *b"BA10",
                Rggb => *b"RG10",
            },
            PixelFormat::Bayer10 { order, packing: MipiPacked } => match order {
                Bggr => *b"pBAA",
                Gbrg => *b"pGAA",
                Grbg => *b"pgAA",
                Rggb => *b"pRAA",
            },
        }
    }

    /// The layout of a V4L2 FourCC, or a named refusal.
    pub fn from_fourcc(code: [u8; 4]) -> Result<Self, PixelError> {
        Self::ALL
            .into_iter()
            .find(|f| f.fourcc() == code)
            .ok_or_else(|| PixelError::UnsupportedFourcc { fourcc: fourcc_string(code) })
    }

    /// Bytes one row of `width` pixels needs (the smallest valid bytesperline).
    pub fn min_bytesperline(self, width: u32) -> usize {
        let w = width as usize;
        match self {
            PixelFormat::Yuyv => 2 * w,
            PixelFormat::Nv12 => w,
            PixelFormat::Bayer10 { packing: Bayer10Packing::Unpacked16Le, .. } => 2 * w,
            PixelFormat::Bayer10 { packing: Bayer10Packing::MipiPacked, .. } => w.div_ceil(4) * 5,
        }
    }

    /// Bytes the converter reads from a buffer: every row's stride except the last, which only
    /// needs its pixels (NV12: only the Y plane is read).
    pub fn min_buffer_len(self, width: u32, height: u32, bytesperline: usize) -> usize {
        if height == 0 {
            return 0;
        }
        bytesperline.saturating_mul(height as usize - 1).saturating_add(self.min_bytesperline(width))
    }

    /// Checks that `width`, `height` and `bytesperline` are usable for this layout.
    pub fn validate(self, width: u32, height: u32, bytesperline: usize) -> Result<(), PixelError> {
        let format = fourcc_string(self.fourcc());
        let bad = |reason| Err(PixelError::BadSize { format: format.clone(), width, height, reason });
        if width == 0 || height == 0 {
            return bad("empty image");
        }
        match self {
            PixelFormat::Yuyv if width & 1 != 0 => return bad("YUYV needs an even width"),
            PixelFormat::Nv12 if width & 1 != 0 || height & 1 != 0 => return bad("NV12 needs even dimensions"),
            PixelFormat::Bayer10 { .. } if width & 1 != 0 || height & 1 != 0 => {
                return bad("Bayer needs even dimensions (whole 2x2 CFA blocks)")
            }
            PixelFormat::Bayer10 { packing: Bayer10Packing::MipiPacked, .. } if width & 3 != 0 => {
                return bad("RAW10 packed needs a width divisible by 4")
            }
            _ => {}
        }
        let min = self.min_bytesperline(width);
        if bytesperline < min {
            return Err(PixelError::StrideTooSmall { format, width, height, stride: bytesperline, min });
        }
        Ok(())
    }
}

/// Fixed-point luma gains per CFA colour for the 3x3 tent (see the module doc): the tent gives R and
/// B a quarter and G half of its weight at every site, so the gains are 0.299*4, 0.587*2, 0.114*4,
/// scaled by 1024 and rounded so that a flat field maps to itself exactly (1225 + 2*1202 + 467 = 4096).
const GAIN_R: u32 = 1225;
const GAIN_G: u32 = 1202;
const GAIN_B: u32 = 467;
/// Tent weight 16 times gain scale 1024: the luma sum of a 10-bit value `v` is `v << 14` (< 2^24).
const LUMA_SHIFT: u32 = 14;
/// Largest black level accepted (a quarter of the 10-bit range; the OV8856's is 64).
pub const MAX_BLACK_LEVEL: u16 = 256;

/// 8-bit gray from a luma sum: `((sum - bias).max(0) >> 10) * scale >> 20`, with `bias = black << 14`
/// and `scale = ceil(2^24 / (1024 - black))` (16384 for black 0: exactly `v >> 2`). The product stays
/// below 2^29; the rounded-up scale errs by at most 1/64 of a grey level.
#[inline(always)]
fn gray8(sum: u32, bias: u32, scale: u32) -> u8 {
    ((((sum.saturating_sub(bias)) >> 10) * scale) >> 20).min(255) as u8
}

#[derive(Clone, Copy)]
enum Cfa {
    R,
    G,
    B,
}

fn gain(c: Cfa) -> u32 {
    match c {
        Cfa::R => GAIN_R,
        Cfa::G => GAIN_G,
        Cfa::B => GAIN_B,
    }
}

impl CfaOrder {
    /// Colours of the top-left 2x2 block: `[row][col]`.
    fn sites(self) -> [[Cfa; 2]; 2] {
        use Cfa::*;
        match self {
            CfaOrder::Bggr => [[B, G], [G, R]],
            CfaOrder::Gbrg => [[G, B], [R, G]],
            CfaOrder::Grbg => [[G, R], [B, G]],
            CfaOrder::Rggb => [[R, G], [G, B]],
        }
    }
}

/// Converts one stream's buffers to gray; holds the scratch rows so no frame allocates.
#[derive(Clone, Debug)]
pub struct GrayConverter {
    format: PixelFormat,
    width: u32,
    height: u32,
    stride: usize,
    bias: u32,
    scale: u32,
    rows: [Vec<u16>; 3],
    vsum: Vec<u32>,
    /// Per-column luma gain of an even and an odd Bayer row (plain slices vectorise; `x & 1` does not).
    row_gains: [Vec<u32>; 2],
}

impl GrayConverter {
    /// A converter for `width` x `height` buffers with `bytesperline` bytes per row. `black_level`
    /// (10-bit units) is subtracted from raw Bayer data; it is ignored for YUV.
    pub fn new(
        format: PixelFormat,
        width: u32,
        height: u32,
        bytesperline: usize,
        black_level: u16,
    ) -> Result<Self, PixelError> {
        format.validate(width, height, bytesperline)?;
        if black_level > MAX_BLACK_LEVEL {
            return Err(PixelError::BadBlackLevel { black: black_level });
        }
        let black = u32::from(black_level);
        // Rounded up: a truncated scale would put exact multiples (e.g. v - black = 63 of 1008) one level low.
        let (bias, scale) = (black << LUMA_SHIFT, (1u32 << 24).div_ceil(1024 - black));
        let (rows, vsum, row_gains) = match format {
            PixelFormat::Bayer10 { order, .. } => {
                let w = width as usize;
                let sites = order.sites();
                let gains = |p: usize| (0..w).map(|x| gain(sites[p][x % 2])).collect();
                ([vec![0; w], vec![0; w], vec![0; w]], vec![0; w], [gains(0), gains(1)])
            }
            _ => Default::default(),
        };
        Ok(GrayConverter { format, width, height, stride: bytesperline, bias, scale, rows, vsum, row_gains })
    }

    /// The pixel format converted.
    pub fn format(&self) -> PixelFormat {
        self.format
    }

    /// Frame width (px).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height (px).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Bytes per row of the input, padding included.
    pub fn bytesperline(&self) -> usize {
        self.stride
    }

    /// Bytes a source buffer must hold at least.
    pub fn min_src_len(&self) -> usize {
        self.format.min_buffer_len(self.width, self.height, self.stride)
    }

    /// Bytes of gray output (`width * height`, tightly packed).
    pub fn dst_len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Converts `src` (one V4L2 buffer, `bytesused` long) into `dst[..width*height]`.
    pub fn convert(&mut self, src: &[u8], dst: &mut [u8]) -> Result<(), PixelError> {
        let expected = self.min_src_len();
        if src.len() < expected {
            return Err(PixelError::SrcTooShort {
                format: fourcc_string(self.format.fourcc()),
                width: self.width,
                height: self.height,
                stride: self.stride,
                expected,
                got: src.len(),
            });
        }
        let n = self.dst_len();
        if dst.len() < n {
            return Err(PixelError::DstTooShort {
                width: self.width,
                height: self.height,
                expected: n,
                got: dst.len(),
            });
        }
        let dst = &mut dst[..n];
        let w = self.width as usize;
        match self.format {
            PixelFormat::Yuyv => {
                for (y, out) in dst.chunks_exact_mut(w).enumerate() {
                    let row = &src[y * self.stride..y * self.stride + 2 * w];
                    // Fixed-size blocks let the compiler turn the byte gather into shuffles.
                    let mut outs = out.chunks_exact_mut(16);
                    let mut pxs = row.chunks_exact(32);
                    for (o, px) in (&mut outs).zip(&mut pxs) {
                        for i in 0..16 {
                            o[i] = px[2 * i];
                        }
                    }
                    for (o, px) in outs.into_remainder().iter_mut().zip(pxs.remainder().chunks_exact(2)) {
                        *o = px[0];
                    }
                }
            }
            PixelFormat::Nv12 => {
                for (y, out) in dst.chunks_exact_mut(w).enumerate() {
                    out.copy_from_slice(&src[y * self.stride..y * self.stride + w]);
                }
            }
            PixelFormat::Bayer10 { packing, .. } => self.bayer_to_gray(src, dst, packing),
        }
        Ok(())
    }

    fn unpack_row(&mut self, src: &[u8], y: usize, packing: Bayer10Packing) {
        let w = self.width as usize;
        let out = &mut self.rows[y % 3];
        let row = &src[y * self.stride..];
        match packing {
            Bayer10Packing::Unpacked16Le => {
                for (o, b) in out.iter_mut().zip(row[..2 * w].chunks_exact(2)) {
                    *o = u16::from_le_bytes([b[0], b[1]]) & 0x3ff;
                }
            }
            Bayer10Packing::MipiPacked => {
                for (o, b) in out.chunks_exact_mut(4).zip(row[..w / 4 * 5].chunks_exact(5)) {
                    let lo = u16::from(b[4]);
                    o[0] = (u16::from(b[0]) << 2) | (lo & 3);
                    o[1] = (u16::from(b[1]) << 2) | ((lo >> 2) & 3);
                    o[2] = (u16::from(b[2]) << 2) | ((lo >> 4) & 3);
                    o[3] = (u16::from(b[3]) << 2) | (lo >> 6);
                }
            }
        }
    }

    fn bayer_to_gray(&mut self, src: &[u8], dst: &mut [u8], packing: Bayer10Packing) {
        let (w, h) = (self.width as usize, self.height as usize);
        // Row r lives in slot r % 3: rows y-1, y, y+1 are always resident (reflect-101 at the ends).
        self.unpack_row(src, 0, packing);
        self.unpack_row(src, 1, packing);
        for (y, out) in dst.chunks_exact_mut(w).enumerate() {
            if y + 1 < h && y + 1 >= 2 {
                self.unpack_row(src, y + 1, packing);
            }
            let up = if y == 0 { 1 } else { y - 1 };
            let dn = if y + 1 == h { h - 2 } else { y + 1 };
            // Rows y-1 and y+1 have the same CFA parity, so one gain pair serves both.
            let (gm, go) = (&self.row_gains[y % 2], &self.row_gains[(y + 1) % 2]);
            let (ru, rm, rd) = (&self.rows[up % 3], &self.rows[y % 3], &self.rows[dn % 3]);
            for (((((v, u), m), d), gm), go) in self.vsum.iter_mut().zip(ru).zip(rm).zip(rd).zip(gm).zip(go) {
                *v = go * (u32::from(*u) + u32::from(*d)) + 2 * gm * u32::from(*m);
            }
            let v = &self.vsum;
            let (bias, scale) = (self.bias, self.scale);
            out[0] = gray8(2 * v[1] + 2 * v[0], bias, scale);
            // Three shifted slices rather than `windows(3)`: this form vectorises.
            for (((o, a), b), c) in out[1..w - 1].iter_mut().zip(&v[..w - 2]).zip(&v[1..w - 1]).zip(&v[2..]) {
                *o = gray8(a + 2 * b + c, bias, scale);
            }
            out[w - 1] = gray8(2 * v[w - 2] + 2 * v[w - 1], bias, scale);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourcc_round_trip_and_refusal() {
        for f in PixelFormat::ALL {
            assert_eq!(PixelFormat::from_fourcc(f.fourcc()), Ok(f));
        }
        let e = PixelFormat::from_fourcc(*b"MJPG").unwrap_err();
        assert!(e.to_string().contains("MJPG"), "{e}");
    }

    #[test]
    fn ten_to_eight_bits() {
        let c = GrayConverter::new(PixelFormat::Nv12, 2, 2, 2, 0).unwrap();
        for v in 0..1024u32 {
            assert_eq!(gray8(v << LUMA_SHIFT, c.bias, c.scale), (v >> 2) as u8);
        }
        for black in [16u32, 64, 256] {
            let c = GrayConverter::new(PixelFormat::Nv12, 2, 2, 2, black as u16).unwrap();
            for v in 0..1024u32 {
                let want = (f64::from(v) - f64::from(black)).max(0.0) * 256.0 / f64::from(1024 - black);
                let got = f64::from(gray8(v << LUMA_SHIFT, c.bias, c.scale));
                assert!(got <= want.min(255.0) + 0.02 && got > want.min(255.0) - 1.0, "{black} {v}: {got} vs {want}");
            }
            assert_eq!(gray8(1023 << LUMA_SHIFT, c.bias, c.scale), 255);
        }
        assert!(GrayConverter::new(PixelFormat::Nv12, 2, 2, 2, 257).is_err());
    }
}
