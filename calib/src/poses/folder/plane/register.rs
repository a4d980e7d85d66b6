//! Image registration for the planar method: the image side of the Python planar script it
//! was ported from (`scripts/real-data/thermal_facade_dataset.py`, removed since; in git
//! history: its `register_pair`, and in `main` the
//! `warpPerspective` into the reference orientation and the CLAHE) in pure Rust, without OpenCV.
//!
//! Per image, then per pair:
//! 1. [`warp_homography`] turns a camera's undistorted image into the reference orientation
//!    (`H = K·R_refᵀ·R_i·K⁻¹`), bilinear, `NaN` outside (OpenCV fills 0, which then correlates
//!    as if it were content).
//! 2. [`clahe`] normalises the contrast as OpenCV's `createCLAHE(2.0, (8, 8))`, aware of `NaN`.
//! 3. [`register_pair`] finds patches of one image in the other near the shift the GPS predicts
//!    and keeps the pair when enough of them agree.
//!
//! # Matching
//! As the script: 64-px patches of `a` on a 32-px grid (flat ones, std < 6, skipped) are found in
//! `b` by zero-mean normalised cross-correlation (`TM_CCOEFF_NORMED`) within ±170 px (each axis)
//! of the predicted shift; peaks ≥ 0.5 are matches; the pair is registered when ≥ 3 matches lie
//! within 4 px of the matches' median shift, and those are returned.
//!
//! The script's exhaustive search costs (2·170 + 1)² · 64² ≈ 5·10⁸ multiply-adds per patch. Here
//! it is coarse to fine, per patch: a pyramid of 2×2 means down to 1/8 (a patch is 8×8 there;
//! the thermal core's own 160×120 is the 1/4 level); at 1/8, the patch's correlation at every
//! shift of its window (43×43, the window statistics from integral images); the three best
//! local maxima climbed (hill climbing over the four axis neighbours) at 1/4, the best of them
//! at 1/2 and at full resolution, where its integer peak gives the score (OpenCV's value) and a
//! parabola per axis through the peak and its two neighbours the sub-pixel shift.
//!
//! Why per patch rather than one coarse shift per pair, then a small search per patch: measured
//! on the facade's 782 candidate pairs (every two shots within 3.2 m). A pair-level coarse shift
//! (the patches' coarse correlation surfaces summed) with a ±8 px search per patch registered
//! 430 pairs, 266 of them inconsistent with the script's in-plane solve: the images are smooth,
//! most patches correlate ≥ 0.5 somewhere near any shift, and the agreement test means nothing.
//! It keeps its meaning when each patch's peak is its best over the whole window, so the coarse
//! search is exhaustive per patch (coarse templates with more context, 12 or 16 px at 1/8, did
//! worse: the large-scale gradients then agree on wrong shifts). More than three coarse
//! candidates (six) found the exhaustive peak a little more often (74.5 % against 74.0 %) at
//! 27 % more time.
//!
//! Against the exhaustive search (OpenCV on the same CLAHE'd images, all 782 pairs): of the
//! 61 180 patches whose exhaustive peak is ≥ 0.5 and inside the window, this finds the same peak
//! (±1 px) for 89 %, another for 9 % (the 8×8 coarse template misses the best; these score a
//! median 0.69 against 0.70) and none for 2 %.
//!
//! Where it departs from the script, on purpose:
//! - a peak on the edge of the window or of `b` is no match (the correlation still rises past
//!   it): the script keeps those, 15 % of its peaks ≥ 0.5, scattered;
//! - the grid is symmetric, `stride / 2` from every border (234 patches in 640×480; the
//!   script's ranges stop one row and one column short: 204);
//! - a patch's centre is at its middle, `x + 31.5` (the script says `x + 32`; shifts are alike);
//! - shifts are sub-pixel.
//!
//! Outcome on the facade (images warped and normalised here, from the script's undistorted
//! images): 179 of the 782 pairs registered (the script 140; the exhaustive search with the
//! symmetric grid 152, 132 in common with this, median shifts 1.2 px apart: the agreeing subsets
//! differ, shifts vary by several pixels across a frame). Fed to the script's own bundle
//! adjustment: median reprojection error 0.41 px (90th percentile 1.05) over all 178 pairs of an
//! earlier run, 0.36 px (0.91) over the 122 pairs the script registers too; the script's own
//! matches give 0.36 px (1.00), and 0.36 (0.98) once refined to sub-pixel: the bundle's error is
//! mostly its model's, and the pairs the script does not register are the wider, harder ones.
//!
//! # Sub-pixel accuracy
//! The parabola per axis on the correlation surface at full resolution: on smooth synthetic
//! texture like the core's 4× upsampled images (gain, offset and noise changed) the mean shift
//! is within 0.022 px of the truth for fractional shifts 0 to 0.9 and single patches within
//! 0.08 px (tests); on a real pair against OpenCV's surface with the same fit, 106 patches in
//! common: median 0.03 px apart, 90th percentile 0.10, largest 0.45 (JPEG decoders,
//! undistortion and CLAHE differ slightly). The fractional parts of the facade's shifts are
//! close to uniform (little pixel locking).
//!
//! # Contrast normalisation
//! CLAHE as the script: without it (raw warped images) 165 pairs registered with a median of 11
//! agreeing patches, against 178 with 15 (NCC is blind to gain and offset, not to CLAHE's local
//! stretch, and the flatness gate `min_std` is in CLAHE'd units). This CLAHE against OpenCV's
//! (same images, same matching): 179 pairs registered against 181.
//!
//! # Speed
//! Dev profile (this crate at opt-level 1), the 782 facade pairs: 12 s of CPU in all, 15 ms
//! per pair (the exhaustive 1/8 search ~40 %, the climbs ~45 %), measured on a shared, busy
//! machine; so ~6 s on two idle cores (rayon over each pair's patches; callers may run pairs
//! in parallel too); 1 100 pairs would take ~17 s of CPU, ~9 s on two cores. Release: 8.5 s
//! of CPU for the 782. One textured pair (all 234 patches) takes 20 to 100 ms. The kernels are scalar at opt-level 1 (no vectoriser): the
//! eight (or four) running sums only keep the chains independent. Memory is per pair: the two
//! pyramids (a third of an image each) and the 1/8 level's integral images.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// A grey image in floating point, row-major, `NaN` where there is no data (outside the source
/// after [`warp_homography`]). Pixel centres are at integer coordinates (OpenCV's convention).
/// The matching functions expect 8-bit-like values (0 to 255), as [`clahe`] writes them.
#[derive(Debug, Clone, PartialEq)]
pub struct Grey {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` values, row after row; `NaN` marks "no data".
    pub data: Vec<f32>,
}

impl Grey {
    /// An image from its values; `None` when `data` does not hold `width * height` of them.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Option<Self> {
        (width.checked_mul(height) == Some(data.len())).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// An image of one value everywhere (`f32::NAN`: no data anywhere).
    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width.saturating_mul(height)],
        }
    }

    /// An 8-bit grey image's values (0 to 255) as floats.
    pub fn from_luma8(img: &image::GrayImage) -> Self {
        Self {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.as_raw().iter().map(|&v| f32::from(v)).collect(),
        }
    }

    /// An 8-bit colour image in grey by OpenCV's weights (`0.299 R + 0.587 G + 0.114 B`,
    /// rounded: `cvtColor(…, COLOR_BGR2GRAY)` to within one level), as the Python planar
    /// script reads the DJI thermal JPEGs (`image`'s own `to_luma8` weighs by Rec. 709).
    pub fn from_rgb8(img: &image::RgbImage) -> Self {
        Self {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img
                .pixels()
                .map(|p| {
                    (0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2]))
                        .round()
                })
                .collect(),
        }
    }

    /// Whether `data` holds `width * height` values (the fields are public: an image built by
    /// hand may not; the functions of this module treat such an image as having no data).
    fn is_consistent(&self) -> bool {
        self.width.checked_mul(self.height) == Some(self.data.len())
    }

    /// The value at pixel (`x`, `y`); `NaN` outside the image.
    pub fn get(&self, x: usize, y: usize) -> f32 {
        if x < self.width && y < self.height && self.is_consistent() {
            self.data[y * self.width + x]
        } else {
            f32::NAN
        }
    }

    /// Bilinear interpolation at (`x`, `y`) (pixel centres at integers); `NaN` outside
    /// `[0, width - 1] × [0, height - 1]` or next to a pixel without data.
    pub fn sample(&self, x: f64, y: f64) -> f32 {
        let (w, h) = (self.width, self.height);
        if !self.is_consistent()
            || w == 0
            || h == 0
            || !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64)
        {
            return f32::NAN;
        }
        let x0 = (x.floor() as usize).min(w.saturating_sub(2));
        let y0 = (y.floor() as usize).min(h.saturating_sub(2));
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let d = &self.data;
        let top = d[y0 * w + x0] * (1.0 - fx) + d[y0 * w + x1] * fx;
        let bottom = d[y1 * w + x0] * (1.0 - fx) + d[y1 * w + x1] * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Half the size: the mean of each 2×2 block (`NaN` if any of the four is); an odd last
    /// row or column is dropped.
    fn half(&self) -> Self {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            let r0 = &self.data[2 * y * self.width..];
            let r1 = &self.data[(2 * y + 1) * self.width..];
            for x in 0..w {
                data.push(0.25 * (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]));
            }
        }
        Self {
            width: w,
            height: h,
            data,
        }
    }
}

/// `src` seen through the homography `h`: output pixel `p` (integer coordinates, pixel centres
/// at integers as in OpenCV) takes `src` at `h⁻¹·p`, interpolated bilinearly; `NaN` where that
/// falls outside `src` (or next to a pixel of `src` without data), and everywhere when `h` is
/// singular. With `H = K·R_refᵀ·R_i·K⁻¹` it turns camera `i`'s undistorted image into the
/// reference orientation, as OpenCV's `warpPerspective(src, H, size)` does.
pub fn warp_homography(src: &Grey, h: &Matrix3<f64>, width: usize, height: usize) -> Grey {
    let mut out = Grey::filled(width, height, f32::NAN);
    let Some(inv) = h.try_inverse() else {
        return out;
    };
    if width == 0 || !inv.iter().all(|v| v.is_finite()) {
        return out;
    }
    out.data
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let q = inv * Vector3::new(x as f64, y as f64, 1.0);
                if q.z > 1e-12 {
                    *o = src.sample(q.x / q.z, q.y / q.z);
                }
            }
        });
    out
}

/// Contrast-limited adaptive histogram equalisation, as OpenCV's `createCLAHE(clip_limit,
/// tiles).apply` on an 8-bit image, for values 0 to 255 (others are clamped into that range)
/// and aware of missing data: pixels without data are left out of the tiles' histograms and
/// stay `NaN`. Each tile's histogram (256 bins, the value rounded) is clipped at
/// `clip_limit × pixels / 256` with the excess spread over all bins, its cumulative sum is the
/// tile's map, and each pixel blends the maps of the four nearest tile centres bilinearly.
/// Unlike OpenCV the output is not rounded and the maps are interpolated between bins
/// (the warped images have fractional values); a tile without data maps values to themselves.
pub fn clahe(img: &Grey, clip_limit: f64, tiles: [usize; 2]) -> Grey {
    let (w, h) = (img.width, img.height);
    if !img.is_consistent() || w == 0 || h == 0 {
        return Grey::filled(w, h, f32::NAN);
    }
    let (tx, ty) = (tiles[0].clamp(1, w), tiles[1].clamp(1, h));
    let (tw, th) = (w.div_ceil(tx), h.div_ceil(ty));
    let bin = |v: f32| v.round().clamp(0.0, 255.0) as usize;
    // One map of 256 values per tile.
    let maps: Vec<[f32; 256]> = (0..tx * ty)
        .into_par_iter()
        .map(|t| {
            let (i, j) = (t % tx, t / tx);
            let mut hist = [0u32; 256];
            let mut n = 0u32;
            for y in j * th..((j + 1) * th).min(h) {
                for &v in &img.data[y * w + i * tw..y * w + ((i + 1) * tw).min(w)] {
                    if !v.is_nan() {
                        hist[bin(v)] += 1;
                        n += 1;
                    }
                }
            }
            let mut map = [0f32; 256];
            if n == 0 {
                for (k, m) in map.iter_mut().enumerate() {
                    *m = k as f32;
                }
                return map;
            }
            if clip_limit > 0.0 {
                let limit = ((clip_limit * f64::from(n) / 256.0) as u32).max(1);
                let mut clipped = 0u32;
                for c in &mut hist {
                    if *c > limit {
                        clipped += *c - limit;
                        *c = limit;
                    }
                }
                let (batch, mut residual) = (clipped / 256, clipped % 256);
                for c in &mut hist {
                    *c += batch;
                }
                if residual > 0 {
                    let step = (256 / residual as usize).max(1);
                    for c in hist.iter_mut().step_by(step) {
                        if residual == 0 {
                            break;
                        }
                        *c += 1;
                        residual -= 1;
                    }
                }
            }
            let scale = 255.0 / f64::from(n);
            let mut sum = 0u32;
            for (m, &c) in map.iter_mut().zip(&hist) {
                sum += c;
                *m = (f64::from(sum) * scale) as f32;
            }
            map
        })
        .collect();
    // Tile indices and weights along one axis, as OpenCV's interpolation.
    let axis = |x: usize, size: usize, count: usize| {
        let f = x as f64 / size as f64 - 0.5;
        let t1 = f.floor();
        let a = (f - t1) as f32;
        let t1 = t1 as isize;
        let lo = t1.max(0) as usize;
        let hi = ((t1 + 1).max(0) as usize).min(count - 1);
        (lo.min(count - 1), hi, a)
    };
    let xs: Vec<(usize, usize, f32)> = (0..w).map(|x| axis(x, tw, tx)).collect();
    let mut out = Grey::filled(w, h, f32::NAN);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (y1, y2, b) = axis(y, th, ty);
        for ((o, &v), &(x1, x2, a)) in row.iter_mut().zip(&img.data[y * w..(y + 1) * w]).zip(&xs) {
            if v.is_nan() {
                continue;
            }
            let v = v.clamp(0.0, 255.0);
            let k0 = (v.floor() as usize).min(254);
            let f = v - k0 as f32;
            let at = |t: usize| maps[t][k0] * (1.0 - f) + maps[t][k0 + 1] * f;
            let top = at(y1 * tx + x1) * (1.0 - a) + at(y1 * tx + x2) * a;
            let bottom = at(y2 * tx + x1) * (1.0 - a) + at(y2 * tx + x2) * a;
            *o = top * (1.0 - b) + bottom * b;
        }
    });
    out
}

/// One patch of image `a` and where it was found in image `b`, in the (warped) images' pixel
/// coordinates (pixel centres at integers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchMatch {
    /// The patch's centre in `a` (a 64-pixel patch at columns `x..x + 64` has its centre at
    /// `x + 31.5`).
    pub a: [f64; 2],
    /// Its match's centre in `b`, sub-pixel: `b − a` is the patch's shift.
    pub b: [f64; 2],
    /// Zero-mean normalised cross-correlation at the integer peak (OpenCV's
    /// `TM_CCOEFF_NORMED`), −1 to 1.
    pub score: f64,
}

/// How [`register_pair`] matches; the defaults are those of the Python planar script.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterParams {
    /// Half the side of the square patches, px (patches are `2 × half_patch` wide).
    pub half_patch: usize,
    /// Spacing of the patch grid in `a`, px.
    pub stride: usize,
    /// Search radius around the predicted shift, px (a square: each axis within it).
    pub search_px: f64,
    /// Least correlation peak of a kept match.
    pub min_score: f64,
    /// Least standard deviation of a patch of `a` (8-bit units, after contrast normalisation):
    /// flatter patches (sky, plain wall) have no position and are skipped.
    pub min_std: f64,
    /// A match agrees when its shift is within this of the median shift, px.
    pub agree_px: f64,
    /// Least number of agreeing matches for the pair to be registered.
    pub min_agree: usize,
}

impl Default for RegisterParams {
    fn default() -> Self {
        Self {
            half_patch: 32,
            stride: 32,
            search_px: 170.0,
            min_score: 0.5,
            min_std: 6.0,
            agree_px: 4.0,
            min_agree: 3,
        }
    }
}

/// Candidate peaks of the coarsest level carried to the next one (the best of them after that
/// level goes on).
const COARSE_CANDIDATES: usize = 3;
/// Coarsest level: images reduced by 2^MAX_LEVELS at most.
const MAX_LEVELS: usize = 3;
/// Smallest patch side at the coarsest level, px.
const MIN_COARSE_SIDE: usize = 8;
/// Hill-climbing steps at a finer level before giving up.
const CLIMB_STEPS: usize = 12;

/// Integral images of the values, their squares and the count of pixels without data: the
/// window statistics of the exhaustive search at the coarsest level.
struct Integral {
    w: usize,
    sum: Vec<f64>,
    sum2: Vec<f64>,
    bad: Vec<u32>,
}

impl Integral {
    fn new(g: &Grey) -> Self {
        let (w, h) = (g.width, g.height);
        let s = w + 1;
        let mut sum = vec![0.0; s * (h + 1)];
        let mut sum2 = vec![0.0; s * (h + 1)];
        let mut bad = vec![0u32; s * (h + 1)];
        if w > 0 {
            for (y, row) in g.data.chunks_exact(w).enumerate() {
                let (mut rs, mut rs2, mut rb) = (0.0f64, 0.0f64, 0u32);
                let (above, below) = (y * s + 1, (y + 1) * s + 1);
                for (x, &v) in row.iter().enumerate() {
                    if v.is_nan() {
                        rb += 1;
                    } else {
                        let v = f64::from(v);
                        rs += v;
                        rs2 += v * v;
                    }
                    sum[below + x] = sum[above + x] + rs;
                    sum2[below + x] = sum2[above + x] + rs2;
                    bad[below + x] = bad[above + x] + rb;
                }
            }
        }
        Self { w, sum, sum2, bad }
    }

    /// Sum and sum of squares of the `m × m` window at top-left (`x`, `y`) (inside the image);
    /// `None` when it holds a pixel without data.
    fn window(&self, x: usize, y: usize, m: usize) -> Option<(f64, f64)> {
        let s = self.w + 1;
        let (i00, i01, i10, i11) = (
            y * s + x,
            y * s + x + m,
            (y + m) * s + x,
            (y + m) * s + x + m,
        );
        if self.bad[i11] + self.bad[i00] != self.bad[i01] + self.bad[i10] {
            return None;
        }
        let box_sum = |t: &[f64]| t[i11] - t[i01] - t[i10] + t[i00];
        Some((box_sum(&self.sum), box_sum(&self.sum2)))
    }
}

/// A patch of `a` at one level: its values less their mean, their norm and standard deviation.
struct Template {
    m: usize,
    data: Vec<f32>,
    norm: f64,
    std: f64,
}

impl Template {
    /// The `m × m` patch of `g` at top-left (`x`, `y`); `None` when it leaves the image, holds a
    /// pixel without data or is flat.
    fn new(g: &Grey, x: usize, y: usize, m: usize) -> Option<Self> {
        if m == 0 || x + m > g.width || y + m > g.height {
            return None;
        }
        let mut data = vec![0f32; m * m];
        let mut sum = 0.0f64;
        for (r, row) in data.chunks_exact_mut(m).enumerate() {
            let start = (y + r) * g.width + x;
            row.copy_from_slice(&g.data[start..start + m]);
            sum += f64::from(row.iter().sum::<f32>());
        }
        let n = (m * m) as f64;
        let mean = sum / n;
        if !mean.is_finite() {
            return None;
        }
        let mean32 = mean as f32;
        let mut sq = 0.0f64;
        for row in data.chunks_exact_mut(m) {
            let mut rs = 0f32;
            for v in row.iter_mut() {
                *v -= mean32;
                rs += *v * *v;
            }
            sq += f64::from(rs);
        }
        let norm = sq.sqrt();
        (norm > 1e-6 * n).then_some(Self {
            m,
            data,
            norm,
            std: norm / n.sqrt(),
        })
    }

    /// The top-left corner of `b`'s window at (`x`, `y`) when the window is inside `b`.
    fn inside(&self, b: &Grey, x: isize, y: isize) -> Option<(usize, usize)> {
        (x >= 0 && y >= 0 && x as usize + self.m <= b.width && y as usize + self.m <= b.height)
            .then_some((x as usize, y as usize))
    }

    /// Zero-mean normalised cross-correlation (`TM_CCOEFF_NORMED`) with `b`'s window at
    /// top-left (`x`, `y`), its statistics from `ib` (`b`'s integral images); `None` when the
    /// window leaves `b` or holds a pixel without data, 0 when it is flat.
    fn ncc_integral(&self, b: &Grey, ib: &Integral, x: isize, y: isize) -> Option<f64> {
        let (x, y) = self.inside(b, x, y)?;
        let m = self.m;
        let (s, s2) = ib.window(x, y, m)?;
        let n = (m * m) as f64;
        let var = s2 - s * s / n;
        if var <= 1e-9 * n {
            return Some(0.0);
        }
        let num = corr(&self.data, m, &b.data, b.width, x, y);
        Some(num / (self.norm * var.sqrt()))
    }

    /// As [`Template::ncc_integral`], the window's statistics summed with the products.
    fn ncc(&self, b: &Grey, x: isize, y: isize) -> Option<f64> {
        let (x, y) = self.inside(b, x, y)?;
        let m = self.m;
        let (num, s, s2) = corr3(&self.data, m, &b.data, b.width, x, y);
        if !num.is_finite() || !s2.is_finite() {
            return None;
        }
        let n = (m * m) as f64;
        let var = s2 - s * s / n;
        if var <= 1e-9 * n {
            return Some(0.0);
        }
        Some(num / (self.norm * var.sqrt()))
    }
}

/// Terms summed in `f32` before a partial sum goes into the `f64` total.
const F32_RUN: usize = 512;

/// `Σ t·b` over the `m`-wide rows of `t` and the window of `b` (row length `stride`) at
/// top-left (`x`, `y`) (inside `b`): eight running `f32` sums (independent chains), moved into
/// an `f64` total every [`F32_RUN`] terms.
fn corr(t: &[f32], m: usize, b: &[f32], stride: usize, x: usize, y: usize) -> f64 {
    let rows_per_run = (F32_RUN / m.max(1)).max(1);
    let mut total = 0.0f64;
    for (k, block) in t.chunks(rows_per_run * m.max(1)).enumerate() {
        let mut acc = [0f32; 8];
        let mut tail = 0f32;
        for (r, trow) in block.chunks_exact(m).enumerate() {
            let start = (y + k * rows_per_run + r) * stride + x;
            let brow = &b[start..start + m];
            let (tc, tr) = trow.as_chunks::<8>();
            let (bc, br) = brow.as_chunks::<8>();
            for (u, v) in tc.iter().zip(bc) {
                for i in 0..8 {
                    acc[i] += u[i] * v[i];
                }
            }
            for (u, v) in tr.iter().zip(br) {
                tail += u * v;
            }
        }
        total += f64::from(acc.iter().sum::<f32>() + tail);
    }
    total
}

/// As [`corr`], with `Σ b` and `Σ b²` over the window (four running sums each: twelve fit in
/// the registers).
fn corr3(t: &[f32], m: usize, b: &[f32], stride: usize, x: usize, y: usize) -> (f64, f64, f64) {
    let rows_per_run = (F32_RUN / m.max(1)).max(1);
    let (mut tp, mut ts, mut ts2) = (0.0f64, 0.0f64, 0.0f64);
    for (k, block) in t.chunks(rows_per_run * m.max(1)).enumerate() {
        let (mut p, mut s, mut s2) = ([0f32; 4], [0f32; 4], [0f32; 4]);
        let (mut rp, mut rs, mut rs2) = (0f32, 0f32, 0f32);
        for (r, trow) in block.chunks_exact(m).enumerate() {
            let start = (y + k * rows_per_run + r) * stride + x;
            let brow = &b[start..start + m];
            let (tc, tr) = trow.as_chunks::<4>();
            let (bc, br) = brow.as_chunks::<4>();
            for (u, v) in tc.iter().zip(bc) {
                for i in 0..4 {
                    p[i] += u[i] * v[i];
                    s[i] += v[i];
                    s2[i] += v[i] * v[i];
                }
            }
            for (u, &v) in tr.iter().zip(br) {
                rp += u * v;
                rs += v;
                rs2 += v * v;
            }
        }
        tp += f64::from(p.iter().sum::<f32>() + rp);
        ts += f64::from(s.iter().sum::<f32>() + rs);
        ts2 += f64::from(s2.iter().sum::<f32>() + rs2);
    }
    (tp, ts, ts2)
}

/// Patches of `a` found in `b` near the `predicted` shift (px, `b − a`, the shift the GPS
/// predicts): the matches that agree, or `None` when fewer than `p.min_agree` do (or nothing
/// could be matched: flat or missing data, no overlap, unusable parameters). Expects
/// contrast-normalised images ([`clahe`]), values 0 to 255, `NaN` for no data; the two may
/// differ in size.
pub fn register_pair(
    a: &Grey,
    b: &Grey,
    predicted: [f64; 2],
    p: &RegisterParams,
) -> Option<Vec<PatchMatch>> {
    let side = p.half_patch.checked_mul(2)?;
    let usable = side > 0
        && p.stride > 0
        && a.is_consistent()
        && b.is_consistent()
        && p.search_px >= 0.0
        && p.search_px.is_finite()
        && predicted.iter().all(|v| v.is_finite());
    if !usable {
        return None;
    }
    // Levels: the coarsest keeps patches at least MIN_COARSE_SIDE wide and the search at least
    // two of its pixels.
    let mut top = 0;
    while top < MAX_LEVELS
        && side >> (top + 1) >= MIN_COARSE_SIDE
        && p.search_px / f64::from(1u32 << (top + 1)) >= 2.0
    {
        top += 1;
    }
    let (pa, pb) = (pyramid(a, top), pyramid(b, top));
    let la: Vec<&Grey> = std::iter::once(a).chain(&pa).collect();
    let lb: Vec<&Grey> = std::iter::once(b).chain(&pb).collect();
    let ib = Integral::new(lb[top]);
    // The grid: patches `stride` apart, `stride / 2` from the borders.
    let margin = p.stride / 2;
    let fits = |at: usize, size: usize| at.saturating_add(margin).saturating_add(side) <= size;
    let mut corners = Vec::new();
    let mut py = margin;
    while fits(py, a.height) {
        let mut px = margin;
        while fits(px, a.width) {
            corners.push((px, py));
            px = px.saturating_add(p.stride);
        }
        py = py.saturating_add(p.stride);
    }
    let levels = Levels {
        a: &la,
        b: &lb,
        ib: &ib,
        top,
        side,
    };
    let found: Vec<PatchMatch> = corners
        .par_iter()
        .filter_map(|&(px, py)| match_patch(&levels, px, py, predicted, p))
        .collect();
    let need = p.min_agree.max(1);
    if found.len() < need {
        return None;
    }
    let shift = |m: &PatchMatch| [m.b[0] - m.a[0], m.b[1] - m.a[1]];
    let med = |k: usize| {
        let mut v: Vec<f64> = found.iter().map(|m| shift(m)[k]).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let (mx, my) = (med(0), med(1));
    let agree: Vec<PatchMatch> = found
        .into_iter()
        .filter(|m| {
            let s = shift(m);
            (s[0] - mx).hypot(s[1] - my) < p.agree_px
        })
        .collect();
    (agree.len() >= need).then_some(agree)
}

/// Levels 1 to `top` of `g`'s pyramid (each half the one before).
fn pyramid(g: &Grey, top: usize) -> Vec<Grey> {
    let mut out: Vec<Grey> = Vec::with_capacity(top);
    for _ in 0..top {
        let next = out.last().unwrap_or(g).half();
        out.push(next);
    }
    out
}

/// Both pyramids of a pair (level 0 the images), the integral images of `b`'s coarsest level,
/// that level and the patches' side at full resolution.
struct Levels<'a> {
    a: &'a [&'a Grey],
    b: &'a [&'a Grey],
    ib: &'a Integral,
    top: usize,
    side: usize,
}

/// The patch of `a` at top-left (`px`, `py`) (full resolution) found in `b`: the full search
/// window at the coarsest level, its best peaks climbed level by level, the sub-pixel fit at
/// full resolution.
fn match_patch(
    lv: &Levels,
    px: usize,
    py: usize,
    predicted: [f64; 2],
    p: &RegisterParams,
) -> Option<PatchMatch> {
    let (top, side) = (lv.top, lv.side);
    // The gate, at full resolution.
    let full = Template::new(lv.a[0], px, py, side)?;
    if full.std < p.min_std {
        return None;
    }
    let r = p.search_px;
    // Shift (full-resolution px) allowed at level l: the search window, with one pixel of the
    // level as slack at the coarser levels.
    let allowed = |l: usize, dx: f64, dy: f64| {
        let slack = if l == 0 { 0.0 } else { f64::from(1u32 << l) };
        (dx - predicted[0]).abs() <= r + slack && (dy - predicted[1]).abs() <= r + slack
    };
    // Coarsest level: every position of the window.
    let sc = 1isize << top;
    let coarse;
    let tpl = if top == 0 {
        &full
    } else {
        coarse = Template::new(lv.a[top], px >> top, py >> top, side >> top)?;
        &coarse
    };
    let (xa, ya) = ((px >> top) as isize, (py >> top) as isize);
    let bt = lv.b[top];
    let scf = sc as f64;
    let lo_x = (((predicted[0] - r) / scf).ceil() as isize).max(-xa);
    let hi_x =
        (((predicted[0] + r) / scf).floor() as isize).min(bt.width as isize - tpl.m as isize - xa);
    let lo_y = (((predicted[1] - r) / scf).ceil() as isize).max(-ya);
    let hi_y =
        (((predicted[1] + r) / scf).floor() as isize).min(bt.height as isize - tpl.m as isize - ya);
    if hi_x < lo_x || hi_y < lo_y {
        return None;
    }
    let (nx, ny) = ((hi_x - lo_x + 1) as usize, (hi_y - lo_y + 1) as usize);
    let mut grid = vec![f64::NAN; nx * ny];
    for (j, row) in grid.chunks_exact_mut(nx).enumerate() {
        for (i, g) in row.iter_mut().enumerate() {
            let (dx, dy) = (lo_x + i as isize, lo_y + j as isize);
            if let Some(v) = tpl.ncc_integral(bt, lv.ib, xa + dx, ya + dy) {
                *g = v;
            }
        }
    }
    // Local maxima (over the valid neighbours), best first.
    let mut peaks: Vec<(f64, isize, isize)> = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let v = grid[j * nx + i];
            if v.is_nan() {
                continue;
            }
            let is_max = NEIGHBOURS.iter().all(|&(di, dj)| {
                let (ii, jj) = (i as isize + di, j as isize + dj);
                if ii < 0 || jj < 0 || ii as usize >= nx || jj as usize >= ny {
                    return true;
                }
                let u = grid[jj as usize * nx + ii as usize];
                // Ties: the first in scan order is the maximum.
                !(u > v || (u == v && (dj, di) < (0, 0)))
            });
            if is_max {
                peaks.push((v, lo_x + i as isize, lo_y + j as isize));
            }
        }
    }
    peaks.sort_by(|x, y| y.0.total_cmp(&x.0));
    peaks.truncate(if top == 0 { 1 } else { COARSE_CANDIDATES });
    // Shifts in full-resolution px, climbed level by level; the best after the first finer
    // level goes on alone.
    let mut cands: Vec<(isize, isize)> = peaks
        .iter()
        .map(|&(_, dx, dy)| (dx * sc, dy * sc))
        .collect();
    let mut best: Option<Climb> = None;
    for l in (0..top.max(1)).rev() {
        let s = 1isize << l;
        let finer;
        let tpl = if l == 0 {
            &full
        } else {
            finer = Template::new(lv.a[l], px >> l, py >> l, side >> l)?;
            &finer
        };
        let (xa, ya) = ((px >> l) as isize, (py >> l) as isize);
        let mut next: Option<Climb> = None;
        for &(tx, ty) in &cands {
            // Nearest level pixel to the full-resolution shift.
            let start = (
                (tx as f64 / s as f64).round() as isize,
                (ty as f64 / s as f64).round() as isize,
            );
            let eval = |dx: isize, dy: isize| {
                if allowed(l, (dx * s) as f64, (dy * s) as f64) {
                    tpl.ncc(lv.b[l], xa + dx, ya + dy)
                } else {
                    None
                }
            };
            if let Some(c) = climb(eval, start)
                && next.as_ref().is_none_or(|b| c.score > b.score)
            {
                next = Some(c);
            }
        }
        let c = next?;
        cands = vec![(c.at.0 * s, c.at.1 * s)];
        best = Some(c);
    }
    let c = best?;
    if c.score < p.min_score {
        return None;
    }
    let (fx, fy) = subpixel(&c.around)?;
    let half = p.half_patch as f64 - 0.5;
    let a_c = [px as f64 + half, py as f64 + half];
    Some(PatchMatch {
        a: a_c,
        b: [a_c[0] + c.at.0 as f64 + fx, a_c[1] + c.at.1 as f64 + fy],
        score: c.score,
    })
}

/// The four neighbours of a grid position along the axes.
const AXIS_NEIGHBOURS: [(isize, isize); 4] = [(0, -1), (-1, 0), (1, 0), (0, 1)];

/// The eight neighbours of a grid position.
const NEIGHBOURS: [(isize, isize); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// A climbed peak: its shift (level px), score and the scores around it, `around[1 + dy][1 + dx]`:
/// the centre and its four axis neighbours (`NaN` where the correlation is not defined or not
/// allowed; the corners are not evaluated and stay `NaN`).
struct Climb {
    at: (isize, isize),
    score: f64,
    around: [[f64; 3]; 3],
}

/// From shift `start` (level px), move to the best of the four axis neighbours until the
/// centre is the best (at most [`CLIMB_STEPS`] moves); `eval` gives the correlation at a shift, `None`
/// where it is not defined or not allowed.
fn climb(eval: impl Fn(isize, isize) -> Option<f64>, start: (isize, isize)) -> Option<Climb> {
    let mut seen: Vec<((isize, isize), f64)> = Vec::with_capacity(32);
    let mut get = |d: (isize, isize)| -> f64 {
        if let Some(&(_, v)) = seen.iter().find(|(k, _)| *k == d) {
            return v;
        }
        let v = eval(d.0, d.1).unwrap_or(f64::NAN);
        seen.push((d, v));
        v
    };
    let mut c = start;
    for _ in 0..=CLIMB_STEPS {
        let v = get(c);
        if v.is_nan() {
            return None;
        }
        let mut around = [[f64::NAN; 3]; 3];
        around[1][1] = v;
        let (mut best, mut bv) = (c, v);
        for (di, dj) in AXIS_NEIGHBOURS {
            let d = (c.0 + di, c.1 + dj);
            let u = get(d);
            around[(dj + 1) as usize][(di + 1) as usize] = u;
            if u > bv {
                best = d;
                bv = u;
            }
        }
        if best == c {
            return Some(Climb {
                at: c,
                score: v,
                around,
            });
        }
        c = best;
    }
    None
}

/// Sub-pixel offset of the peak from the correlation values around it (as [`Climb::around`]): a
/// parabola through the three values along each axis, vertex within ±0.5 px; `None` when one is
/// missing (a peak on the edge of the search window or of the image).
fn subpixel(v: &[[f64; 3]; 3]) -> Option<(f64, f64)> {
    let para = |l: f64, c: f64, r: f64| -> Option<f64> {
        if !(l.is_finite() && c.is_finite() && r.is_finite()) {
            return None;
        }
        let d = l - 2.0 * c + r;
        Some(if d < 0.0 {
            (0.5 * (l - r) / d).clamp(-0.5, 0.5)
        } else {
            0.0
        })
    };
    Some((
        para(v[1][0], v[1][1], v[1][2])?,
        para(v[0][1], v[1][1], v[2][1])?,
    ))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    /// Catmull-Rom interpolation of a grid of random values, one cell every `cell` px and
    /// periodic every `period` cells along x: smooth texture like the thermal core's upsampled
    /// images, defined at any real position.
    struct Texture {
        cells: Vec<f64>,
        nx: usize,
        ny: usize,
        cell: f64,
    }

    impl Texture {
        fn new(nx: usize, ny: usize, cell: f64, seed: u64) -> Self {
            use rand::{Rng, SeedableRng};
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            Self {
                cells: (0..nx * ny)
                    .map(|_| rng.random_range(40.0..210.0))
                    .collect(),
                nx,
                ny,
                cell,
            }
        }

        fn at(&self, x: f64, y: f64) -> f64 {
            let cr = |t: f64| {
                let (t2, t3) = (t * t, t * t * t);
                [
                    -0.5 * t3 + t2 - 0.5 * t,
                    1.5 * t3 - 2.5 * t2 + 1.0,
                    -1.5 * t3 + 2.0 * t2 + 0.5 * t,
                    0.5 * t3 - 0.5 * t2,
                ]
            };
            let (u, v) = (x / self.cell, y / self.cell);
            let (i, j) = (u.floor(), v.floor());
            let (wu, wv) = (cr(u - i), cr(v - j));
            let mut s = 0.0;
            for (b, wb) in wv.iter().enumerate() {
                let jj = (j as isize + b as isize - 1).rem_euclid(self.ny as isize) as usize;
                for (a, wa) in wu.iter().enumerate() {
                    let ii = (i as isize + a as isize - 1).rem_euclid(self.nx as isize) as usize;
                    s += wa * wb * self.cells[jj * self.nx + ii];
                }
            }
            s
        }

        /// `gain · texture(x − shift) + offset + noise` on a `w × h` grid (`size`), `gain_offset`
        /// the gain and the offset, `noise` the noise's standard deviation.
        fn render(
            &self,
            size: [usize; 2],
            shift: [f64; 2],
            gain_offset: [f64; 2],
            noise: f64,
            seed: u64,
        ) -> Grey {
            let ([w, h], [gain, offset]) = (size, gain_offset);
            use rand::SeedableRng;
            use rand_distr::Distribution;
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let n = rand_distr::Normal::new(0.0, noise.max(1e-12)).unwrap();
            let mut data = Vec::with_capacity(w * h);
            for y in 0..h {
                for x in 0..w {
                    let v = gain * self.at(x as f64 - shift[0], y as f64 - shift[1])
                        + offset
                        + n.sample(&mut rng);
                    data.push(v.clamp(0.0, 255.0) as f32);
                }
            }
            Grey::new(w, h, data).unwrap()
        }
    }

    fn shifts(m: &[PatchMatch]) -> Vec<[f64; 2]> {
        m.iter()
            .map(|q| [q.b[0] - q.a[0], q.b[1] - q.a[1]])
            .collect()
    }

    /// A shifted copy of a smooth random texture (gain, offset and noise changed, periodic
    /// every 400 px along x as a facade's repeated windows): found at the true sub-pixel shift
    /// when the prediction is near it, the repeat when the prediction is near that, nothing
    /// when neither is within the search.
    #[test]
    fn synthetic_shift_found_subpixel_and_bounded_by_the_prediction() {
        let tex = Texture::new(100, 130, 4.0, 7);
        let truth = [-153.3, 20.6];
        let a = tex.render([640, 480], [0.0, 0.0], [1.0, 0.0], 1.0, 1);
        let b = tex.render([640, 480], truth, [0.8, 20.0], 1.0, 2);
        let p = RegisterParams::default();
        let t = std::time::Instant::now();
        let m = register_pair(&a, &b, [-120.0, 0.0], &p).expect("registered");
        let el = t.elapsed();
        let err: Vec<f64> = shifts(&m)
            .iter()
            .map(|s| (s[0] - truth[0]).hypot(s[1] - truth[1]))
            .collect();
        let max = err.iter().copied().fold(0.0, f64::max);
        let mut sorted = err.clone();
        sorted.sort_by(f64::total_cmp);
        eprintln!(
            "synthetic: {} matches in {el:?}, shift error median {:.3} px, max {max:.3} px",
            m.len(),
            sorted[sorted.len() / 2]
        );
        assert!(m.len() > 100, "{} matches", m.len());
        assert!(max < 0.15, "shift error up to {max} px");
        assert!(m.iter().all(|q| q.score > 0.9));
        // The repeat, 400 px to the right, when the prediction is near it.
        let m = register_pair(&a, &b, [220.0, 10.0], &p).expect("the repeat");
        for s in shifts(&m) {
            assert!(
                (s[0] - (truth[0] + 400.0)).abs() < 0.15 && (s[1] - truth[1]).abs() < 0.15,
                "{s:?}"
            );
        }
        // An unrelated texture: with the score threshold low enough for peaks to count, they
        // scatter and too few agree.
        let other =
            Texture::new(100, 130, 4.0, 8).render([640, 480], [0.0, 0.0], [1.0, 0.0], 1.0, 3);
        let loose = RegisterParams {
            min_score: 0.25,
            ..p.clone()
        };
        assert!(register_pair(&a, &other, [-120.0, 0.0], &loose).is_none());
        // Neither within the search (rows 30 px and more off): nothing.
        assert!(register_pair(&a, &b, [-150.0, 200.0], &p).is_none());
    }

    /// Sub-pixel accuracy over fractional shifts (the bias of the peak fit).
    #[test]
    fn synthetic_subpixel_bias_is_small_over_fractions() {
        let tex = Texture::new(60, 40, 4.0, 11);
        let a = tex.render([240, 160], [0.0, 0.0], [1.0, 0.0], 0.5, 3);
        let p = RegisterParams {
            search_px: 20.0,
            ..RegisterParams::default()
        };
        let mut worst: f64 = 0.0;
        for k in 0..10 {
            let f = k as f64 / 10.0;
            let truth = [-10.0 - f, 5.0 + 0.7 * f];
            let b = tex.render([240, 160], truth, [1.1, -10.0], 0.5, 4 + k);
            let m = register_pair(&a, &b, [-10.0, 5.0], &p).expect("registered");
            let s = shifts(&m);
            let mean = [
                s.iter().map(|v| v[0]).sum::<f64>() / s.len() as f64,
                s.iter().map(|v| v[1]).sum::<f64>() / s.len() as f64,
            ];
            let e = [mean[0] - truth[0], mean[1] - truth[1]];
            eprintln!(
                "fraction {f:.1}: mean error ({:+.3}, {:+.3}) px over {} patches",
                e[0],
                e[1],
                s.len()
            );
            worst = worst.max(e[0].abs()).max(e[1].abs());
        }
        assert!(worst < 0.05, "mean error up to {worst} px");
    }

    /// Identity and translation homographies; outside the source is `NaN`; a singular matrix
    /// gives no data.
    #[test]
    fn warp_identity_translation_and_outside() {
        let (w, h) = (40, 30);
        let data: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 101) as f32).collect();
        let src = Grey::new(w, h, data).unwrap();
        assert_eq!(warp_homography(&src, &Matrix3::identity(), w, h), src);
        // A linear ramp is reproduced exactly by bilinear interpolation.
        let ramp = Grey::new(
            w,
            h,
            (0..w * h)
                .map(|i| (3 * (i % w) + 5 * (i / w)) as f32)
                .collect(),
        )
        .unwrap();
        let (tx, ty) = (2.5, -1.25);
        let t = Matrix3::new(1.0, 0.0, tx, 0.0, 1.0, ty, 0.0, 0.0, 1.0);
        let out = warp_homography(&ramp, &t, w, h);
        for y in 0..h {
            for x in 0..w {
                let (sx, sy) = (x as f64 - tx, y as f64 - ty);
                let v = out.get(x, y);
                if sx < 0.0 || sy > (h - 1) as f64 {
                    assert!(v.is_nan(), "({x}, {y}) = {v}");
                } else {
                    assert!(
                        (f64::from(v) - (3.0 * sx + 5.0 * sy)).abs() < 1e-3,
                        "({x}, {y}) = {v}"
                    );
                }
            }
        }
        // A larger output than the source: its extra pixels have no data.
        let big = warp_homography(&src, &Matrix3::identity(), w + 5, h);
        assert!(big.get(w + 2, 3).is_nan() && big.get(w - 1, 3) == src.get(w - 1, 3));
        let singular = Matrix3::new(1.0, 2.0, 0.0, 2.0, 4.0, 0.0, 0.0, 0.0, 1.0);
        assert!(
            warp_homography(&src, &singular, w, h)
                .data
                .iter()
                .all(|v| v.is_nan())
        );
    }

    /// CLAHE against OpenCV's `createCLAHE(2.0, (8, 8)).apply` on an 8-bit test image (values
    /// from Python: `v = (7x + 13y + xy mod 17) mod 256`, `v // 4 + 100` for x < 40); OpenCV
    /// rounds its maps and its output, so within 1.
    #[test]
    fn clahe_as_opencv_and_nan_aware() {
        let (w, h) = (64usize, 48usize);
        let v = |x: usize, y: usize| {
            let v = (x * 7 + y * 13 + (x * y) % 17) % 256;
            if x < 40 { v / 4 + 100 } else { v }
        };
        let img = Grey::new(w, h, (0..w * h).map(|i| v(i % w, i / w) as f32).collect()).unwrap();
        let out = clahe(&img, 2.0, [8, 8]);
        let opencv = [
            (0, 0, 53),
            (5, 3, 161),
            (17, 20, 132),
            (33, 9, 153),
            (39, 47, 175),
            (40, 0, 14),
            (52, 30, 255),
            (63, 47, 58),
            (20, 40, 153),
            (10, 25, 142),
        ];
        for (x, y, e) in opencv {
            assert!(
                (out.get(x, y) - e as f32).abs() <= 1.0,
                "({x}, {y}): {} vs {e}",
                out.get(x, y)
            );
        }
        let sum: f64 = out.data.iter().map(|&v| f64::from(v)).sum();
        assert!(
            (sum / (w * h) as f64 - 434668.0 / (w * h) as f64).abs() < 0.5,
            "mean {}",
            sum / (w * h) as f64
        );
        // No data stays no data, the rest is still mapped.
        let mut holed = img.clone();
        for y in 10..20 {
            for x in 0..w {
                holed.data[y * w + x] = f32::NAN;
            }
        }
        let out = clahe(&holed, 2.0, [8, 8]);
        for (i, (&o, &s)) in out.data.iter().zip(&holed.data).enumerate() {
            assert_eq!(o.is_nan(), s.is_nan(), "pixel {i}");
        }
        assert!(
            clahe(&Grey::filled(w, h, f32::NAN), 2.0, [8, 8])
                .data
                .iter()
                .all(|v| v.is_nan())
        );
    }

    /// Flat images, images without data, images too small for a patch, a broken image and
    /// zero-sized parameters: no registration, no panic.
    #[test]
    fn flat_or_missing_data_is_not_registered() {
        let p = RegisterParams::default();
        let flat = Grey::filled(640, 480, 100.0);
        let none = Grey::filled(640, 480, f32::NAN);
        let tex = Texture::new(100, 130, 4.0, 5).render([640, 480], [0.0, 0.0], [1.0, 0.0], 1.0, 9);
        assert!(register_pair(&flat, &flat, [0.0, 0.0], &p).is_none());
        assert!(register_pair(&none, &none, [0.0, 0.0], &p).is_none());
        assert!(register_pair(&tex, &none, [0.0, 0.0], &p).is_none());
        assert!(register_pair(&tex, &flat, [0.0, 0.0], &p).is_none());
        assert!(register_pair(&none, &tex, [0.0, 0.0], &p).is_none());
        let small = Grey::filled(20, 10, 1.0);
        assert!(register_pair(&small, &small, [0.0, 0.0], &p).is_none());
        let broken = Grey {
            width: 640,
            height: 480,
            data: vec![1.0; 7],
        };
        assert!(register_pair(&broken, &tex, [0.0, 0.0], &p).is_none());
        assert!(register_pair(&tex, &tex, [f64::NAN, 0.0], &p).is_none());
        for bad in [
            RegisterParams {
                half_patch: 0,
                ..p.clone()
            },
            RegisterParams {
                stride: 0,
                ..p.clone()
            },
            RegisterParams {
                search_px: f64::NAN,
                ..p.clone()
            },
            RegisterParams {
                search_px: -1.0,
                ..p.clone()
            },
        ] {
            assert!(
                register_pair(&tex, &tex, [0.0, 0.0], &bad).is_none(),
                "{bad:?}"
            );
        }
        // Low contrast (std ~3.5 in 8-bit units): below `min_std`, skipped; registered with a
        // lower gate.
        let faint =
            Texture::new(100, 130, 4.0, 5).render([640, 480], [0.0, 0.0], [0.1, 100.0], 0.1, 9);
        assert!(register_pair(&faint, &faint, [0.0, 0.0], &p).is_none());
        let low = RegisterParams {
            min_std: 1.0,
            ..p.clone()
        };
        assert!(register_pair(&faint, &faint, [0.0, 0.0], &low).is_some());
        // The same textured image registers with itself (so the cases above fail for their reason).
        let m = register_pair(&tex, &tex, [3.0, -2.0], &p).unwrap();
        assert!(
            shifts(&m)
                .iter()
                .all(|s| s[0].abs() < 0.01 && s[1].abs() < 0.01)
        );
        // Half of b without data: only the patches that land in the other half match.
        let mut half = tex.clone();
        for v in &mut half.data[..640 * 240] {
            *v = f32::NAN;
        }
        let m = register_pair(&tex, &half, [0.0, 0.0], &p).unwrap();
        assert!(m.iter().all(|q| q.b[1] - 31.5 >= 240.0));
    }

    /// The thermal-facade images, when the shared data is there.
    fn facade_images() -> Option<std::path::PathBuf> {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/thermal-facade/images");
        dir.is_dir().then_some(dir)
    }

    /// A DJI thermal JPEG as the Python script reads it: decoded, grey by OpenCV's weights,
    /// undistorted with one radial term (`initUndistortRectifyMap` + `remap`, bilinear, the new
    /// camera matrix the old one: focal `f`, centre at the middle).
    fn load_undistorted(path: &std::path::Path, f: f64, k1: f64) -> Grey {
        let g = Grey::from_rgb8(&image::open(path).unwrap().to_rgb8());
        let (w, h) = (g.width, g.height);
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let mut out = Grey::filled(w, h, f32::NAN);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = ((u as f64 - cx) / f, (v as f64 - cy) / f);
                let s = 1.0 + k1 * (x * x + y * y);
                out.data[v * w + u] = g.sample(f * x * s + cx, f * y * s + cy);
            }
        }
        out
    }

    /// Two neighbouring shots of the facade (DJI_0600 and DJI_0602, a row's neighbours, 1 m
    /// apart; their gimbal angles are the reference orientation, so the script's homography is
    /// the identity) through this module's chain against OpenCV's.
    ///
    /// Reference, measured once with Python (`python3-opencv` 4.x): each image read by
    /// `cv2.imread`, `cvtColor(BGR2GRAY)`, undistorted (`initUndistortRectifyMap`, f = 589,
    /// k1 = −0.28, `remap` bilinear), `createCLAHE(2.0, (8, 8)).apply`; each 64-px patch of the
    /// script's grid (std ≥ 6) searched by `matchTemplate(TM_CCOEFF_NORMED)` within 170 px of
    /// the GPS-predicted shift (−205.2, 0), its integer peak refined by the same parabola per axis
    /// on the result surface. 184 patches peak at ≥ 0.5 inside the window, 108 agree within 4 px
    /// of their median; median shift of those (−146.117, 1.895). Below, every tenth of them:
    /// (patch top-left x, y; shift x, y).
    #[test]
    fn real_pair_matches_opencv_within_half_a_pixel() {
        let Some(dir) = facade_images() else {
            eprintln!(
                "skipped: no thermal-facade images beside the repository (shared/data/thermal-facade)"
            );
            return;
        };
        const OPENCV: [(usize, usize, f64, f64); 11] = [
            (304, 48, -144.098, 1.749),
            (400, 80, -147.567, 2.241),
            (400, 112, -148.022, 1.980),
            (432, 144, -147.622, 1.577),
            (400, 176, -147.683, 2.297),
            (400, 208, -146.484, 1.691),
            (368, 240, -148.456, 1.359),
            (336, 272, -145.733, 1.495),
            (368, 304, -143.079, 2.095),
            (336, 336, -145.677, 2.351),
            (368, 368, -145.444, -0.227),
        ];
        let t = std::time::Instant::now();
        let a = clahe(
            &load_undistorted(&dir.join("DJI_0600.JPG"), 589.0, -0.28),
            2.0,
            [8, 8],
        );
        let b = clahe(
            &load_undistorted(&dir.join("DJI_0602.JPG"), 589.0, -0.28),
            2.0,
            [8, 8],
        );
        let prepared = t.elapsed();
        let t = std::time::Instant::now();
        let m =
            register_pair(&a, &b, [-205.224, 0.0], &RegisterParams::default()).expect("registered");
        let registered = t.elapsed();
        let s = shifts(&m);
        let median = |k: usize| {
            let mut v: Vec<f64> = s.iter().map(|x| x[k]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let mut worst: f64 = 0.0;
        let mut common = 0;
        for (px, py, sx, sy) in OPENCV {
            let centre = [px as f64 + 31.5, py as f64 + 31.5];
            if let Some(q) = m.iter().find(|q| q.a == centre) {
                common += 1;
                worst = worst.max((q.b[0] - q.a[0] - sx).hypot(q.b[1] - q.a[1] - sy));
            }
        }
        eprintln!(
            "real pair: prepared in {prepared:?}, registered in {registered:?}: {} matches, median shift \
             ({:.3}, {:.3}); {common} of the {} OpenCV patches among them, off by up to {worst:.3} px",
            m.len(),
            median(0),
            median(1),
            OPENCV.len()
        );
        assert!((90..=125).contains(&m.len()), "{} matches", m.len());
        assert!((median(0) + 146.117).abs() < 0.2 && (median(1) - 1.895).abs() < 0.2);
        assert!(common >= 10, "{common} patches in common");
        assert!(worst < 0.5, "{worst} px from OpenCV");
    }
}
