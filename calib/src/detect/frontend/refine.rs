//! Sub-pixel corner refinement (the front end's step 4): the unquantised float image,
//! `cornerSubPix` on it, the saddle-model fit of [`crate::detect::saddle`], and the set of refinements
//! of one board with the one kept (the smallest planar fit).

use glam::DVec2;
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::detection::Refinement;
use super::grid::{median_spacing, min_spacing, planar_fit_rms};
use crate::detect::saddle::{EdgeWidth, FloatImage, SaddleFit};
use crate::detect::scalar::{ScalarImage, quantiles};
use crate::error::{CalibError, cv};

/// The saddle fit runs only on boards whose median corner spacing is below this (px): on the
/// simulated Lepton boards (5–9 px squares) it takes the corner error from 0.19 px
/// (`cornerSubPix`) to 0.01 px; on the real sun-board thermal images (blurry 8-bit JPEG,
/// 15–40 px squares) it never ranked first and cost 0.2 s per image.
pub const SADDLE_MAX_SPACING_PX: f64 = f64::INFINITY;

/// Float copy of the image stretched like [`crate::detect::scalar::stretch_to_u8`] (0..255, not
/// quantised): the image the refinements run on, and quantised, the one the detectors search.
pub(super) fn stretched_f32(img: &ScalarImage) -> Result<Mat, CalibError> {
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

/// Corner positions in an image upscaled by `s` (pixel-centre origin on both sides), as
/// OpenCV points.
pub(super) fn upscaled_points(pts: &[DVec2], s: f64) -> Vector<Point2f> {
    pts.iter()
        .map(|p| {
            Point2f::new(
                ((p.x + 0.5) * s - 0.5) as f32,
                ((p.y + 0.5) * s - 0.5) as f32,
            )
        })
        .collect()
}

/// `cornerSubPix` on the float image, window from the square size. Images are refined at
/// `upscale` × their resolution (cubic interpolation) when `upscale` > 1: at 160×120 the
/// squares are only ~10 px and the gradient window then holds too few samples.
pub(super) fn refine(
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
    let mut corners = upscaled_points(pts, s);
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

/// Refines every corner by the saddle-model fit ([`crate::detect::saddle`]) on the float image at its
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
    let img = FloatImage {
        width_px,
        height_px,
        values,
    };
    let local = RawGrid { raw, cols, rows }.local_geometry();
    let fit = |i: usize, start: DVec2, width: EdgeWidth| {
        let l = &local[i];
        crate::detect::saddle::fit_saddle(img, start, l.step_row, l.step_col, width)
    };
    let width = EdgeWidth::Fixed(image_edge_width(pts, &fit));
    let mut out = pts.to_vec();
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

/// The image's edge width for the fixed-width fits: the median over (at most 12, spread over
/// the board) corners of a short free-width fit (`fit(index, start, width)`), else 0.5 px.
fn image_edge_width(
    pts: &[DVec2],
    fit: &dyn Fn(usize, DVec2, EdgeWidth) -> Option<SaddleFit>,
) -> f64 {
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
    widths.get(widths.len() / 2).copied().unwrap_or(0.5)
}

/// A corner's grid geometry from its neighbours: the steps to the next corner along the row
/// and the column (the saddle fit's window), and where the neighbours put the corner.
struct Local {
    step_row: DVec2,
    step_col: DVec2,
    predicted: Option<DVec2>,
}

/// The detector's unrefined corners as a `rows × cols` grid (row-major).
struct RawGrid<'a> {
    raw: &'a [DVec2],
    cols: usize,
    rows: usize,
}

impl RawGrid<'_> {
    /// The corner at row `r`, column `c`; `None` outside the grid.
    fn at(&self, r: i64, c: i64) -> Option<DVec2> {
        (r >= 0 && c >= 0 && (r as usize) < self.rows && (c as usize) < self.cols)
            .then(|| self.raw[r as usize * self.cols + c as usize])
    }

    /// Median length of the grid segments within three steps of the corner along (dr, dc):
    /// robust to one misplaced corner, including the corner itself.
    fn spacing(&self, r: i64, c: i64, dr: i64, dc: i64) -> f64 {
        let mut d: Vec<f64> = (-3..3)
            .filter_map(|k| {
                Some(
                    (self.at(r + (k + 1) * dr, c + (k + 1) * dc)?
                        - self.at(r + k * dr, c + k * dc)?)
                    .length(),
                )
            })
            .collect();
        d.sort_by(f64::total_cmp);
        d.get(d.len().saturating_sub(1) / 2).copied().unwrap_or(0.0)
    }

    /// Direction along (dr, dc) from neighbours only: the central difference, or at the border
    /// the next segment inwards.
    fn direction(&self, r: i64, c: i64, dr: i64, dc: i64) -> DVec2 {
        let at = |r, c| self.at(r, c);
        match (at(r + dr, c + dc), at(r - dr, c - dc)) {
            (Some(a), Some(b)) => a - b,
            (Some(a), None) => at(r + 2 * dr, c + 2 * dc).map_or(DVec2::ZERO, |a2| a2 - a),
            (None, Some(b)) => at(r - 2 * dr, c - 2 * dc).map_or(DVec2::ZERO, |b2| b - b2),
            (None, None) => DVec2::ZERO,
        }
    }

    /// Where the neighbours put the corner: the mean of the midpoints of opposite neighbours,
    /// or for border corners without them, of the extrapolations 2·p₁ − p₂ inwards.
    fn predicted(&self, r: i64, c: i64) -> Option<DVec2> {
        let at = |r, c| self.at(r, c);
        let mids: Vec<DVec2> = [(0, 1), (1, 0), (1, 1), (1, -1)]
            .iter()
            .filter_map(|&(dr, dc)| Some((at(r + dr, c + dc)? + at(r - dr, c - dc)?) * 0.5))
            .collect();
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
            .filter_map(|&(dr, dc)| Some(at(r + dr, c + dc)? * 2.0 - at(r + 2 * dr, c + 2 * dc)?))
            .collect()
        } else {
            mids
        };
        (!guesses.is_empty()).then(|| guesses.iter().copied().sum::<DVec2>() / guesses.len() as f64)
    }

    /// Every corner's [`Local`] geometry, row-major.
    fn local_geometry(&self) -> Vec<Local> {
        let mut local = Vec::with_capacity(self.rows * self.cols);
        for r in 0..self.rows as i64 {
            for c in 0..self.cols as i64 {
                let row_dir = self.direction(r, c, 0, 1).normalize_or_zero();
                let col_dir = self.direction(r, c, 1, 0).normalize_or_zero();
                local.push(Local {
                    step_row: row_dir * self.spacing(r, c, 0, 1),
                    step_col: col_dir * self.spacing(r, c, 1, 0),
                    predicted: self.predicted(r, c),
                });
            }
        }
        local
    }
}

/// The sub-pixel refinements of one board and the one kept (the smallest planar fit).
pub(super) struct Refined {
    pub(super) fit: f64,
    pub(super) pts: Vec<DVec2>,
    pub(super) refinement: Refinement,
    pub(super) variants: Vec<(Refinement, Vec<DVec2>)>,
}

impl Refined {
    /// Adds the saddle fit of a whole board (from `start`, else `raw`: [`saddle_refine`]) as a
    /// variant, kept when its planar fit is smaller; nothing for squares beyond
    /// [`SADDLE_MAX_SPACING_PX`].
    pub(super) fn add_saddle(
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
