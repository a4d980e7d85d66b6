//! A new run's starting state: initial primitives from the dataset's points (3DGS's
//! nearest-neighbour scales, under the hard budget) and the consistency pairs chosen once by
//! camera overlap.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{Backend, Trainer, params};
use crate::camera::PinholeCamera;
use crate::dataset::Dataset;
use crate::primitive::{BETA_RAW_FROZEN, PrimitiveInit, Primitives};

impl<B: Backend> Trainer<B> {
    pub(super) fn bands_for_mode(&self) -> usize {
        if self.cfg.mode.has_bands() {
            self.cfg.bands
        } else {
            0
        }
    }

    pub(super) fn initial_primitives(&mut self) -> Primitives<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ 0x5eed_1417);
        let sh = self.data.has_rgb().then_some(self.cfg.sh_degree);
        let mut prims = Primitives::<f64>::new(self.bands_for_mode(), sh);
        let mut pts: Vec<([f64; 3], [u8; 3])> = self
            .data
            .points_m
            .iter()
            .copied()
            .zip(self.data.point_rgb.iter().copied())
            .collect();
        let (lo, hi) = self.data.bounds_m();
        if pts.is_empty() {
            let n = self.cfg.budget.min(10_000);
            pts = (0..n)
                .map(|_| {
                    (
                        [0, 1, 2].map(|a| rng.random_range(lo[a]..=hi[a].max(lo[a] + 1e-9))),
                        [128; 3],
                    )
                })
                .collect();
        }
        // Hard budget: subsample (seeded partial shuffle).
        if pts.len() > self.cfg.budget {
            for i in 0..self.cfg.budget {
                let j = rng.random_range(i..pts.len());
                pts.swap(i, j);
            }
            pts.truncate(self.cfg.budget);
        }
        let positions: Vec<[f64; 3]> = pts.iter().map(|p| p.0).collect();
        let nn = knn3_mean_distance(&positions, lo, hi);
        let min_scale = f64::from(self.min_log_scale).exp();
        for (k, (p, rgb)) in pts.iter().enumerate() {
            // 3DGS initialises σ to the mean distance to the 3 nearest points; our kernel has no
            // ½, so s = √2·σ gives the same footprint.
            let s = (nn[k] * std::f64::consts::SQRT_2).max(min_scale);
            let bands = (0..prims.bands)
                .map(|_| {
                    let (freq, phase) = draw_band(&mut rng, s);
                    (0.0, freq, phase)
                })
                .collect();
            let c0 = crate::ply::SH_C0;
            prims.push(&PrimitiveInit {
                mean_m: *p,
                scale_m: [s; 3],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity: self.cfg.init_opacity,
                beta: 2.0,
                omega_low: self.data.thermal_at(*p).map_or(0.5, f64::from),
                bands,
                sh: vec![
                    (self.data.rgb_at(*p))
                        .unwrap_or_else(|| rgb.map(|c| f64::from(c) / 255.0))
                        .map(|c| (c - 0.5) / c0),
                ],
            });
        }
        let mut prims = prims.cast::<f32>();
        // β ≡ 2 during the warm-up (and for the whole run in modes without learnable β): frozen
        // on the cheap Gaussian path; released at the warm-up's end (see `step`).
        if !self.cfg.mode.learns_beta() || self.cfg.warmup > 0 {
            prims.beta_raw.fill(BETA_RAW_FROZEN as f32);
        }
        // The bands are off during the warm-up: no band storage at all (M = 0), so the
        // renderers do no band work and the gradients, Adam and uploads no band traffic — a
        // warm-up step costs what a 3dgs step does. (With the zero bands evaluated it cost
        // 1.38× more: 205 against 282 steps in the first 15 s on the simulated walk, Vulkan
        // on lavapipe; with M slots stored but idle still 1.12×: 127 against 144 steps in the
        // first 30 s on the real thermal-facade.) The storage grows to `cfg.bands` slots and
        // they go live at the warm-up's end (see `step`), their frequencies and phases drawn
        // from the primitives' scales at that time.
        if prims.bands > 0 && self.cfg.warmup > 0 {
            prims = params::compact_bands(&prims, &vec![Vec::new(); prims.len()], 0);
        }
        self.grad_accum = vec![0.0; prims.len()];
        self.grad_count = vec![0; prims.len()];
        prims
    }
}

/// A band's initial frequency (cycles per metre: a random direction, magnitude 0.5–2 cycles
/// per 4 scales `s`) and phase; its amplitude starts at 0.
pub(super) fn draw_band(rng: &mut ChaCha8Rng, s: f64) -> ([f64; 3], f64) {
    let d = random_unit(rng);
    let f = rng.random_range(0.5..2.0) / (4.0 * s);
    (
        [d[0] * f, d[1] * f, d[2] * f],
        rng.random_range(0.0..std::f64::consts::TAU),
    )
}

pub(super) fn random_unit(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let v: [f64; 3] = [0, 1, 2].map(|_| rng.random_range(-1.0..1.0));
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 0.1 && n <= 1.0 {
            return v.map(|x| x / n);
        }
    }
}

/// Mean distance to the 3 nearest neighbours (grid search over the 27 cells around each point;
/// a point with fewer neighbours there gets the mean of the others, or a scene-size default).
pub(super) fn knn3_mean_distance(pts: &[[f64; 3]], lo: [f64; 3], hi: [f64; 3]) -> Vec<f64> {
    use std::collections::HashMap;
    let n = pts.len();
    if n == 0 {
        return Vec::new();
    }
    let diag = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2))
        .sqrt()
        .max(1e-6);
    let cell = (diag / (n as f64).cbrt()).max(1e-9);
    let key = |p: &[f64; 3]| [0, 1, 2].map(|a| ((p[a] - lo[a]) / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in pts.iter().enumerate() {
        grid.entry(key(p)).or_default().push(i);
    }
    let mut out = vec![f64::NAN; n];
    for (i, p) in pts.iter().enumerate() {
        let k = key(p);
        let mut best = [f64::INFINITY; 3];
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &j in list {
                            if j == i {
                                continue;
                            }
                            let q = &pts[j];
                            let d = ((p[0] - q[0]).powi(2)
                                + (p[1] - q[1]).powi(2)
                                + (p[2] - q[2]).powi(2))
                            .sqrt();
                            if d < best[2] {
                                best[2] = d;
                                best.sort_by(f64::total_cmp);
                            }
                        }
                    }
                }
            }
        }
        let found: Vec<f64> = best
            .iter()
            .copied()
            .filter(|d| d.is_finite() && *d > 0.0)
            .collect();
        if !found.is_empty() {
            out[i] = found.iter().sum::<f64>() / found.len() as f64;
        }
    }
    let valid: Vec<f64> = out.iter().copied().filter(|d| d.is_finite()).collect();
    let fallback = if valid.is_empty() {
        cell
    } else {
        valid.iter().sum::<f64>() / valid.len() as f64
    };
    out.iter()
        .map(|d| if d.is_finite() { *d } else { fallback })
        .collect()
}

/// The fraction of a 6×6 grid of `a`'s rays, cut at the depth of the point `centre`, that
/// lands inside `b`'s image.
pub(super) fn view_overlap(a: &PinholeCamera, b: &PinholeCamera, centre: [f64; 3]) -> f64 {
    let depth = a.to_cam(centre)[2];
    if depth.is_nan() || depth <= 0.0 {
        return 0.0;
    }
    let mut hit = 0;
    const G: usize = 6;
    for gy in 0..G {
        for gx in 0..G {
            let u = (gx as f64 + 0.5) / G as f64 * a.width as f64 - 0.5;
            let v = (gy as f64 + 0.5) / G as f64 * a.height as f64 - 0.5;
            let pc = b.to_cam(a.unproject(u, v, depth));
            if pc[2] > 0.0 {
                let [x, y] = b.project_cam(pc);
                if x >= 0.0 && y >= 0.0 && x <= (b.width - 1) as f64 && y <= (b.height - 1) as f64 {
                    hit += 1;
                }
            }
        }
    }
    f64::from(hit) / (G * G) as f64
}

/// Overlap partner of every training view (see the module docs), and every training view's
/// overlapping views (overlap ≥ `min_overlap`, ascending index, same modality).
pub(super) fn choose_pairs(
    data: &Dataset,
    centre: [f64; 3],
    min_overlap: f64,
) -> (Vec<Option<usize>>, Vec<Vec<usize>>) {
    let overlap = |a: &PinholeCamera, b: &PinholeCamera| view_overlap(a, b, centre);
    let mut pairs = vec![None; data.views.len()];
    let mut neighbours = vec![Vec::new(); data.views.len()];
    for &i in &data.train {
        let a = &data.views[i].camera;
        let ca = a.centre_world();
        let mut best: Option<(f64, usize)> = None;
        let thermal = data.views[i].thermal.is_some();
        for &j in &data.train {
            // Pairs within one modality: the term regularises the thermal head's Ψ buffers,
            // and a joint run's RGB steps would only dilute the thermal views' pairs.
            if j == i || data.views[j].thermal.is_some() != thermal {
                continue;
            }
            let b = &data.views[j].camera;
            let cb = b.centre_world();
            let baseline =
                ((ca[0] - cb[0]).powi(2) + (ca[1] - cb[1]).powi(2) + (ca[2] - cb[2]).powi(2))
                    .sqrt();
            if baseline < 1e-9 {
                continue;
            }
            let o = overlap(a, b);
            if o >= min_overlap {
                neighbours[i].push(j);
                if best.is_none_or(|(bo, _)| o > bo) {
                    best = Some((o, j));
                }
            }
        }
        pairs[i] = best.map(|b| b.1);
    }
    (pairs, neighbours)
}
