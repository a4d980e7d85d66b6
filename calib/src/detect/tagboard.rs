//! AprilTags on the calibration board (layout in [`crate::detect::board`]): board identity, corner
//! order, and the corners of a partly visible board.
//!
//! - **Identity and order** ([`order_by_tags`]): a whole-board detection is mapped back to
//!   board coordinates through the homography of its corners; each decoded tag of the board
//!   must sit at its square's centre (within [`TAG_MATCH_SQ`] squares) either as the corners
//!   are ordered or after a 180° turn. The order more tags agree with wins, so a
//!   colour-symmetric board (cols + rows even) is ordered by its print, not by the image's
//!   top-left. Tags inside the board that are not in `apriltag_ids` (another board), or
//!   tags of this board that sit in neither place (a different layout or `apriltag_ratio`),
//!   reject the detection with that reason.
//! - **Boards from tags** ([`partial_from_tags`]; the detection front end runs it first wherever a tag of
//!   the board is decoded, whole board or not): each decoded tag of the board gives the four
//!   inner corners around its square; the board then grows corner
//!   by corner: a candidate next to accepted corners is predicted by the homography of the
//!   known points within a few squares (tag corners and accepted corners: local, so lens
//!   distortion does not accumulate), refined by `cornerSubPix` on the masked image (below)
//!   with the whole-board window (0.4 of the square), and accepted only if it moved less than
//!   [`MAX_MOVE_SQ`] of a square and both coated squares beside it read as tag ink
//!   (nearer the tags' black border cells than their white code cells). Corners beside a tag
//!   that is not decoded get that tag painted over where the local homography puts it, and are
//!   refused when it is cut by the image border. A board from tags needs
//!   [`MIN_PARTIAL_CORNERS`] corners over at least two rows and two columns.
//! - **Masking** ([`mask_tags`]): before any sub-pixel refinement (whole or partial board) each
//!   decoded tag and the inner half of its white margin are painted with the paper shade
//!   measured around it, so a refinement window sees a plain chessboard: a tag's border inside
//!   a `cornerSubPix` window pulled corners by up to 1.2 px on the simulated boards, and a
//!   window kept clear of the tags (0.15 of a square) was too small for 20 px squares.

use std::cell::RefCell;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use glam::DVec2;
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use crate::detect::board::BoardSpec;
use crate::detect::homography::{Homography, planar_fit_rms};
use crate::error::{CalibError, cv};
use crate::tags::{TagConfig, TagDetection, TagDetector, tag36h11_cells};

/// A decoded tag matches its square when its centre maps within this many squares of the
/// square's centre.
pub const TAG_MATCH_SQ: f64 = 0.3;
/// A partial-board corner is refused when `cornerSubPix` moved it further than this fraction
/// of a square from its prediction.
pub const MAX_MOVE_SQ: f64 = 0.2;
/// Fewest corners a partial board is used with (a board pose from fewer is weak).
pub const MIN_PARTIAL_CORNERS: usize = 8;

thread_local! {
    /// One tag detector per rayon worker (the C detector is not `Send`).
    static DETECTOR: RefCell<Option<TagDetector>> = const { RefCell::new(None) };
}

/// Decodes every tag36h11 tag in `grey` at full resolution (any id: foreign ids tell another
/// board apart), then, for a small image (thermal cores) that shows none, in its inverse (a
/// thermal camera that sees the print may see it in either polarity). Decimating the quad
/// search by 2 halves the cost at 720p (0.05 s instead of 0.12 s per image) but its coarser
/// tag corners mask the tags less exactly: one simulated partial view's corners went from
/// 0.07 to 0.27 px.
pub fn find_tags(grey: &image::GrayImage) -> Result<Vec<TagDetection>, CalibError> {
    let image = Path::new("board image");
    let err = |source: crate::tags::TagError| CalibError::Tags { source };
    DETECTOR.with(|cell| {
        let mut slot = cell.borrow_mut();
        if slot.is_none() {
            *slot = Some(TagDetector::new(TagConfig::default()).map_err(err)?);
        }
        let Some(det) = slot.as_mut() else {
            return Ok(Vec::new());
        };
        let found = det.detect(grey, image).map_err(err)?;
        if !found.is_empty() || grey.width().max(grey.height()) >= 1000 {
            return Ok(found);
        }
        let mut inverted = grey.clone();
        image::imageops::invert(&mut inverted);
        det.detect(&inverted, image).map_err(err)
    })
}

/// Tag units: a tag's border spans `[-0.5, 0.5]²` (library corner order: bottom-left,
/// bottom-right, top-right, top-left).
const TAG_UNIT: [DVec2; 4] = [
    DVec2::new(-0.5, 0.5),
    DVec2::new(0.5, 0.5),
    DVec2::new(0.5, -0.5),
    DVec2::new(-0.5, -0.5),
];

/// Paints one tag (given by the map from tag units to image pixels) and the inner half of its
/// white margin with the median of 8 samples on the margin's midline. Returns false when
/// fewer than 3 of those samples lie in the image (nothing painted).
fn paint_tag(
    data: &mut [f32],
    (w, h): (i32, i32),
    board: &BoardSpec,
    to_image: impl Fn(DVec2) -> DVec2,
) -> bool {
    // The margin's midline in tag units: 0.5 + quiet / (2 · ratio), quiet = (1 − ratio) / 2.
    let quiet = 0.5 * (1.0 - board.apriltag_ratio);
    let mid = 0.5 + quiet / (2.0 * board.apriltag_ratio);
    let at = |p: DVec2| -> Option<f32> {
        let (x, y) = (p.x.round() as i32, p.y.round() as i32);
        (x >= 0 && y >= 0 && x < w && y < h).then(|| data[(y * w + x) as usize])
    };
    let mut ring: Vec<f32> = (0..8)
        .filter_map(|k| {
            // The midline square's side midpoints and corners.
            let a = f64::from(k) * std::f64::consts::FRAC_PI_4;
            let d = DVec2::new(a.cos(), a.sin());
            at(to_image(d / d.x.abs().max(d.y.abs()) * mid))
        })
        .collect();
    if ring.len() < 3 {
        return false;
    }
    let m = ring.len() / 2;
    ring.select_nth_unstable_by(m, f32::total_cmp);
    let paper = ring[m];
    let quad = TAG_UNIT.map(|u| to_image(u * (2.0 * mid)));
    let lo = quad.iter().fold(DVec2::INFINITY, |a, p| a.min(*p));
    let hi = quad.iter().fold(DVec2::NEG_INFINITY, |a, p| a.max(*p));
    if !(lo.is_finite() && hi.is_finite()) {
        return false;
    }
    let (x0, x1) = (
        lo.x.floor().max(0.0) as i32,
        hi.x.ceil().min(f64::from(w - 1)) as i32,
    );
    let (y0, y1) = (
        lo.y.floor().max(0.0) as i32,
        hi.y.ceil().min(f64::from(h - 1)) as i32,
    );
    // Inside a convex quad: the same side of all four edges.
    let sides = |p: DVec2| (0..4).map(move |k| (quad[(k + 1) % 4] - quad[k]).perp_dot(p - quad[k]));
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = DVec2::new(f64::from(x), f64::from(y));
            if sides(p).all(|s| s >= 0.0) || sides(p).all(|s| s <= 0.0) {
                data[(y * w + x) as usize] = paper;
            }
        }
    }
    true
}

/// The float image with every decoded tag and the inner half of its white margin painted
/// with the paper shade around it (see the module docs); unchanged when `tags` is empty. A
/// tag's extent comes from its own decoded corners, so this needs no board pose.
pub fn mask_tags(
    mut float_img: Mat,
    board: &BoardSpec,
    tags: &[TagDetection],
) -> Result<Mat, CalibError> {
    let size = (float_img.cols(), float_img.rows());
    let data = float_img
        .data_typed_mut::<f32>()
        .map_err(cv("float image data"))?;
    for t in tags {
        let img_c: Vec<DVec2> = t.corners_px.iter().map(|p| DVec2::from(*p)).collect();
        if let Some(hm) = Homography::fit(&TAG_UNIT, &img_c)? {
            paint_tag(data, size, board, |u| hm.apply(u));
        }
    }
    Ok(float_img)
}

/// Board position (square units) of inner corner `id`.
fn corner_sq(board: &BoardSpec, id: usize) -> DVec2 {
    let cols = board.cols() as usize;
    DVec2::new((id % cols) as f64, (id / cols) as f64)
}

/// What the board's tags say about a whole-board detection's order (see the module docs):
/// `Ok(None)` when no tag of the board was seen, `Ok(Some(turn))` when the tags fixed the order
/// (`turn`: the corners must be turned by 180°), and `Err(reason)` when the tags say this is
/// not the board of `board.toml`. `corners_px[k]` is board corner `corner_ids[k]`.
pub fn order_by_tags(
    board: &BoardSpec,
    corners_px: &[DVec2],
    corner_ids: &[usize],
    tags: &[TagDetection],
) -> Result<Result<Option<bool>, TagRejection>, CalibError> {
    if tags.is_empty() {
        return Ok(Ok(None));
    }
    let board_pts: Vec<DVec2> = corner_ids.iter().map(|&i| corner_sq(board, i)).collect();
    let Some(image_to_board) = Homography::fit(corners_px, &board_pts)? else {
        return Ok(Ok(None));
    };
    let (cols, rows) = (f64::from(board.cols()), f64::from(board.rows()));
    let turn = |p: DVec2| DVec2::new(cols - 1.0 - p.x, rows - 1.0 - p.y);
    let (mut as_is, mut turned) = (Vec::new(), Vec::new());
    let mut misplaced = Vec::new();
    let mut foreign = BTreeSet::new();
    for t in tags {
        let seen = image_to_board.apply(DVec2::from(t.centre_px));
        match board.tag_corners_sq(t.id) {
            Some(c) => {
                let centre = (c[0] + c[2]) * 0.5;
                if (seen - centre).length() < TAG_MATCH_SQ {
                    as_is.push(t.id);
                } else if (seen - turn(centre)).length() < TAG_MATCH_SQ {
                    turned.push(t.id);
                } else {
                    misplaced.push(t.id);
                }
            }
            None => {
                if seen.x > -1.0 && seen.x < cols && seen.y > -1.0 && seen.y < rows {
                    foreign.insert(t.id);
                }
            }
        }
    }
    if as_is.is_empty() && turned.is_empty() {
        if !foreign.is_empty() {
            let ids: Vec<u32> = foreign.into_iter().collect();
            return Ok(Err(TagRejection::ForeignBoard { ids }));
        }
        if !misplaced.is_empty() {
            return Ok(Err(TagRejection::Misplaced { ids: misplaced }));
        }
        return Ok(Ok(None));
    }
    tracing::debug!(
        ?as_is,
        ?turned,
        ?misplaced,
        ?foreign,
        "board ordered by tags"
    );
    Ok(Ok(Some(turned.len() > as_is.len())))
}

/// Tag ink and paper as this image shows them: medians of the tags' black border cells and
/// white code cells (raw image values, either polarity).
fn ink_and_paper(
    sample: &dyn Fn(DVec2) -> f64,
    board: &BoardSpec,
    tags: &[(&TagDetection, Homography)],
) -> Option<(f64, f64)> {
    let (mut ink, mut paper) = (Vec::new(), Vec::new());
    for (t, h) in tags {
        let (Some(cells), Some(c)) = (tag36h11_cells(t.id), board.tag_corners_sq(t.id)) else {
            continue;
        };
        let (origin, side) = (c[3], c[1].x - c[3].x);
        for (y, row) in cells.iter().enumerate() {
            for (x, white) in row.iter().enumerate() {
                let p = origin + DVec2::new(x as f64 + 0.5, y as f64 + 0.5) * side / 8.0;
                let v = sample(h.apply(p));
                let border = x == 0 || y == 0 || x == 7 || y == 7;
                if border {
                    ink.push(v);
                } else if *white {
                    paper.push(v);
                }
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        if v.is_empty() {
            return None;
        }
        let mid = v.len() / 2;
        v.select_nth_unstable_by(mid, f64::total_cmp);
        Some(v[mid])
    };
    Some((median(&mut ink)?, median(&mut paper)?))
}

/// A board's corners found from its tags: whole or partial, ascending corner ids.
#[derive(Debug, Clone)]
pub struct TagCorners {
    pub corners_px: Vec<DVec2>,
    /// The board's row-major corner index of each corner.
    pub corner_ids: Vec<usize>,
    /// RMS distance of the corners from the best homography of their board positions (px).
    pub planar_fit_px: f64,
}

/// Why the tags in view give no board (order or partial board): the typed reason, worded for
/// the detection report.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TagRejection {
    #[error(
        "the board in view carries AprilTags {ids:?}, none of board.toml's apriltag_ids: another board"
    )]
    ForeignBoard { ids: Vec<u32> },
    #[error(
        "AprilTags {ids:?} of this board are not where board.toml puts them (check the tag layout and apriltag_ratio)"
    )]
    Misplaced { ids: Vec<u32> },
    #[error("no AprilTag in view")]
    NoTagInView,
    #[error("none of the AprilTags in view ({in_view:?}) is board.toml's")]
    NoBoardTag { in_view: Vec<u32> },
    #[error("the tags' cells could not be sampled")]
    CellsUnsampled,
    #[error(
        "partial board: {accepted} corners verified around AprilTags {tags:?} (need {MIN_PARTIAL_CORNERS} over 2+ rows and columns); refused: {refused:?}"
    )]
    TooFewCorners {
        accepted: usize,
        tags: Vec<u32>,
        refused: BTreeMap<&'static str, usize>,
    },
}

/// Why no tag of the board can seed it: no tag in view, or only other boards' tags.
pub fn no_board_tags(tags: &[TagDetection]) -> TagRejection {
    if tags.is_empty() {
        TagRejection::NoTagInView
    } else {
        TagRejection::NoBoardTag {
            in_view: tags.iter().map(|t| t.id).collect(),
        }
    }
}

/// The corners of a board grown from its decoded tags (see the module docs), or why there are
/// too few. `sample` reads the image's raw values (bilinear, any polarity), `size` is its
/// width and height; `float_img` is the stretched float image (tags masked) `cornerSubPix`
/// runs on.
pub fn partial_from_tags(
    sample: &dyn Fn(DVec2) -> f64,
    size: (u32, u32),
    float_img: &Mat,
    board: &BoardSpec,
    tags: &[TagDetection],
) -> Result<Result<TagCorners, TagRejection>, CalibError> {
    // Known points: board position (squares) → image position.
    let (mut known, ours) = board_tags(board, tags)?;
    if ours.is_empty() {
        return Ok(Err(no_board_tags(tags)));
    }
    let Some((ink, paper)) = ink_and_paper(sample, board, &ours) else {
        return Ok(Err(TagRejection::CellsUnsampled));
    };
    let contrast = (paper - ink).abs();
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        60,
        1e-5,
    )
    .map_err(cv("TermCriteria"))?;
    // Tags painted over (decoded ones by `mask_tags`; the others, e.g. cut by the image
    // border, are painted where a local homography puts them before a corner beside them is
    // refined).
    let mut masked = float_img.try_clone().map_err(cv("copy float image"))?;
    let mut painted = decoded_tag_squares(board, &ours);
    let tagged: BTreeSet<(i64, i64)> = board
        .tag_squares()
        .into_iter()
        .map(|(i, j)| (i64::from(i), i64::from(j)))
        .collect();
    let mut grow = Grow {
        sample,
        float_img: &mut masked,
        painted: &mut painted,
        tagged: &tagged,
        board,
        ink,
        contrast,
        size: (f64::from(size.0), f64::from(size.1)),
        criteria: &criteria,
    };
    let (accepted, reasons) = grow.grow_from(&mut known, seed_corners(board, &ours))?;
    tag_corners(board, &ours, accepted, reasons)
}

/// Known points of a growing board: board position (squares) → image position.
type KnownPoints = Vec<(DVec2, DVec2)>;
/// The decoded tags of this board, each with the homography of its square.
type BoardTags<'t> = Vec<(&'t TagDetection, Homography)>;

/// The decoded tags of this board with the homography of their square, and their corners as
/// known points.
fn board_tags<'t>(
    board: &BoardSpec,
    tags: &'t [TagDetection],
) -> Result<(KnownPoints, BoardTags<'t>), CalibError> {
    let mut known: Vec<(DVec2, DVec2)> = Vec::new();
    let mut ours: Vec<(&TagDetection, Homography)> = Vec::new();
    for t in tags {
        let Some(c) = board.tag_corners_sq(t.id) else {
            continue;
        };
        let img_c: Vec<DVec2> = t.corners_px.iter().map(|p| DVec2::from(*p)).collect();
        let Some(hm) = Homography::fit(&c, &img_c)? else {
            continue;
        };
        known.extend(c.iter().copied().zip(img_c));
        ours.push((t, hm));
    }
    Ok((known, ours))
}

/// Seeds: the inner corners `(column, row)` at the four corners of each tag's square.
fn seed_corners(board: &BoardSpec, ours: &[(&TagDetection, Homography)]) -> BTreeSet<(i64, i64)> {
    let mut frontier: BTreeSet<(i64, i64)> = BTreeSet::new();
    for (t, _) in ours {
        if let Some(c) = board.tag_corners_sq(t.id) {
            let centre = (c[0] + c[2]) * 0.5;
            for (dx, dy) in [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)] {
                frontier.insert((
                    (centre.x + dx).round() as i64,
                    (centre.y + dy).round() as i64,
                ));
            }
        }
    }
    frontier
}

/// The squares `(i, j)` of the decoded tags (painted over by [`mask_tags`]).
fn decoded_tag_squares(
    board: &BoardSpec,
    ours: &[(&TagDetection, Homography)],
) -> BTreeSet<(i64, i64)> {
    ours.iter()
        .filter_map(|(t, _)| board.tag_corners_sq(t.id))
        .map(|c| {
            let centre = (c[0] + c[2]) * 0.5;
            (
                (centre.x + 0.5).round() as i64,
                (centre.y + 0.5).round() as i64,
            )
        })
        .collect()
}

/// Corners accepted while growing a board, keyed (row, column): the map's order is the
/// board's row-major order.
type Accepted = BTreeMap<(i64, i64), DVec2>;
/// Refused corners counted by reason.
type Refusals = BTreeMap<&'static str, usize>;

/// The grown board as [`TagCorners`] (ascending ids, with its planar fit), or
/// [`TagRejection::TooFewCorners`] below [`MIN_PARTIAL_CORNERS`] or two rows and columns.
fn tag_corners(
    board: &BoardSpec,
    ours: &[(&TagDetection, Homography)],
    accepted: Accepted,
    reasons: Refusals,
) -> Result<Result<TagCorners, TagRejection>, CalibError> {
    let cols = board.cols() as i64;
    let rows_seen = accepted.keys().map(|k| k.0).collect::<BTreeSet<_>>().len();
    let cols_seen = accepted.keys().map(|k| k.1).collect::<BTreeSet<_>>().len();
    if accepted.len() < MIN_PARTIAL_CORNERS || rows_seen < 2 || cols_seen < 2 {
        return Ok(Err(TagRejection::TooFewCorners {
            accepted: accepted.len(),
            tags: ours.iter().map(|(t, _)| t.id).collect(),
            refused: reasons,
        }));
    }
    let corner_ids: Vec<usize> = accepted
        .keys()
        .map(|&(r, c)| (r * cols + c) as usize)
        .collect();
    let corners_px: Vec<DVec2> = accepted.into_values().collect();
    let board_pts: Vec<DVec2> = corner_ids.iter().map(|&i| corner_sq(board, i)).collect();
    let planar_fit_px = planar_fit_rms(&board_pts, &corners_px)?;
    tracing::debug!(
        corners = corners_px.len(),
        ?reasons,
        "board grown from tags"
    );
    Ok(Ok(TagCorners {
        corners_px,
        corner_ids,
        planar_fit_px,
    }))
}

/// The state a partial board grows in.
struct Grow<'a> {
    /// The image's raw values.
    sample: &'a dyn Fn(DVec2) -> f64,
    /// The float image, tags painted over.
    float_img: &'a mut Mat,
    /// Tag squares `(i, j)` painted so far.
    painted: &'a mut BTreeSet<(i64, i64)>,
    /// Squares `(i, j)` that carry a tag.
    tagged: &'a BTreeSet<(i64, i64)>,
    board: &'a BoardSpec,
    /// Tag ink shade and |paper − ink| (raw image values).
    ink: f64,
    contrast: f64,
    size: (f64, f64),
    criteria: &'a TermCriteria,
}

impl Grow<'_> {
    /// Grows the board from the seed corners `(column, row)` in `frontier`, each accepted
    /// corner joining the known points and putting its four neighbours in the frontier.
    fn grow_from(
        &mut self,
        known: &mut Vec<(DVec2, DVec2)>,
        mut frontier: BTreeSet<(i64, i64)>,
    ) -> Result<(Accepted, Refusals), CalibError> {
        let (cols, rows) = (self.board.cols() as i64, self.board.rows() as i64);
        let mut accepted = Accepted::new();
        let mut refused: BTreeSet<(i64, i64)> = BTreeSet::new();
        let mut reasons = Refusals::new();
        while let Some((c, r)) = frontier.pop_first() {
            if c < 0 || r < 0 || c >= cols || r >= rows || accepted.contains_key(&(r, c)) {
                continue;
            }
            let at = DVec2::new(c as f64, r as f64);
            match self.try_corner(known, at)? {
                Ok(p) => {
                    accepted.insert((r, c), p);
                    known.push((at, p));
                    for (dc, dr) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                        let (nc, nr) = (c + dc, r + dr);
                        if !accepted.contains_key(&(nr, nc)) && !refused.contains(&(nc, nr)) {
                            frontier.insert((nc, nr));
                        }
                    }
                }
                Err(why) => {
                    refused.insert((c, r));
                    *reasons.entry(why).or_default() += 1;
                }
            }
        }
        Ok((accepted, reasons))
    }

    /// Predicts, refines and verifies inner corner `at` (square units) from the known points.
    fn try_corner(
        &mut self,
        known: &[(DVec2, DVec2)],
        at: DVec2,
    ) -> Result<Result<DVec2, &'static str>, CalibError> {
        let (ink, contrast, (w, h)) = (self.ink, self.contrast, self.size);
        // Local homography: the known points within 2.5 squares, widened until there are 8.
        let mut local = None;
        for radius in [2.5, 4.0, f64::INFINITY] {
            let near: Vec<&(DVec2, DVec2)> = known
                .iter()
                .filter(|(b, _)| (*b - at).length() <= radius)
                .collect();
            if near.len() >= 8 || radius.is_infinite() {
                let src: Vec<DVec2> = near.iter().map(|(b, _)| *b).collect();
                let dst: Vec<DVec2> = near.iter().map(|(_, p)| *p).collect();
                local = Homography::fit(&src, &dst)?;
                break;
            }
        }
        let Some(hm) = local else {
            return Ok(Err("no local homography"));
        };
        let predicted = hm.apply(at);
        let spacing = [DVec2::X, -DVec2::X, DVec2::Y, -DVec2::Y]
            .iter()
            .map(|d| (hm.apply(at + *d) - predicted).length())
            .fold(f64::INFINITY, f64::min);
        // The window and criteria of the whole-board refinement (the detection front end's): the tags are masked.
        let half = (0.4 * spacing).floor();
        if !(predicted.is_finite() && spacing.is_finite()) || half < 2.0 {
            return Ok(Err("squares under 5 px"));
        }
        let half = half.min(12.0);
        let margin = half + 2.0;
        if predicted.x < margin
            || predicted.y < margin
            || predicted.x > w - 1.0 - margin
            || predicted.y > h - 1.0 - margin
        {
            return Ok(Err("outside the image"));
        }
        // Paint the tags of the (up to two) uncoated squares beside the corner that are not
        // painted yet; square (i, j) is uncoated when i + j is odd.
        let (c, r) = (at.x as i64, at.y as i64);
        for sq in [(c, r), (c + 1, r), (c, r + 1), (c + 1, r + 1)] {
            if self.tagged.contains(&sq) && !self.painted.contains(&sq) {
                let centre = DVec2::new(sq.0 as f64 - 0.5, sq.1 as f64 - 0.5);
                let ratio = self.board.apriltag_ratio;
                let size = (self.float_img.cols(), self.float_img.rows());
                let data = self
                    .float_img
                    .data_typed_mut::<f32>()
                    .map_err(cv("float image data"))?;
                if !paint_tag(data, size, self.board, |u| hm.apply(centre + u * ratio)) {
                    return Ok(Err("a tag beside it is cut by the image border"));
                }
                self.painted.insert(sq);
            }
        }
        let mut pts: Vector<Point2f> = Vector::new();
        pts.push(Point2f::new(predicted.x as f32, predicted.y as f32));
        imgproc::corner_sub_pix(
            &*self.float_img,
            &mut pts,
            Size::new(half as i32, half as i32),
            Size::new(-1, -1),
            *self.criteria,
        )
        .map_err(cv("cornerSubPix"))?;
        let q = pts.get(0).map_err(cv("cornerSubPix result"))?;
        let refined = DVec2::new(f64::from(q.x), f64::from(q.y));
        if !refined.is_finite() || (refined - predicted).length() > MAX_MOVE_SQ * spacing {
            return Ok(Err("refinement moved too far"));
        }
        // The two coated squares beside the corner: square (i, j) is coated when i + j is even;
        // the squares around inner corner (c, r) are (c..=c+1, r..=r+1).
        for (i, j) in [(c, r), (c + 1, r), (c, r + 1), (c + 1, r + 1)] {
            if (i + j) % 2 != 0 {
                continue;
            }
            let centre = DVec2::new(i as f64 - 0.5, j as f64 - 0.5);
            let p = hm.apply(centre) + (refined - predicted);
            if p.x < 0.0 || p.y < 0.0 || p.x > w - 1.0 || p.y > h - 1.0 {
                continue;
            }
            if ((self.sample)(p) - ink).abs() > 0.35 * contrast {
                return Ok(Err("coated square does not read as tag ink"));
            }
        }
        Ok(Ok(refined))
    }
}
