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
//! Not here yet: the RGB (SH colour) branch.

use super::accumulate::AccumulateVariant;
use std::collections::VecDeque;
use std::sync::Mutex;

use super::context::{
    ComputeKernel, GpuBuffer, GpuContext, KernelTiming, MemoryLocation, Recorder,
};
use super::error::GpuError;
use super::pool::BufferPool;
use super::scan::GpuScan;
use super::shaders::{self, push_u32s};
use super::sort::{GpuRadixSort, ItemCount};
use crate::camera::PinholeCamera;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings, TILE_SIZE};

/// Bytes of one `PrimView` (raster_common.glsl).
const PRIM_VIEW_BYTES: u64 = 112;
const PROJECT_WG: usize = 128;
const RANGES_WG: usize = 256;
/// Output planes of `raster_forward`, in order.
pub const PLANES: [&str; 6] = [
    "thermal", "psi_low", "psi_high", "psi_beta", "depth", "alpha",
];

/// The rasteriser's kernels; buffers are sized per view.
#[derive(Debug)]
pub struct GpuRasterizer {
    project: ComputeKernel,
    emit: ComputeKernel,
    ranges: ComputeKernel,
    forward: ComputeKernel,
    backward: ComputeKernel,
    finish: ComputeKernel,
    variant: AccumulateVariant,
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

/// Capacity to allocate for `need` items: 25 % headroom so slowly growing views do not
/// reallocate every step.
fn grown(need: usize) -> usize {
    need + need / 4 + 64
}

/// Floats of per-primitive view-space gradient sums for `bands` bands (`acc_fields` in
/// raster_common.glsl).
fn acc_fields(bands: usize) -> usize {
    16 + 5 * bands
}

/// What a render of a view computes, and what its backward pass takes upstream gradient for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outputs {
    /// The thermal image and every G-buffer.
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

/// Bytes of one `BandView` (raster_common.glsl).
const BAND_VIEW_BYTES: u64 = 32;
/// Planes of `raster_forward`'s output: the six of [`PLANES`] and the end plane.
const FORWARD_PLANES: usize = 7;
/// Rendered views kept for the backward pass of the same view (the training step renders at
/// most two views before it back-propagates them).
const KEPT_VIEWS: usize = 2;

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

/// What a view was binned from: the parameter values (host source) or the generation of a
/// resident parameter block.
#[derive(Debug, Clone, PartialEq)]
enum ParamKey {
    Values(Vec<f32>),
    Generation(u64),
}

impl ParamKey {
    fn of(prims: &Primitives<f32>, src: ParamSource<'_>) -> Self {
        match src {
            ParamSource::Host => Self::Values(parameter_block(prims)),
            ParamSource::Device { generation, .. } => Self::Generation(generation),
        }
    }
}

/// Floats of the parameter block of `prims` (every group but the SH colour).
pub fn parameter_count(prims: &Primitives<f32>) -> usize {
    prims.len() * (13 + 5 * prims.bands)
}

/// The largest per-primitive and per-pixel buffers a run with `budget` primitives of `bands`
/// bands and views of `npix` pixels allocates, as (name, bytes): the parameter block (the
/// optimiser's moments and gradients have its size), the view data, the backward pass's
/// scratch, the tile counts and the forward planes. The key lists depend on the scene's
/// coverage and are checked when created.
pub fn run_buffers(budget: usize, bands: usize, npix: usize) -> [(&'static str, u64); 6] {
    let n = budget as u64;
    [
        ("parameters", n * (13 + 5 * bands as u64) * 4),
        ("raster.views", n * PRIM_VIEW_BYTES),
        ("raster.bands", n * bands as u64 * BAND_VIEW_BYTES),
        ("raster.grad_acc", n * acc_fields(bands) as u64 * 4),
        ("raster.tile_counts", (n + 1) * 4),
        ("raster.planes", (FORWARD_PLANES * npix * 4) as u64),
    ]
}

/// The per-primitive buffers the rasterisers read as texel buffers (see raster_common.glsl), as
/// (name, texels) for a run with `budget` primitives of `bands` bands: checked against the
/// device's `maxTexelBufferElements` before training (the sorted lists are checked when bound).
pub fn run_texel_buffers(budget: usize, bands: usize) -> [(&'static str, u64); 2] {
    let n = budget as u64;
    [
        ("raster.views", n * PRIM_VIEW_BYTES / 16),
        ("raster.bands", n * bands as u64 * BAND_VIEW_BYTES / 16),
    ]
}

/// How [`GpuRasterizer::render_kept`] sizes a view's key list (one key per primitive and tile
/// it covers), whose length only the GPU knows after binning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KeySizing {
    /// The host reads the key totals of all views after binning (one small read) and sizes
    /// every list exactly.
    Exact,
    /// Every list has room for this many keys and the host reads nothing: the sort and the
    /// tile ranges read the total on the GPU. A view with more keys is cut to its first
    /// `capacity` (an incomplete render); the caller finds out from the view's
    /// [`KeptView::key_total`] and repeats the work with more room.
    Capacity(usize),
}

/// A view binned (and, once rendered, with its forward planes) on the GPU. The buffers are
/// owned here and released with [`BinnedView::destroy`]; [`Transient`] does that on drop.
#[derive(Debug)]
struct BinnedView {
    buffers: Vec<GpuBuffer>,
    cam: usize,
    params: usize,
    views: usize,
    bands: usize,
    /// Live band counts (absent without primitives).
    band_count_buf: Option<usize>,
    /// The key total (u32) the GPU computed when binning (absent without primitives).
    total: Option<usize>,
    /// The (tile, depth) keys (absent when no primitive covers the view).
    keys: Option<usize>,
    /// Sorted primitive indices and per-tile ranges; `None` when no primitive covers a tile.
    lists: Option<(usize, usize)>,
    /// Output of `raster_forward` ([`FORWARD_PLANES`] planes), once rendered.
    planes: Option<usize>,
    /// What `raster_forward` computed.
    outputs: Outputs,
    tiles: [usize; 2],
    /// What was binned: the camera block, the parameters and the live band counts (the cache
    /// key of kept views).
    camera_block: [f32; 32],
    param_key: ParamKey,
    band_count: Vec<u32>,
}

impl BinnedView {
    fn keep(&mut self, b: GpuBuffer) -> usize {
        self.buffers.push(b);
        self.buffers.len() - 1
    }

    fn get(&self, handle: usize) -> &GpuBuffer {
        &self.buffers[handle]
    }

    /// Whether this view was binned from this camera block, these parameters and `prims`' live
    /// band counts (the key of kept views).
    fn is_view_of(
        &self,
        camera: &[f32; 32],
        parameters: &ParamKey,
        prims: &Primitives<f32>,
    ) -> bool {
        self.camera_block == *camera
            && self.param_key == *parameters
            && self.band_count.len() == prims.len()
            && self
                .band_count
                .iter()
                .enumerate()
                .all(|(i, &c)| c as usize == prims.live_bands(i))
    }

    /// Returns the view's buffers to `pool`.
    fn release(mut self, ctx: &GpuContext, pool: &BufferPool) {
        for b in self.buffers.drain(..) {
            pool.give(ctx, b);
        }
    }
}

/// The GPU buffers of a kept rendered view (see [`GpuRasterizer::submit_with_views`]).
#[derive(Debug, Clone, Copy)]
pub struct KeptView<'a> {
    /// The camera block ([`camera_block`]).
    pub camera: &'a GpuBuffer,
    /// `raster_forward`'s planes (the six of [`PLANES`], then the end plane); `None` when no
    /// primitive covers the view (every plane is then zero).
    pub planes: Option<&'a GpuBuffer>,
    pub width: usize,
    pub height: usize,
    /// The view's key total (one u32) as the GPU computed it; `None` without primitives.
    pub key_total: Option<&'a GpuBuffer>,
    /// The kept view itself (for [`GpuRasterizer::record_backward`]).
    view: &'a BinnedView,
}

/// A view's buffers before any work ([`GpuRasterizer::alloc_view`]).
struct AllocatedView<'a, 'b> {
    view: Transient<'a>,
    /// The resident parameter block to copy into the view's, and its bytes.
    resident_copy: Option<(&'b GpuBuffer, u64)>,
    /// Handle of the tile-count buffer (absent without primitives).
    counts: Option<usize>,
}

/// A view's buffers on the way to the cache or to release: returned to the pool if the render
/// fails.
struct Transient<'a> {
    ctx: &'a GpuContext,
    pool: &'a BufferPool,
    view: Option<BinnedView>,
}

impl<'a> Transient<'a> {
    /// A view with no buffers yet.
    fn new(
        ctx: &'a GpuContext,
        pool: &'a BufferPool,
        tiles: [usize; 2],
        outputs: Outputs,
        camera_block: [f32; 32],
        param_key: ParamKey,
        band_count: Vec<u32>,
    ) -> Self {
        Self {
            ctx,
            pool,
            view: Some(BinnedView {
                buffers: Vec::new(),
                cam: 0,
                params: 0,
                views: 0,
                bands: 0,
                band_count_buf: None,
                total: None,
                keys: None,
                lists: None,
                planes: None,
                outputs,
                tiles,
                camera_block,
                param_key,
                band_count,
            }),
        }
    }

    fn view(&self) -> Result<&BinnedView, GpuError> {
        self.view.as_ref().ok_or_else(|| poisoned("binned view"))
    }

    fn view_mut(&mut self) -> Result<&mut BinnedView, GpuError> {
        self.view.as_mut().ok_or_else(|| poisoned("binned view"))
    }

    fn take(mut self) -> Option<BinnedView> {
        self.view.take()
    }
}

impl Drop for Transient<'_> {
    fn drop(&mut self) {
        if let Some(v) = self.view.take() {
            v.release(self.ctx, self.pool);
        }
    }
}

/// The camera block of `raster_common.glsl`.
pub fn camera_block(cam: &PinholeCamera, settings: &RenderSettings) -> [f32; 32] {
    let mut out = [0f32; 32];
    let c = cam.centre_world();
    let w = cam.pixel_to_world_dir();
    let r = cam.rotation_cam_from_world();
    let t = cam.cam_from_world.translation_m;
    let tail = [
        t.x,
        t.y,
        t.z,
        cam.fx_px,
        cam.fy_px,
        cam.cx_px,
        cam.cy_px,
        settings.near_m,
        cam.width as f64,
        cam.height as f64,
        if settings.cull { 1.0 } else { 0.0 },
    ];
    let fields = c.iter().chain(w.iter()).chain(r.iter()).chain(tail.iter());
    for (o, v) in out.iter_mut().zip(fields) {
        *o = *v as f32;
    }
    out
}

/// The parameter block of `raster_common.glsl` (sections in its order).
pub fn parameter_block(prims: &Primitives<f32>) -> Vec<f32> {
    let mut out = Vec::new();
    for section in [
        &prims.means,
        &prims.log_scales,
        &prims.quats,
        &prims.opacity_logits,
        &prims.beta_raw,
        &prims.omega_low,
        &prims.band_amp,
        &prims.band_freq,
        &prims.band_phase,
    ] {
        out.extend_from_slice(section);
    }
    out
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
        let backward = match (variant, subgroup_reduce) {
            (AccumulateVariant::FloatAtomic, true) => "raster_backward_atomic_sg",
            (AccumulateVariant::FloatAtomic, false) => "raster_backward_atomic",
            (AccumulateVariant::CompareAndSwap, true) => "raster_backward_cas_sg",
            (AccumulateVariant::CompareAndSwap, false) => "raster_backward_cas",
        };
        let names = [
            "raster_project",
            "raster_emit",
            "raster_ranges",
            "raster_forward",
            backward,
            "raster_backward_finish",
        ];
        let mut built = Vec::new();
        for name in names {
            match shaders::build(ctx, name) {
                Ok(k) => built.push(k),
                Err(e) => {
                    for k in built {
                        ctx.destroy_kernel(k);
                    }
                    return Err(e);
                }
            }
        }
        let mut it = built.into_iter();
        match (
            it.next(),
            it.next(),
            it.next(),
            it.next(),
            it.next(),
            it.next(),
        ) {
            (
                Some(project),
                Some(emit),
                Some(ranges),
                Some(forward),
                Some(backward),
                Some(finish),
            ) => Ok(Self {
                project,
                emit,
                ranges,
                forward,
                backward,
                finish,
                variant,
                timings: None,
                scan: Mutex::new(None),
                sort: Mutex::new(None),
                kept: Mutex::new(VecDeque::new()),
                pool: BufferPool::new(),
            }),
            _ => Err(GpuError::Shader {
                name: "raster".to_owned(),
                reason: "kernel list incomplete".to_owned(),
            }),
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

    /// The buffers of one view before any work: camera, parameters (uploaded from the host, or
    /// the resident block to copy in the first submission), primitive views, band views, live
    /// band counts, tile counts.
    fn alloc_view<'a, 'b>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'b>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
    ) -> Result<AllocatedView<'a, 'b>, GpuError> {
        let invalid = |reason: String| GpuError::InvalidInput { reason };
        match src {
            // The host values are the ones rendered: check them.
            ParamSource::Host => prims.validate().map_err(|e| invalid(e.to_string()))?,
            // Resident values: only the structure is on the host.
            ParamSource::Device { buffer, .. } => {
                let need = (parameter_count(prims) * 4) as u64;
                if buffer.size_bytes() < need {
                    return Err(invalid(format!(
                        "resident parameter block `{}` holds {} bytes, {} primitives with {} \
                         bands need {need}",
                        buffer.name(),
                        buffer.size_bytes(),
                        prims.len(),
                        prims.bands
                    )));
                }
            }
        }
        cam.validate().map_err(|e| invalid(e.to_string()))?;
        let n = prims.len();
        let (tiles_x, tiles_y) = (
            cam.width.div_ceil(TILE_SIZE),
            cam.height.div_ceil(TILE_SIZE),
        );
        let camera_block = camera_block(cam, settings);
        let band_count: Vec<u32> = (0..n).map(|i| prims.live_bands(i) as u32).collect();
        let mut out = Transient::new(
            ctx,
            &self.pool,
            [tiles_x, tiles_y],
            outputs,
            camera_block,
            ParamKey::of(prims, src),
            band_count,
        );
        let pool = &self.pool;
        // Per-primitive buffers have room for the run's budget (see BufferPool).
        let cap = pool.prims_capacity(n) as u64;
        let m = prims.bands as u64;
        let param_bytes = (parameter_count(prims) * 4) as u64;
        let param_cap = cap * (13 + 5 * m) * 4;
        let binned = out.view_mut()?;
        binned.cam = binned.keep(pool.upload(ctx, "raster.camera", &binned.camera_block, 0)?);
        // A resident block is copied on the GPU (first thing in the first submission): the
        // optimiser may change it while this view is kept.
        let (params, resident) = match (&binned.param_key, src) {
            (ParamKey::Values(block), _) => {
                (pool.upload(ctx, "raster.params", block, param_cap)?, None)
            }
            (ParamKey::Generation(_), ParamSource::Device { buffer, .. }) => {
                let copy = pool.take(
                    ctx,
                    "raster.params",
                    param_bytes.max(4),
                    param_cap,
                    MemoryLocation::DeviceOnly,
                )?;
                (copy, Some((buffer, param_bytes)))
            }
            (ParamKey::Generation(_), ParamSource::Host) => {
                return Err(poisoned("parameter source"));
            }
        };
        binned.params = binned.keep(params);
        binned.views = binned.keep(pool.take(
            ctx,
            "raster.views",
            n.max(1) as u64 * PRIM_VIEW_BYTES,
            cap * PRIM_VIEW_BYTES,
            MemoryLocation::DeviceOnly,
        )?);
        binned.bands = binned.keep(pool.take(
            ctx,
            "raster.bands",
            (n * prims.bands).max(1) as u64 * BAND_VIEW_BYTES,
            cap * m * BAND_VIEW_BYTES,
            MemoryLocation::DeviceOnly,
        )?);
        if n == 0 {
            return Ok(AllocatedView {
                view: out,
                resident_copy: resident,
                counts: None,
            });
        }
        let band_count =
            binned.keep(pool.upload(ctx, "raster.band_count", &binned.band_count, cap * 4)?);
        binned.band_count_buf = Some(band_count);
        // n counts + 1 trailing zero: after the exclusive scan, element n is the key total.
        let counts = binned.keep(pool.upload(
            ctx,
            "raster.tile_counts",
            &vec![0u32; n + 1],
            (cap + 1) * 4,
        )?);
        binned.total = Some(binned.keep(pool.take(
            ctx,
            "raster.key_total",
            4,
            4,
            MemoryLocation::DeviceOnly,
        )?));
        Ok(AllocatedView {
            view: out,
            resident_copy: resident,
            counts: Some(counts),
        })
    }

    /// Bins and renders `prims` seen by each camera of `cams`: projection, culling, tile counts
    /// and their scan for every view in one submission, then key emission, sort, tile ranges
    /// and `raster_forward` for every view in a second submission. The planes stay on the GPU.
    /// With [`KeySizing::Exact`] the host reads the key totals of all views between the two (one
    /// read) and sizes the key lists exactly; with [`KeySizing::Capacity`] it reads nothing and
    /// every list has room for that many keys (see [`KeySizing`]). Each camera comes with what
    /// its render computes.
    fn bin_and_render_views<'a>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cams: &[(&PinholeCamera, Outputs)],
        settings: &RenderSettings,
        sizing: KeySizing,
    ) -> Result<Vec<Transient<'a>>, GpuError> {
        let n = prims.len();
        let mut outs = Vec::with_capacity(cams.len());
        let mut copies = Vec::with_capacity(cams.len());
        let mut counts = Vec::with_capacity(cams.len());
        for &(cam, outputs) in cams {
            let a = self.alloc_view(ctx, prims, src, cam, outputs, settings)?;
            outs.push(a.view);
            copies.push(a.resident_copy);
            counts.push(a.counts);
        }
        if n == 0 || cams.is_empty() {
            return Ok(outs);
        }
        let mut scan_slot = lock(&self.scan)?;
        if scan_slot.as_ref().is_none_or(|s| s.capacity() < n + 1) {
            if let Some(old) = scan_slot.take() {
                old.destroy(ctx);
            }
            *scan_slot = Some(GpuScan::new(ctx, grown(n + 1))?);
        }
        let scan = scan_slot.as_ref().ok_or_else(|| poisoned("scan"))?;
        let totals_buf = match sizing {
            KeySizing::Exact => Some(self.pool.take(
                ctx,
                "raster.key_totals",
                (4 * cams.len()) as u64,
                (4 * KEPT_VIEWS) as u64,
                MemoryLocation::Readback,
            )?),
            KeySizing::Capacity(_) => None,
        };
        let first = (|| -> Result<Vec<u32>, GpuError> {
            self.submit(ctx, |rec| {
                for (v, out) in outs.iter().enumerate() {
                    let b = out.view()?;
                    let c = counts[v].ok_or_else(|| poisoned("tile counts"))?;
                    let bc = b.band_count_buf.ok_or_else(|| poisoned("band counts"))?;
                    let total = b.total.ok_or_else(|| poisoned("key total"))?;
                    let [tiles_x, tiles_y] = b.tiles;
                    if let Some((buffer, bytes)) = copies[v] {
                        rec.copy_buffer(buffer, b.get(b.params), bytes)?;
                    }
                    rec.dispatch(
                        &self.project,
                        &[
                            b.get(b.cam),
                            b.get(b.params),
                            b.get(b.views),
                            b.get(c),
                            b.get(b.bands),
                            b.get(bc),
                        ],
                        &push_u32s(&[n as u32, prims.bands as u32, tiles_x as u32, tiles_y as u32]),
                        [n.div_ceil(PROJECT_WG) as u32, 1, 1],
                    )?;
                    rec.compute_barrier();
                    scan.record(rec, b.get(c), n + 1)?;
                    rec.copy_region(b.get(c), (4 * n) as u64, b.get(total), 0, 4)?;
                    if let Some(t) = &totals_buf {
                        rec.copy_region(b.get(c), (4 * n) as u64, t, (4 * v) as u64, 4)?;
                    }
                }
                Ok(())
            })?;
            match (&totals_buf, sizing) {
                (Some(t), _) => ctx.read::<u32>(t, cams.len()),
                (None, KeySizing::Capacity(cap)) => Ok(vec![cap as u32; cams.len()]),
                (None, KeySizing::Exact) => Err(poisoned("key totals")),
            }
        })();
        drop(scan_slot);
        if let Some(t) = totals_buf {
            self.pool.give(ctx, t);
        }
        // Exact: the totals; Capacity: the room of every list (the totals stay on the GPU).
        let room = first?;

        // Keys, lists and planes of every covered view.
        let mut max_room = 0;
        for (v, out) in outs.iter_mut().enumerate() {
            let room = room[v] as usize;
            if room == 0 {
                continue;
            }
            max_room = max_room.max(room);
            let binned = out.view_mut()?;
            let tiles = binned.tiles[0] * binned.tiles[1];
            let pool = &self.pool;
            let room_cap = grown(room) as u64;
            let keys = binned.keep(pool.take(
                ctx,
                "raster.keys",
                (room * 8) as u64,
                room_cap * 8,
                MemoryLocation::DeviceOnly,
            )?);
            let values = binned.keep(pool.take(
                ctx,
                "raster.values",
                (room * 4) as u64,
                room_cap * 4,
                MemoryLocation::DeviceOnly,
            )?);
            let ranges =
                binned.keep(pool.upload(ctx, "raster.ranges", &vec![[0u32; 2]; tiles], 0)?);
            let npix = (cams[v].0.width * cams[v].0.height) as u64;
            let planes = binned.keep(pool.take(
                ctx,
                "raster.planes",
                FORWARD_PLANES as u64 * npix * 4,
                0,
                MemoryLocation::Readback,
            )?);
            binned.keys = Some(keys);
            binned.lists = Some((values, ranges));
            binned.planes = Some(planes);
        }
        if max_room == 0 {
            return Ok(outs);
        }
        let mut sort_slot = lock(&self.sort)?;
        if sort_slot.as_ref().is_none_or(|s| s.capacity() < max_room) {
            if let Some(old) = sort_slot.take() {
                old.destroy(ctx);
            }
            *sort_slot = Some(GpuRadixSort::new(ctx, grown(max_room))?);
        }
        let sort = sort_slot.as_ref().ok_or_else(|| poisoned("sort"))?;
        let second = self.submit(ctx, |rec| {
            for (v, out) in outs.iter().enumerate() {
                let b = out.view()?;
                let (Some(keys), Some((values, ranges)), Some(planes), Some(c), Some(total)) =
                    (b.keys, b.lists, b.planes, counts[v], b.total)
                else {
                    continue;
                };
                let room = room[v] as usize;
                let [tiles_x, tiles_y] = b.tiles;
                let tiles = tiles_x * tiles_y;
                let key_bits = 32 + (usize::BITS - (tiles.max(2) - 1).leading_zeros());
                rec.dispatch(
                    &self.emit,
                    &[b.get(b.views), b.get(c), b.get(keys), b.get(values)],
                    &push_u32s(&[n as u32, tiles_x as u32, room as u32]),
                    [n.div_ceil(PROJECT_WG) as u32, 1, 1],
                )?;
                rec.compute_barrier();
                let count = ItemCount {
                    at_most: room,
                    buffer: b.get(total),
                    index: 0,
                };
                sort.record(rec, b.get(keys), b.get(values), count, key_bits)?;
                rec.dispatch(
                    &self.ranges,
                    &[b.get(keys), b.get(ranges), b.get(total)],
                    &push_u32s(&[room as u32]),
                    [room.div_ceil(RANGES_WG) as u32, 1, 1],
                )?;
                rec.compute_barrier();
                rec.dispatch(
                    &self.forward,
                    &[
                        b.get(b.cam),
                        b.get(b.views),
                        b.get(b.bands),
                        b.get(values),
                        b.get(ranges),
                        b.get(planes),
                    ],
                    &push_u32s(&[
                        n as u32,
                        prims.bands as u32,
                        cams[v].0.width as u32,
                        cams[v].0.height as u32,
                        tiles_x as u32,
                        b.outputs.thermal_flag(),
                    ]),
                    [2 * tiles_x as u32, tiles_y as u32, 1],
                )?;
                rec.compute_barrier();
            }
            Ok(())
        });
        drop(sort_slot);
        second?;
        Ok(outs)
    }

    /// Bins `prims` for `cam` and runs the forward kernel; the planes stay on the GPU.
    fn bin_and_render<'a>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
    ) -> Result<Transient<'a>, GpuError> {
        self.bin_and_render_views(
            ctx,
            prims,
            src,
            &[(cam, outputs)],
            settings,
            KeySizing::Exact,
        )?
        .pop()
        .ok_or_else(|| poisoned("rendered view"))
    }

    /// Keeps a rendered view for the backward pass of the same view and parameters.
    fn keep_view(&self, ctx: &GpuContext, view: BinnedView) -> Result<(), GpuError> {
        let mut kept = lock(&self.kept)?;
        kept.push_back(view);
        while kept.len() > KEPT_VIEWS {
            if let Some(old) = kept.pop_front() {
                old.release(ctx, &self.pool);
            }
        }
        Ok(())
    }

    /// Renders the thermal image and G-buffers (no RGB planes) of `prims` seen by `cam`; with
    /// [`Outputs::GBuffers`] the thermal plane is zero.
    pub fn render(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
    ) -> Result<GBuffers<f32>, GpuError> {
        let rendered =
            self.bin_and_render(ctx, prims, ParamSource::Host, cam, outputs, settings)?;
        let npix = cam.width * cam.height;
        let mut out = GBuffers::zeros(cam.width, cam.height, false);
        let view = rendered.view()?;
        if let Some(planes) = view.planes {
            let data: Vec<f32> = ctx.read(view.get(planes), 6 * npix)?;
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
        }
        if let Some(view) = rendered.take() {
            self.keep_view(ctx, view)?;
        }
        Ok(out)
    }

    /// Renders `prims` seen by each camera of `cams` (at most [`KEPT_VIEWS`]) and keeps the
    /// planes on the GPU for [`GpuRasterizer::submit_with_views`] and the backward pass: two
    /// submissions for all the views, and nothing read back but their key totals (one read;
    /// none with [`KeySizing::Capacity`]).
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
        for rendered in self.bin_and_render_views(ctx, prims, src, cams, settings, sizing)? {
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
        let key_params = ParamKey::of(prims, src);
        let kept = lock(&self.kept)?;
        let mut views = Vec::with_capacity(cams.len());
        for &(cam, outputs) in cams {
            let key_cam = camera_block(cam, settings);
            let v = kept
                .iter()
                .find(|v| v.outputs.serves(outputs) && v.is_view_of(&key_cam, &key_params, prims))
                .ok_or_else(|| GpuError::InvalidInput {
                    reason: "submit_with_views: a view was not rendered from these parameters"
                        .to_owned(),
                })?;
            views.push(KeptView {
                camera: v.get(v.cam),
                planes: v.planes.map(|h| v.get(h)),
                key_total: v.total.map(|h| v.get(h)),
                width: cam.width,
                height: cam.height,
                view: v,
            });
        }
        self.submit(ctx, |rec| record(rec, &views))
    }

    /// Gradient of `Σ upstream · buffers` w.r.t. every parameter of `prims` (same layout as
    /// `prims`; the SH colour group stays zero: no RGB branch on the GPU yet). `upstream` gives
    /// dL/d(thermal, psi_low, psi_high, psi_beta, depth, alpha); an empty plane counts as zero.
    /// When the same view of the same parameters was just rendered, its binning and forward
    /// planes are reused; otherwise the view is binned and rendered first.
    pub fn render_backward(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        settings: &RenderSettings,
        upstream: &GBuffers<f32>,
    ) -> Result<Primitives<f32>, GpuError> {
        let (width, height) = (cam.width, cam.height);
        let npix = width * height;
        let mut up = vec![0f32; 6 * npix];
        let sources = [
            ("thermal", &upstream.thermal),
            ("psi_low", &upstream.psi_low),
            ("psi_high", &upstream.psi_high),
            ("psi_beta", &upstream.psi_beta),
            ("depth", &upstream.depth),
            ("alpha", &upstream.alpha),
        ];
        for ((name, src), dst) in sources.into_iter().zip(up.chunks_exact_mut(npix)) {
            if src.is_empty() {
                continue;
            }
            if src.len() != npix {
                return Err(GpuError::InvalidInput {
                    reason: format!(
                        "upstream {name} has {} values, the {width}x{height} view needs {npix}",
                        src.len()
                    ),
                });
            }
            dst.copy_from_slice(src);
        }
        // Without thermal upstream the band phases need not be evaluated (same gradients).
        let outputs = if upstream.thermal.iter().all(|&g| g == 0.0) {
            Outputs::GBuffers
        } else {
            Outputs::All
        };
        let up_buf = self.pool.upload(ctx, "raster.upstream", &up, 0)?;
        let result = self.render_backward_device(ctx, prims, cam, outputs, settings, &up_buf);
        self.pool.give(ctx, up_buf);
        result
    }

    /// [`GpuRasterizer::render_backward`] with the upstream gradient planes already on the GPU
    /// (6 planes of `cam.width × cam.height` floats, the order of [`PLANES`]); with
    /// [`Outputs::GBuffers`] the thermal plane of `up_buf` is taken as zero.
    pub fn render_backward_device(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
        up_buf: &GpuBuffer,
    ) -> Result<Primitives<f32>, GpuError> {
        let mut grads = prims.zeros_like();
        let param_count = parameter_count(prims);
        let out = self.pool.take(
            ctx,
            "raster.grads",
            (param_count.max(1) * 4) as u64,
            0,
            MemoryLocation::Readback,
        )?;
        let result = self
            .backward_into(
                ctx,
                prims,
                ParamSource::Host,
                cam,
                outputs,
                settings,
                up_buf,
                &out,
            )
            .and_then(|written| {
                if written {
                    ctx.read::<f32>(&out, param_count)
                } else {
                    Ok(Vec::new())
                }
            });
        self.pool.give(ctx, out);
        let flat = result?;
        if flat.is_empty() {
            return Ok(grads);
        }
        let mut rest = flat.as_slice();
        let targets = [
            &mut grads.means,
            &mut grads.log_scales,
            &mut grads.quats,
            &mut grads.opacity_logits,
            &mut grads.beta_raw,
            &mut grads.omega_low,
            &mut grads.band_amp,
            &mut grads.band_freq,
            &mut grads.band_phase,
        ];
        for target in targets {
            let (head, tail) = rest.split_at(target.len().min(rest.len()));
            target.copy_from_slice(head);
            rest = tail;
        }
        Ok(grads)
    }

    /// The backward pass of `cam` with the upstream planes in `up_buf`, writing the parameter
    /// gradients into `out` on the GPU (the parameter-block layout, [`parameter_count`] floats;
    /// nothing is read back). Returns `false` when no primitive covers the view: `out` is then
    /// not written and the caller treats the gradient as zero. With [`Outputs::GBuffers`] the
    /// thermal upstream is taken as zero (see [`Outputs`]).
    #[allow(clippy::too_many_arguments)]
    pub fn backward_into(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
        up_buf: &GpuBuffer,
        out: &GpuBuffer,
    ) -> Result<bool, GpuError> {
        let (width, height) = (cam.width, cam.height);
        let npix = width * height;
        if up_buf.size_bytes() < (6 * npix * 4) as u64 {
            return Err(GpuError::InvalidInput {
                reason: format!(
                    "upstream buffer of {} bytes, the {width}x{height} view needs {}",
                    up_buf.size_bytes(),
                    6 * npix * 4
                ),
            });
        }
        let param_count = parameter_count(prims);
        if out.size_bytes() < (param_count * 4) as u64 {
            return Err(GpuError::BufferRange {
                name: out.name().to_owned(),
                requested_bytes: (param_count * 4) as u64,
                capacity_bytes: out.size_bytes(),
            });
        }
        let key_cam = camera_block(cam, settings);
        let key_params = ParamKey::of(prims, src);
        let mut kept = lock(&self.kept)?;
        let position = kept
            .iter()
            .position(|v| v.outputs.serves(outputs) && v.is_view_of(&key_cam, &key_params, prims));
        let mut fresh = None;
        let view: &mut BinnedView = match position {
            Some(at) => &mut kept[at],
            None => {
                drop(kept);
                fresh = Some(self.bin_and_render(ctx, prims, src, cam, outputs, settings)?);
                kept = lock(&self.kept)?;
                fresh
                    .as_mut()
                    .and_then(|t| t.view.as_mut())
                    .ok_or_else(|| poisoned("binned view"))?
            }
        };
        if view.lists.is_none() || view.planes.is_none() {
            return Ok(false);
        }
        // Scratch for this call, returned to the pool at its end.
        let acc = self.pool.take(
            ctx,
            "raster.grad_acc",
            Self::backward_scratch_floats(prims).max(1) as u64 * 4,
            0,
            MemoryLocation::DeviceOnly,
        )?;
        let v = &*view;
        let kept_view = KeptView {
            camera: v.get(v.cam),
            planes: v.planes.map(|h| v.get(h)),
            key_total: v.total.map(|h| v.get(h)),
            width,
            height,
            view: v,
        };
        let recorded = self.submit(ctx, |rec| {
            self.record_backward(rec, prims, &kept_view, outputs, up_buf, &acc, out)
                .map(|_| ())
        });
        self.pool.give(ctx, acc);
        recorded?;
        drop(kept);
        drop(fresh);
        Ok(true)
    }

    /// Floats of the view-space gradient sums [`Self::record_backward`] needs as scratch.
    pub fn backward_scratch_floats(prims: &Primitives<f32>) -> usize {
        acc_fields(prims.bands) * prims.len()
    }

    /// Records the backward pass of a kept view (inside [`Self::submit_with_views`]) with the
    /// upstream planes in `up_buf`, writing the parameter gradients into `out` (the
    /// parameter-block layout, [`parameter_count`] floats) and using `acc`
    /// ([`Self::backward_scratch_floats`]) as scratch. Returns `false` when no primitive covers
    /// the view: nothing is recorded and the caller treats the gradient as zero. With
    /// [`Outputs::GBuffers`] the thermal upstream is taken as zero (see [`Outputs`]); a view
    /// rendered without its thermal image cannot take thermal upstream.
    #[allow(clippy::too_many_arguments)]
    pub fn record_backward(
        &self,
        rec: &mut Recorder<'_>,
        prims: &Primitives<f32>,
        view: &KeptView<'_>,
        outputs: Outputs,
        up_buf: &GpuBuffer,
        acc: &GpuBuffer,
        out: &GpuBuffer,
    ) -> Result<bool, GpuError> {
        let (width, height) = (view.width, view.height);
        let npix = width * height;
        let need = [
            (up_buf, (6 * npix * 4) as u64),
            (acc, (Self::backward_scratch_floats(prims) * 4) as u64),
            (out, (parameter_count(prims) * 4) as u64),
        ];
        for (b, bytes) in need {
            if b.size_bytes() < bytes {
                return Err(GpuError::BufferRange {
                    name: b.name().to_owned(),
                    requested_bytes: bytes,
                    capacity_bytes: b.size_bytes(),
                });
            }
        }
        let v = view.view;
        if !v.outputs.serves(outputs) {
            return Err(GpuError::InvalidInput {
                reason: "record_backward: thermal upstream for a view rendered without its \
                         thermal image"
                    .to_owned(),
            });
        }
        let (Some((values, ranges)), Some(planes)) = (v.lists, v.planes) else {
            return Ok(false);
        };
        let n = prims.len();
        let [tiles_x, tiles_y] = v.tiles;
        rec.fill_zero(acc);
        rec.dispatch(
            &self.backward,
            &[
                v.get(v.cam),
                v.get(v.views),
                v.get(v.bands),
                v.get(values),
                v.get(ranges),
                up_buf,
                v.get(planes),
                acc,
            ],
            &push_u32s(&[
                n as u32,
                prims.bands as u32,
                width as u32,
                height as u32,
                tiles_x as u32,
                outputs.thermal_flag(),
            ]),
            [2 * tiles_x as u32, tiles_y as u32, 1],
        )?;
        rec.compute_barrier();
        rec.dispatch(
            &self.finish,
            &[v.get(v.cam), v.get(v.params), acc, out, v.get(v.views)],
            &push_u32s(&[n as u32, prims.bands as u32]),
            [n.div_ceil(PROJECT_WG) as u32, 1, 1],
        )?;
        rec.compute_barrier();
        Ok(true)
    }

    pub fn destroy(self, ctx: &GpuContext) {
        for k in [
            self.project,
            self.emit,
            self.ranges,
            self.forward,
            self.backward,
            self.finish,
        ] {
            ctx.destroy_kernel(k);
        }
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

fn lock<T>(m: &Mutex<T>) -> Result<std::sync::MutexGuard<'_, T>, GpuError> {
    m.lock().map_err(|_| poisoned("rasteriser cache"))
}

fn poisoned(what: &str) -> GpuError {
    GpuError::InvalidInput {
        reason: format!("{what} unavailable: an earlier panic left it in an unknown state"),
    }
}
