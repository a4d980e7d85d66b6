//! The compute backend the training loop runs on. The loop (schedule, losses, optimiser,
//! density control, reports) is backend-agnostic; a backend renders the image and G-buffers of
//! a view and back-propagates upstream buffer gradients to the primitives. The CPU backend wraps
//! the reference renderer ([`crate::render`]); the Vulkan backend implements the same trait.

use crate::camera::PinholeCamera;
use crate::error::TrainerError;
use crate::loss::LossWeights;
use crate::loss::consistency::ConsistencyOptions;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings, render, render_backward};

/// One training step's thermal losses, for a backend that evaluates them on its own device
/// ([`Backend::device_step`]): the view's `(1 − λ)·L1 + λ·(1 − SSIM)`, sparsity and TV against
/// `target`, plus, with `pair`, the consistency term against the paired view.
#[derive(Debug, Clone, Copy)]
pub struct DeviceStep<'a> {
    /// Index of the view in the dataset (a backend may keep its target on the device by index).
    pub view: usize,
    pub cam: &'a PinholeCamera,
    /// The view's normalised thermal image.
    pub target: &'a [f32],
    /// The consistency partner's camera (only its renders are needed, not its image).
    pub pair: Option<&'a PinholeCamera>,
    pub weights: LossWeights,
    pub consistency: ConsistencyOptions,
}

/// What [`Backend::device_step`] computed.
#[derive(Debug, Clone)]
pub struct DeviceStepResult {
    /// Weighted loss (as the host path's: view terms plus λc times the consistency term).
    pub loss: f64,
    /// `dL/dprims`, both views' contributions summed.
    pub grads: Primitives<f32>,
}

/// A renderer with gradients.
pub trait Backend {
    /// Short name for logs and reports (`cpu`, `vulkan`).
    fn name(&self) -> &'static str;
    /// Image and G-buffers of `prims` seen by `cam`.
    fn render(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, TrainerError>;
    /// `dL/dprims` given `dL/d(buffers)` for the same view.
    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, TrainerError>;
    /// Renders, evaluates the thermal losses of `step` and back-propagates them on the
    /// backend's own device, so that images and their gradients never travel to the host.
    /// `None`: this backend (or this step) has no device path, and the loop renders, evaluates
    /// the losses on the host and calls [`Backend::backward`]. Both paths compute the same
    /// quantities (held together by tests).
    fn device_step(
        &mut self,
        _prims: &Primitives<f32>,
        _step: &DeviceStep<'_>,
    ) -> Option<Result<DeviceStepResult, TrainerError>> {
        None
    }
}

/// The CPU reference renderer in f32.
#[derive(Debug, Clone, Default)]
pub struct CpuBackend {
    pub settings: RenderSettings,
}

impl Backend for CpuBackend {
    fn name(&self) -> &'static str {
        "cpu"
    }
    fn render(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, TrainerError> {
        let _span = tracing::trace_span!("cpu_render").entered();
        render(prims, cam, &self.settings)
    }
    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, TrainerError> {
        let _span = tracing::trace_span!("cpu_backward").entered();
        render_backward(prims, cam, &self.settings, upstream)
    }
}
