//! A plane-to-image homography (board plane → pixels) through OpenCV and the planar-fit RMS
//! built on it: how well corners fit one plane seen through a pinhole. The detection front
//! end ranks its sub-pixel refinements by it; the tag board maps tags and grows partial
//! boards with it.

use glam::DVec2;
use opencv::calib3d;
use opencv::core::{Mat, Point2f, Vector};
use opencv::prelude::*;

use crate::error::{CalibError, cv};

/// A plane-to-image homography (row-major 3×3), e.g. board squares → pixels.
#[derive(Debug, Clone, Copy)]
pub struct Homography([[f64; 3]; 3]);

impl Homography {
    /// Least-squares homography `src → dst` (OpenCV `findHomography` over all points);
    /// `None` with fewer than 4 pairs or when degenerate.
    pub fn fit(src: &[DVec2], dst: &[DVec2]) -> Result<Option<Self>, CalibError> {
        if src.len() < 4 || src.len() != dst.len() {
            return Ok(None);
        }
        let to_cv = |v: &[DVec2]| -> Vector<Point2f> {
            v.iter()
                .map(|p| Point2f::new(p.x as f32, p.y as f32))
                .collect()
        };
        let h = calib3d::find_homography(&to_cv(src), &to_cv(dst), &mut Mat::default(), 0, 3.0)
            .map_err(cv("findHomography"))?;
        if h.empty() {
            return Ok(None);
        }
        let mut m = [[0.0; 3]; 3];
        for (r, row) in m.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = *h
                    .at_2d::<f64>(r as i32, c as i32)
                    .map_err(cv("homography"))?;
            }
        }
        Ok(m.iter().flatten().all(|v| v.is_finite()).then_some(Self(m)))
    }

    pub fn apply(&self, p: DVec2) -> DVec2 {
        let m = &self.0;
        let w = m[2][0] * p.x + m[2][1] * p.y + m[2][2];
        DVec2::new(
            (m[0][0] * p.x + m[0][1] * p.y + m[0][2]) / w,
            (m[1][0] * p.x + m[1][1] * p.y + m[1][2]) / w,
        )
    }
}

/// RMS distance (px) of `image` points from the best homography of their `board` positions:
/// how well they fit one plane seen through a pinhole; infinite when no homography fits.
pub fn planar_fit_rms(board: &[DVec2], image: &[DVec2]) -> Result<f64, CalibError> {
    let Some(h) = Homography::fit(board, image)? else {
        return Ok(f64::INFINITY);
    };
    let ss: f64 = board
        .iter()
        .zip(image)
        .map(|(b, p)| (h.apply(*b) - *p).length_squared())
        .sum();
    let fit = (ss / image.len().max(1) as f64).sqrt();
    Ok(if fit.is_finite() { fit } else { f64::INFINITY })
}
