//! A view's radiometric response: the map from the scene's normalised thermal value to what
//! that view's camera recorded, applied to the rendered thermal plane before the loss.
//!
//! `observed = gain·(rendered − pivot) + pivot + offset`
//!
//! - 8-bit exports tone-mapped per frame (automatic gain control) differ per view by a gain
//!   and an offset;
//! - 16-bit radiometric frames drift between flat-field corrections by an offset.
//!
//! The pivot is a constant of the scene (the training images' mean level), so gain and offset
//! are nearly independent: a change of gain leaves the mean level in place. This module is
//! the transform and its exact gradient for given values (whoever learns them: the training
//! loop depends on this module, not the other way round), the reference the GPU loss kernels
//! (`loss_ssim_prepare`, `loss_grad`) are held to.

use super::{LossWeights, ViewLoss, check_len, view_loss_of};
use crate::error::RenderError;
use crate::real::Real;
use crate::render::GBuffers;

/// One view's response (identity: gain 1, offset 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewResponse {
    pub gain: f64,
    pub offset: f64,
    /// Value the gain pivots about (normalised units).
    pub pivot: f64,
}

impl ViewResponse {
    /// The identity about `pivot`.
    pub fn identity(pivot: f64) -> Self {
        Self {
            gain: 1.0,
            offset: 0.0,
            pivot,
        }
    }

    /// What the view records for the scene value `x`.
    pub fn apply<T: Real>(&self, x: T) -> T {
        let (g, b, m) = (
            T::from_f64(self.gain),
            T::from_f64(self.offset),
            T::from_f64(self.pivot),
        );
        g * (x - m) + m + b
    }
}

/// `dL/dgain` and `dL/doffset` of a view's loss.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ResponseGrad {
    pub gain: f64,
    pub offset: f64,
}

/// [`super::view_loss`] of `rendered` seen through `response`: the loss of the responded
/// thermal plane against `target`. Adds the gradient w.r.t. the *rendered* (scene) buffers into
/// `upstream` and returns the loss terms with `dL/dgain`, `dL/doffset`.
///
/// With `x' = g·(x − m) + m + b` and `u' = dL/dx'`: `dL/dx = g·u'`, `dL/dg = Σ u'·(x − m)`,
/// `dL/db = Σ u'`.
pub fn view_loss_with_response<T: Real>(
    rendered: &GBuffers<T>,
    target: &[T],
    weights: &LossWeights,
    response: &ViewResponse,
    upstream: &mut GBuffers<T>,
) -> Result<(ViewLoss, ResponseGrad), RenderError> {
    let (w, h) = (rendered.width, rendered.height);
    check_len("rendered.thermal", rendered.thermal.len(), w, h)?;
    check_len("upstream.thermal", upstream.thermal.len(), w, h)?;
    let seen: Vec<T> = rendered
        .thermal
        .iter()
        .map(|&x| response.apply(x))
        .collect();
    // The thermal plane's gradient is gathered apart (the other planes' terms do not see the
    // response), then chained through it.
    let own = std::mem::replace(&mut upstream.thermal, vec![T::ZERO; w * h]);
    let loss = view_loss_of(&seen, rendered, target, weights, upstream);
    let through = std::mem::replace(&mut upstream.thermal, own);
    let loss = loss?;
    let m = T::from_f64(response.pivot);
    let g = T::from_f64(response.gain);
    let mut grad = ResponseGrad::default();
    for ((u, &du), &x) in upstream
        .thermal
        .iter_mut()
        .zip(&through)
        .zip(&rendered.thermal)
    {
        grad.gain += (du * (x - m)).to_f64();
        grad.offset += du.to_f64();
        *u += g * du;
    }
    Ok((loss, grad))
}
