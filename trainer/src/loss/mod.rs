//! Losses of S³-TIR (paper eq. 5–8) with their exact gradients w.r.t. the rendered buffers.
//!
//! `L = L_render + λc·L_consist + λs·L_sparse + λg·L_smooth` with
//! `L_render = (1 − λ)·L1 + λ·(1 − SSIM)` (λ = 0.2, 11×11 Gaussian window, σ = 1.5), see
//! [`photometric`]; `L_consist` in [`consistency`]; `L_sparse` and `L_smooth` in [`regularizers`].
//! Every function returns the value and adds `weight · dL/d(buffer)` into caller-provided
//! gradient buffers, so the terms accumulate straight into the renderer's upstream
//! [`GBuffers`](crate::render::GBuffers). A view's radiometric response (per-frame gain and
//! offset) is applied to the rendered thermal plane before these terms: [`response`].
//! Optional TGA-GS thermal gradient alignment (depth-buffer normals vs the target's gradient):
//! [`align`].

pub mod align;
pub mod consistency;
pub mod photometric;
pub mod regularizers;
pub mod response;

use crate::error::RenderError;
use crate::real::Real;
use crate::render::GBuffers;

/// Loss weights (defaults from the paper §4.1 / the brief).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossWeights {
    /// λ of D-SSIM inside `L_render`.
    pub lambda_dssim: f64,
    /// λc, multi-view frequency consistency.
    pub lambda_consist: f64,
    /// λs, L1 sparsity of Ψ_high.
    pub lambda_sparse: f64,
    /// λg, isotropic TV of Ψ_β.
    pub lambda_smooth: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            lambda_dssim: 0.2,
            lambda_consist: 0.01,
            lambda_sparse: 0.005,
            lambda_smooth: 0.01,
        }
    }
}

/// Values of the single-view terms (unweighted) and their weighted sum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewLoss {
    pub l1: f64,
    pub ssim: f64,
    pub render: f64,
    pub sparse: f64,
    pub smooth: f64,
    /// `render + λs·sparse + λg·smooth` (the consistency term is added per view pair).
    pub total: f64,
}

/// The single-view part of eq. 6 for the thermal image: returns the terms and adds the gradient
/// of `total` into `upstream` (same size as `rendered`).
pub fn view_loss<T: Real>(
    rendered: &GBuffers<T>,
    target: &[T],
    weights: &LossWeights,
    upstream: &mut GBuffers<T>,
) -> Result<ViewLoss, RenderError> {
    view_loss_of(&rendered.thermal, rendered, target, weights, upstream)
}

/// [`view_loss`] with `thermal` standing in for `rendered.thermal` (the plane seen through a
/// view's response, [`response`]); the other planes come from `rendered`.
pub(crate) fn view_loss_of<T: Real>(
    thermal: &[T],
    rendered: &GBuffers<T>,
    target: &[T],
    weights: &LossWeights,
    upstream: &mut GBuffers<T>,
) -> Result<ViewLoss, RenderError> {
    let (w, h) = (rendered.width, rendered.height);
    check_len("thermal", thermal.len(), w, h)?;
    check_len("target", target.len(), w, h)?;
    check_len("upstream.thermal", upstream.thermal.len(), w, h)?;
    check_len("upstream.psi_high", upstream.psi_high.len(), w, h)?;
    check_len("upstream.psi_beta", upstream.psi_beta.len(), w, h)?;
    let r = photometric::l1_dssim(
        thermal,
        target,
        w,
        h,
        weights.lambda_dssim,
        T::ONE,
        &mut upstream.thermal,
    )?;
    let sparse = regularizers::l1_sparsity(
        &rendered.psi_high,
        T::from_f64(weights.lambda_sparse),
        &mut upstream.psi_high,
    );
    let smooth = regularizers::tv_isotropic(
        &rendered.psi_beta,
        w,
        h,
        T::from_f64(weights.lambda_smooth),
        &mut upstream.psi_beta,
    )?;
    Ok(ViewLoss {
        l1: r.l1,
        ssim: r.ssim,
        render: r.loss,
        sparse,
        smooth,
        total: r.loss + weights.lambda_sparse * sparse + weights.lambda_smooth * smooth,
    })
}

pub(crate) fn check_len(
    buffer: &'static str,
    actual: usize,
    width: usize,
    height: usize,
) -> Result<(), RenderError> {
    if actual == width * height {
        Ok(())
    } else {
        Err(RenderError::BufferSize {
            buffer,
            width,
            height,
            expected: width * height,
            actual,
        })
    }
}
