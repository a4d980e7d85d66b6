//! The OpenCV chessboard search (the front end's step 3): the search scale (upscaled small
//! images, half-size large ones, one finer retry), the sector-based and classic detectors on
//! the image and its inverse, and the classic detector's second opinion on an SB grid that
//! fits no plane.

use glam::DVec2;
use opencv::calib3d;
use opencv::core::{Mat, Point2f, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::grid::{median_spacing, planar_fit_rms};
use crate::detect::chessboard::{Detector, mat_from_luma};
use crate::error::{CalibError, cv};

/// An SB detection whose corners are further than this fraction of the corner spacing (RMS)
/// from the best homography of the grid is checked against the classic detector.
pub const SUSPECT_PLANAR_FIT: f64 = 0.03;

/// One detector's corners at the search scale.
pub(super) struct Candidate {
    pub(super) corners_up: Vec<Point2f>,
    pub(super) detector: Detector,
    pub(super) inverted: bool,
}

/// What the search found: the candidates of the first scale that found any, that scale
/// (search pixels per image pixel) and the 8-bit image searched at it.
pub(super) struct Search {
    pub(super) candidates: Vec<Candidate>,
    pub(super) scale: f64,
    pub(super) image: Mat,
}

/// A corner at search scale `scale` in image pixels (origin at the centre of the top-left
/// pixel at both scales).
pub(super) fn to_original(p: &Point2f, scale: f64) -> DVec2 {
    DVec2::new(
        (f64::from(p.x) + 0.5) / scale - 0.5,
        (f64::from(p.y) + 0.5) / scale - 0.5,
    )
}

/// Searches the stretched 8-bit image `grey` for a board of `cols × rows` inner corners.
pub(super) fn search(
    grey: &image::GrayImage,
    cols: usize,
    rows: usize,
) -> Result<Search, CalibError> {
    let pattern = Size::new(cols as i32, rows as i32);
    let longest = grey.width().max(grey.height());
    // Search scale: small images are upscaled (the detectors need ~10+ px squares), large
    // ones searched at half size (speed); corners are then refined at full resolution.
    let primary: f64 = if longest < 480 {
        f64::from((480 / longest.max(1)).clamp(1, 4))
    } else if longest > 1000 {
        0.5
    } else {
        1.0
    };
    // When the first search scale finds nothing, one more: a finer upscale for small images
    // (tiny, tilted boards) or full resolution for large ones.
    let fallback = if primary > 1.0 {
        Some(primary + 1.0)
    } else if primary < 1.0 {
        Some(1.0)
    } else {
        None
    };
    let base = mat_from_luma(grey)?;
    let mut candidates = Vec::new();
    let mut scale = primary;
    let mut searched = Mat::default();
    for attempt in std::iter::once(primary).chain(fallback) {
        scale = attempt;
        searched = if attempt != 1.0 {
            let mut out = Mat::default();
            let interpolation = if attempt > 1.0 {
                imgproc::INTER_CUBIC
            } else {
                imgproc::INTER_AREA
            };
            imgproc::resize(
                &base,
                &mut out,
                Size::new(0, 0),
                attempt,
                attempt,
                interpolation,
            )
            .map_err(cv("resize"))?;
            out
        } else {
            base.clone()
        };
        // SB's board is kept alone, also on small upscaled images (which once ran the classic
        // detector as well and kept the better): the saddle fit, run once on the kept board,
        // converges to the same corners from either detector's. Without the second detector
        // the 70-pair synthetic Lepton detection lost 0.3 s and no RMS beyond 1e-6 px.
        let both = false;
        // A large image's full-resolution retry runs the classic detector on the image as it
        // is only: the half-size search already ran SB and both polarities, and at 720p+ each
        // exhaustive full-resolution search costs seconds per view without a whole board.
        let full_res_retry = primary < 1.0 && attempt >= 1.0;
        run_detectors(
            &searched,
            pattern,
            both,
            !full_res_retry,
            !full_res_retry,
            &mut candidates,
        )?;
        if !candidates.is_empty() {
            break;
        }
    }
    let to_orig = |p: &Point2f| to_original(p, scale);
    // An SB grid that does not fit one plane (a corner caught on the wrong saddle: on the real
    // sun-board RGB photo Img31 the half-size SB grid is 2.7 px RMS off any homography) gets
    // a second opinion from the classic detector; the candidate with the better fit is kept.
    if let [only] = candidates.as_slice()
        && only.detector == Detector::SectorBased
    {
        let pts: Vec<DVec2> = only.corners_up.iter().map(to_orig).collect();
        if pts.len() == cols * rows {
            let fit = planar_fit_rms(&pts, cols)?;
            let spacing = median_spacing(&pts, cols);
            tracing::trace!(fit, spacing, ratio = fit / spacing, "SB planar fit");
            if fit > SUSPECT_PLANAR_FIT * spacing {
                run_detectors(&searched, pattern, true, false, true, &mut candidates)?;
            }
        }
    }
    Ok(Search {
        candidates,
        scale,
        image: searched,
    })
}

/// Runs the detectors on `up` and appends what they find, cheapest and most general first.
///
/// 1. `findChessboardCornersSB` with `CALIB_CB_EXHAUSTIVE` only, on the stretched grey image.
///    It answers to saddle points of either polarity, so one search covers coated-dark and
///    coated-bright thermal boards. No `CALIB_CB_NORMALIZE_IMAGE`: its histogram equalisation
///    loses 13 of the 47 real sun-board thermal boards (OpenCV 4.6: 34/47 with it, 47/47
///    without, 27 ms per 640×480 image), and no `CALIB_CB_ACCURACY`: it costs 4× and the
///    sub-pixel refinement below supersedes it.
/// 2. Only when that fails, or in addition when `both` (small upscaled images, where both are
///    cheap and the smoother refined grid is kept): the classic detector
///    (`findChessboardCorners`, adaptive threshold, polarity-dependent), then on the inverted
///    image when nothing was found yet. On the real sun-board RGB photos at half size the
///    classic detector finds 47/47 at 25 ms where SB finds 41/47.
///
/// `sb = false` skips step 1 (a large image's full-resolution retry, where SB's exhaustive
/// search costs seconds per partial view); `invert = false` skips the inverted classic search.
fn run_detectors(
    up: &Mat,
    pattern: Size,
    both: bool,
    sb: bool,
    invert: bool,
    out: &mut Vec<Candidate>,
) -> Result<(), CalibError> {
    let found_before = out.len();
    if sb {
        let mut corners = Vector::<Point2f>::new();
        if calib3d::find_chessboard_corners_sb(
            up,
            pattern,
            &mut corners,
            calib3d::CALIB_CB_EXHAUSTIVE,
        )
        .map_err(cv("findChessboardCornersSB"))?
        {
            out.push(Candidate {
                corners_up: corners.to_vec(),
                detector: Detector::SectorBased,
                inverted: false,
            });
            if !both {
                return Ok(());
            }
        }
    }
    let classic_flags = calib3d::CALIB_CB_ADAPTIVE_THRESH
        | calib3d::CALIB_CB_NORMALIZE_IMAGE
        | calib3d::CALIB_CB_FILTER_QUADS;
    let mut corners = Vector::<Point2f>::new();
    if calib3d::find_chessboard_corners(up, pattern, &mut corners, classic_flags)
        .map_err(cv("findChessboardCorners"))?
    {
        out.push(Candidate {
            corners_up: corners.to_vec(),
            detector: Detector::Classic,
            inverted: false,
        });
        return Ok(());
    }
    if !invert || out.len() > found_before {
        return Ok(());
    }
    let mut inv = Mat::default();
    opencv::core::bitwise_not_def(up, &mut inv).map_err(cv("bitwise_not"))?;
    let mut corners = Vector::<Point2f>::new();
    if calib3d::find_chessboard_corners(&inv, pattern, &mut corners, classic_flags)
        .map_err(cv("findChessboardCorners"))?
    {
        out.push(Candidate {
            corners_up: corners.to_vec(),
            detector: Detector::Classic,
            inverted: true,
        });
    }
    Ok(())
}
