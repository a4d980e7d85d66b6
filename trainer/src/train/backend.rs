//! The compute backend the training loop runs on. The loop (schedule, losses, optimiser,
//! density control, reports) is backend-agnostic; a backend renders the image and G-buffers of
//! a view and back-propagates upstream buffer gradients to the primitives. The CPU backend wraps
//! the reference renderer ([`crate::render`]); the Vulkan backend implements the same trait.

use crate::camera::PinholeCamera;
use crate::error::RenderError;
use crate::loss::LossWeights;
use crate::loss::consistency::ConsistencyOptions;
use crate::loss::response::{ResponseGrad, ViewResponse};
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings, render, render_backward, render_gbuffers};
use crate::train::adam::{AdamParams, AdamState, GroupLrs};

/// One training step's thermal losses, for a backend that evaluates them on its own device
/// ([`Backend::device_step`]): the view's `(1 − λ)·L1 + λ·(1 − SSIM)`, sparsity and TV against
/// `target` (the thermal plane seen through `response` when the run learns one), plus, with
/// `pair`, the consistency term against the paired view.
#[derive(Debug, Clone, Copy)]
pub struct DeviceStep<'a> {
    /// Index of the view in the dataset (a backend may keep its target on the device by index).
    pub view: usize,
    pub cam: &'a PinholeCamera,
    /// The view's normalised thermal image.
    pub target: &'a [f32],
    /// The consistency partner (only its G-buffers are needed, not its image).
    pub pair: Option<Partner<'a>>,
    pub weights: LossWeights,
    pub consistency: ConsistencyOptions,
    /// The view's radiometric response ([`crate::loss::response`]); `None`: the run learns
    /// none (identity, no gradient sums).
    pub response: Option<ViewResponse>,
}

/// The consistency partner of a step ([`DeviceStep::pair`]; see
/// [`crate::train::ConsistPartner`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Partner<'a> {
    /// Rendered in this step (G-buffers only); both views get the term's gradients.
    Render(&'a PinholeCamera),
    /// The training view of the backend's previous device step, seen by this camera: its
    /// G-buffers as that step rendered them (the backend keeps them), under stop-gradient.
    /// Nothing is rendered for it.
    Previous(&'a PinholeCamera),
}

impl<'a> Partner<'a> {
    pub fn camera(&self) -> &'a PinholeCamera {
        match *self {
            Partner::Render(c) | Partner::Previous(c) => c,
        }
    }
}

/// What [`Backend::device_step`] computed.
#[derive(Debug, Clone)]
pub struct DeviceStepResult {
    /// Weighted loss (as the host path's: view terms plus λc times the consistency term).
    pub loss: f64,
    /// `dL/dprims`, both views' contributions summed.
    pub grads: Primitives<f32>,
    /// `dL/dgain`, `dL/doffset` of the step's response (when it had one).
    pub response: Option<ResponseGrad>,
}

/// What [`Backend::resident_step`] computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidentStepResult {
    /// Weighted loss.
    pub loss: f64,
    /// `dL/dgain`, `dL/doffset` of the step's response (when it had one); the loop updates
    /// the response on the host.
    pub response: Option<ResponseGrad>,
}

/// One optimisation step with the optimiser state resident on the backend's device
/// ([`Backend::resident_step`]): the losses of `losses`, then Adam with these settings.
#[derive(Debug, Clone, Copy)]
pub struct ResidentStep<'a> {
    pub losses: DeviceStep<'a>,
    /// Each group's step size, bias corrections included ([`AdamState::step_sizes`]).
    pub sizes: GroupLrs,
    pub hp: AdamParams,
    /// Lower bound of every log-scale after the update.
    pub min_log_scale: f32,
    /// The band amplitudes' proximal shrink ([`AdamState::band_shrink`]; 0: none).
    pub band_shrink: f64,
}

/// The optimiser state the training loop keeps: parameters, Adam moments and the
/// densification statistics (sum of screen-space mean-gradient norms and their count).
#[derive(Debug)]
pub struct OptimiserState<'a> {
    pub prims: &'a mut Primitives<f32>,
    pub adam: &'a mut AdamState,
    pub grad_accum: &'a mut [f64],
    pub grad_count: &'a mut [u32],
}

/// The largest work a training run can give a backend: the primitive budget, the bands per
/// primitive, and the largest view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunShape {
    pub budget: usize,
    pub bands: usize,
    pub width: usize,
    pub height: usize,
    /// SH coefficients per colour channel ((degree + 1)²; 0: the run has no colour).
    pub sh_k: usize,
}

/// A renderer with gradients.
pub trait Backend {
    /// Short name for logs and reports (`cpu`, `vulkan`).
    fn name(&self) -> &'static str;
    /// Checks, before training starts, that a run of `shape` fits the backend (device limits);
    /// an error names what does not fit. A backend may prepare for the run here (the Vulkan
    /// backend sizes its per-primitive buffers for the budget).
    fn check_run(&self, _shape: &RunShape) -> Result<(), RenderError> {
        Ok(())
    }
    /// Image and G-buffers of `prims` seen by `cam`.
    fn render(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, RenderError>;
    /// The G-buffers of `prims` seen by `cam` without the thermal image (its plane is zero): all
    /// a view needs whose image does not enter the loss (the consistency partner), without
    /// the band cosines. The default renders everything.
    fn render_gbuffers(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, RenderError> {
        self.render(prims, cam)
    }
    /// `dL/dprims` given `dL/d(buffers)` for the same view.
    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, RenderError>;
    /// Renders, evaluates the thermal losses of `step` and back-propagates them on the
    /// backend's own device, so that images and their gradients never travel to the host.
    /// A backend with a device path keeps the G-buffers of each step's training view until its
    /// next step, for a [`Partner::Previous`] there.
    /// `None`: this backend (or this step) has no device path, and the loop renders, evaluates
    /// the losses on the host and calls [`Backend::backward`]. Both paths compute the same
    /// quantities (held together by tests).
    fn device_step(
        &mut self,
        _prims: &Primitives<f32>,
        _step: &DeviceStep<'_>,
    ) -> Option<Result<DeviceStepResult, RenderError>> {
        None
    }

    /// Takes the optimiser state onto the backend's device, so that whole steps
    /// ([`Backend::resident_step`]) run there with at most small readbacks. `Ok(false)`: this
    /// backend keeps no state (the default), the loop runs Adam on the host.
    fn resident_upload(&mut self, _state: &mut OptimiserState<'_>) -> Result<bool, RenderError> {
        Ok(false)
    }

    /// One step on the resident state: renders, evaluates the losses, back-propagates,
    /// accumulates the densification statistics and steps Adam, all on the device; returns the
    /// weighted loss (and the response's gradient). `prims` gives the structure only (its
    /// values may be stale). `None`: this step cannot run resident; the loop then downloads
    /// the state and takes the host path.
    fn resident_step(
        &mut self,
        _prims: &Primitives<f32>,
        _step: &ResidentStep<'_>,
    ) -> Option<Result<ResidentStepResult, RenderError>> {
        None
    }

    /// Copies the resident state into the host's (before the loop reads or changes it) and
    /// releases it from the device: the host's copy is the truth again.
    fn resident_download(&mut self, _state: &mut OptimiserState<'_>) -> Result<(), RenderError> {
        Ok(())
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
    ) -> Result<GBuffers<f32>, RenderError> {
        let _span = tracing::trace_span!("cpu_render").entered();
        render(prims, cam, &self.settings)
    }
    fn render_gbuffers(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
    ) -> Result<GBuffers<f32>, RenderError> {
        let _span = tracing::trace_span!("cpu_render_gbuffers").entered();
        render_gbuffers(prims, cam, &self.settings)
    }
    fn backward(
        &mut self,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, RenderError> {
        let _span = tracing::trace_span!("cpu_backward").entered();
        render_backward(prims, cam, &self.settings, upstream)
    }
}
