//! The compute backend the training loop runs on. The loop (schedule, losses, optimiser,
//! density control, reports) is backend-agnostic; a backend renders the image and G-buffers of
//! a view and back-propagates upstream buffer gradients to the primitives. The CPU backend wraps
//! the reference renderer ([`crate::render`]); the Vulkan backend implements the same trait.

use crate::camera::PinholeCamera;
use crate::error::TrainerError;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings, render, render_backward};

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
