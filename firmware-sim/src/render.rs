//! Rendering planes and simple scenes through the calibrated camera model.
//!
//! Pixel coordinates follow OpenCV: (0, 0) is the centre of the top-left pixel, so pixel
//! (u, v) covers [u − ½, u + ½] × [v − ½, v + ½]. The undistorted ray of every pixel *corner*
//! is computed once per camera ([`RayGrid`], Newton inversion of Brown–Conrady); rays inside
//! a pixel are bilinear between its corner rays (the distortion varies by < 10⁻³ px across
//! one pixel for the models used here).
//!
//! Planar textures ([`render_plane`]) are area-integrated: each pixel is split into `sub × sub`
//! sub-pixels (≥ 4 × 4), every sub-pixel's footprint is mapped onto the plane as a
//! quadrilateral and clipped against the texture's cells (the squares of a checkerboard), so
//! an edge's contribution is its exact covered area rather than a count of point samples.
//! Pixels whose four corners fall in one cell take the cell's value at the pixel centre.

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use s3tir_calib::{CameraModel, Rigid3};

/// A texture on the plane z = 0 of its own frame, piecewise smooth on a square grid.
pub trait PlaneTexture: Sync {
    /// Edge length of the grid cells inside which the texture is smooth, metres.
    fn cell_m(&self) -> f64;
    /// Value at (x, y); `None` off the textured area (the background shows).
    fn value(&self, x_m: f64, y_m: f64) -> Option<f64>;
}

/// Undistorted normalised rays through every pixel corner of a camera.
#[derive(Debug, Clone)]
pub struct RayGrid {
    width: usize,
    height: usize,
    /// (width + 1) × (height + 1) corner rays (x/z, y/z); NaN where undistortion failed.
    corners: Vec<DVec2>,
}

impl RayGrid {
    pub fn new(cam: &CameraModel) -> Self {
        let (w, h) = (cam.width_px as usize, cam.height_px as usize);
        let mut corners = Vec::with_capacity((w + 1) * (h + 1));
        for j in 0..=h {
            for i in 0..=w {
                let px = DVec2::new(i as f64 - 0.5, j as f64 - 0.5);
                corners.push(
                    cam.unproject(px)
                        .map(|r| DVec2::new(r.x, r.y))
                        .unwrap_or(DVec2::NAN),
                );
            }
        }
        Self {
            width: w,
            height: h,
            corners,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Ray at fractional position (a, b) ∈ [0,1]² inside pixel (u, v).
    fn ray(&self, u: usize, v: usize, a: f64, b: f64) -> DVec2 {
        let stride = self.width + 1;
        let c00 = self.corners[v * stride + u];
        let c10 = self.corners[v * stride + u + 1];
        let c01 = self.corners[(v + 1) * stride + u];
        let c11 = self.corners[(v + 1) * stride + u + 1];
        (c00 * (1.0 - a) + c10 * a) * (1.0 - b) + (c01 * (1.0 - a) + c11 * a) * b
    }

    /// The normalised ray of each pixel centre (for depth maps and scene rendering).
    pub fn centre_ray(&self, u: usize, v: usize) -> DVec3 {
        let r = self.ray(u, v, 0.5, 0.5);
        DVec3::new(r.x, r.y, 1.0)
    }

    /// Ray at sub-pixel (a, b) of pixel (u, v), as a direction with z = 1.
    pub fn sub_ray(&self, u: usize, v: usize, a: f64, b: f64) -> DVec3 {
        let r = self.ray(u, v, a, b);
        DVec3::new(r.x, r.y, 1.0)
    }
}

/// The plane z = 0 of a plane frame, seen from the camera: intersections in closed form.
struct PlaneHitter {
    /// Plane normal in the camera frame and its offset (n · p = d on the plane).
    normal: DVec3,
    offset: f64,
    plane_from_cam_rot: glam::DMat3,
    cam_from_plane_t: DVec3,
}

impl PlaneHitter {
    fn new(cam_from_plane: &Rigid3) -> Self {
        let rot = cam_from_plane.rotation_matrix();
        let normal = rot * DVec3::Z;
        Self {
            normal,
            offset: normal.dot(cam_from_plane.translation_m),
            plane_from_cam_rot: rot.transpose(),
            cam_from_plane_t: cam_from_plane.translation_m,
        }
    }

    /// Plane coordinates where the camera ray `dir_cam` meets the plane, if in front.
    #[inline]
    fn hit(&self, dir_cam: DVec3) -> Option<DVec2> {
        let denom = self.normal.dot(dir_cam);
        if !denom.is_finite() || denom.abs() < 1e-12 {
            return None;
        }
        let t = self.offset / denom;
        if t <= 0.0 {
            return None;
        }
        let p = self.plane_from_cam_rot * (dir_cam * t - self.cam_from_plane_t);
        Some(DVec2::new(p.x, p.y))
    }
}

/// Renders a planar texture: per pixel, the area-average of the texture (or `background`).
/// Returns `width × height` values, row-major.
pub fn render_plane(
    grid: &RayGrid,
    cam_from_plane: &Rigid3,
    sub: u32,
    texture: &dyn PlaneTexture,
    background: f64,
) -> Vec<f64> {
    let hitter = PlaneHitter::new(cam_from_plane);
    let (w, h) = (grid.width, grid.height);
    let stride = w + 1;
    // Plane hits of all pixel corners.
    let hits: Vec<Option<DVec2>> = grid
        .corners
        .iter()
        .map(|r| hitter.hit(DVec3::new(r.x, r.y, 1.0)))
        .collect();
    let cell = texture.cell_m();
    let sub = sub.max(1) as usize;
    let mut out = vec![background; w * h];
    if w == 0 {
        return out;
    }
    // Rows are independent: rendered in parallel, each pixel as alone (the result does not
    // depend on the thread count).
    out.par_chunks_mut(w).enumerate().for_each_init(
        || vec![None; (sub + 1) * (sub + 1)],
        |sub_hits, (v, row)| {
            for (u, px) in row.iter_mut().enumerate() {
                *px = render_pixel(
                    grid, &hitter, &hits, stride, u, v, sub, cell, texture, background, sub_hits,
                );
            }
        },
    );
    out
}

/// One pixel of [`render_plane`].
#[allow(clippy::too_many_arguments)]
fn render_pixel(
    grid: &RayGrid,
    hitter: &PlaneHitter,
    hits: &[Option<DVec2>],
    stride: usize,
    u: usize,
    v: usize,
    sub: usize,
    cell: f64,
    texture: &dyn PlaneTexture,
    background: f64,
    sub_hits: &mut [Option<DVec2>],
) -> f64 {
    let cell_of = |p: DVec2| ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
    let c = [
        hits[v * stride + u],
        hits[v * stride + u + 1],
        hits[(v + 1) * stride + u],
        hits[(v + 1) * stride + u + 1],
    ];
    if let [Some(a), Some(b), Some(cc), Some(d)] = c {
        let k = cell_of(a);
        if cell_of(b) == k && cell_of(cc) == k && cell_of(d) == k {
            // One cell (convex): the value at the pixel centre.
            return hitter
                .hit(grid.centre_ray(u, v))
                .and_then(|p| texture.value(p.x, p.y))
                .unwrap_or(background);
        }
    } else if c.iter().all(Option::is_none) {
        return background;
    }
    // Edge pixel: sub × sub sub-pixels, each area-integrated over the cells it covers.
    for j in 0..=sub {
        for i in 0..=sub {
            let ray = grid.sub_ray(u, v, i as f64 / sub as f64, j as f64 / sub as f64);
            sub_hits[j * (sub + 1) + i] = hitter.hit(ray);
        }
    }
    let mut acc = 0.0;
    for j in 0..sub {
        for i in 0..sub {
            let q = [
                sub_hits[j * (sub + 1) + i],
                sub_hits[j * (sub + 1) + i + 1],
                sub_hits[(j + 1) * (sub + 1) + i + 1],
                sub_hits[(j + 1) * (sub + 1) + i],
            ];
            acc += match q {
                [Some(a), Some(b), Some(cc), Some(d)] => {
                    quad_average(&[a, b, cc, d], cell, texture, background)
                }
                _ => {
                    // Part of the sub-pixel sees past the horizon: point-sample its centre.
                    let ray = grid.sub_ray(
                        u,
                        v,
                        (i as f64 + 0.5) / sub as f64,
                        (j as f64 + 0.5) / sub as f64,
                    );
                    hitter
                        .hit(ray)
                        .and_then(|p| texture.value(p.x, p.y))
                        .unwrap_or(background)
                }
            };
        }
    }
    acc / (sub * sub) as f64
}

/// Area-average of the texture over a quadrilateral on the plane.
fn quad_average(quad: &[DVec2; 4], cell: f64, texture: &dyn PlaneTexture, background: f64) -> f64 {
    let total = polygon_area(quad).abs();
    let centroid = (quad[0] + quad[1] + quad[2] + quad[3]) / 4.0;
    if total.is_nan() || total <= 1e-18 {
        return texture.value(centroid.x, centroid.y).unwrap_or(background);
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in quad {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    let (i0, i1) = ((x0 / cell).floor() as i64, (x1 / cell).floor() as i64);
    let (j0, j1) = ((y0 / cell).floor() as i64, (y1 / cell).floor() as i64);
    if (i1 - i0 + 1) * (j1 - j0 + 1) > 64 {
        // Footprint spans many cells (far, grazing view): a point sample is as good as any.
        return texture.value(centroid.x, centroid.y).unwrap_or(background);
    }
    let mut acc = 0.0;
    for j in j0..=j1 {
        for i in i0..=i1 {
            let (cx0, cy0) = (i as f64 * cell, j as f64 * cell);
            let clipped = clip_to_rect(quad, cx0, cy0, cx0 + cell, cy0 + cell);
            let clipped = clipped.as_slice();
            if clipped.len() < 3 {
                continue;
            }
            let area = polygon_area(clipped).abs();
            if area <= 0.0 {
                continue;
            }
            let c = clipped.iter().copied().sum::<DVec2>() / clipped.len() as f64;
            acc += area * texture.value(c.x, c.y).unwrap_or(background);
        }
    }
    acc / total
}

/// Shoelace area (signed).
fn polygon_area(poly: &[DVec2]) -> f64 {
    let n = poly.len();
    let mut s = 0.0;
    for k in 0..n {
        let (a, b) = (poly[k], poly[(k + 1) % n]);
        s += a.x * b.y - b.x * a.y;
    }
    s / 2.0
}

/// A convex polygon of at most 8 vertices (a quadrilateral clipped by 4 half-planes).
#[derive(Clone, Copy)]
struct Poly {
    pts: [DVec2; 8],
    n: usize,
}

impl Poly {
    fn as_slice(&self) -> &[DVec2] {
        &self.pts[..self.n]
    }
}

/// Sutherland–Hodgman clip of a convex quadrilateral against an axis-aligned rectangle.
fn clip_to_rect(quad: &[DVec2; 4], x0: f64, y0: f64, x1: f64, y1: f64) -> Poly {
    let mut cur = Poly {
        pts: [DVec2::ZERO; 8],
        n: 4,
    };
    cur.pts[..4].copy_from_slice(quad);
    // (axis, bound, keep_greater)
    for (axis, bound, keep_ge) in [(0, x0, true), (0, x1, false), (1, y0, true), (1, y1, false)] {
        if cur.n == 0 {
            break;
        }
        let inside = |p: DVec2| {
            let c = if axis == 0 { p.x } else { p.y };
            if keep_ge { c >= bound } else { c <= bound }
        };
        let mut next = Poly {
            pts: [DVec2::ZERO; 8],
            n: 0,
        };
        for k in 0..cur.n {
            let a = cur.pts[k];
            let b = cur.pts[(k + 1) % cur.n];
            let (ia, ib) = (inside(a), inside(b));
            if ia && next.n < 8 {
                next.pts[next.n] = a;
                next.n += 1;
            }
            if ia != ib && next.n < 8 {
                let (ca, cb) = if axis == 0 { (a.x, b.x) } else { (a.y, b.y) };
                let t = (bound - ca) / (cb - ca);
                next.pts[next.n] = a + (b - a) * t;
                next.n += 1;
            }
        }
        cur = next;
    }
    cur
}

/// Separable Gaussian blur with clamp-to-edge borders; `sigma_px <= 0` returns the input.
pub fn gaussian_blur(img: &[f64], width: usize, height: usize, sigma_px: f64) -> Vec<f64> {
    if sigma_px <= 0.0 || width == 0 || height == 0 {
        return img.to_vec();
    }
    let radius = (3.0 * sigma_px).ceil() as isize;
    let kernel: Vec<f64> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma_px * sigma_px)).exp())
        .collect();
    let norm: f64 = kernel.iter().sum();
    let kernel: Vec<f64> = kernel.iter().map(|k| k / norm).collect();
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0.0; img.len()];
    for y in 0..height {
        for x in 0..width {
            let mut s = 0.0;
            for (k, wk) in kernel.iter().enumerate() {
                s += wk * img[y * width + clamp(x as isize + k as isize - radius, width)];
            }
            tmp[y * width + x] = s;
        }
    }
    let mut out = vec![0.0; img.len()];
    for y in 0..height {
        for x in 0..width {
            let mut s = 0.0;
            for (k, wk) in kernel.iter().enumerate() {
                s += wk * tmp[clamp(y as isize + k as isize - radius, height) * width + x];
            }
            out[y * width + x] = s;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    //! Proves: polygon clipping conserves area and the blur conserves the mean. The geometric
    //! accuracy of rendered corners is tested in `tests/render_geometry.rs`.
    use super::*;

    #[test]
    fn clipping_a_square_across_four_cells_conserves_area() {
        let quad = [
            DVec2::new(-0.3, -0.2),
            DVec2::new(0.7, -0.25),
            DVec2::new(0.75, 0.8),
            DVec2::new(-0.35, 0.7),
        ];
        let total = polygon_area(&quad).abs();
        let mut sum = 0.0;
        for j in -1..=0 {
            for i in -1..=0 {
                let c = clip_to_rect(
                    &quad,
                    f64::from(i),
                    f64::from(j),
                    f64::from(i + 1),
                    f64::from(j + 1),
                );
                sum += polygon_area(c.as_slice()).abs();
            }
        }
        assert!(
            (sum - total).abs() < 1e-12,
            "clipped areas sum {sum}, quad {total}"
        );
    }

    #[test]
    fn blur_conserves_a_flat_image_and_the_mean_of_a_spike() {
        let flat = vec![3.0; 20 * 10];
        let b = gaussian_blur(&flat, 20, 10, 1.2);
        assert!(
            b.iter().all(|v| (v - 3.0).abs() < 1e-12),
            "flat image must stay flat"
        );
        let mut spike = vec![0.0; 21 * 21];
        spike[10 * 21 + 10] = 1.0;
        let b = gaussian_blur(&spike, 21, 21, 1.0);
        let s: f64 = b.iter().sum();
        assert!((s - 1.0).abs() < 1e-12, "sum {s}");
    }
}
