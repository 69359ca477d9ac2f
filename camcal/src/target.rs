//! Calibration targets: Kalibr-style AprilGrids (tag36h11) and chessboards, with the 3D
//! coordinates of their corners in the board frame.
//!
//! AprilGrid board frame (Kalibr's): origin at the outer corner of the bottom-left tag, x to the
//! right, y up (as the printed board is seen), z out of the board toward the viewer; millimetres.
//! Tag (row r from the bottom, column c) has id `first_id + r * cols + c`; its corners k = 0..4
//! are bottom-left, bottom-right, top-right, top-left. Board b of a multi-board setup owns tag ids
//! `b * cols * rows .. (b + 1) * cols * rows` (the paper: board 0 tags 0-35, board 1 tags 36-71, ...).
//! A corner's global id is `4 * tag_id + k`.
//!
//! Chessboard frame: inner corner (i, j) (i along the `cols` direction) at (i * square, j * square, 0),
//! in the order OpenCV's findChessboardCorners returns them; corner id `j * cols + i`.
use crate::error::{CamcalError, Result};
use nalgebra::Vector3;
use std::str::FromStr;

/// A Kalibr AprilGrid: `cols` x `rows` tag36h11 tags of side `tag_mm` (the outer black square,
/// 2-bit black border), `spacing` x `tag_mm` apart, with black squares of that size at every
/// intersection (which makes every tag corner a saddle point).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AprilGridSpec {
    pub cols: usize,
    pub rows: usize,
    pub tag_mm: f64,
    pub spacing: f64,
}

impl Default for AprilGridSpec {
    /// Kalibr's common 6x6 grid, 88 mm tags, spacing 0.3.
    fn default() -> Self {
        AprilGridSpec { cols: 6, rows: 6, tag_mm: 88.0, spacing: 0.3 }
    }
}

impl AprilGridSpec {
    pub fn tags_per_board(&self) -> u32 {
        (self.cols * self.rows) as u32
    }
    /// Board index and tag index inside the board of a tag id.
    pub fn board_of_tag(&self, tag_id: u32) -> (u32, u32) {
        (tag_id / self.tags_per_board(), tag_id % self.tags_per_board())
    }
    /// Side of one tag cell (tag + gap), mm.
    pub fn pitch_mm(&self) -> f64 {
        self.tag_mm * (1.0 + self.spacing)
    }
    /// Size of the whole board including the outer corner squares, mm: the board frame origin
    /// sits at (gap, gap) from the outer edge of that area.
    pub fn outer_size_mm(&self) -> [f64; 2] {
        let g = self.tag_mm * self.spacing;
        [self.cols as f64 * self.pitch_mm() + g, self.rows as f64 * self.pitch_mm() + g]
    }
    /// Board-frame position (mm) of corner `k` of tag `local` (index inside its board).
    pub fn corner_mm(&self, local: u32, k: u32) -> Vector3<f64> {
        let (r, c) = ((local as usize / self.cols) as f64, (local as usize % self.cols) as f64);
        let (x0, y0) = (c * self.pitch_mm(), r * self.pitch_mm());
        let s = self.tag_mm;
        let (dx, dy) = match k {
            0 => (0.0, 0.0),
            1 => (s, 0.0),
            2 => (s, s),
            _ => (0.0, s),
        };
        Vector3::new(x0 + dx, y0 + dy, 0.0)
    }
    /// Board-frame position (mm) of a global corner id, and its board.
    pub fn corner_by_id(&self, corner_id: u32) -> (u32, Vector3<f64>) {
        let (board, local) = self.board_of_tag(corner_id / 4);
        (board, self.corner_mm(local, corner_id % 4))
    }
}

/// A chessboard: `cols` x `rows` inner corners, `square_mm` squares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChessboardSpec {
    pub cols: usize,
    pub rows: usize,
    pub square_mm: f64,
}

impl ChessboardSpec {
    pub fn corner_mm(&self, id: u32) -> Vector3<f64> {
        let (i, j) = ((id as usize % self.cols) as f64, (id as usize / self.cols) as f64);
        Vector3::new(i * self.square_mm, j * self.square_mm, 0.0)
    }
}

/// A calibration target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Target {
    AprilGrid(AprilGridSpec),
    Chessboard(ChessboardSpec),
}

impl Target {
    /// Board and board-frame position (mm) of a corner id.
    pub fn corner(&self, corner_id: u32) -> (u32, Vector3<f64>) {
        match self {
            Target::AprilGrid(g) => g.corner_by_id(corner_id),
            Target::Chessboard(c) => (0, c.corner_mm(corner_id)),
        }
    }
}

fn parse_dims(s: &str) -> Result<(usize, usize)> {
    let (a, b) = s.split_once(['x', 'X']).ok_or_else(|| CamcalError::Invalid(format!("'{s}': expected COLSxROWS")))?;
    let p = |t: &str| t.parse::<usize>().map_err(|_| CamcalError::Invalid(format!("'{t}' is not a count in '{s}'")));
    let (c, r) = (p(a)?, p(b)?);
    if c < 2 || r < 1 {
        return Err(CamcalError::Invalid(format!("'{s}': too few corners")));
    }
    Ok((c, r))
}

fn parse_pos(s: &str, what: &str) -> Result<f64> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(CamcalError::Invalid(format!("{what} '{s}' must be a positive number"))),
    }
}

impl FromStr for Target {
    type Err = CamcalError;
    /// `aprilgrid` (6x6, 88 mm, 0.3), `aprilgrid:COLSxROWS:TAG_MM:SPACING`, or
    /// `chessboard:COLSxROWS:SQUARE_MM` (inner corners).
    fn from_str(s: &str) -> Result<Target> {
        let parts: Vec<&str> = s.split(':').collect();
        match parts.as_slice() {
            ["aprilgrid"] => Ok(Target::AprilGrid(AprilGridSpec::default())),
            ["aprilgrid", dims, tag, spacing] => {
                let (cols, rows) = parse_dims(dims)?;
                Ok(Target::AprilGrid(AprilGridSpec {
                    cols,
                    rows,
                    tag_mm: parse_pos(tag, "tag size")?,
                    spacing: parse_pos(spacing, "spacing")?,
                }))
            }
            ["chessboard", dims, sq] => {
                let (cols, rows) = parse_dims(dims)?;
                Ok(Target::Chessboard(ChessboardSpec { cols, rows, square_mm: parse_pos(sq, "square size")? }))
            }
            _ => Err(CamcalError::Invalid(format!(
                "target '{s}': expected aprilgrid, aprilgrid:COLSxROWS:TAG_MM:SPACING or chessboard:COLSxROWS:SQUARE_MM"
            ))),
        }
    }
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Target::AprilGrid(g) => write!(f, "aprilgrid:{}x{}:{}:{}", g.cols, g.rows, g.tag_mm, g.spacing),
            Target::Chessboard(c) => write!(f, "chessboard:{}x{}:{}", c.cols, c.rows, c.square_mm),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_and_layout() {
        let t: Target = "aprilgrid".parse().unwrap();
        assert_eq!(t.to_string().parse::<Target>().unwrap(), t);
        let Target::AprilGrid(g) = t else { panic!() };
        assert_eq!(g.board_of_tag(36), (1, 0));
        assert_eq!(g.board_of_tag(71), (1, 35));
        // tag 7 = row 1, col 1; its top-right corner
        let p = g.corner_mm(7, 2);
        assert!((p.x - (88.0 * 1.3 + 88.0)).abs() < 1e-9 && (p.y - (88.0 * 1.3 + 88.0)).abs() < 1e-9);
        let c: Target = "chessboard:9x6:25".parse().unwrap();
        assert_eq!(c.corner(10).1, Vector3::new(25.0, 25.0, 0.0));
        assert!("chessboard:9x6".parse::<Target>().is_err());
        assert!("aprilgrid:6x6:-1:0.3".parse::<Target>().is_err());
    }
}
