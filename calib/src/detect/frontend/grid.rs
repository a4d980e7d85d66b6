//! Measures of a row-major corner grid the front end's steps share: corner spacing, roughness
//! and the fit to one plane.

use glam::DVec2;

use crate::error::CalibError;

/// RMS second difference of the grid along rows and columns (px).
pub(super) fn roughness(corners: &[DVec2], cols: usize, rows: usize) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for r in 0..rows {
        for c in 1..cols.saturating_sub(1) {
            let i = r * cols + c;
            sum += (corners[i - 1] - 2.0 * corners[i] + corners[i + 1]).length_squared();
            n += 1;
        }
    }
    for r in 1..rows.saturating_sub(1) {
        for c in 0..cols {
            let i = r * cols + c;
            sum += (corners[i - cols] - 2.0 * corners[i] + corners[i + cols]).length_squared();
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
}

/// Median distance between neighbouring corners along rows (px).
pub(super) fn median_spacing(corners: &[DVec2], cols: usize) -> f64 {
    let mut d: Vec<f64> = corners
        .windows(2)
        .enumerate()
        .filter(|(i, _)| (i + 1) % cols != 0)
        .map(|(_, w)| (w[1] - w[0]).length())
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(0.0)
}

/// RMS distance (px) of the corners from the least-squares homography of the board grid.
pub(super) fn planar_fit_rms(corners: &[DVec2], cols: usize) -> Result<f64, CalibError> {
    let grid: Vec<DVec2> = (0..corners.len())
        .map(|i| DVec2::new((i % cols) as f64, (i / cols) as f64))
        .collect();
    crate::detect::homography::planar_fit_rms(&grid, corners)
}

/// Smallest distance between neighbouring corners along rows (px).
pub(super) fn min_spacing(corners: &[DVec2], cols: usize) -> f64 {
    corners
        .windows(2)
        .enumerate()
        .filter(|(i, _)| (i + 1) % cols != 0)
        .map(|(_, w)| (w[1] - w[0]).length())
        .fold(f64::INFINITY, f64::min)
}
