//! Canonical corner order (the front end's steps 5–6): the grid turned so the board is seen
//! from its front, the square-contrast check that refuses a board whose dark and bright
//! squares cannot be told apart, and the 180° choice by square colour or, for
//! colour-symmetric boards, by the image's orientation.

use glam::DVec2;

use super::detection::{BoardOrder, DetectFailure, Refinement};
use crate::detect::board::BoardSpec;
use crate::detect::scalar::ScalarImage;

/// Puts `pts` and every variant of them (row-major, `board`'s cols × rows) into canonical
/// order (see the front end's overview, step 6) and returns what fixed the order and the
/// square contrast z, or why the board is ambiguous. `quiet` is the white margin around a
/// tag as a fraction of the square (boards with tags), where the squares are sampled.
pub(super) fn canonical_order(
    img: &ScalarImage,
    board: &BoardSpec,
    pts: &mut Vec<DVec2>,
    variants: &mut [(Refinement, Vec<DVec2>)],
    quiet: Option<f64>,
) -> Result<(BoardOrder, f64), DetectFailure> {
    let (cols, rows) = (board.cols() as usize, board.rows() as usize);
    // Handedness: row direction × column direction > 0 in image coordinates (y down).
    let a = pts[1] - pts[0];
    let b = pts[cols] - pts[0];
    if a.perp_dot(b) < 0.0 {
        *pts = flip_rows(pts, cols, rows);
        for (_, v) in variants.iter_mut() {
            *v = flip_rows(v, cols, rows);
        }
    }
    let (m_even, m_odd, spread) = square_parity_stats(img, pts, cols, rows, quiet);
    let contrast_z = (m_even - m_odd).abs() / spread.max(1e-9);
    if contrast_z < 3.0 {
        return Err(DetectFailure::Ambiguous(format!(
            "square contrast z = {contrast_z:.1} < 3: dark and bright squares cannot be told apart"
        )));
    }
    let order = if board.is_colour_symmetric() {
        BoardOrder::ImageOrientation
    } else {
        BoardOrder::SquareColour
    };
    let rotate = if order == BoardOrder::SquareColour {
        // Inner square (0,0) must be the dark one.
        m_even > m_odd
    } else {
        let d = pts[pts.len() - 1] - pts[0];
        d.x + d.y < 0.0
    };
    if rotate {
        pts.reverse();
        for (_, v) in variants.iter_mut() {
            v.reverse();
        }
    }
    Ok((order, contrast_z))
}

/// Reorders a row-major grid: flip rows.
fn flip_rows(corners: &[DVec2], cols: usize, rows: usize) -> Vec<DVec2> {
    (0..rows)
        .rev()
        .flat_map(|r| corners[r * cols..(r + 1) * cols].iter().copied())
        .collect()
}

/// Parity statistics of the inner squares: (mean even, mean odd, pooled std). Squares are sampled
/// at their centres, or, on a board with tags (`quiet`: the white margin around a tag, as a
/// fraction of the square), at the middle of each side half the margin inside, where no tag cell
/// lies.
fn square_parity_stats(
    img: &ScalarImage,
    corners: &[DVec2],
    cols: usize,
    rows: usize,
    quiet: Option<f64>,
) -> (f64, f64, f64) {
    let mut groups: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for r in 0..rows - 1 {
        for c in 0..cols - 1 {
            let i = r * cols + c;
            let (c00, c10, c01, c11) = (
                corners[i],
                corners[i + 1],
                corners[i + cols],
                corners[i + cols + 1],
            );
            let at = |u: f64, v: f64| {
                img.sample(
                    c00 * (1.0 - u) * (1.0 - v)
                        + c10 * u * (1.0 - v)
                        + c01 * (1.0 - u) * v
                        + c11 * u * v,
                )
            };
            let value = match quiet {
                None => at(0.5, 0.5),
                Some(q) => {
                    let t = 0.5 * q;
                    (at(0.5, t) + at(0.5, 1.0 - t) + at(t, 0.5) + at(1.0 - t, 0.5)) * 0.25
                }
            };
            groups[(r + c) % 2].push(value);
        }
    }
    let stats = |g: &[f64]| {
        let n = g.len().max(1) as f64;
        let m = g.iter().sum::<f64>() / n;
        let v = g.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n;
        (m, v)
    };
    let (m0, v0) = stats(&groups[0]);
    let (m1, v1) = stats(&groups[1]);
    (m0, m1, ((v0 + v1) * 0.5).sqrt())
}
