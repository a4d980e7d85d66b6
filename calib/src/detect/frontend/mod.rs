//! Board detection front end shared by thermal and RGB images.
//!
//! 1. **Decode to a scalar image** ([`crate::detect::scalar::load_scalar`]): 16-bit counts kept, 8-bit
//!    grey, photos as luminance, pseudo-colour thermal images inverted through a palette.
//! 2. **Robust 8-bit normalisation**: a percentile stretch (0.5 % → 0, 99.5 % → 255), so a
//!    hot object in a 16-bit frame does not squash the board's few counts of contrast
//!    ([`crate::detect::scalar::stretch_to_u8`]; the float copy the refinements use: `refine`).
//! 3. **Detection** (`search`): small images (longest side < 480 px, e.g. Lepton 160×120) are
//!    upscaled by an integer factor with cubic interpolation for the search, large ones (> 1000 px)
//!    searched at half size; if nothing is found, once more at the next finer scale (one step more
//!    upscaling, or full size, where only the classic detector runs: at 720p each full-resolution
//!    SB search of an image without a whole board costs seconds). At each scale
//!    `findChessboardCornersSB` runs first (exhaustive, *without* OpenCV's histogram normalisation,
//!    which loses 13 of the 47 real sun-board thermal boards), then, where it fails, the classic
//!    detector on the image and on its inverse. An SB grid that fits no homography (RMS above
//!    [`SUSPECT_PLANAR_FIT`] of the corner spacing: a corner caught on the wrong saddle) gets the
//!    classic detector's second opinion.
//! 4. **Sub-pixel refinements** (`refine`), each kept as a variant of the detection
//!    ([`BoardDetection::variants`]): the SB detector's own corners; `cornerSubPix` on an
//!    unquantised float copy of the stretched image (at full resolution, or cubic-upscaled
//!    like the search for small images), window half-size 0.4 × the smallest corner spacing
//!    (0.5 for upscaled small images; a move of more than a quarter square is discarded); and
//!    the saddle-model fit of [`crate::detect::saddle`] on the float image at its own resolution (the
//!    image's edge width is the median of short free-width fits on up to 12 corners, then
//!    every corner is fitted with that width held fixed, starting from its `cornerSubPix`
//!    position, else the detector's, else where its neighbours put it). No refinement wins
//!    everywhere: on the simulated Lepton boards the saddle fit takes the corner error from
//!    0.19 px (`cornerSubPix`) to 0.01 px, and on OpenCV's stereo samples it gives 0.18 px
//!    RMS against SB's 0.24; on the real, blurry sun-board thermal JPEGs the SB detector's own
//!    corners give 0.457 px, `cornerSubPix` 0.65 and the saddle fit 0.89. The per-image
//!    default is the variant with the smallest homography-fit RMS; the pipeline then chooses
//!    per camera by that camera's own calibration RMS (`pipeline`).
//! 5. **Score and ambiguity check** (the contrast: `order`): OpenCV's `estimateChessboardSharpness`
//!    (edge rise in px) and the square contrast: mean of even- vs odd-parity inner squares, sampled
//!    at their centres, over the pooled standard deviation. Detections whose squares cannot be told
//!    apart (contrast z < 3) are rejected as ambiguous: their ordering cannot be fixed.
//! 6. **Canonical ordering** (`order`): rows are flipped if needed so that the image-space cross
//!    product of the row and column directions is positive (the board is seen from its front), then
//!    the whole grid is rotated by 180° if needed so that inner square (0, 0) — and so the outer
//!    square diagonally beyond corner 0 — is the *dark* one in the image. For RGB, dark = coated.
//!    For thermal the coated squares may be dark or bright; the pipeline fixes that per session
//!    from `thermal_polarity` or, for `auto`, by voting over pairs (where a folder's or session's
//!    detections are collected, `views`). For colour-symmetric boards (cols + rows even) the 180°
//!    choice falls back to "corner 0 nearest the image's top-left", which is only consistent
//!    between cameras mounted the same way up.
//! 7. **AprilTags** (boards whose `board.toml` lists `apriltag_ids`, see [`crate::detect::tagboard`]):
//!    the tags are decoded in the 8-bit image *before* step 3 and painted over for every
//!    sub-pixel refinement. Where any of the board's tags is seen, the board is grown from its
//!    tags (whole or partial: [`BoardDetection::corner_ids`]) and steps 3–6 are skipped:
//!    ChArUco-like prints slow OpenCV's chessboard detectors 3–4× and make them miss boards
//!    (12 simulated 720p tag boards: 16.3 s and 10 found, against 4.7 s and 12 without tags).
//!    Where no tag of the board is seen (thermal images, where print does not show), steps
//!    3–6 run, and tags seen on a whole board then fix its order or refuse another board.
//!
//! The result types are in `detection`; `grid` holds the measures of a corner grid the
//! steps share (spacing, roughness, planar fit). [`detect_board`] runs the steps for one image:
//! the board from its tags (`board_from_tags`) where a tag of it is seen, else the search, the
//! candidate with the best refinement (`best_candidate`), its canonical order and scores
//! (`ordered_detection`) and the tags' say on that order (`order_by_board_tags`).

mod detection;
mod grid;
mod order;
mod refine;
mod search;

use glam::DVec2;
use opencv::calib3d;
use opencv::core::{Mat, Size};
use opencv::prelude::*;

use crate::detect::board::BoardSpec;
use crate::detect::chessboard::Detector;
use crate::detect::scalar::ScalarImage;
use crate::detect::tagboard::TagRejection;
use crate::error::{CalibError, cv};
use crate::tags::TagDetection;
pub use detection::{BoardDetection, BoardOrder, DetectFailure, Refinement, rotate_180};
use grid::{min_spacing, planar_fit_rms, roughness};
pub use refine::SADDLE_MAX_SPACING_PX;
use refine::{Refined, refine, stretched_f32};
pub use search::SUSPECT_PLANAR_FIT;

/// Detects the board in a scalar image and returns it in canonical order.
pub fn detect_board(
    img: &ScalarImage,
    board: &BoardSpec,
) -> Result<Result<BoardDetection, DetectFailure>, CalibError> {
    let (cols, rows) = (board.cols() as usize, board.rows() as usize);
    // The stretched float image (for sub-pixel refinement) and its 8-bit quantisation (for
    // the detectors): `stretch_to_u8(img, 0.005, 0.995)` from one quantile pass.
    let stretched = stretched_f32(img)?;
    let grey = quantised(img, &stretched)?;
    // A board with tags: the tags are decoded first. Where any of the board's tags is seen,
    // the board grows from them (`tagboard`): ChArUco-like prints slow OpenCV's chessboard
    // detectors 3–4× and make them miss boards, and the tags give the order and identity
    // directly. The decoded tags are painted over with the paper around them before any
    // sub-pixel refinement (a tag's border inside a refinement window pulls the corner).
    let tags = if board.has_tags() {
        crate::detect::tagboard::find_tags(&grey)?
    } else {
        Vec::new()
    };
    let float_img = crate::detect::tagboard::mask_tags(stretched, board, &tags)?;
    let mut from_tags = None;
    if tags.iter().any(|t| board.tag_corners_sq(t.id).is_some()) {
        match board_from_tags(img, &float_img, board, &tags)? {
            Ok(det) => return Ok(Ok(det)),
            Err(why) => from_tags = Some(why),
        }
    }
    let found = search::search(&grey, cols, rows)?;
    let Some(best) = best_candidate(&found, &float_img, cols, rows)? else {
        if !board.has_tags() {
            return Ok(Err(DetectFailure::NotFound));
        }
        return Ok(Err(DetectFailure::NoPartial(from_tags.unwrap_or_else(
            || crate::detect::tagboard::no_board_tags(&tags),
        ))));
    };
    let det = match ordered_detection(img, board, best, found.scale, &found.image)? {
        Ok(det) => det,
        Err(why) => return Ok(Err(why)),
    };
    order_by_board_tags(board, det, &tags)
}

/// The stretched float image quantised to 8 bits (the image the detectors search).
fn quantised(img: &ScalarImage, stretched: &Mat) -> Result<image::GrayImage, CalibError> {
    let data = stretched
        .data_typed::<f32>()
        .map_err(cv("float image data"))?;
    let bytes = data
        .iter()
        .map(|v| v.clamp(0.0, 255.0).round() as u8)
        .collect();
    Ok(image::GrayImage::from_raw(img.width_px, img.height_px, bytes).unwrap_or_default())
}

/// The board grown from its decoded tags (whole or partial, `cornerSubPix` on the masked
/// image; a whole board also gets the saddle fit), or why the tags give none.
fn board_from_tags(
    img: &ScalarImage,
    float_img: &Mat,
    board: &BoardSpec,
    tags: &[TagDetection],
) -> Result<Result<BoardDetection, TagRejection>, CalibError> {
    let sample = |p: DVec2| img.sample(p);
    let size = (img.width_px, img.height_px);
    let found =
        match crate::detect::tagboard::partial_from_tags(&sample, size, float_img, board, tags)? {
            Ok(found) => found,
            Err(why) => return Ok(Err(why)),
        };
    let mut refined = Refined {
        fit: found.planar_fit_px,
        pts: found.corners_px.clone(),
        refinement: Refinement::CornerSubPix,
        variants: vec![(Refinement::CornerSubPix, found.corners_px)],
    };
    // A whole board from tags also gets the saddle fit (on the masked image).
    if found.corner_ids.len() == board.corner_count() {
        let (cols, rows) = (board.cols() as usize, board.rows() as usize);
        let start = refined.pts.clone();
        refined.add_saddle(float_img, &start, &start, cols, rows)?;
    }
    Ok(Ok(BoardDetection {
        corners_px: refined.pts,
        corner_ids: found.corner_ids,
        detector: "apriltag",
        inverted: false,
        sharpness_px: f64::NAN,
        contrast_z: f64::NAN,
        roughness_px: f64::NAN,
        planar_fit_px: refined.fit,
        refinement: refined.refinement,
        variants: refined.variants,
        order: BoardOrder::Tags,
    }))
}

/// The kept search candidate with its refinements.
struct Best<'a> {
    refined: Refined,
    cand: &'a search::Candidate,
    /// The detector's corners (the saddle fit's second start).
    raw: Vec<DVec2>,
    /// The `cornerSubPix` corners (the saddle fit's first start).
    subpix: Vec<DVec2>,
}

/// The candidate whose best refinement has the smallest planar fit (the first on ties), with
/// the saddle fit added; `None` when no candidate is usable.
fn best_candidate<'a>(
    found: &'a search::Search,
    float_img: &Mat,
    cols: usize,
    rows: usize,
) -> Result<Option<Best<'a>>, CalibError> {
    let mut best: Option<Best> = None;
    for cand in &found.candidates {
        if let Some(b) = refine_candidate(cand, found.scale, float_img, cols, rows)?
            && best
                .as_ref()
                .is_none_or(|kept| b.refined.fit < kept.refined.fit)
        {
            best = Some(b);
        }
    }
    // The saddle fit (the dearest refinement) runs once, on the kept candidate: when both
    // detectors found the board (small upscaled images), their corners differ by sub-pixel
    // amounts and the fit converges to the same corners from either.
    if let Some(b) = best.as_mut() {
        b.refined
            .add_saddle(float_img, &b.subpix, &b.raw, cols, rows)?;
    }
    Ok(best)
}

/// A candidate's refinements (the SB detector's own corners, `cornerSubPix`) and the one with
/// the smallest planar fit; `None` for a candidate with the wrong corner count, non-finite
/// corners or corners closer than 2 px.
fn refine_candidate<'a>(
    cand: &'a search::Candidate,
    scale: f64,
    float_img: &Mat,
    cols: usize,
    rows: usize,
) -> Result<Option<Best<'a>>, CalibError> {
    let pts: Vec<DVec2> = cand
        .corners_up
        .iter()
        .map(|p| search::to_original(p, scale))
        .collect();
    if pts.len() != cols * rows
        || pts.iter().any(|p| !p.is_finite())
        || min_spacing(&pts, cols) < 2.0
    {
        return Ok(None);
    }
    let raw = pts.clone();
    let refined = refine(float_img, &pts, cols, scale.max(1.0))?;
    // Refinement must not jump to another corner.
    let max_move = refined
        .iter()
        .zip(&pts)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    let mut variants: Vec<(Refinement, Vec<DVec2>)> = Vec::with_capacity(3);
    // The SB detector's own corners are sub-pixel already; the classic detector's are not.
    if cand.detector == Detector::SectorBased {
        variants.push((Refinement::Detector, raw.clone()));
    }
    let subpix = if max_move < 0.25 * min_spacing(&pts, cols) {
        refined
    } else {
        pts
    };
    variants.push((Refinement::CornerSubPix, subpix.clone()));
    let mut pick: Option<(f64, usize)> = None;
    for (i, (refinement, pts)) in variants.iter().enumerate() {
        let fit = planar_fit_rms(pts, cols)?;
        tracing::trace!(?refinement, planar_fit_px = fit, "refinement candidate");
        if pick.is_none_or(|(f, _)| fit < f) {
            pick = Some((fit, i));
        }
    }
    Ok(pick.map(|(fit, i)| Best {
        refined: Refined {
            fit,
            pts: variants[i].1.clone(),
            refinement: variants[i].0,
            variants,
        },
        cand,
        raw,
        subpix,
    }))
}

/// The kept candidate as a detection in canonical order, scored (sharpness on the search
/// image `up`, upscaled by `scale`; contrast), or why it is ambiguous.
fn ordered_detection(
    img: &ScalarImage,
    board: &BoardSpec,
    best: Best<'_>,
    scale: f64,
    up: &Mat,
) -> Result<Result<BoardDetection, DetectFailure>, CalibError> {
    let (cols, rows) = (board.cols() as usize, board.rows() as usize);
    let pattern = Size::new(cols as i32, rows as i32);
    let quiet = board
        .has_tags()
        .then_some(0.5 * (1.0 - board.apriltag_ratio));
    let Best {
        refined:
            Refined {
                fit: planar_fit_px,
                mut pts,
                refinement,
                mut variants,
            },
        cand,
        ..
    } = best;
    let rough = roughness(&pts, cols, rows);
    if min_spacing(&pts, cols) < 2.0 {
        return Ok(Err(DetectFailure::Ambiguous(
            "corners closer than 2 px".into(),
        )));
    }
    let (order, contrast_z) =
        match order::canonical_order(img, board, &mut pts, &mut variants, quiet) {
            Ok(found) => found,
            Err(why) => return Ok(Err(why)),
        };
    // Sharpness on the 8-bit original-resolution-mapped corners (upscaled image, then rescaled).
    let s = scale;
    let up_corners = refine::upscaled_points(&pts, s);
    let sharp = calib3d::estimate_chessboard_sharpness_def(up, pattern, &up_corners)
        .map(|v| v[0] / s)
        .unwrap_or(f64::NAN);
    Ok(Ok(BoardDetection {
        corner_ids: (0..pts.len()).collect(),
        corners_px: pts,
        detector: match cand.detector {
            Detector::SectorBased => "sb",
            Detector::Classic => "classic",
        },
        inverted: cand.inverted,
        sharpness_px: sharp,
        contrast_z,
        roughness_px: rough,
        planar_fit_px,
        refinement,
        variants,
        order,
    }))
}

/// On a board with tags, the tags seen fix the detection's order (turning it 180° where they
/// say so) or reject it as another board's.
fn order_by_board_tags(
    board: &BoardSpec,
    mut det: BoardDetection,
    tags: &[TagDetection],
) -> Result<Result<BoardDetection, DetectFailure>, CalibError> {
    if board.has_tags() {
        match crate::detect::tagboard::order_by_tags(board, &det.corners_px, &det.corner_ids, tags)?
        {
            Err(why) => return Ok(Err(DetectFailure::Ambiguous(why.to_string()))),
            Ok(Some(turn)) => {
                if turn {
                    rotate_180(&mut det, board.corner_count());
                }
                det.order = BoardOrder::Tags;
            }
            Ok(None) => {}
        }
    }
    Ok(Ok(det))
}
