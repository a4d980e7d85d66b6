//! Chessboard detection through OpenCV (feature `opencv`).
//!
//! Tries OpenCV's sector-based detector (`findChessboardCornersSB`, accurate and robust to blur)
//! first and the classic detector with `cornerSubPix` refinement second. The thermal-specific
//! front end (percentile stretch of 16-bit data, pseudo-colour to scalar, both polarities) builds
//! on these in the calibration pipeline.

use std::path::Path;

use glam::DVec2;
use opencv::core::{CV_8UC1, Mat, Point2f, Scalar, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgproc};

use crate::error::{CalibError, cv};

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
        .map_err(|source| CalibError::ImageFile {
            path: path.to_path_buf(),
            source,
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
