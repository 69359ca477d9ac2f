//! PFM, the disparity maps' file format (grayscale "Pf", little- or big-endian, rows bottom to top): the
//! writer and a parser that refuses every malformed input with a message instead of panicking (the one
//! reader of the program, its tests and the scoring).
use std::path::Path;

use crate::error::{DisparityError, Result};

/// Writes a PFM (grayscale, little-endian, rows bottom to top); NaN is written as +inf (the format's "no value").
pub fn write_pfm(path: &Path, w: usize, h: usize, data: &[f32]) -> Result<()> {
    if data.len() != w * h {
        return Err(DisparityError::Invalid(format!("PFM of {w}x{h} from {} values", data.len())));
    }
    let mut out = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
    out.reserve(w * h * 4);
    for y in (0..h).rev() {
        for v in &data[y * w..(y + 1) * w] {
            let v = if v.is_nan() { f32::INFINITY } else { *v };
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, out).map_err(|source| DisparityError::Write { path: path.to_path_buf(), source })
}

/// Largest PFM the tools read (values): 2^28 floats = 1 GiB, far above any disparity map.
pub const MAX_PFM_VALUES: usize = 1 << 28;

/// Reads a grayscale PFM into row-major top-to-bottom order.
pub fn read_pfm(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).map_err(|source| DisparityError::Read { path: path.to_path_buf(), source })?;
    parse_pfm(&bytes).map_err(|msg| DisparityError::Format { path: path.to_path_buf(), msg })
}

/// Parses a grayscale PFM ("Pf", width, height, scale: negative = little-endian, then rows bottom to top).
/// Every malformed input is an error, never a panic: a bad or truncated header, a size of 0 or beyond
/// [`MAX_PFM_VALUES`], a scale that is 0 or not a number, too little data. Trailing bytes are ignored.
pub fn parse_pfm(bytes: &[u8]) -> std::result::Result<(usize, usize, Vec<f32>), String> {
    let mut fields: Vec<&[u8]> = Vec::with_capacity(4);
    let mut pos = 0;
    while fields.len() < 4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 64 {
            pos += 1;
        }
        if start == pos {
            return Err(format!("truncated PFM header ({} of 4 fields: Pf, width, height, scale)", fields.len()));
        }
        if pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            return Err("PFM header field longer than 64 bytes".into());
        }
        fields.push(&bytes[start..pos]);
    }
    // exactly one whitespace byte ends the header
    if pos >= bytes.len() {
        return Err("PFM header not followed by data".into());
    }
    pos += 1;
    let text = |f: &[u8]| String::from_utf8_lossy(f).into_owned();
    if fields[0] != b"Pf" {
        return Err(format!("`{}` is not a grayscale PFM (expected Pf)", text(fields[0])));
    }
    let dim = |f: &[u8], what: &str| -> std::result::Result<usize, String> {
        let v: usize = std::str::from_utf8(f)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("{what} `{}` is not a whole number", text(f)))?;
        if v == 0 {
            return Err(format!("{what} is 0"));
        }
        Ok(v)
    };
    let w = dim(fields[1], "width")?;
    let h = dim(fields[2], "height")?;
    let n = w
        .checked_mul(h)
        .filter(|&n| n <= MAX_PFM_VALUES)
        .ok_or_else(|| format!("{w}x{h} exceeds the largest PFM read ({MAX_PFM_VALUES} values)"))?;
    let scale: f32 = std::str::from_utf8(fields[3])
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|s: &f32| s.is_finite() && *s != 0.0)
        .ok_or_else(|| format!("scale `{}` is not a finite non-zero number", text(fields[3])))?;
    let have = bytes.len() - pos;
    if have < n * 4 {
        return Err(format!("{have} bytes of data for {w}x{h} (expected {})", n * 4));
    }
    let data = &bytes[pos..pos + n * 4];
    let mut out = vec![0f32; n];
    for (y, row) in out.chunks_exact_mut(w).enumerate() {
        let src = &data[(h - 1 - y) * w * 4..(h - y) * w * 4];
        for (o, b) in row.iter_mut().zip(src.chunks_exact(4)) {
            let b = [b[0], b[1], b[2], b[3]];
            *o = if scale < 0.0 { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) };
        }
    }
    Ok((w, h, out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn pfm(w: usize, h: usize, scale: &str, data: &[f32]) -> Vec<u8> {
        let mut b = format!("Pf\n{w} {h}\n{scale}\n").into_bytes();
        for v in data {
            b.extend_from_slice(&if scale.starts_with('-') { v.to_le_bytes() } else { v.to_be_bytes() });
        }
        b
    }

    #[test]
    fn a_written_pfm_reads_back_in_both_byte_orders() {
        let d: Vec<f32> = (0..12).map(|i| i as f32 * 0.5).collect();
        // rows are stored bottom to top
        let stored: Vec<f32> = d.chunks(4).rev().flatten().copied().collect();
        for scale in ["-1.0", "1.0"] {
            assert_eq!(parse_pfm(&pfm(4, 3, scale, &stored)).unwrap(), (4, 3, d.clone()), "scale {scale}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.pfm");
        write_pfm(&p, 4, 3, &d).unwrap();
        assert_eq!(read_pfm(&p).unwrap(), (4, 3, d));
    }

    #[test]
    fn each_documented_pfm_error() {
        let ok = pfm(2, 2, "-1.0", &[1.0; 4]);
        let cases: &[(&[u8], &str)] = &[
            (b"", "truncated PFM header"),
            (b"Pf\n2 2", "truncated PFM header"),
            (b"Pf\n2 2\n-1.0", "not followed by data"),
            (b"PF\n2 2\n-1.0\n", "not a grayscale PFM"),
            (b"Pf\n0 2\n-1.0\n", "width is 0"),
            (b"Pf\n2 -2\n-1.0\n", "height `-2` is not a whole number"),
            // w*h*4 overflows usize: refused before any allocation
            (b"Pf\n18446744073709551615 18446744073709551615\n-1.0\n", "exceeds the largest PFM"),
            (b"Pf\n65536 65536\n-1.0\n", "exceeds the largest PFM"),
            (b"Pf\n2 2\n0\n", "scale `0`"),
            (b"Pf\n2 2\nnan\n", "scale `nan`"),
            (b"Pf\n2 2\ninf\n", "scale `inf`"),
            (&ok[..ok.len() - 1], "15 bytes of data for 2x2 (expected 16)"),
        ];
        for (bytes, want) in cases {
            let e = parse_pfm(bytes).unwrap_err();
            assert!(e.contains(want), "{:?}: `{e}` lacks `{want}`", String::from_utf8_lossy(bytes));
        }
        // the path is named
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cut.pfm");
        std::fs::write(&p, &ok[..14]).unwrap();
        let e = read_pfm(&p).unwrap_err().to_string();
        assert!(e.contains("cut.pfm") && e.contains("2 bytes of data for 2x2"), "{e}");
    }

    fn mutate(mut b: Vec<u8>, edits: &[(usize, u8, u8)]) -> Vec<u8> {
        for &(at, kind, v) in edits {
            if b.is_empty() {
                b.push(v);
                continue;
            }
            let i = at % b.len();
            match kind % 4 {
                0 => b[i] = v,
                1 => {
                    b.remove(i);
                }
                2 => b.insert(i, v),
                _ => b.truncate(i),
            }
        }
        b
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        /// Random bytes: an error or a map, never a panic.
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            if let Ok((w, h, d)) = parse_pfm(&bytes) {
                prop_assert_eq!(d.len(), w * h);
            }
        }

        /// Random headers (digits, signs, huge sizes) in front of some data.
        #[test]
        fn random_headers_never_panic(
            w in "[-+0-9a-z]{0,22}", h in "[-+0-9a-z]{0,22}", scale in "[-+0-9.eEinfa]{0,8}",
            sep in "[ \n\t]{1,3}", data in proptest::collection::vec(any::<u8>(), 0..128),
        ) {
            let mut b = format!("Pf{sep}{w}{sep}{h}{sep}{scale}{sep}").into_bytes();
            b.extend_from_slice(&data);
            if let Ok((w, h, d)) = parse_pfm(&b) {
                prop_assert_eq!(d.len(), w * h);
                prop_assert!(w * h * 4 <= b.len());
            }
        }

        /// Valid files mutated (bytes changed, removed, inserted, cut): an error or a map, never a panic.
        #[test]
        fn mutated_files_never_panic(
            w in 1usize..6, h in 1usize..6, le in any::<bool>(),
            edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..6),
        ) {
            let data: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
            let b = mutate(pfm(w, h, if le { "-1.0" } else { "1.0" }, &data), &edits);
            if let Ok((w2, h2, d)) = parse_pfm(&b) {
                prop_assert_eq!(d.len(), w2 * h2);
            }
        }
    }
}
