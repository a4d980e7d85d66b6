//! Shared helpers of the trainer's integration tests (and of `benches/cpu_render.rs`): seeded
//! scenes (the GPU parity tests' [`parity_scene`], the CPU renderer's [`field_scene`]), cameras
//! and a central-difference gradient checker. Not a test by itself.
#![allow(dead_code, clippy::unwrap_used)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::primitive::{PrimitiveInit, Primitives};
use s3tir_trainer::real::Real;
use s3tir_trainer::render::{GBuffers, RenderSettings, render, render_backward};

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `n` values drawn uniformly from `[lo, hi)` with `seed` (an image plane or a buffer).
pub fn random_plane(seed: u64, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    let mut r = rng(seed);
    (0..n).map(|_| r.random_range(lo..hi)).collect()
}

/// Camera at the origin looking down +z (world = camera frame).
pub fn front_camera(width: usize, height: usize, f_px: f64) -> PinholeCamera {
    PinholeCamera::look_at(
        [0.0; 3],
        [0.0, 0.0, 1.0],
        [0.0, -1.0, 0.0],
        f_px,
        width,
        height,
    )
}

/// World point that camera `cam` sees at pixel `(u, v)` with depth `z`.
pub fn point_at_pixel(cam: &PinholeCamera, u: f64, v: f64, z: f64) -> [f64; 3] {
    cam.unproject(u, v, z)
}

pub fn random_quat(r: &mut ChaCha8Rng) -> [f64; 4] {
    [
        r.random_range(-1.0..1.0),
        r.random_range(-1.0..1.0),
        r.random_range(-1.0..1.0),
        r.random_range(-1.0..1.0),
    ]
}

/// A random primitive near `centre` with the given β, `bands` bands and SH degree `sh_degree`.
pub fn random_primitive(
    r: &mut ChaCha8Rng,
    centre: [f64; 3],
    beta: f64,
    bands: usize,
    sh_k: usize,
) -> PrimitiveInit {
    PrimitiveInit {
        mean_m: [
            centre[0] + r.random_range(-0.3..0.3),
            centre[1] + r.random_range(-0.3..0.3),
            centre[2] + r.random_range(-0.3..0.3),
        ],
        scale_m: [
            r.random_range(0.2..0.6),
            r.random_range(0.2..0.6),
            r.random_range(0.2..0.6),
        ],
        quat: random_quat(r),
        opacity: r.random_range(0.3..0.85),
        beta,
        omega_low: r.random_range(0.4..0.9),
        bands: (0..bands)
            .map(|_| {
                (
                    r.random_range(-0.15..0.15),
                    [
                        r.random_range(-0.8..0.8),
                        r.random_range(-0.8..0.8),
                        r.random_range(-0.8..0.8),
                    ],
                    r.random_range(-3.0..3.0),
                )
            })
            .collect(),
        sh: (0..sh_k)
            .map(|_| {
                [
                    r.random_range(-0.1..0.1),
                    r.random_range(-0.1..0.1),
                    r.random_range(-0.1..0.1),
                ]
            })
            .collect(),
    }
}

/// Random upstream gradients for every buffer (the linear functional whose gradient is checked).
pub fn random_upstream<T: Real>(r: &mut ChaCha8Rng, like: &GBuffers<T>) -> GBuffers<T> {
    let mut g = GBuffers::zeros(like.width, like.height, !like.rgb.is_empty());
    for (_, v) in g.planes_mut() {
        for x in v.iter_mut() {
            *x = T::from_f64(r.random_range(-1.0..1.0));
        }
    }
    g
}

/// `Σ upstream · buffers`.
pub fn dot_buffers<T: Real>(a: &GBuffers<T>, b: &GBuffers<T>) -> f64 {
    a.planes()
        .iter()
        .zip(b.planes().iter())
        .map(|((_, x), (_, y))| {
            x.iter()
                .zip(y.iter())
                .map(|(p, q)| p.to_f64() * q.to_f64())
                .sum::<f64>()
        })
        .sum()
}

/// Worst disagreement between the analytic render gradient and central differences, per
/// parameter group: returns `(group, index, analytic, numeric)` for every entry that fails
/// `|a − n| ≤ atol + rtol·max(|a|, |n|)`, plus the number of entries checked.
pub fn check_render_gradient(
    prims: &Primitives<f64>,
    cam: &PinholeCamera,
    settings: &RenderSettings,
    seed: u64,
    h: f64,
    atol: f64,
    rtol: f64,
) -> (Vec<(String, usize, f64, f64)>, usize) {
    let out = render(prims, cam, settings).unwrap();
    let mut r = rng(seed);
    let up = random_upstream(&mut r, &out);
    let grads = render_backward(prims, cam, settings, &up).unwrap();
    let loss = |p: &Primitives<f64>| dot_buffers(&render(p, cam, settings).unwrap(), &up);
    let mut failures = Vec::new();
    let mut checked = 0;
    let names: Vec<&'static str> = prims.groups().iter().map(|(n, _)| n.name()).collect();
    for (gi, name) in names.iter().enumerate() {
        let len = prims.groups()[gi].1.len();
        for k in 0..len {
            let mut plus = prims.clone();
            plus.groups_mut()[gi].1[k] += h;
            let mut minus = prims.clone();
            minus.groups_mut()[gi].1[k] -= h;
            let numeric = (loss(&plus) - loss(&minus)) / (2.0 * h);
            let analytic = grads.groups()[gi].1[k];
            checked += 1;
            let ok = (analytic - numeric).abs() <= atol + rtol * analytic.abs().max(numeric.abs());
            if !ok || !analytic.is_finite() {
                failures.push((name.to_string(), k, analytic, numeric));
            }
        }
        // A group whose gradient is identically zero would pass vacuously.
        if len > 0 && grads.groups()[gi].1.iter().all(|g| g.abs() < 1e-9) {
            failures.push((format!("{name} (identically zero)"), 0, 0.0, 0.0));
        }
    }
    (failures, checked)
}

/// Largest |x| over every buffer.
pub fn max_abs_buffers<T: Real>(b: &GBuffers<T>) -> f64 {
    b.planes()
        .iter()
        .flat_map(|(_, v)| v.iter())
        .fold(0.0f64, |m, x| m.max(x.to_f64().abs()))
}

// ---- Adam for the fitting tests (the trainer's own optimiser lives in `train::adam`) ----

/// Learning rates per parameter group, in the order of [`Primitives::groups`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroupLr {
    pub means: f64,
    pub log_scales: f64,
    pub quats: f64,
    pub opacity_logits: f64,
    pub beta_raw: f64,
    pub omega_low: f64,
    pub band_amp: f64,
    pub band_freq: f64,
    pub band_phase: f64,
    pub sh: f64,
}

impl GroupLr {
    fn as_array(&self) -> [f64; 10] {
        [
            self.means,
            self.log_scales,
            self.quats,
            self.opacity_logits,
            self.beta_raw,
            self.omega_low,
            self.band_amp,
            self.band_freq,
            self.band_phase,
            self.sh,
        ]
    }
}

/// Adam (Kingma & Ba) with bias correction.
#[derive(Debug, Clone)]
pub struct Adam<T> {
    pub lr: GroupLr,
    pub beta1: f64,
    pub beta2: f64,
    pub epsilon: f64,
    step: u32,
    m: Primitives<T>,
    v: Primitives<T>,
}

impl<T: Real> Adam<T> {
    /// State shaped like `params` with the usual β1 = 0.9, β2 = 0.999, ε = 1e-15 (3DGS's ε).
    pub fn new(params: &Primitives<T>, lr: GroupLr) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-15,
            step: 0,
            m: params.zeros_like(),
            v: params.zeros_like(),
        }
    }

    /// One update `params −= lr · m̂ / (√v̂ + ε)`. The shapes must match the construction's.
    pub fn step(&mut self, params: &mut Primitives<T>, grads: &Primitives<T>) {
        self.step += 1;
        let t = f64::from(self.step);
        let bc1 = 1.0 - self.beta1.powf(t);
        let bc2 = 1.0 - self.beta2.powf(t);
        let (b1, b2, eps) = (
            T::from_f64(self.beta1),
            T::from_f64(self.beta2),
            T::from_f64(self.epsilon),
        );
        let lrs = self.lr.as_array();
        let grads_g = grads.groups();
        let m_g = self.m.groups_mut();
        let v_g = self.v.groups_mut();
        for ((((_, p), (_, g)), (_, m)), ((_, v), lr)) in params
            .groups_mut()
            .into_iter()
            .zip(grads_g)
            .zip(m_g)
            .zip(v_g.into_iter().zip(lrs))
        {
            if lr == 0.0 {
                continue;
            }
            let step = T::from_f64(lr / bc1);
            let c2 = T::from_f64(bc2);
            for (((pk, gk), mk), vk) in p
                .iter_mut()
                .zip(g.iter())
                .zip(m.iter_mut())
                .zip(v.iter_mut())
            {
                *mk = b1 * *mk + (T::ONE - b1) * *gk;
                *vk = b2 * *vk + (T::ONE - b2) * *gk * *gk;
                *pk -= step * *mk / ((*vk / c2).sqrt() + eps);
            }
        }
    }
}

// ---- Random scenes of the GPU parity tests and of the CPU renderer's thread/bench checks ----

/// The camera of the GPU parity tests (`gpu_raster.rs`, `gpu_colour.rs`): off-axis, looking at
/// the middle of [`parity_scene`]'s primitives, focal length 0.9 × width.
pub fn parity_camera(width: usize, height: usize) -> PinholeCamera {
    PinholeCamera::look_at(
        [0.3, -0.2, -0.5],
        [0.0, 0.0, 3.0],
        [0.0, -1.0, 0.0],
        0.9 * width as f64,
        width,
        height,
    )
}

/// How [`parity_scene`] draws its primitives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParityScene {
    /// Random primitives.
    pub n: usize,
    pub bands: usize,
    /// SH degree of the colour; `None`: thermal only. Degree-0 coefficients in ±2.5 put some
    /// colours below zero (the ReLU), degree-k ones in ±1/k.
    pub sh_degree: Option<usize>,
    /// β is 2 for every fifth primitive (from the first), else drawn from `[2, beta_max)`.
    pub beta_max: f64,
    /// The stiff cases: β = 64 for every fifth primitive (from the second), opacity 0.999 (the
    /// α clamp) for every seventh, a needle or pancake (one scale 1e-3) for every eleventh.
    pub stiff: bool,
    /// Each primitive's opacity is drawn before its mean, also when the stiff case pins it at
    /// 0.999 (`gpu_colour.rs`'s random stream); otherwise after its rotation and only when not
    /// pinned (`gpu_raster.rs`'s). Only the stream differs: each test's seeds keep giving the
    /// scenes its bounds were measured on.
    pub opacity_first: bool,
    /// Three more primitives: one straddling the near plane (a full-image rectangle), one
    /// behind the camera, one huge and far.
    pub extras: bool,
}

/// A random scene in front of [`parity_camera`], drawn with `seed` as `spec` says.
pub fn parity_scene(seed: u64, spec: &ParityScene) -> Primitives<f64> {
    let mut r = rng(seed);
    let bands = spec.bands;
    let mut prims = Primitives::new(bands, spec.sh_degree);
    let sh_k = prims.sh_k();
    for i in 0..spec.n {
        let beta = if i % 5 == 0 {
            2.0
        } else if spec.stiff && i % 5 == 1 {
            64.0
        } else {
            r.random_range(2.0..spec.beta_max)
        };
        let mut scale_m = [
            r.random_range(0.05..0.5),
            r.random_range(0.05..0.5),
            r.random_range(0.05..0.5),
        ];
        if spec.stiff && i % 11 == 0 {
            scale_m[r.random_range(0..3)] = 1e-3; // needle / pancake
        }
        let pinned = spec.stiff && i % 7 == 0;
        let early_opacity = spec.opacity_first.then(|| r.random_range(0.05..0.9));
        let mean_m = [
            r.random_range(-1.5..1.5),
            r.random_range(-1.2..1.2),
            r.random_range(1.0..5.0),
        ];
        let quat = random_quat(&mut r);
        let opacity = match (pinned, early_opacity) {
            (true, _) => 0.999,
            (false, Some(o)) => o,
            (false, None) => r.random_range(0.05..0.9),
        };
        prims.push(&PrimitiveInit {
            mean_m,
            scale_m,
            quat,
            opacity,
            beta,
            omega_low: r.random_range(0.0..1.0),
            bands: (0..bands)
                .map(|_| {
                    (
                        r.random_range(-0.3..0.3),
                        [
                            r.random_range(-2.0..2.0),
                            r.random_range(-2.0..2.0),
                            r.random_range(-2.0..2.0),
                        ],
                        r.random_range(-3.0..3.0),
                    )
                })
                .collect(),
            sh: (0..sh_k)
                .map(|k| {
                    let s = if k == 0 { 2.5 } else { 1.0 / k as f64 };
                    [
                        r.random_range(-s..s),
                        r.random_range(-s..s),
                        r.random_range(-s..s),
                    ]
                })
                .collect(),
        });
    }
    if spec.extras {
        for (mean, s) in [
            ([0.3, -0.2, -0.45], 0.2),
            ([0.0, 0.0, -3.0], 0.5),
            ([0.0, 0.0, 30.0], 20.0),
        ] {
            prims.push(&PrimitiveInit {
                mean_m: mean,
                scale_m: [s, s, s],
                quat: [1.0, 0.0, 0.0, 0.0],
                opacity: 0.5,
                beta: 3.0,
                omega_low: 0.5,
                bands: vec![(0.1, [0.5, 0.0, 0.0], 0.0); bands],
                sh: vec![[0.0; 3]; sh_k],
            });
        }
    }
    prims
}

/// How [`field_scene`] draws its primitives (`cpu_threads.rs`, `benches/cpu_render.rs`).
#[derive(Debug, Clone, PartialEq)]
pub struct FieldScene {
    pub n: usize,
    pub bands: usize,
    /// SH degree of the colour (coefficients in ±0.5); `None`: thermal only.
    pub sh_degree: Option<usize>,
    /// A primitive at depth z has a largest scale drawn from `scale × z / 3`.
    pub scale: std::ops::Range<f64>,
    /// β is drawn from `[2, beta_max)`.
    pub beta_max: f64,
}

/// Small primitives filling the view of a camera at the origin looking down +z, at depths 2 to
/// 6 m with sizes growing with depth (a frame's worth of tiles to cull), drawn with `seed`.
pub fn field_scene(seed: u64, spec: &FieldScene) -> Primitives<f64> {
    let mut r = rng(seed);
    let mut p = Primitives::new(spec.bands, spec.sh_degree);
    let sh_k = p.sh_k();
    for _ in 0..spec.n {
        let z: f64 = r.random_range(2.0..6.0);
        let s = r.random_range(spec.scale.clone()) * z / 3.0;
        p.push(&PrimitiveInit {
            mean_m: [
                r.random_range(-0.6..0.6) * z,
                r.random_range(-0.45..0.45) * z,
                z,
            ],
            scale_m: [
                s,
                s * r.random_range(0.3..1.0),
                s * r.random_range(0.3..1.0),
            ],
            quat: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                1.0,
            ],
            opacity: r.random_range(0.2..0.9),
            beta: r.random_range(2.0..spec.beta_max),
            omega_low: r.random_range(0.2..0.8),
            bands: (0..spec.bands)
                .map(|_| {
                    (
                        r.random_range(-0.1..0.1),
                        [r.random_range(-2.0..2.0), r.random_range(-2.0..2.0), 0.0],
                        0.3,
                    )
                })
                .collect(),
            sh: (0..sh_k)
                .map(|_| {
                    [
                        r.random_range(-0.5..0.5),
                        r.random_range(-0.5..0.5),
                        r.random_range(-0.5..0.5),
                    ]
                })
                .collect(),
        });
    }
    p
}
