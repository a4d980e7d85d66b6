//! The S³-TIR primitive (paper §3.1) as flat, GPU-friendly parameter arrays.
//!
//! Every parameter group is one `Vec<T>` with a fixed stride per primitive, so the same layout can
//! be uploaded to a storage buffer unchanged. The gradient of a [`Primitives`] is another
//! [`Primitives`] with identical layout (see [`Primitives::zeros_like`]).
//!
//! # Parameterisation (what the optimiser sees → what the kernel uses)
//! - centre `μ = means[3i..3i+3]` (world metres);
//! - scales `s = exp(log_scales)` (metres), covariance `Σ = R diag(s²) Rᵀ`;
//! - rotation `R` from the quaternion `quats[4i..4i+4] = (w, x, y, z)`, **normalised in the
//!   forward pass** (the gradient flows through the normalisation). A quaternion of norm below
//!   [`QUAT_NORM_MIN`] is read as the identity and receives a zero gradient (no NaN);
//! - opacity `o = sigmoid(opacity_logits[i])`;
//! - shape `β = min(2 + softplus(beta_raw[i]), BETA_MAX)`: β ≥ 2 by construction; the upper clamp
//!   [`BETA_MAX`] = 64 keeps `m^β` finite for every `m` the renderer evaluates (it only evaluates
//!   where `m^β ≤ ln 255`), and the gradient w.r.t. `beta_raw` is zero on the clamp.
//!   `beta_raw = `[`BETA_RAW_GAUSSIAN`] gives β = 2 + 4.5e-5 (the paper's "β init 2");
//!   `beta_raw = `[`BETA_RAW_FROZEN`] (−10³⁰) gives, **through the same formula**, β = 2 exactly
//!   and `dβ/dbeta_raw = 0` exactly in f32 and f64 (`softplus` and `sigmoid` underflow to 0): a
//!   primitive frozen on the Gaussian path. No renderer or shader formula changes for it;
//!   the optimiser leaves such values alone ([`is_beta_frozen`]);
//! - base intensity `ω_low = omega_low[i]`;
//! - `M = bands` Gabor band slots per primitive: amplitude `band_amp[M i + j]`, frequency
//!   `band_freq[3(M i + j)..+3]` (cycles per metre, world frame), phase `band_phase[M i + j]`
//!   (radians). `M = 0` is allowed (then the primitive is a GES primitive);
//! - live bands `band_count[i]` ≤ M: slots `j < band_count[i]` are the primitive's bands, slots
//!   from `band_count[i]` on are **dropped** (capacity adaptation): they are not part of the
//!   model — they contribute nothing to any output and their gradients are zero — and the
//!   trainer keeps their parameters at 0 and never updates them, so they cannot grow back. (A
//!   renderer that ignores `band_count`, e.g. the Vulkan kernels today, computes the same
//!   outputs because the dropped slots hold zeros; only its gradients of those slots differ,
//!   and the optimiser discards them.) [`Primitives::push`] makes every slot live;
//! - optional RGB colour as real spherical harmonics of degree `sh_degree` (`None`: no colour):
//!   `sh[(K i + k) * 3 + c]`, `K = (degree + 1)²`.
//!
//! # The kernel and the 3DGS convention
//! Support `S(x) = exp(−m^β)`, `m = ‖Σ^{-1/2}(x − μ)‖` — the paper's kernel has **no ½**. At β = 2
//! it is `exp(−m²)`, whereas 3DGS uses `exp(−½ m_3dgs²)` with `m_3dgs = ‖Σ_3dgs^{-1/2}(x − μ)‖`.
//! The two agree when `Σ_3dgs = ½ Σ`, i.e. **3DGS scales = our scales / √2**
//! (`log_scale_3dgs = log_scale − ½ ln 2`). Exporters to 3DGS `.ply` must apply that shift
//! (only exact at β = 2; for β > 2 there is no 3DGS equivalent).
//!
//! Spectrum `F(x) = ReLU(ω_low + Σ_j ω_j cos(2π f_jᵀ(x − μ) + φ_j))`.

use serde::{Deserialize, Serialize};

use crate::real::Real;

/// Upper clamp of β. Above it the gradient w.r.t. `beta_raw` is zero.
pub const BETA_MAX: f64 = 64.0;
/// `beta_raw` of a primitive frozen on the Gaussian path: β = 2 exactly, `dβ/dbeta_raw = 0`
/// exactly (see the module docs). Finite, so it survives JSON checkpoints and f32 PLY.
pub const BETA_RAW_FROZEN: f64 = -1e30;
/// `beta_raw` giving β ≈ 2 (2 + softplus(−10) = 2 + 4.5e-5).
pub const BETA_RAW_GAUSSIAN: f64 = -10.0;
/// Quaternions with a smaller norm are treated as the identity (zero gradient).
pub const QUAT_NORM_MIN: f64 = 1e-12;
/// Default number of Gabor bands per primitive (paper: M = 4).
pub const DEFAULT_BANDS: usize = 4;

/// A set of S³-TIR primitives, structure-of-arrays (see the module docs for every field).
///
/// Serialisable as is: format-1 checkpoints hold it as JSON (see [`crate::checkpoint`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Primitives<T> {
    /// Gabor bands per primitive (M).
    pub bands: usize,
    /// SH degree of the optional RGB colour (`None`: no colour channels).
    pub sh_degree: Option<usize>,
    pub means: Vec<T>,
    pub log_scales: Vec<T>,
    pub quats: Vec<T>,
    pub opacity_logits: Vec<T>,
    pub beta_raw: Vec<T>,
    pub omega_low: Vec<T>,
    pub band_amp: Vec<T>,
    pub band_freq: Vec<T>,
    pub band_phase: Vec<T>,
    pub sh: Vec<T>,
    /// Live band slots per primitive (slots `0..band_count[i]`, read through
    /// [`Primitives::live_bands`], which clamps to M; see the module docs). Not a
    /// parameter group: no gradient, no optimiser moments (a gradient or moment set carries a
    /// copy of its parameters' counts). Absent from format-1 checkpoints written before the
    /// mask existed (the checkpoint reader fills it: every slot live).
    #[serde(default)]
    pub band_count: Vec<u32>,
}

/// Whether a raw β value is the frozen Gaussian sentinel [`BETA_RAW_FROZEN`].
pub fn is_beta_frozen(raw: f64) -> bool {
    raw <= 0.5 * BETA_RAW_FROZEN
}

/// Number of SH coefficients per colour channel for a degree.
pub fn sh_coeff_count(degree: Option<usize>) -> usize {
    degree.map_or(0, |d| (d + 1) * (d + 1))
}

/// One primitive in natural units, for building scenes in tests and initialisers.
#[derive(Debug, Clone, PartialEq)]
pub struct PrimitiveInit {
    pub mean_m: [f64; 3],
    pub scale_m: [f64; 3],
    /// (w, x, y, z); need not be normalised.
    pub quat: [f64; 4],
    /// Opacity in (0, 1).
    pub opacity: f64,
    /// β ≥ 2 (values ≥ [`BETA_MAX`] are stored at the clamp).
    pub beta: f64,
    pub omega_low: f64,
    /// `(ω_j, f_j, φ_j)` per band; shorter lists are zero-padded, longer ones truncated.
    pub bands: Vec<(f64, [f64; 3], f64)>,
    /// SH coefficients `[k][channel]`; zero-padded/truncated to the set's degree.
    pub sh: Vec<[f64; 3]>,
}

impl Default for PrimitiveInit {
    fn default() -> Self {
        Self {
            mean_m: [0.0; 3],
            scale_m: [0.1; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            opacity: 0.5,
            beta: 2.0,
            omega_low: 0.5,
            bands: Vec::new(),
            sh: Vec::new(),
        }
    }
}

/// Inverse of the β parameterisation: `beta_raw` with `2 + softplus(beta_raw) = β`.
/// β ≤ 2 maps to [`BETA_RAW_GAUSSIAN`]; β ≥ [`BETA_MAX`] maps to the raw value of the clamp.
pub fn beta_raw_from_beta(beta: f64) -> f64 {
    let excess = beta.min(BETA_MAX) - 2.0;
    if excess <= 4.5e-5 {
        BETA_RAW_GAUSSIAN
    } else if excess > 20.0 {
        excess
    } else {
        excess.exp_m1().ln()
    }
}

/// Opacity logit of an opacity in (0, 1) (clamped to `[1e-12, 1 − 1e-12]`).
pub fn logit(o: f64) -> f64 {
    let o = o.clamp(1e-12, 1.0 - 1e-12);
    (o / (1.0 - o)).ln()
}

impl<T: Real> Primitives<T> {
    /// An empty set.
    pub fn new(bands: usize, sh_degree: Option<usize>) -> Self {
        Self {
            bands,
            sh_degree,
            means: Vec::new(),
            log_scales: Vec::new(),
            quats: Vec::new(),
            opacity_logits: Vec::new(),
            beta_raw: Vec::new(),
            omega_low: Vec::new(),
            band_amp: Vec::new(),
            band_freq: Vec::new(),
            band_phase: Vec::new(),
            sh: Vec::new(),
            band_count: Vec::new(),
        }
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.opacity_logits.len()
    }

    pub fn is_empty(&self) -> bool {
        self.opacity_logits.is_empty()
    }

    /// SH coefficients per channel.
    pub fn sh_k(&self) -> usize {
        sh_coeff_count(self.sh_degree)
    }

    /// Appends one primitive given in natural units.
    pub fn push(&mut self, p: &PrimitiveInit) {
        let f = T::from_f64;
        self.means.extend(p.mean_m.iter().map(|&x| f(x)));
        self.log_scales
            .extend(p.scale_m.iter().map(|&s| f(s.max(f64::MIN_POSITIVE).ln())));
        self.quats.extend(p.quat.iter().map(|&x| f(x)));
        self.opacity_logits.push(f(logit(p.opacity)));
        self.beta_raw.push(f(beta_raw_from_beta(p.beta)));
        self.omega_low.push(f(p.omega_low));
        for j in 0..self.bands {
            let (amp, freq, phase) = p.bands.get(j).copied().unwrap_or((0.0, [0.0; 3], 0.0));
            self.band_amp.push(f(amp));
            self.band_freq.extend(freq.iter().map(|&x| f(x)));
            self.band_phase.push(f(phase));
        }
        for k in 0..self.sh_k() {
            let c = p.sh.get(k).copied().unwrap_or([0.0; 3]);
            self.sh.extend(c.iter().map(|&x| f(x)));
        }
        self.band_count
            .push(u32::try_from(self.bands).unwrap_or(u32::MAX));
    }

    /// Live bands of primitive `i` (slots `0..live_bands(i)`).
    #[inline]
    pub fn live_bands(&self, i: usize) -> usize {
        self.band_count
            .get(i)
            .map_or(self.bands, |&c| (c as usize).min(self.bands))
    }

    /// A set of the same shape filled with zeros (the layout of a gradient).
    pub fn zeros_like(&self) -> Self {
        let z = |v: &Vec<T>| vec![T::ZERO; v.len()];
        Self {
            bands: self.bands,
            sh_degree: self.sh_degree,
            means: z(&self.means),
            log_scales: z(&self.log_scales),
            quats: z(&self.quats),
            opacity_logits: z(&self.opacity_logits),
            beta_raw: z(&self.beta_raw),
            omega_low: z(&self.omega_low),
            band_amp: z(&self.band_amp),
            band_freq: z(&self.band_freq),
            band_phase: z(&self.band_phase),
            sh: z(&self.sh),
            band_count: self.band_count.clone(),
        }
    }

    /// Converts every parameter to another precision.
    pub fn cast<U: Real>(&self) -> Primitives<U> {
        let c = |v: &Vec<T>| {
            v.iter()
                .map(|x| U::from_f64(x.to_f64()))
                .collect::<Vec<U>>()
        };
        Primitives {
            bands: self.bands,
            sh_degree: self.sh_degree,
            means: c(&self.means),
            log_scales: c(&self.log_scales),
            quats: c(&self.quats),
            opacity_logits: c(&self.opacity_logits),
            beta_raw: c(&self.beta_raw),
            omega_low: c(&self.omega_low),
            band_amp: c(&self.band_amp),
            band_freq: c(&self.band_freq),
            band_phase: c(&self.band_phase),
            sh: c(&self.sh),
            band_count: self.band_count.clone(),
        }
    }

    /// Every parameter group with its [`Group`], in [`Group::ALL`]'s order, for generic loops
    /// (optimisers, row operations, checkpoints, tests).
    pub fn groups(&self) -> [(Group, &Vec<T>); 10] {
        [
            (Group::Means, &self.means),
            (Group::LogScales, &self.log_scales),
            (Group::Quats, &self.quats),
            (Group::OpacityLogits, &self.opacity_logits),
            (Group::BetaRaw, &self.beta_raw),
            (Group::OmegaLow, &self.omega_low),
            (Group::BandAmp, &self.band_amp),
            (Group::BandFreq, &self.band_freq),
            (Group::BandPhase, &self.band_phase),
            (Group::Sh, &self.sh),
        ]
    }

    /// Mutable access to every parameter group, in [`Group::ALL`]'s order.
    pub fn groups_mut(&mut self) -> [(Group, &mut Vec<T>); 10] {
        [
            (Group::Means, &mut self.means),
            (Group::LogScales, &mut self.log_scales),
            (Group::Quats, &mut self.quats),
            (Group::OpacityLogits, &mut self.opacity_logits),
            (Group::BetaRaw, &mut self.beta_raw),
            (Group::OmegaLow, &mut self.omega_low),
            (Group::BandAmp, &mut self.band_amp),
            (Group::BandFreq, &mut self.band_freq),
            (Group::BandPhase, &mut self.band_phase),
            (Group::Sh, &mut self.sh),
        ]
    }

    /// Checks that every group has the length its stride implies.
    pub fn validate(&self) -> Result<(), crate::error::RenderError> {
        if let Some(degree) = self.sh_degree
            && degree > crate::sh::SH_MAX_DEGREE
        {
            return Err(crate::error::RenderError::UnsupportedShDegree {
                degree,
                max: crate::sh::SH_MAX_DEGREE,
            });
        }
        let n = self.len();
        let m = self.bands;
        let k = self.sh_k();
        for (group, v) in self.groups() {
            let stride = group.stride(m, k);
            if v.len() != stride * n {
                return Err(crate::error::RenderError::ParameterLength {
                    group: group.name(),
                    expected: stride * n,
                    actual: v.len(),
                });
            }
        }
        if self.band_count.len() != n {
            return Err(crate::error::RenderError::ParameterLength {
                group: "band_count",
                expected: n,
                actual: self.band_count.len(),
            });
        }
        Ok(())
    }

    /// β of primitive `i` and `dβ/dbeta_raw` (zero on the clamp).
    #[inline]
    pub fn beta(&self, i: usize) -> (T, T) {
        beta_of_raw(self.beta_raw[i])
    }

    /// Opacity of primitive `i` and `do/dlogit`.
    #[inline]
    pub fn opacity(&self, i: usize) -> (T, T) {
        let o = self.opacity_logits[i].sigmoid();
        (o, o * (T::ONE - o))
    }

    /// Scales (metres) of primitive `i`.
    #[inline]
    pub fn scales(&self, i: usize) -> [T; 3] {
        [
            self.log_scales[3 * i].exp(),
            self.log_scales[3 * i + 1].exp(),
            self.log_scales[3 * i + 2].exp(),
        ]
    }

    #[inline]
    pub fn mean(&self, i: usize) -> [T; 3] {
        [
            self.means[3 * i],
            self.means[3 * i + 1],
            self.means[3 * i + 2],
        ]
    }

    #[inline]
    pub fn quat(&self, i: usize) -> [T; 4] {
        [
            self.quats[4 * i],
            self.quats[4 * i + 1],
            self.quats[4 * i + 2],
            self.quats[4 * i + 3],
        ]
    }
}

/// β and `dβ/dbeta_raw` for a raw value (see the module docs).
#[inline]
pub fn beta_of_raw<T: Real>(raw: T) -> (T, T) {
    let beta = T::TWO + raw.softplus();
    let max = T::from_f64(BETA_MAX);
    if beta >= max {
        (max, T::ZERO)
    } else {
        (beta, raw.sigmoid())
    }
}

/// Rotation matrix (row-major) of a quaternion `(w, x, y, z)`, normalised here; returns the
/// normalised quaternion and the norm (0 for a degenerate quaternion, read as the identity).
#[inline]
pub fn rotation_from_quat<T: Real>(q: [T; 4]) -> ([T; 9], [T; 4], T) {
    let n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    let min = T::from_f64(QUAT_NORM_MIN);
    let usable = n2 > min * min; // false for NaN
    if !usable {
        let i = [T::ONE, T::ZERO, T::ZERO, T::ZERO];
        return (rot_unit(i), i, T::ZERO);
    }
    let n = n2.sqrt();
    let u = [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
    (rot_unit(u), u, n)
}

#[inline]
fn rot_unit<T: Real>(u: [T; 4]) -> [T; 9] {
    let [w, x, y, z] = u;
    let one = T::ONE;
    let two = T::TWO;
    [
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
    ]
}

/// Gradient w.r.t. the raw quaternion given `dL/dR` (row-major), through the normalisation.
#[inline]
pub fn quat_backward<T: Real>(unit: [T; 4], norm: T, g: &[T; 9]) -> [T; 4] {
    if norm == T::ZERO {
        return [T::ZERO; 4];
    }
    let [w, x, y, z] = unit;
    let two = T::TWO;
    let gw = two * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
    let gx = two
        * (y * g[1] + z * g[2] + y * g[3] - two * x * g[4] - w * g[5] + z * g[6] + w * g[7]
            - two * x * g[8]);
    let gy = two
        * (-two * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7]
            - two * y * g[8]);
    let gz = two
        * (-two * z * g[0] - w * g[1] + x * g[2] + w * g[3] - two * z * g[4]
            + y * g[5]
            + x * g[6]
            + y * g[7]);
    let gu = [gw, gx, gy, gz];
    let d = gu[0] * w + gu[1] * x + gu[2] * y + gu[3] * z;
    [
        (gu[0] - d * w) / norm,
        (gu[1] - d * x) / norm,
        (gu[2] - d * y) / norm,
        (gu[3] - d * z) / norm,
    ]
}

/// A parameter group of [`Primitives`]: the one list of the groups, with their names (the
/// checkpoint's tensor names, messages) and strides. Code that treats groups differently
/// matches on it, so a new group or a misspelt one is a compile error, not a silent fallback.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Group {
    Means,
    LogScales,
    Quats,
    OpacityLogits,
    BetaRaw,
    OmegaLow,
    BandAmp,
    BandFreq,
    BandPhase,
    Sh,
}

impl Group {
    /// Every group, in the order [`Primitives::groups`] lists them (and checkpoints and the
    /// GPU parameter block store them).
    pub const ALL: [Group; 10] = [
        Group::Means,
        Group::LogScales,
        Group::Quats,
        Group::OpacityLogits,
        Group::BetaRaw,
        Group::OmegaLow,
        Group::BandAmp,
        Group::BandFreq,
        Group::BandPhase,
        Group::Sh,
    ];

    /// The group's name: its field in [`Primitives`], its tensor in a checkpoint.
    pub const fn name(self) -> &'static str {
        match self {
            Group::Means => "means",
            Group::LogScales => "log_scales",
            Group::Quats => "quats",
            Group::OpacityLogits => "opacity_logits",
            Group::BetaRaw => "beta_raw",
            Group::OmegaLow => "omega_low",
            Group::BandAmp => "band_amp",
            Group::BandFreq => "band_freq",
            Group::BandPhase => "band_phase",
            Group::Sh => "sh",
        }
    }

    /// Values per primitive with `bands` band slots and `sh_k` SH coefficients per channel.
    pub const fn stride(self, bands: usize, sh_k: usize) -> usize {
        match self {
            Group::Means | Group::LogScales => 3,
            Group::Quats => 4,
            Group::OpacityLogits | Group::BetaRaw | Group::OmegaLow => 1,
            Group::BandAmp | Group::BandPhase => bands,
            Group::BandFreq => 3 * bands,
            Group::Sh => 3 * sh_k,
        }
    }

    /// A band group (values per band slot: 1, or 3 for frequencies), `None` otherwise.
    pub const fn per_band_slot(self) -> Option<usize> {
        match self {
            Group::BandAmp | Group::BandPhase => Some(1),
            Group::BandFreq => Some(3),
            _ => None,
        }
    }
}

impl std::fmt::Display for Group {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One value per parameter group of [`Primitives`] (e.g. the optimiser's learning rates and
/// step counts, `train::adam`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Groups<T> {
    pub means: T,
    pub log_scales: T,
    pub quats: T,
    pub opacity_logits: T,
    /// `beta_raw`'s group (the optimiser steps it in β units).
    pub beta: T,
    pub omega_low: T,
    pub band_amp: T,
    pub band_freq: T,
    pub band_phase: T,
    pub sh: T,
}

impl<T: Copy> Groups<T> {
    /// The value of `group`.
    pub fn of(&self, group: Group) -> T {
        match group {
            Group::Means => self.means,
            Group::LogScales => self.log_scales,
            Group::Quats => self.quats,
            Group::OpacityLogits => self.opacity_logits,
            Group::BetaRaw => self.beta,
            Group::OmegaLow => self.omega_low,
            Group::BandAmp => self.band_amp,
            Group::BandFreq => self.band_freq,
            Group::BandPhase => self.band_phase,
            Group::Sh => self.sh,
        }
    }

    /// `v` in every group (e.g. a checkpoint written before groups kept their own step count:
    /// its bias corrections all used the run's count).
    pub fn splat(v: T) -> Self {
        Groups {
            means: v,
            log_scales: v,
            quats: v,
            opacity_logits: v,
            beta: v,
            omega_low: v,
            band_amp: v,
            band_freq: v,
            band_phase: v,
            sh: v,
        }
    }

    /// `f` of each group's pair of values.
    pub fn zip_with<U: Copy, V>(&self, other: &Groups<U>, f: impl Fn(T, U) -> V) -> Groups<V> {
        Groups {
            means: f(self.means, other.means),
            log_scales: f(self.log_scales, other.log_scales),
            quats: f(self.quats, other.quats),
            opacity_logits: f(self.opacity_logits, other.opacity_logits),
            beta: f(self.beta, other.beta),
            omega_low: f(self.omega_low, other.omega_low),
            band_amp: f(self.band_amp, other.band_amp),
            band_freq: f(self.band_freq, other.band_freq),
            band_phase: f(self.band_phase, other.band_phase),
            sh: f(self.sh, other.sh),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every loop over groups (optimisers, row operations, checkpoints, the GPU parameter
    /// block) relies on `groups()`, `groups_mut()` and `Group::ALL` listing one order.
    #[test]
    fn the_group_lists_agree() {
        let mut p = Primitives::<f32>::new(2, Some(1));
        let listed: Vec<Group> = p.groups().iter().map(|(g, _)| *g).collect();
        let listed_mut: Vec<Group> = p.groups_mut().iter().map(|(g, _)| *g).collect();
        assert_eq!(listed, Group::ALL, "groups() must list Group::ALL in order");
        assert_eq!(
            listed_mut,
            Group::ALL,
            "groups_mut() must list Group::ALL in order"
        );
        let names: std::collections::BTreeSet<&str> = Group::ALL.iter().map(|g| g.name()).collect();
        assert_eq!(
            names.len(),
            Group::ALL.len(),
            "group names must be distinct: {names:?}"
        );
    }
}
