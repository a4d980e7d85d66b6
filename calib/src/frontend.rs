//! Board detection front end shared by thermal and RGB images.
//!
//! 1. **Decode to a scalar image** ([`load_scalar`]): 16-bit PNG/TIFF keep their counts
//!    (raw or centikelvin), 8-bit grey its values, RGB/RGBA photos become luminance
//!    (Rec. 601). A thermal image saved as pseudo-colour is mapped back to a scalar by finding,
//!    for each colour, the nearest colour on a known palette curve (approximations of
//!    ironbow and matplotlib's inferno, 9/7 control points interpolated linearly to 256
//!    entries); with `palette = "auto"` the palette whose curve fits the image best is used,
//!    and when neither fits (mean colour distance > 24 of 255) luminance is used instead.
//! 2. **Robust 8-bit normalisation**: a percentile stretch (0.5 % → 0, 99.5 % → 255), so a
//!    hot object in a 16-bit frame does not squash the board's few counts of contrast.
//! 3. **Detection**: small images (longest side < 480 px, e.g. Lepton 160×120) are upscaled
//!    by an integer factor with cubic interpolation for the search, large ones (> 1000 px)
//!    searched at half size; if nothing is found, once more at the next finer scale (one
//!    step more upscaling, or full size, where only the classic detector runs: at 720p each
//!    full-resolution SB search of an image without a whole board costs seconds). At each
//!    scale `findChessboardCornersSB` runs first (exhaustive, *without* OpenCV's histogram
//!    normalisation, which loses 13 of the 47 real sun-board thermal boards), then, where it
//!    fails, the classic detector on the image and on its inverse (`run_detectors`).
//!    An SB grid that fits no homography
//!    (RMS above [`SUSPECT_PLANAR_FIT`] of the corner spacing: a corner caught on the wrong
//!    saddle) gets the classic detector's second opinion.
//! 4. **Sub-pixel refinements**, each kept as a variant of the detection
//!    ([`BoardDetection::variants`]): the SB detector's own corners; `cornerSubPix` on an
//!    unquantised float copy of the stretched image (at full resolution, or cubic-upscaled
//!    like the search for small images), window half-size 0.4 × the smallest corner spacing
//!    (0.5 for upscaled small images; a move of more than a quarter square is discarded); and
//!    the saddle-model fit of [`crate::saddle`] on the float image at its own resolution (the
//!    image's edge width is the median of short free-width fits on up to 12 corners, then
//!    every corner is fitted with that width held fixed, starting from its `cornerSubPix`
//!    position, else the detector's, else where its neighbours put it). No refinement wins
//!    everywhere: on the simulated Lepton boards the saddle fit takes the corner error from
//!    0.19 px (`cornerSubPix`) to 0.01 px, and on OpenCV's stereo samples it gives 0.18 px
//!    RMS against SB's 0.24; on the real, blurry sun-board thermal JPEGs the SB detector's own
//!    corners give 0.457 px, `cornerSubPix` 0.65 and the saddle fit 0.89. The per-image
//!    default is the variant with the smallest homography-fit RMS; the pipeline then chooses
//!    per camera by that camera's own calibration RMS (`pipeline`).
//! 5. **Score and ambiguity check**: OpenCV's `estimateChessboardSharpness` (edge rise in px)
//!    and the square contrast: mean of even- vs odd-parity inner squares, sampled at their
//!    centres, over the pooled standard deviation. Detections whose squares cannot be told
//!    apart (contrast z < 3) are rejected as ambiguous: their ordering cannot be fixed.
//! 6. **Canonical ordering**: rows are flipped if needed so that the image-space cross product
//!    of the row and column directions is positive (the board is seen from its front), then the
//!    whole grid is rotated by 180° if needed so that inner square (0, 0) — and so the outer
//!    square diagonally beyond corner 0 — is the *dark* one in the image. For RGB, dark =
//!    coated. For thermal the coated squares may be dark or bright; the pipeline fixes that
//!    per session from `thermal_polarity` or, for `auto`, by voting over pairs (see
//!    `pipeline`). For colour-symmetric boards (cols + rows even) the 180° choice falls back to
//!    "corner 0 nearest the image's top-left", which is only consistent between cameras
//!    mounted the same way up.
//! 7. **AprilTags** (boards whose `board.toml` lists `apriltag_ids`, see [`crate::tagboard`]):
//!    the tags are decoded in the 8-bit image *before* step 3 and painted over for every
//!    sub-pixel refinement. Where any of the board's tags is seen, the board is grown from its
//!    tags (whole or partial: [`BoardDetection::corner_ids`]) and steps 3–6 are skipped:
//!    ChArUco-like prints slow OpenCV's chessboard detectors 3–4× and make them miss boards
//!    (12 simulated 720p tag boards: 16.3 s and 10 found, against 4.7 s and 12 without tags).
//!    Where no tag of the board is seen (thermal images, where print does not show), steps
//!    3–6 run, and tags seen on a whole board then fix its order or refuse another board.

use std::collections::HashMap;
use std::path::Path;
use std::sync::OnceLock;

use glam::DVec2;
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{calib3d, imgproc};
use serde::{Deserialize, Serialize};

use crate::board::BoardSpec;
use crate::detect::Detector;
use crate::error::CalibError;
use crate::saddle::EdgeWidth;

/// How the coated squares appear in thermal images (image values, after palette inversion).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThermalPolarity {
    /// Decided per session from the pairs (see module docs).
    #[default]
    Auto,
    /// Coated squares have the lower values.
    CoatedDark,
    /// Coated squares have the higher values.
    CoatedBright,
}

/// Palette used to map pseudo-colour thermal images back to a scalar.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Palette {
    /// Best-fitting known palette, else luminance.
    #[default]
    Auto,
    Ironbow,
    Inferno,
    /// Rec. 601 luminance (works for palettes monotonic in brightness).
    Luminance,
}

/// Where a scalar image's values came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceKind {
    Grey16,
    Grey8,
    /// Pseudo-colour thermal image inverted through this palette.
    PseudoColour(Palette),
    /// Colour photo reduced to luminance.
    ColourLuminance,
}

/// A single-channel image in f32 (original value scale).
#[derive(Debug, Clone)]
pub struct ScalarImage {
    pub width_px: u32,
    pub height_px: u32,
    pub values: Vec<f32>,
    pub source: SourceKind,
}

impl ScalarImage {
    fn at(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, i64::from(self.width_px) - 1) as usize;
        let y = y.clamp(0, i64::from(self.height_px) - 1) as usize;
        self.values[y * self.width_px as usize + x]
    }

    /// Bilinear sample with pixel centres on integer coordinates (clamped at the border).
    pub fn sample(&self, p: DVec2) -> f64 {
        let x0 = p.x.floor();
        let y0 = p.y.floor();
        let (fx, fy) = (p.x - x0, p.y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let v = |x, y| f64::from(self.at(x, y));
        (1.0 - fy) * ((1.0 - fx) * v(x0, y0) + fx * v(x0 + 1, y0))
            + fy * ((1.0 - fx) * v(x0, y0 + 1) + fx * v(x0 + 1, y0 + 1))
    }
}

const IRONBOW: [(f32, [f32; 3]); 7] = [
    (0.0, [0.0, 0.0, 0.0]),
    (0.15, [32.0, 0.0, 140.0]),
    (0.35, [145.0, 0.0, 155.0]),
    (0.55, [225.0, 65.0, 40.0]),
    (0.75, [250.0, 160.0, 0.0]),
    (0.9, [255.0, 225.0, 60.0]),
    (1.0, [255.0, 255.0, 255.0]),
];
const INFERNO: [(f32, [f32; 3]); 9] = [
    (0.0, [0.0, 0.0, 4.0]),
    (0.125, [31.0, 12.0, 72.0]),
    (0.25, [85.0, 15.0, 109.0]),
    (0.375, [136.0, 34.0, 106.0]),
    (0.5, [186.0, 54.0, 85.0]),
    (0.625, [227.0, 89.0, 51.0]),
    (0.75, [249.0, 140.0, 10.0]),
    (0.875, [249.0, 201.0, 50.0]),
    (1.0, [252.0, 255.0, 164.0]),
];

fn build_lut(points: &[(f32, [f32; 3])]) -> [[f32; 3]; 256] {
    let mut lut = [[0.0; 3]; 256];
    for (i, entry) in lut.iter_mut().enumerate() {
        let t = i as f32 / 255.0;
        let k = points
            .windows(2)
            .position(|w| t <= w[1].0)
            .unwrap_or(points.len() - 2);
        let (t0, c0) = points[k];
        let (t1, c1) = points[k + 1];
        let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
        for ch in 0..3 {
            entry[ch] = c0[ch] + a * (c1[ch] - c0[ch]);
        }
    }
    lut
}

/// The 256-entry colour table of a palette (`None` for `Auto`/`Luminance`).
pub fn palette_lut(palette: Palette) -> Option<&'static [[f32; 3]; 256]> {
    static IRON: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
    static INF: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
    match palette {
        Palette::Ironbow => Some(IRON.get_or_init(|| build_lut(&IRONBOW))),
        Palette::Inferno => Some(INF.get_or_init(|| build_lut(&INFERNO))),
        Palette::Auto | Palette::Luminance => None,
    }
}

/// Nearest palette index for a colour and the distance to it.
fn nearest_on_palette(lut: &[[f32; 3]; 256], rgb: [u8; 3]) -> (f32, f32) {
    let mut best = (0usize, f32::INFINITY);
    for (i, c) in lut.iter().enumerate() {
        let d = (c[0] - f32::from(rgb[0])).powi(2)
            + (c[1] - f32::from(rgb[1])).powi(2)
            + (c[2] - f32::from(rgb[2])).powi(2);
        if d < best.1 {
            best = (i, d);
        }
    }
    (best.0 as f32, best.1.sqrt())
}

/// Rec. 601 luminance of an 8-bit RGB colour.
pub fn luminance(rgb: [u8; 3]) -> f32 {
    0.299 * f32::from(rgb[0]) + 0.587 * f32::from(rgb[1]) + 0.114 * f32::from(rgb[2])
}

/// True when the colour image is visibly not grey (some pixels with channel spread > 12).
fn is_pseudo_colour(rgb: &image::RgbImage) -> bool {
    let n = rgb.pixels().len().max(1);
    let coloured = rgb
        .pixels()
        .step_by(7)
        .filter(|p| {
            let (mx, mn) = (p.0.iter().max(), p.0.iter().min());
            matches!((mx, mn), (Some(a), Some(b)) if a - b > 12)
        })
        .count();
    coloured * 7 * 50 > n
}

/// Maps a pseudo-colour image to scalar values by palette inversion (see module docs).
pub fn pseudo_colour_to_scalar(rgb: &image::RgbImage, palette: Palette) -> (Vec<f32>, Palette) {
    let candidates: Vec<Palette> = match palette {
        Palette::Auto => vec![Palette::Ironbow, Palette::Inferno],
        p => vec![p],
    };
    // Fit check on a subsample.
    let mut chosen = Palette::Luminance;
    let mut best_fit = f32::INFINITY;
    for p in candidates {
        let Some(lut) = palette_lut(p) else {
            continue;
        };
        let sample: Vec<f32> = rgb
            .pixels()
            .step_by(13)
            .map(|px| nearest_on_palette(lut, px.0).1)
            .collect();
        let fit = sample.iter().sum::<f32>() / sample.len().max(1) as f32;
        if fit < best_fit {
            best_fit = fit;
            chosen = p;
        }
    }
    if palette == Palette::Auto && best_fit > 24.0 {
        chosen = Palette::Luminance;
    }
    let values = match palette_lut(chosen) {
        None => rgb.pixels().map(|p| luminance(p.0)).collect(),
        Some(lut) => {
            let mut cache: HashMap<[u8; 3], f32> = HashMap::new();
            rgb.pixels()
                .map(|p| {
                    *cache
                        .entry(p.0)
                        .or_insert_with(|| nearest_on_palette(lut, p.0).0)
                })
                .collect()
        }
    };
    (values, chosen)
}

/// Decodes an image file into scalar values. `thermal` enables pseudo-colour inversion.
pub fn load_scalar(
    path: &Path,
    thermal: bool,
    palette: Palette,
) -> Result<ScalarImage, CalibError> {
    let img = image::open(path).map_err(|e| CalibError::Image {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let (w, h) = (img.width(), img.height());
    if w < 16 || h < 16 {
        return Err(CalibError::Image {
            path: path.to_path_buf(),
            reason: format!("{w}x{h} is too small for board detection"),
        });
    }
    use image::DynamicImage as D;
    let (values, source) = match &img {
        D::ImageLuma16(g) => (
            g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            SourceKind::Grey16,
        ),
        D::ImageLumaA16(_) => {
            let g = img.to_luma16();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey16,
            )
        }
        D::ImageLuma8(g) => (
            g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            SourceKind::Grey8,
        ),
        D::ImageLumaA8(_) => {
            let g = img.to_luma8();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey8,
            )
        }
        D::ImageRgb16(_) | D::ImageRgba16(_) | D::ImageRgb32F(_) | D::ImageRgba32F(_) => {
            let g = img.to_luma16();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey16,
            )
        }
        _ => {
            let rgb = img.to_rgb8();
            if thermal && is_pseudo_colour(&rgb) {
                let (values, used) = pseudo_colour_to_scalar(&rgb, palette);
                (values, SourceKind::PseudoColour(used))
            } else {
                (
                    rgb.pixels().map(|p| luminance(p.0)).collect(),
                    SourceKind::ColourLuminance,
                )
            }
        }
    };
    Ok(ScalarImage {
        width_px: w,
        height_px: h,
        values,
        source,
    })
}

/// The `lo` and `hi` quantiles (nearest rank) of the finite values, `(0, 0)` when there are
/// none. Two selections instead of a sort (a 4096-bin histogram locating each rank's bin first
/// was slower: 8.3 % of the RGB detection time against 5.9 %).
fn quantiles(values: &[f32], lo: f64, hi: f64) -> (f32, f32) {
    let mut finite: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return (0.0, 0.0);
    }
    let rank = |f: f64| (((finite.len() - 1) as f64 * f).round() as usize).min(finite.len() - 1);
    let (i_lo, i_hi) = (rank(lo.min(hi)), rank(lo.max(hi)));
    let (_, &mut b, _) = finite.select_nth_unstable_by(i_hi, f32::total_cmp);
    // Everything left of i_hi is ≤ b, so the lower quantile is selected within that part.
    let a = if i_lo < i_hi {
        *finite[..i_hi]
            .select_nth_unstable_by(i_lo, f32::total_cmp)
            .1
    } else {
        b
    };
    if lo <= hi { (a, b) } else { (b, a) }
}

/// Percentile stretch to 8 bits: the `lo`/`hi` quantiles map to 0/255.
pub fn stretch_to_u8(img: &ScalarImage, lo: f64, hi: f64) -> image::GrayImage {
    let (a, b) = quantiles(&img.values, lo, hi);
    let scale = if b > a { 255.0 / (b - a) } else { 0.0 };
    let data = img
        .values
        .iter()
        .map(|&v| ((v - a) * scale).clamp(0.0, 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(img.width_px, img.height_px, data).unwrap_or_default()
}

/// A board found in one image, in canonical order (see module docs), with its scores.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoardDetection {
    /// Inner corners, pixels (origin at the centre of the top-left pixel), in ascending
    /// [`Self::corner_ids`] order.
    #[serde(skip)]
    pub corners_px: Vec<DVec2>,
    /// The board's row-major corner index of each corner: `0..cols·rows` for a whole board,
    /// a subset for a partial one (AprilTag boards only). Every variant has these corners.
    #[serde(skip)]
    pub corner_ids: Vec<usize>,
    /// Which detector produced the kept result.
    pub detector: &'static str,
    /// True when found on the inverted image.
    pub inverted: bool,
    /// OpenCV's edge-rise sharpness in (original) pixels; lower is sharper.
    pub sharpness_px: f64,
    /// Square contrast: |mean(dark) − mean(bright)| / pooled std (dimensionless).
    pub contrast_z: f64,
    /// RMS second difference along rows/columns (px): grid roughness, lower is better.
    pub roughness_px: f64,
    /// RMS distance of the corners from the best homography of the board grid (px): how
    /// well they fit one plane seen through a pinhole (lens distortion adds to it equally
    /// for every refinement, so it ranks refinements of one image).
    pub planar_fit_px: f64,
    /// Which sub-pixel refinement `corners_px` holds (per image, the one with the smallest
    /// planar fit; the pipeline may choose another per camera, see [`Self::variants`]).
    pub refinement: Refinement,
    /// Every refinement computed for this image, in the same canonical order as `corners_px`.
    /// The planar fit cannot rank them when lens distortion dominates it (the simulated
    /// Lepton: 0.15–0.4 px for every refinement), so the pipeline ranks them per camera by
    /// the camera's own calibration RMS.
    #[serde(skip)]
    pub variants: Vec<(Refinement, Vec<DVec2>)>,
    /// What fixed the corner order.
    pub order: BoardOrder,
}

/// What fixed a detection's corner order (see the module docs, step 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoardOrder {
    /// The coated square at corner 0 (boards with cols + rows odd).
    SquareColour,
    /// The board's AprilTags.
    Tags,
    /// Corner 0 nearest the image's top-left (colour-symmetric board, no tag seen).
    ImageOrientation,
}

/// Sub-pixel corner refinements, ranked per image by how well the corners fit a plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Refinement {
    /// The SB detector's own sub-pixel corners.
    Detector,
    /// `cornerSubPix` on the unquantised stretched image.
    CornerSubPix,
    /// The blurred-saddle model fit of [`crate::saddle`].
    Saddle,
}

/// The saddle fit runs only on boards whose median corner spacing is below this (px): on the
/// simulated Lepton boards (5–9 px squares) it takes the corner error from 0.19 px
/// (`cornerSubPix`) to 0.01 px; on the real sun-board thermal images (blurry 8-bit JPEG,
/// 15–40 px squares) it never ranked first and cost 0.2 s per image.
pub const SADDLE_MAX_SPACING_PX: f64 = f64::INFINITY;

/// An SB detection whose corners are further than this fraction of the corner spacing (RMS)
/// from the best homography of the grid is checked against the classic detector.
pub const SUSPECT_PLANAR_FIT: f64 = 0.03;

/// Why a detection was not found or rejected.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DetectFailure {
    NotFound,
    Ambiguous(String),
    /// No whole board; the board's AprilTags were looked for and gave no usable partial board
    /// (the reason says why).
    NoPartial(String),
}

fn cv(operation: &'static str) -> impl FnOnce(opencv::Error) -> CalibError {
    move |source| CalibError::OpenCv { operation, source }
}

fn mat_from_grey(img: &image::GrayImage) -> Result<Mat, CalibError> {
    crate::detect::mat_from_luma(img)
}

fn roughness(corners: &[DVec2], cols: usize, rows: usize) -> f64 {
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
fn median_spacing(corners: &[DVec2], cols: usize) -> f64 {
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
fn planar_fit_rms(corners: &[DVec2], cols: usize) -> Result<f64, CalibError> {
    let grid: Vec<DVec2> = (0..corners.len())
        .map(|i| DVec2::new((i % cols) as f64, (i / cols) as f64))
        .collect();
    crate::detect::planar_fit_rms(&grid, corners)
}

fn min_spacing(corners: &[DVec2], cols: usize) -> f64 {
    corners
        .windows(2)
        .enumerate()
        .filter(|(i, _)| (i + 1) % cols != 0)
        .map(|(_, w)| (w[1] - w[0]).length())
        .fold(f64::INFINITY, f64::min)
}

struct Candidate {
    corners_up: Vec<Point2f>,
    detector: Detector,
    inverted: bool,
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

/// Reorders a row-major grid: flip rows.
fn flip_rows(corners: &[DVec2], cols: usize, rows: usize) -> Vec<DVec2> {
    (0..rows)
        .rev()
        .flat_map(|r| corners[r * cols..(r + 1) * cols].iter().copied())
        .collect()
}

/// Parity statistics of the inner squares: (mean even, mean odd, pooled std).
/// Mean of even- and odd-parity inner squares and their pooled spread. Squares are sampled
/// at their centres, or, on a board with tags (`quiet`: the white margin around a tag, as a
/// fraction of the square), at the middle of each side half the margin inside, where no tag
/// cell lies.
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

/// Float copy of the image stretched like [`stretch_to_u8`] (0..255, not quantised).
fn stretched_f32(img: &ScalarImage) -> Result<Mat, CalibError> {
    let (a, b) = quantiles(&img.values, 0.005, 0.995);
    let scale = if b > a { 255.0 / (b - a) } else { 0.0 };
    let mut mat = Mat::new_rows_cols_with_default(
        img.height_px as i32,
        img.width_px as i32,
        opencv::core::CV_32FC1,
        opencv::core::Scalar::all(0.0),
    )
    .map_err(cv("allocate float image"))?;
    let data = mat
        .data_typed_mut::<f32>()
        .map_err(cv("float image data"))?;
    for (d, v) in data.iter_mut().zip(&img.values) {
        *d = ((v - a) * scale).clamp(-64.0, 320.0);
    }
    Ok(mat)
}

/// `cornerSubPix` on the float image, window from the square size. Images are refined at
/// `upscale` × their resolution (cubic interpolation) when `upscale` > 1: at 160×120 the
/// squares are only ~10 px and the gradient window then holds too few samples.
fn refine(
    float_img: &Mat,
    pts: &[DVec2],
    cols: usize,
    upscale: f64,
) -> Result<Vec<DVec2>, CalibError> {
    let (img, s) = if upscale > 1.0 {
        let mut up = Mat::default();
        imgproc::resize(
            float_img,
            &mut up,
            Size::new(0, 0),
            upscale,
            upscale,
            imgproc::INTER_CUBIC,
        )
        .map_err(cv("resize float"))?;
        (up, upscale)
    } else {
        (float_img.clone(), 1.0)
    };
    // Window half-size as a fraction of the corner spacing: 0.4 at native resolution; 0.5 for
    // upscaled small images, whose 5–7 px squares give the gradient window too few real
    // samples at 0.4 (simulated Lepton: thermal RMS 0.103 px at 0.4, 0.092 px at 0.5, 0.128 px
    // at 0.3).
    let win_factor = if upscale > 1.0 { 0.5 } else { 0.4 };
    let half = (win_factor * min_spacing(pts, cols) * s)
        .floor()
        .clamp(2.0, 12.0 * s) as i32;
    let mut corners: Vector<Point2f> = pts
        .iter()
        .map(|p| {
            Point2f::new(
                ((p.x + 0.5) * s - 0.5) as f32,
                ((p.y + 0.5) * s - 0.5) as f32,
            )
        })
        .collect();
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        60,
        1e-5,
    )
    .map_err(cv("TermCriteria"))?;
    imgproc::corner_sub_pix(
        &img,
        &mut corners,
        Size::new(half, half),
        Size::new(-1, -1),
        criteria,
    )
    .map_err(cv("cornerSubPix"))?;
    Ok(corners
        .iter()
        .map(|p| {
            DVec2::new(
                (f64::from(p.x) + 0.5) / s - 0.5,
                (f64::from(p.y) + 0.5) / s - 0.5,
            )
        })
        .collect())
}

/// Refines every corner by the saddle-model fit ([`crate::saddle`]) on the float image at its
/// own resolution, starting from the `cornerSubPix` corner and, when that fit is rejected, from
/// the detector's unrefined corner (`raw`); the grid directions and spacing come from `raw`
/// (a `cornerSubPix` corner that slid towards a neighbour would shrink the window). Corners
/// whose fits are all rejected keep their `cornerSubPix` position.
fn saddle_refine(
    float_img: &Mat,
    pts: &[DVec2],
    raw: &[DVec2],
    cols: usize,
    rows: usize,
) -> Result<Vec<DVec2>, CalibError> {
    let width_px = float_img.cols().max(0) as usize;
    let height_px = float_img.rows().max(0) as usize;
    let values = float_img
        .data_typed::<f32>()
        .map_err(cv("float image data"))?;
    let img = crate::saddle::FloatImage {
        width_px,
        height_px,
        values,
    };
    let mut out = pts.to_vec();
    let at = |r: i64, c: i64| -> Option<DVec2> {
        (r >= 0 && c >= 0 && (r as usize) < rows && (c as usize) < cols)
            .then(|| raw[r as usize * cols + c as usize])
    };
    // Median length of the grid segments within three steps of the corner along (dr, dc):
    // robust to one misplaced corner, including the corner itself.
    let spacing = |r: i64, c: i64, dr: i64, dc: i64| -> f64 {
        let mut d: Vec<f64> = (-3..3)
            .filter_map(|k| {
                Some(
                    (at(r + (k + 1) * dr, c + (k + 1) * dc)? - at(r + k * dr, c + k * dc)?)
                        .length(),
                )
            })
            .collect();
        d.sort_by(f64::total_cmp);
        d.get(d.len().saturating_sub(1) / 2).copied().unwrap_or(0.0)
    };
    // Direction along (dr, dc) from neighbours only: the central difference, or at the border
    // the next segment inwards.
    let direction = |r: i64, c: i64, dr: i64, dc: i64| -> DVec2 {
        match (at(r + dr, c + dc), at(r - dr, c - dc)) {
            (Some(a), Some(b)) => a - b,
            (Some(a), None) => at(r + 2 * dr, c + 2 * dc).map_or(DVec2::ZERO, |a2| a2 - a),
            (None, Some(b)) => at(r - 2 * dr, c - 2 * dc).map_or(DVec2::ZERO, |b2| b - b2),
            (None, None) => DVec2::ZERO,
        }
    };
    struct Local {
        step_row: DVec2,
        step_col: DVec2,
        predicted: Option<DVec2>,
    }
    let mut local = Vec::with_capacity(rows * cols);
    for r in 0..rows as i64 {
        for c in 0..cols as i64 {
            // Where the neighbours put the corner: mean of the midpoints of opposite neighbours.
            let mids: Vec<DVec2> = [(0, 1), (1, 0), (1, 1), (1, -1)]
                .iter()
                .filter_map(|&(dr, dc)| Some((at(r + dr, c + dc)? + at(r - dr, c - dc)?) * 0.5))
                .collect();
            // Border corners without opposite neighbours: extrapolate 2·p₁ − p₂ inwards.
            let guesses: Vec<DVec2> = if mids.is_empty() {
                [
                    (0, 1),
                    (1, 0),
                    (0, -1),
                    (-1, 0),
                    (1, 1),
                    (1, -1),
                    (-1, 1),
                    (-1, -1),
                ]
                .iter()
                .filter_map(|&(dr, dc)| {
                    Some(at(r + dr, c + dc)? * 2.0 - at(r + 2 * dr, c + 2 * dc)?)
                })
                .collect()
            } else {
                mids
            };
            let row_dir = direction(r, c, 0, 1).normalize_or_zero();
            let col_dir = direction(r, c, 1, 0).normalize_or_zero();
            local.push(Local {
                step_row: row_dir * spacing(r, c, 0, 1),
                step_col: col_dir * spacing(r, c, 1, 0),
                predicted: (!guesses.is_empty())
                    .then(|| guesses.iter().copied().sum::<DVec2>() / guesses.len() as f64),
            });
        }
    }
    let fit = |i: usize, start: DVec2, width: EdgeWidth| {
        let l = &local[i];
        crate::saddle::fit_saddle(img, start, l.step_row, l.step_col, width)
    };
    // The image's edge width: median over (at most 12, spread over the board) corners of a
    // short free-width fit.
    let stride = pts.len().div_ceil(12).max(1);
    let mut widths: Vec<f64> = (0..pts.len())
        .step_by(stride)
        .filter_map(|i| {
            fit(
                i,
                pts[i],
                EdgeWidth::Estimate {
                    guess_px: 0.5,
                    max_iterations: 15,
                },
            )
        })
        .map(|f| f.edge_width_px)
        .collect();
    widths.sort_by(f64::total_cmp);
    let width = EdgeWidth::Fixed(widths.get(widths.len() / 2).copied().unwrap_or(0.5));
    for i in 0..pts.len() {
        if let Some(f) = fit(i, pts[i], width)
            .or_else(|| fit(i, raw[i], width))
            .or_else(|| local[i].predicted.and_then(|p| fit(i, p, width)))
        {
            out[i] = f.corner_px;
        }
    }
    Ok(out)
}

/// Detects the board in a scalar image and returns it in canonical order.
pub fn detect_board(
    img: &ScalarImage,
    board: &BoardSpec,
) -> Result<Result<BoardDetection, DetectFailure>, CalibError> {
    let (cols, rows) = (board.cols() as usize, board.rows() as usize);
    let pattern = Size::new(cols as i32, rows as i32);
    // The stretched float image (for sub-pixel refinement) and its 8-bit quantisation (for
    // the detectors): `stretch_to_u8(img, 0.005, 0.995)` from one quantile pass.
    let stretched = stretched_f32(img)?;
    let grey = {
        let data = stretched
            .data_typed::<f32>()
            .map_err(cv("float image data"))?;
        let bytes = data
            .iter()
            .map(|v| v.clamp(0.0, 255.0).round() as u8)
            .collect();
        image::GrayImage::from_raw(img.width_px, img.height_px, bytes).unwrap_or_default()
    };
    // A board with tags: the tags are decoded first. Where any of the board's tags is seen,
    // the board grows from them (`tagboard`): ChArUco-like prints slow OpenCV's chessboard
    // detectors 3–4× and make them miss boards, and the tags give the order and identity
    // directly. The decoded tags are painted over with the paper around them before any
    // sub-pixel refinement (a tag's border inside a refinement window pulls the corner).
    let tags = if board.has_tags() {
        crate::tagboard::find_tags(&grey)?
    } else {
        Vec::new()
    };
    let float_img = crate::tagboard::mask_tags(stretched, board, &tags)?;
    let mut from_tags = None;
    if tags.iter().any(|t| board.tag_corners_sq(t.id).is_some()) {
        let sample = |p: DVec2| img.sample(p);
        let size = (img.width_px, img.height_px);
        match crate::tagboard::partial_from_tags(&sample, size, &float_img, board, &tags)? {
            Ok(found) => {
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
                    refined.add_saddle(&float_img, &start, &start, cols, rows)?;
                }
                return Ok(Ok(BoardDetection {
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
                }));
            }
            Err(why) => from_tags = Some(why),
        }
    }
    let longest = img.width_px.max(img.height_px);
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
    let base = mat_from_grey(&grey)?;
    let mut candidates = Vec::new();
    let mut scale = primary;
    let mut search = Mat::default();
    for attempt in std::iter::once(primary).chain(fallback) {
        scale = attempt;
        search = if attempt != 1.0 {
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
            &search,
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
    let s = scale;
    let to_orig = |p: &Point2f| {
        DVec2::new(
            (f64::from(p.x) + 0.5) / s - 0.5,
            (f64::from(p.y) + 0.5) / s - 0.5,
        )
    };
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
                run_detectors(&search, pattern, true, false, true, &mut candidates)?;
            }
        }
    }
    let quiet = board
        .has_tags()
        .then_some(0.5 * (1.0 - board.apriltag_ratio));
    struct Best<'a> {
        refined: Refined,
        cand: &'a Candidate,
        /// The detector's corners (the saddle fit's second start).
        raw: Vec<DVec2>,
        /// The `cornerSubPix` corners (the saddle fit's first start).
        subpix: Vec<DVec2>,
    }
    let mut best: Option<Best> = None;
    for cand in &candidates {
        let pts: Vec<DVec2> = cand.corners_up.iter().map(to_orig).collect();
        if pts.len() != cols * rows
            || pts.iter().any(|p| !p.is_finite())
            || min_spacing(&pts, cols) < 2.0
        {
            continue;
        }
        let raw = pts.clone();
        let refined = refine(&float_img, &pts, cols, scale.max(1.0))?;
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
        if let Some((fit, i)) = pick
            && best.as_ref().is_none_or(|b| fit < b.refined.fit)
        {
            best = Some(Best {
                refined: Refined {
                    fit,
                    pts: variants[i].1.clone(),
                    refinement: variants[i].0,
                    variants,
                },
                cand,
                raw,
                subpix,
            });
        }
    }
    // The saddle fit (the dearest refinement) runs once, on the kept candidate: when both
    // detectors found the board (small upscaled images), their corners differ by sub-pixel
    // amounts and the fit converges to the same corners from either.
    if let Some(b) = best.as_mut() {
        b.refined
            .add_saddle(&float_img, &b.subpix, &b.raw, cols, rows)?;
    }
    let Some(Best {
        refined:
            Refined {
                fit: planar_fit_px,
                mut pts,
                refinement,
                mut variants,
            },
        cand,
        ..
    }) = best
    else {
        if !board.has_tags() {
            return Ok(Err(DetectFailure::NotFound));
        }
        return Ok(Err(DetectFailure::NoPartial(
            from_tags.unwrap_or_else(|| crate::tagboard::no_board_tags(&tags)),
        )));
    };
    let rough = roughness(&pts, cols, rows);
    let up = search;
    if min_spacing(&pts, cols) < 2.0 {
        return Ok(Err(DetectFailure::Ambiguous(
            "corners closer than 2 px".into(),
        )));
    }
    // Handedness: row direction × column direction > 0 in image coordinates (y down).
    let a = pts[1] - pts[0];
    let b = pts[cols] - pts[0];
    if a.perp_dot(b) < 0.0 {
        pts = flip_rows(&pts, cols, rows);
        for (_, v) in &mut variants {
            *v = flip_rows(v, cols, rows);
        }
    }
    let (m_even, m_odd, spread) = square_parity_stats(img, &pts, cols, rows, quiet);
    let contrast_z = (m_even - m_odd).abs() / spread.max(1e-9);
    if contrast_z < 3.0 {
        return Ok(Err(DetectFailure::Ambiguous(format!(
            "square contrast z = {contrast_z:.1} < 3: dark and bright squares cannot be told apart"
        ))));
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
        for (_, v) in &mut variants {
            v.reverse();
        }
    }
    // Sharpness on the 8-bit original-resolution-mapped corners (upscaled image, then rescaled).
    let up_corners: Vector<Point2f> = pts
        .iter()
        .map(|p| {
            Point2f::new(
                ((p.x + 0.5) * s - 0.5) as f32,
                ((p.y + 0.5) * s - 0.5) as f32,
            )
        })
        .collect();
    let sharp = calib3d::estimate_chessboard_sharpness_def(&up, pattern, &up_corners)
        .map(|v| v[0] / s)
        .unwrap_or(f64::NAN);
    let mut det = BoardDetection {
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
    };
    if board.has_tags() {
        match crate::tagboard::order_by_tags(board, &det.corners_px, &det.corner_ids, &tags)? {
            Err(why) => return Ok(Err(DetectFailure::Ambiguous(why))),
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

/// The sub-pixel refinements of one board and the one kept (the smallest planar fit).
struct Refined {
    fit: f64,
    pts: Vec<DVec2>,
    refinement: Refinement,
    variants: Vec<(Refinement, Vec<DVec2>)>,
}

impl Refined {
    /// Adds the saddle fit of a whole board (from `start`, else `raw`: [`saddle_refine`]) as a
    /// variant, kept when its planar fit is smaller; nothing for squares beyond
    /// [`SADDLE_MAX_SPACING_PX`].
    fn add_saddle(
        &mut self,
        float_img: &Mat,
        start: &[DVec2],
        raw: &[DVec2],
        cols: usize,
        rows: usize,
    ) -> Result<(), CalibError> {
        if median_spacing(start, cols) >= SADDLE_MAX_SPACING_PX {
            return Ok(());
        }
        let saddle = saddle_refine(float_img, start, raw, cols, rows)?;
        let fit = planar_fit_rms(&saddle, cols)?;
        tracing::trace!(planar_fit_px = fit, "saddle refinement");
        if fit < self.fit {
            self.fit = fit;
            self.pts = saddle.clone();
            self.refinement = Refinement::Saddle;
        }
        self.variants.push((Refinement::Saddle, saddle));
        Ok(())
    }
}

/// Rotates a canonical detection by 180° (corner i ↔ corner n−1−i, `n` the board's corner
/// count; partial detections keep their ascending id order). Used when the coated squares
/// turn out to be the bright ones in thermal images, or when the tags say so.
pub fn rotate_180(det: &mut BoardDetection, n: usize) {
    det.corners_px.reverse();
    for id in &mut det.corner_ids {
        *id = n.saturating_sub(1 + *id);
    }
    det.corner_ids.reverse();
    for (_, v) in &mut det.variants {
        v.reverse();
    }
}

impl BoardDetection {
    /// The corners of refinement `r`, or `corners_px` when `r` was not computed here (the
    /// classic detector has no sub-pixel corners of its own; the saddle fit runs on small
    /// squares only).
    pub fn corners_of(&self, r: Refinement) -> &[DVec2] {
        self.variants
            .iter()
            .find(|(v, _)| *v == r)
            .map_or(self.corners_px.as_slice(), |(_, c)| c.as_slice())
    }

    /// Makes refinement `r` the one in `corners_px` (no change when it was not computed).
    pub fn choose(&mut self, r: Refinement) {
        if let Some((_, c)) = self.variants.iter().find(|(v, _)| *v == r) {
            self.corners_px = c.clone();
            self.refinement = r;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_half_turn_maps_corner_ids_and_keeps_them_ascending() {
        let pts = vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.0, 1.0),
        ];
        let mut det = BoardDetection {
            corners_px: pts.clone(),
            corner_ids: vec![0, 1, 9],
            detector: "apriltag",
            inverted: false,
            sharpness_px: f64::NAN,
            contrast_z: f64::NAN,
            roughness_px: f64::NAN,
            planar_fit_px: 0.0,
            refinement: Refinement::CornerSubPix,
            variants: vec![(Refinement::CornerSubPix, pts)],
            order: BoardOrder::Tags,
        };
        // A 9x6 board: corner i becomes 53 - i.
        rotate_180(&mut det, 54);
        assert_eq!(det.corner_ids, vec![44, 52, 53]);
        assert_eq!(
            det.corners_px[0],
            DVec2::new(0.0, 1.0),
            "corner 9 became 44, listed first"
        );
        assert_eq!(
            det.variants[0].1, det.corners_px,
            "variants turn with the corners"
        );
    }

    #[test]
    fn palette_inversion_recovers_the_index() {
        for p in [Palette::Ironbow, Palette::Inferno] {
            let lut = palette_lut(p).unwrap_or_else(|| panic!("{p:?} has a table"));
            for i in [0usize, 17, 100, 200, 255] {
                let c = lut[i].map(|v| v.round() as u8);
                let (idx, dist) = nearest_on_palette(lut, c);
                assert!(
                    (idx - i as f32).abs() <= 3.0,
                    "{p:?}: entry {i} came back as {idx} (distance {dist})"
                );
            }
        }
    }

    #[test]
    fn every_listed_file_format_decodes_to_the_right_scalar_kind() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let (w, h) = (32u32, 24u32);
        let tiff = dir.path().join("t16.tiff");
        image::ImageBuffer::<image::Luma<u16>, _>::from_fn(w, h, |x, _| {
            image::Luma([30000 + x as u16])
        })
        .save(&tiff)
        .unwrap_or_else(|e| panic!("{e}"));
        let grey = dir.path().join("g8.png");
        image::GrayImage::from_fn(w, h, |x, _| image::Luma([x as u8]))
            .save(&grey)
            .unwrap_or_else(|e| panic!("{e}"));
        let rgba = dir.path().join("c.png");
        image::RgbaImage::from_fn(w, h, |_, _| image::Rgba([200, 100, 50, 255]))
            .save(&rgba)
            .unwrap_or_else(|e| panic!("{e}"));
        let load = |p: &Path, thermal| {
            load_scalar(p, thermal, Palette::Auto).unwrap_or_else(|e| panic!("{e}"))
        };
        let t = load(&tiff, true);
        assert_eq!(t.source, SourceKind::Grey16, "16-bit TIFF");
        assert_eq!(
            t.values[5], 30005.0,
            "16-bit counts kept, got {}",
            t.values[5]
        );
        assert_eq!(load(&grey, true).source, SourceKind::Grey8, "8-bit grey");
        let c = load(&rgba, false);
        assert_eq!(c.source, SourceKind::ColourLuminance, "RGBA photo");
        let want = 0.299 * 200.0 + 0.587 * 100.0 + 0.114 * 50.0;
        assert!(
            (f64::from(c.values[0]) - want).abs() < 1e-3,
            "luminance {} want {want}",
            c.values[0]
        );
    }

    #[test]
    fn quantiles_match_a_sort() {
        // Values with ties, a wide spread and non-finite entries (ignored).
        let mut values: Vec<f32> = (0..5000u32)
            .map(|i| ((i * 7919) % 1000) as f32 * 0.37 + if i % 97 == 0 { 1e4 } else { 0.0 })
            .collect();
        values[3] = f32::NAN;
        values[10] = f32::INFINITY;
        let mut sorted: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f32::total_cmp);
        for (lo, hi) in [(0.005, 0.995), (0.0, 1.0), (0.5, 0.5), (0.25, 0.9)] {
            let rank = |f: f64| ((sorted.len() - 1) as f64 * f).round() as usize;
            assert_eq!(
                quantiles(&values, lo, hi),
                (sorted[rank(lo)], sorted[rank(hi)]),
                "quantiles {lo}, {hi}"
            );
        }
        assert_eq!(quantiles(&[f32::NAN], 0.1, 0.9), (0.0, 0.0));
        assert_eq!(quantiles(&[2.0, 2.0], 0.1, 0.9), (2.0, 2.0));
    }

    #[test]
    fn stretch_ignores_a_hot_outlier() {
        let mut values = vec![1000.0f32; 100 * 100];
        for (i, v) in values.iter_mut().enumerate() {
            *v += (i % 2) as f32 * 20.0;
        }
        values[0] = 60000.0;
        let img = ScalarImage {
            width_px: 100,
            height_px: 100,
            values,
            source: SourceKind::Grey16,
        };
        let g = stretch_to_u8(&img, 0.005, 0.995);
        assert_eq!(
            g.as_raw()[1],
            255,
            "the bright half of the board must reach 255"
        );
        assert_eq!(g.as_raw()[2], 0, "the dark half must reach 0");
    }
}
