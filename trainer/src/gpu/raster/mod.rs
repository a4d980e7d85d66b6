//! GPU forward rasteriser of S³-TIR primitives: the CPU reference renderer
//! (`crate::render`, same maths, same order, same thresholds) as compute kernels.
//!
//! Per view: `raster_project` (derived parameters, whitened ray data, visibility, culling
//! rectangle, tile counts, the bands in view form) → exclusive scan of the counts (element n:
//! the number of (tile, primitive) keys, copied to the view's key-total buffer) →
//! `raster_emit` (keys `(tile, depth bits)` + primitive index) → stable radix sort →
//! `raster_ranges` (per-tile ranges) → `raster_forward` (two workgroups per 16×16 tile: thermal
//! image, the G-buffers Ψ_low, Ψ_high, Ψ_β, depth, alpha, and per pixel the end of its
//! samples). The key lists are sized either from the totals, read by the host ([`KeySizing`]),
//! or from a room the caller gives; the sort and the ranges read the count on the GPU.
//!
//! Backward (`render_backward`): `raster_backward_{atomic,cas}{,_sg}` walks each pixel's samples
//! once, front to back, using the forward planes of the same view (the upstream-weighted blend
//! and the end of the samples), and accumulates the view-space gradient sums per primitive with
//! `atomicAdd(float)` or, without float atomics, a compare-and-swap loop (chosen from the
//! context's capabilities), after a subgroup sum where the device has subgroup arithmetic;
//! `raster_backward_finish` (per primitive) chains them to the parameters. The training step
//! renders a view before it back-propagates it: the last two rendered views keep
//! their binning and planes on the GPU, so the backward pass of the same view and parameters
//! reuses them (compared by value) instead of binning and rendering again.
//!
//! Both rasterisers give each invocation the 16 pixels of a tile column (a workgroup is the
//! 8 columns of half a tile, one SIMD batch on lavapipe), and walk the tile's list in batches
//! of 32 samples in two phases: a cheap screen of every sample at every pixel (in front of the
//! near plane, q ≤ q_max), then the full evaluation only of the samples that passed (per pixel
//! in the forward pass, per group of 4 rows in the backward pass). SIMD implementations run
//! both sides of every branch (lavapipe's gallivm never skips an `if`), so only a loop's trip
//! count saves work; the screen makes the same decisions as the single loop did. The backward
//! pass adds a sample's subgroup sums with one atomic per `gl_SubgroupSize` fields. Both read
//! the primitive views, band views and sorted lists through texel buffers (`texelFetch`): gallivm
//! fetches texels with vector gathers but loads storage buffers one invocation at a time, with
//! a branch per invocation and component, and those loads were most of the rasterisers' time
//! (the bound: `maxTexelBufferElements`, checked up front with the storage limits). Measured in
//! `s3tir-train bench` (per-kernel times).
//!
//! [`Outputs::GBuffers`] renders a view without its thermal image (no band phases), and its
//! backward pass takes no thermal upstream: the consistency partner of a training step needs
//! only its G-buffers, and the bands' gradient through Ψ_high is one per-primitive sum
//! (`raster_backward_finish` gives band j `sign(ω_j)` of it), so a rendered partner
//! ([`crate::train::Partner::Render`]) costs about what a 3DGS view does; the default partner
//! ([`crate::train::Partner::Previous`]) is not rendered at all.
//!
//! RGB (SH colour, joint RGB + thermal runs): primitives with `sh` render and back-propagate
//! through the `*_rgb` variants of the projection, forward, backward and finish kernels (the
//! same shader sources compiled with `USE_COLOUR`, built when a view with colour is first
//! rendered). `raster_project_rgb` evaluates each primitive's colour for the view,
//! `c = max(0, Σ_k Y_k(d) sh_k + ½)`, `d = (μ − c_cam)/‖μ − c_cam‖` (`crate::sh`, degrees 0–3);
//! `raster_forward_rgb` blends it into three more planes (R, G, B, after the end plane);
//! `raster_backward_*_rgb` adds the colour's share to each sample's upstream-weighted value (so
//! to dL/dα) and sums dL/dc per primitive (three more fields, the same atomic, compare-and-swap
//! and subgroup paths); `raster_backward_finish_rgb` chains them through the ReLU to the SH
//! coefficients (`Y_k(d)`) and to μ through `d`. A view renders its colour with
//! [`Outputs::All`] ([`GpuRasterizer::render`]: `GBuffers::rgb`, planar) and its backward pass
//! takes the colour kernels only when the RGB upstream is not zero. Runs without colour never
//! build or dispatch the colour kernels, and the thermal kernels' SPIR-V does not depend on
//! the colour branch. The device paths' calls ([`GpuRasterizer::render_kept`],
//! [`GpuRasterizer::record_backward`], …) are thermal-only and refuse primitives with colour.
//!
//! Files: `mod.rs` (the rasteriser and its public calls), `kernels` (the two kernel sets),
//! `layout` (parameter and camera blocks, plane and buffer sizes, [`run_buffers`]),
//! `view_cache` (a view's buffers on the GPU and the kept views matched for the backward
//! pass), `forward` (allocation, binning, sort and forward pass of views), `backward` (the
//! backward pass and its finish).

mod backward;
mod forward;
mod kernels;
mod layout;
mod view_cache;

use std::collections::VecDeque;
use std::sync::{Mutex, OnceLock};

use super::accumulate::AccumulateVariant;
use super::context::{ComputeKernel, GpuBuffer, GpuContext, KernelTiming, Recorder};
use super::error::GpuError;
use super::pool::BufferPool;
use super::scan::GpuScan;
use super::sort::GpuRadixSort;
use crate::camera::PinholeCamera;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings};

use kernels::StageKernels;
pub use layout::{
    KeySizing, PLANES, camera_block, parameter_block, parameter_count, run_buffers,
    run_texel_buffers,
};
use layout::{RGB_PLANE, forward_planes};
pub use view_cache::KeptView;
use view_cache::{BinnedView, KEPT_VIEWS, ParamKey};

/// The rasteriser's kernels; buffers are sized per view.
#[derive(Debug)]
pub struct GpuRasterizer {
    /// Projection, forward, backward and finish of views without colour.
    thermal: StageKernels,
    /// The same with the SH colour, built when a view with colour is first rendered.
    colour: OnceLock<StageKernels>,
    emit: ComputeKernel,
    ranges: ComputeKernel,
    variant: AccumulateVariant,
    /// Whether the backward pass sums over the subgroup first (for building `colour`).
    subgroup_reduce: bool,
    /// When profiling: GPU time of every dispatch since the last `take_timings`.
    timings: Option<Mutex<Vec<KernelTiming>>>,
    /// Scan and sort with their scratch buffers, kept across views and grown when a view needs
    /// more (pipeline creation is expensive: JIT compilation on lavapipe).
    scan: Mutex<Option<GpuScan>>,
    sort: Mutex<Option<GpuRadixSort>>,
    /// The last rendered views, for the backward pass of the same view and parameters.
    kept: Mutex<VecDeque<BinnedView>>,
    /// Released view buffers for the next views (see [`BufferPool`]).
    pool: BufferPool,
}

/// What a render of a view computes, and what its backward pass takes upstream gradient for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outputs {
    /// The thermal image and every G-buffer, and with [`GpuRasterizer::render`] of primitives
    /// with an SH colour the R, G, B planes.
    All,
    /// The G-buffers only (Ψ_low, Ψ_high, Ψ_β, depth, alpha): the thermal plane is zero and no
    /// band phase is evaluated; the backward pass takes the thermal upstream as zero, so the
    /// bands get gradient through Ψ_high only. What a view needs when only its G-buffers enter
    /// the loss (the consistency partner): its G-buffers and, given a zero thermal upstream, its
    /// gradients are exactly those of [`Outputs::All`], without the band cosines.
    GBuffers,
}

impl Outputs {
    /// Whether a view rendered with `self` serves a request for `wanted`.
    fn serves(self, wanted: Outputs) -> bool {
        self == Outputs::All || wanted == Outputs::GBuffers
    }

    fn thermal_flag(self) -> u32 {
        u32::from(self == Outputs::All)
    }
}

/// Where the rasteriser reads the primitives' parameter values. The structure (count, band
/// slots, live band counts) always comes from the host `Primitives`.
#[derive(Debug, Clone, Copy)]
pub enum ParamSource<'a> {
    /// The host `Primitives`' values, uploaded per view; kept views are matched by value.
    Host,
    /// A parameter block resident on the GPU (the layout of raster_common.glsl, every group but
    /// the SH colour), copied on the GPU per view. `generation` identifies its values: the owner
    /// changes it whenever they change, and kept views are matched by it.
    Device {
        buffer: &'a GpuBuffer,
        generation: u64,
    },
}

impl GpuRasterizer {
    /// Builds the kernels; gradient accumulation uses `variant` (see
    /// [`AccumulateVariant::best_for`]): asking for float atomics on a context without them is a
    /// typed `MissingFeature` error.
    pub fn new(ctx: &GpuContext, variant: AccumulateVariant) -> Result<Self, GpuError> {
        Self::with_reduction(ctx, variant, ctx.capabilities().subgroup_arithmetic)
    }

    /// As [`GpuRasterizer::new`], choosing whether the backward pass sums each subgroup's
    /// contributions in shared memory first (`subgroup_reduce`, needs subgroup arithmetic) or
    /// adds every pixel's contribution to global memory (the path of devices without subgroup
    /// arithmetic; tests force it to keep it correct).
    pub fn with_reduction(
        ctx: &GpuContext,
        variant: AccumulateVariant,
        subgroup_reduce: bool,
    ) -> Result<Self, GpuError> {
        let thermal = StageKernels::build(ctx, variant, subgroup_reduce, false)?;
        let shared = match kernels::build_all(ctx, &["raster_emit", "raster_ranges"]) {
            Ok(k) => k,
            Err(e) => {
                thermal.destroy(ctx);
                return Err(e);
            }
        };
        let mut it = shared.into_iter();
        match (it.next(), it.next()) {
            (Some(emit), Some(ranges)) => Ok(Self {
                thermal,
                colour: OnceLock::new(),
                emit,
                ranges,
                variant,
                subgroup_reduce,
                timings: None,
                scan: Mutex::new(None),
                sort: Mutex::new(None),
                kept: Mutex::new(VecDeque::new()),
                pool: BufferPool::new(),
            }),
            _ => {
                thermal.destroy(ctx);
                Err(GpuError::Shader {
                    name: "raster".to_owned(),
                    reason: "kernel list incomplete".to_owned(),
                })
            }
        }
    }

    /// The kernels of views with (`colour`) or without the SH colour, building the colour set
    /// on first use.
    fn stages(&self, ctx: &GpuContext, colour: bool) -> Result<&StageKernels, GpuError> {
        if !colour {
            return Ok(&self.thermal);
        }
        if let Some(k) = self.colour.get() {
            return Ok(k);
        }
        let built = StageKernels::build(ctx, self.variant, self.subgroup_reduce, true)?;
        if let Err(extra) = self.colour.set(built) {
            extra.destroy(ctx);
        }
        self.built_stages(true)
    }

    /// The kernels of views with or without colour, already built (a view with colour was
    /// rendered with them).
    fn built_stages(&self, colour: bool) -> Result<&StageKernels, GpuError> {
        if colour {
            self.colour.get().ok_or_else(|| poisoned("colour kernels"))
        } else {
            Ok(&self.thermal)
        }
    }

    /// Buffers the rasteriser had to create so far (a warm training step reuses released ones).
    pub fn buffers_created(&self) -> u64 {
        self.pool.created()
    }

    /// Sizes the per-primitive buffers of views created from now on for at least `prims`
    /// primitives (the run's budget: density control then never reallocates them).
    pub fn reserve_primitives(&self, prims: usize) {
        self.pool.set_reserve_prims(prims);
    }

    /// Times every dispatch with timestamp queries from now on (`false`: stop and drop them).
    pub fn set_profiling(&mut self, on: bool) {
        self.timings = on.then(|| Mutex::new(Vec::new()));
    }

    /// The dispatch timings collected since the last call (empty when not profiling).
    pub fn take_timings(&self) -> Vec<KernelTiming> {
        self.timings
            .as_ref()
            .and_then(|t| t.lock().ok().map(|mut v| std::mem::take(&mut *v)))
            .unwrap_or_default()
    }

    fn submit<F>(&self, ctx: &GpuContext, record: F) -> Result<(), GpuError>
    where
        F: FnOnce(&mut Recorder<'_>) -> Result<(), GpuError>,
    {
        match &self.timings {
            None => ctx.submit(record),
            Some(sink) => {
                let timed = ctx.submit_profiled(record)?;
                if let Ok(mut v) = sink.lock() {
                    v.extend(timed);
                }
                Ok(())
            }
        }
    }

    /// The gradient-accumulation path in use.
    pub fn variant(&self) -> AccumulateVariant {
        self.variant
    }
    /// Renders the thermal image and G-buffers of `prims` seen by `cam`, and with
    /// [`Outputs::All`] of primitives with an SH colour its three planes (`rgb`, planar R, G, B
    /// as the CPU reference); with [`Outputs::GBuffers`] the thermal plane is zero and `rgb`
    /// empty.
    pub fn render(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
    ) -> Result<GBuffers<f32>, GpuError> {
        let colour = has_colour(prims) && outputs == Outputs::All;
        let rendered = self.bin_and_render(
            ctx,
            prims,
            ParamSource::Host,
            cam,
            (outputs, colour),
            settings,
        )?;
        let npix = cam.width * cam.height;
        let mut out = GBuffers::zeros(cam.width, cam.height, colour);
        let view = rendered.view()?;
        if let Some(planes) = view.planes {
            // Six planes, the end plane, then (with colour) R, G, B: one read.
            let count = if colour { forward_planes(true) } else { 6 };
            let data: Vec<f32> = ctx.read(view.get(planes), count * npix)?;
            let targets = [
                &mut out.thermal,
                &mut out.psi_low,
                &mut out.psi_high,
                &mut out.psi_beta,
                &mut out.depth,
                &mut out.alpha,
            ];
            for (plane, chunk) in targets.into_iter().zip(data.chunks_exact(npix)) {
                plane.copy_from_slice(chunk);
            }
            if colour {
                out.rgb
                    .copy_from_slice(&data[RGB_PLANE * npix..(RGB_PLANE + 3) * npix]);
            }
        }
        if let Some(view) = rendered.take() {
            self.keep_view(ctx, view)?;
        }
        Ok(out)
    }

    /// Renders `prims` seen by each camera of `cams` (at most [`KEPT_VIEWS`]) and keeps the
    /// planes on the GPU for [`GpuRasterizer::submit_with_views`] and the backward pass: two
    /// submissions for all the views, and nothing read back but their key totals (one read;
    /// none with [`KeySizing::Capacity`]). Thermal and G-buffers only (the training step's
    /// device paths): primitives with an SH colour are refused.
    pub fn render_kept(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cams: &[(&PinholeCamera, Outputs)],
        settings: &RenderSettings,
        sizing: KeySizing,
    ) -> Result<(), GpuError> {
        if cams.len() > KEPT_VIEWS {
            return Err(GpuError::InvalidInput {
                reason: format!(
                    "render_kept: {} views, the rasteriser keeps {KEPT_VIEWS}",
                    cams.len()
                ),
            });
        }
        thermal_only(prims, "render_kept")?;
        let cams: Vec<_> = cams.iter().map(|&(c, o)| (c, (o, false))).collect();
        for rendered in self.bin_and_render_views(ctx, prims, src, &cams, settings, sizing)? {
            if let Some(view) = rendered.take() {
                self.keep_view(ctx, view)?;
            }
        }
        Ok(())
    }

    /// Submits `record` with the GPU buffers of kept rendered views (one per camera of `cams`,
    /// rendered from `prims` with at least those outputs by [`GpuRasterizer::render`] or
    /// [`GpuRasterizer::render_kept`]); a view that is not kept is an error.
    pub fn submit_with_views<F>(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cams: &[(&PinholeCamera, Outputs)],
        settings: &RenderSettings,
        record: F,
    ) -> Result<(), GpuError>
    where
        F: FnOnce(&mut Recorder<'_>, &[KeptView<'_>]) -> Result<(), GpuError>,
    {
        thermal_only(prims, "submit_with_views")?;
        let key_params = ParamKey::of(prims, src);
        let kept = lock(&self.kept)?;
        let mut views = Vec::with_capacity(cams.len());
        for &(cam, outputs) in cams {
            let key_cam = camera_block(cam, settings);
            let v = kept
                .iter()
                .find(|v| v.serves(outputs, false) && v.is_view_of(&key_cam, &key_params, prims))
                .ok_or_else(|| GpuError::InvalidInput {
                    reason: "submit_with_views: a view was not rendered from these parameters"
                        .to_owned(),
                })?;
            views.push(v.kept(cam.width, cam.height));
        }
        self.submit(ctx, |rec| record(rec, &views))
    }

    pub fn destroy(self, ctx: &GpuContext) {
        self.thermal.destroy(ctx);
        if let Some(k) = self.colour.into_inner() {
            k.destroy(ctx);
        }
        ctx.destroy_kernel(self.emit);
        ctx.destroy_kernel(self.ranges);
        if let Some(s) = self.scan.into_inner().ok().flatten() {
            s.destroy(ctx);
        }
        if let Some(s) = self.sort.into_inner().ok().flatten() {
            s.destroy(ctx);
        }
        if let Ok(kept) = self.kept.into_inner() {
            for v in kept {
                v.release(ctx, &self.pool);
            }
        }
        self.pool.destroy(ctx);
    }
}

/// Whether `prims` carry an SH colour.
fn has_colour(prims: &Primitives<f32>) -> bool {
    prims.sh_k() > 0
}

/// The device paths' calls (thermal and G-buffers only) refuse primitives with colour: a clear
/// error instead of gradients without the colour's share.
fn thermal_only(prims: &Primitives<f32>, call: &str) -> Result<(), GpuError> {
    if has_colour(prims) {
        return Err(GpuError::InvalidInput {
            reason: format!(
                "{call}: the primitives carry an SH colour; the rasteriser's device paths render                  and back-propagate thermal and G-buffers only (use render / render_backward,                  which take the RGB planes)"
            ),
        });
    }
    Ok(())
}

fn lock<T>(m: &Mutex<T>) -> Result<std::sync::MutexGuard<'_, T>, GpuError> {
    m.lock().map_err(|_| poisoned("rasteriser cache"))
}

fn poisoned(what: &str) -> GpuError {
    GpuError::InvalidInput {
        reason: format!("{what} unavailable: an earlier panic left it in an unknown state"),
    }
}
