//! CPU reference renderer of S³-TIR primitives: forward ([`render`]) and exact analytic backward
//! ([`render_backward`]), generic over `f32`/`f64`. This is the ground truth the Vulkan kernels are
//! held to, so every choice below is deliberate and documented.
//!
//! # Per pixel, per primitive
//! The pixel `(u, v)` (origin at the centre of the top-left pixel) has the world ray
//! `x(t) = c + t·d`, `d = R_world_from_cam K⁻¹ (u, v, 1)`, so `t` is the **camera-frame depth z**.
//! In the primitive's whitened frame (`N = diag(1/s) Rᵀ`, `Σ⁻¹ = NᵀN`) the ray is `a + t·b` with
//! `a = N(c − μ)`, `b = N d`, and the squared Mahalanobis distance `q(t) = ‖a + t b‖²` is minimised
//! in closed form at `t* = −a·b / b·b` with `q* = ‖a + t* b‖²` (this point does not depend on β:
//! `S` is monotone in `m`). There `S = exp(−q*^{β/2})`, `α = min(ALPHA_MAX, o·S)`, and the spectrum
//! `F` is evaluated at `x* = c + t*·d`.
//!
//! A sample contributes only if `α ≥ ALPHA_MIN` (= 1/255) and `t* > near`.
//!
//! # Blending
//! (The paper sorts with the bounding Gaussian; its centre is μ, so this is the same key.)
//! Primitives are sorted once per view by the **camera-frame z of their centre μ** (ascending,
//! ties by index); the same order is used in every tile. Front to back, `w_i = T_i α_i`,
//! `T_{i+1} = T_i (1 − α_i)`. Early stop as in 3DGS: a sample that would bring `T` below
//! [`T_MIN`] is not blended and ends the pixel (this also bounds the work for 10⁵ overlapping
//! primitives and keeps `T` far from underflow). Outputs, all blended with the same weights `w_i`:
//! thermal image `Σ w F`, optional RGB `Σ w c`, `Ψ_low = Σ w ω_low`, `Ψ_high = Σ w Σ_j|ω_j|`,
//! `Ψ_β = Σ w β`, depth `Σ w t*` (divide by `alpha` for the expected depth) and `alpha = Σ w`.
//!
//! # Leaving out what a primitive does not need (exact shortcuts, not other formulas)
//! - **Cheap Gaussian path.** A primitive whose β is exactly 2 (the trainer stores
//!   [`crate::primitive::BETA_RAW_FROZEN`] for it: `β = 2`, `dβ/dbeta_raw = 0` through the
//!   unchanged parameterisation) has `m^β = q*` and `∂S/∂q* = −S`, so `pow` is skipped in the
//!   forward and backward passes, and the `∂S/∂β = −S m^β ln m` term, which only reaches
//!   `beta_raw` through `dβ/dbeta_raw = 0`, is not evaluated. Every value is the one the general
//!   path gives (`pow(q, 1) = q`, `pow(q, 0) = 1`).
//! - **Dropped bands.** Band slots `j ≥ band_count[i]` are not part of the model: the spectrum,
//!   Ψ_high and their gradients loop over the live slots only (dropped slots hold zeros, so the
//!   outputs equal those of a loop over every slot; their gradients are zero by definition).
//!
//! A primitive with β = 2 and no live band therefore costs one `exp` per sample, like a 3DGS
//! Gaussian. (GPU kernels that do not branch compute the same outputs.)
//!
//! # Near plane
//! A primitive whose centre has camera z ≤ `near_m` is skipped entirely (as in 3DGS); a sample
//! whose peak point has `t* ≤ near_m` is skipped. A primitive whose culling ellipsoid reaches the
//! near plane is put in every tile (its silhouette is not a bounded ellipse), which is correct but
//! slow; such primitives are rare.
//!
//! # Tile culling (the bounding Gaussian)
//! Tiles are [`TILE_SIZE`]² pixels. `α ≥ 1/255 ⇔ m^β ≤ L = ln(255·o)`. For `L ≥ 1`,
//! `L^{1/β} ≤ L^{1/2}`; for `L < 1`, `L^{1/β} < 1`; so for every β ≥ 2 a contributing ray passes
//! within Mahalanobis radius `r = max(1, √L)` of μ, i.e. meets the ellipsoid `E_r = {x : (x−μ)ᵀΣ⁻¹(x−μ) ≤ r²}`.
//! That ellipsoid lies in front of the near plane (else: every tile), so the intersection projects
//! into its silhouette, the conic with dual `C* = K (r²Σ_cam − μ_cam μ_camᵀ) Kᵀ`. The exact bounding
//! box of that conic comes from its tangent lines `u = const`: `C*₀₀ − 2u C*₀₂ + u² C*₂₂ = 0`
//! (likewise for `v`). The box is padded by [`CULL_PAD_PX`] against rounding, computed in f64, and
//! every tile whose pixel centres meet it is listed. `tests/culling.rs` checks it against brute force.
//!
//! # Threads
//! Prepare runs per primitive, the forward pass per row of pixels, the backward pass per tile,
//! all on rayon's pool. Per-primitive and per-pixel work is independent; the backward pass sums
//! each tile's contributions per primitive, then adds the tiles' sums in tile order, in
//! batches of tiles that bound the memory held. Partitions and summation order never depend on
//! the thread count, so every output is the same bit for bit on 1 thread or 64
//! (`tests/cpu_threads.rs`), though the backward pass's sums are in a different order than a
//! plain row-major loop would take (a few ulp apart from the single-threaded code this replaced).
//!
//! # Anti-aliasing
//! None: each pixel is **one point sample** of the pixel-centre ray — no EWA low-pass, no 0.3 px
//! dilation (which would change the kernel and break the β-coupling). Primitives smaller than a
//! pixel footprint therefore alias (they can vanish between pixel centres); the trainer is expected
//! to keep scales above the footprint (a 3-D smoothing filter à la Mip-Splatting is the planned
//! remedy, not implemented here).

mod backward;
mod buffers;
mod forward;
mod prepare;

pub use backward::{render_backward, render_backward_prepared};
pub use buffers::GBuffers;
pub use forward::{render, render_gbuffers, render_prepared};
pub use prepare::{Prepared, PrimView, prepare};

/// Tile edge in pixels.
pub const TILE_SIZE: usize = 16;
/// Upper clamp of α.
pub const ALPHA_MAX: f64 = 0.99;
/// Samples with α below this are skipped (1/255).
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// Early-stop transmittance.
pub const T_MIN: f64 = 1e-4;
/// Padding of the culling box, pixels.
pub const CULL_PAD_PX: f64 = 1.0;

/// Renderer options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Near plane, camera-frame z in metres.
    pub near_m: f64,
    /// Tile culling on (false: every visible primitive is tested at every pixel — the reference
    /// the culling test compares against).
    pub cull: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            near_m: 0.01,
            cull: true,
        }
    }
}
