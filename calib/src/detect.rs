//! Chessboard detection through OpenCV (feature `opencv`).
//!
//! Tries OpenCV's sector-based detector (`findChessboardCornersSB`, accurate and robust to blur)
//! first and the classic detector with `cornerSubPix` refinement second. The thermal-specific
//! front end (percentile stretch of 16-bit data, pseudo-colour to scalar, both polarities) builds
//! on these in the calibration pipeline. [`Homography`] and [`planar_fit_rms`] (board plane →
//! image) are shared by the front end's refinement ranking and the tag board ([`crate::tagboard`]).

use std::path::Path;

use glam::DVec2;
use opencv::core::{CV_8UC1, Mat, Point2f, Scalar, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgproc};

use crate::error::CalibError;

/// Which OpenCV detector found a board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Detector {
    /// `findChessboardCornersSB` (sub-pixel accurate by construction).
    SectorBased,
    /// `findChessboardCorners` + `cornerSubPix`.
    Classic,
}

/// Inner-corner positions of a detected chessboard, row-major from OpenCV's first corner,
/// in pixels with the origin at the centre of the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub corners_px: Vec<DVec2>,
    pub detector: Detector,
}

fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}

/// Copies an 8-bit grey image into an OpenCV matrix.
pub fn mat_from_luma(img: &image::GrayImage) -> Result<Mat, CalibError> {
    let (w, h) = img.dimensions();
    let mut mat = Mat::new_rows_cols_with_default(h as i32, w as i32, CV_8UC1, Scalar::all(0.0))
        .map_err(cv("allocate image"))?;
    mat.data_bytes_mut()
        .map_err(cv("access image bytes"))?
        .copy_from_slice(img.as_raw());
    Ok(mat)
}

/// Reads any image file the `image` crate decodes and converts it to 8-bit grey.
pub fn read_grey(path: &Path) -> Result<image::GrayImage, CalibError> {
    image::open(path)
        .map(|i| i.to_luma8())
        .map_err(|e| CalibError::Image {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })
}

/// Finds a chessboard with `cols x rows` inner corners. `Ok(None)` when neither detector finds it.
pub fn find_chessboard(grey: &Mat, cols: u32, rows: u32) -> Result<Option<Detection>, CalibError> {
    if cols < 2 || rows < 2 {
        return Err(CalibError::BoardTooSmall { cols, rows });
    }
    let pattern = Size::new(cols as i32, rows as i32);
    let mut corners = Vector::<Point2f>::new();
    let sb_flags = calib3d::CALIB_CB_NORMALIZE_IMAGE
        | calib3d::CALIB_CB_EXHAUSTIVE
        | calib3d::CALIB_CB_ACCURACY;
    let found = calib3d::find_chessboard_corners_sb(grey, pattern, &mut corners, sb_flags)
        .map_err(cv("findChessboardCornersSB"))?;
    if found {
        return Ok(Some(Detection {
            corners_px: to_dvec(&corners),
            detector: Detector::SectorBased,
        }));
    }
    let classic_flags = calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE;
    let found = calib3d::find_chessboard_corners(grey, pattern, &mut corners, classic_flags)
        .map_err(cv("findChessboardCorners"))?;
    if !found {
        return Ok(None);
    }
    classic_sub_pix(grey, &mut corners)?;
    Ok(Some(Detection {
        corners_px: to_dvec(&corners),
        detector: Detector::Classic,
    }))
}

/// The classic detector's usual refinement: `cornerSubPix` with an 11 × 11 window, 30
/// iterations or 1e-3 px (OpenCV's calibration samples).
pub fn classic_sub_pix(grey: &Mat, corners: &mut Vector<Point2f>) -> Result<(), CalibError> {
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        30,
        1e-3,
    )
    .map_err(cv("TermCriteria"))?;
    imgproc::corner_sub_pix(
        grey,
        corners,
        Size::new(11, 11),
        Size::new(-1, -1),
        criteria,
    )
    .map_err(cv("cornerSubPix"))
}

fn to_dvec(corners: &Vector<Point2f>) -> Vec<DVec2> {
    corners
        .iter()
        .map(|p| DVec2::new(f64::from(p.x), f64::from(p.y)))
        .collect()
}

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
