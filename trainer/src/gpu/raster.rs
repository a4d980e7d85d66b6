//! GPU forward rasteriser of S³-TIR primitives: the CPU reference renderer
//! (`crate::render`, same maths, same order, same thresholds) as compute kernels.
//!
//! Per view: `raster_project` (derived parameters, whitened ray data, visibility, culling
//! rectangle, tile counts) → exclusive scan of the counts (one 4-byte readback: the number of
//! (tile, primitive) keys) → `raster_emit` (keys `(tile, depth bits)` + primitive index) →
//! stable radix sort → `raster_ranges` (per-tile ranges) → `raster_forward` (one workgroup per
//! 16×16 tile: thermal image and the G-buffers Ψ_low, Ψ_high, Ψ_β, depth, alpha).
//!
//! Backward (`render_backward`): the same binning, then `raster_backward_{atomic,cas}` (per
//! pixel, the exact gradients of the CPU reference's backward pass, accumulated per primitive
//! with `atomicAdd(float)` or, without float atomics, a compare-and-swap loop — chosen from the
//! context's capabilities) and `raster_backward_finish` (per primitive: chain to the parameters).
//!
//! Not here yet: the RGB (SH colour) branch, buffer reuse across views and steps.

use super::accumulate::AccumulateVariant;
use std::sync::Mutex;

use super::context::{
    ComputeKernel, GpuBuffer, GpuContext, KernelTiming, MemoryLocation, Recorder,
};
use super::error::GpuError;
use super::scan::GpuScan;
use super::shaders::{self, push_u32s};
use super::sort::GpuRadixSort;
use crate::camera::PinholeCamera;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings, TILE_SIZE};

/// Bytes of one `PrimView` (raster_common.glsl).
const PRIM_VIEW_BYTES: u64 = 128;
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
}

/// Capacity to allocate for `need` items: 25 % headroom so slowly growing views do not
/// reallocate every step.
fn grown(need: usize) -> usize {
    need + need / 4 + 64
}

/// Floats of per-primitive view-space gradient sums (`ACC_STRIDE` in the shaders).
const ACC_STRIDE: usize = 17;

/// A view binned on the GPU: buffers (released with the scope) and the number of keys.
struct BinnedView<'a> {
    scope: BufferScope<'a>,
    cam: usize,
    params: usize,
    views: usize,
    /// Sorted primitive indices and per-tile ranges; `None` when no primitive covers a tile.
    lists: Option<(usize, usize)>,
    tiles: [usize; 2],
}

/// The camera block of `raster_common.glsl`.
fn camera_block(cam: &PinholeCamera, settings: &RenderSettings) -> [f32; 32] {
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
fn parameter_block(prims: &Primitives<f32>) -> Vec<f32> {
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
        // Subgroup arithmetic, where present, sums each subgroup's contributions before the
        // atomic: 1 atomic per subgroup instead of one per pixel.
        let backward = match (variant, ctx.capabilities().subgroup_arithmetic) {
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
            }),
            _ => Err(GpuError::Shader {
                name: "raster".to_owned(),
                reason: "kernel list incomplete".to_owned(),
            }),
        }
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

    /// Projection, culling, key emission, sort and tile ranges of one view (two submissions and
    /// one 4-byte readback: the key count).
    fn bin_view<'a>(
        &self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        settings: &RenderSettings,
    ) -> Result<BinnedView<'a>, GpuError> {
        let invalid = |reason: String| GpuError::InvalidInput { reason };
        prims.validate().map_err(|e| invalid(e.to_string()))?;
        cam.validate().map_err(|e| invalid(e.to_string()))?;
        let n = prims.len();
        let (tiles_x, tiles_y) = (
            cam.width.div_ceil(TILE_SIZE),
            cam.height.div_ceil(TILE_SIZE),
        );
        let tiles = tiles_x * tiles_y;
        let mut scope = BufferScope {
            ctx,
            buffers: Vec::new(),
        };
        let cam_buf = scope.keep(ctx.upload("raster.camera", &camera_block(cam, settings))?);
        let params = scope.keep(ctx.upload("raster.params", &parameter_block(prims))?);
        let views = scope.keep(ctx.create_buffer(
            "raster.views",
            n.max(1) as u64 * PRIM_VIEW_BYTES,
            MemoryLocation::DeviceOnly,
        )?);
        let mut binned = BinnedView {
            scope,
            cam: cam_buf,
            params,
            views,
            lists: None,
            tiles: [tiles_x, tiles_y],
        };
        if n == 0 {
            return Ok(binned);
        }
        // n counts + 1 trailing zero: after the exclusive scan, element n is the key total.
        let counts = binned
            .scope
            .keep(ctx.upload("raster.tile_counts", &vec![0u32; n + 1])?);
        let scope = &binned.scope;
        let mut scan_slot = lock(&self.scan)?;
        if scan_slot.as_ref().is_none_or(|s| s.capacity() < n + 1) {
            if let Some(old) = scan_slot.take() {
                old.destroy(ctx);
            }
            *scan_slot = Some(GpuScan::new(ctx, grown(n + 1))?);
        }
        let scan = scan_slot.as_ref().ok_or_else(|| poisoned("scan"))?;
        let project_push =
            push_u32s(&[n as u32, prims.bands as u32, tiles_x as u32, tiles_y as u32]);
        let first = self.submit(ctx, |rec| {
            rec.dispatch(
                &self.project,
                &[
                    scope.get(cam_buf),
                    scope.get(params),
                    scope.get(views),
                    scope.get(counts),
                ],
                &project_push,
                [n.div_ceil(PROJECT_WG) as u32, 1, 1],
            )?;
            rec.compute_barrier();
            scan.record(rec, scope.get(counts), n + 1)
        });
        drop(scan_slot);
        first?;
        let total = ctx
            .read_at::<u32>(scope.get(counts), n, 1)?
            .first()
            .copied()
            .unwrap_or(0) as usize;
        if total == 0 {
            return Ok(binned);
        }
        let keys = binned.scope.keep(ctx.create_buffer(
            "raster.keys",
            (total * 8) as u64,
            MemoryLocation::DeviceOnly,
        )?);
        let values = binned.scope.keep(ctx.create_buffer(
            "raster.values",
            (total * 4) as u64,
            MemoryLocation::DeviceOnly,
        )?);
        let ranges = binned
            .scope
            .keep(ctx.upload("raster.ranges", &vec![[0u32; 2]; tiles])?);
        let scope = &binned.scope;
        let key_bits = 32 + (usize::BITS - (tiles.max(2) - 1).leading_zeros());
        let mut sort_slot = lock(&self.sort)?;
        if sort_slot.as_ref().is_none_or(|s| s.capacity() < total) {
            if let Some(old) = sort_slot.take() {
                old.destroy(ctx);
            }
            *sort_slot = Some(GpuRadixSort::new(ctx, grown(total))?);
        }
        let sort = sort_slot.as_ref().ok_or_else(|| poisoned("sort"))?;
        let second = self.submit(ctx, |rec| {
            rec.dispatch(
                &self.emit,
                &[
                    scope.get(views),
                    scope.get(counts),
                    scope.get(keys),
                    scope.get(values),
                ],
                &push_u32s(&[n as u32, tiles_x as u32]),
                [n.div_ceil(PROJECT_WG) as u32, 1, 1],
            )?;
            rec.compute_barrier();
            sort.record(rec, scope.get(keys), scope.get(values), total, key_bits)?;
            rec.dispatch(
                &self.ranges,
                &[scope.get(keys), scope.get(ranges)],
                &push_u32s(&[total as u32]),
                [total.div_ceil(RANGES_WG) as u32, 1, 1],
            )?;
            rec.compute_barrier();
            Ok(())
        });
        drop(sort_slot);
        second?;
        binned.lists = Some((values, ranges));
        Ok(binned)
    }

    /// Renders the thermal image and G-buffers (no RGB planes) of `prims` seen by `cam`.
    pub fn render(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        settings: &RenderSettings,
    ) -> Result<GBuffers<f32>, GpuError> {
        let mut binned = self.bin_view(ctx, prims, cam, settings)?;
        let (width, height) = (cam.width, cam.height);
        let npix = width * height;
        let mut out = GBuffers::zeros(width, height, false);
        let Some((values, ranges)) = binned.lists else {
            return Ok(out);
        };
        let planes = binned.scope.keep(ctx.create_buffer(
            "raster.planes",
            (6 * npix * 4) as u64,
            MemoryLocation::Readback,
        )?);
        let scope = &binned.scope;
        let [tiles_x, tiles_y] = binned.tiles;
        self.submit(ctx, |rec| {
            rec.dispatch(
                &self.forward,
                &[
                    scope.get(binned.cam),
                    scope.get(binned.params),
                    scope.get(binned.views),
                    scope.get(values),
                    scope.get(ranges),
                    scope.get(planes),
                ],
                &push_u32s(&[
                    prims.len() as u32,
                    prims.bands as u32,
                    width as u32,
                    height as u32,
                    tiles_x as u32,
                ]),
                [tiles_x as u32, tiles_y as u32, 1],
            )
        })?;
        let data: Vec<f32> = ctx.read(scope.get(planes), 6 * npix)?;
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
        Ok(out)
    }

    /// Gradient of `Σ upstream · buffers` w.r.t. every parameter of `prims` (same layout as
    /// `prims`; the SH colour group stays zero: no RGB branch on the GPU yet). `upstream` gives
    /// dL/d(thermal, psi_low, psi_high, psi_beta, depth, alpha); an empty plane counts as zero.
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
        let mut grads = prims.zeros_like();
        let mut binned = self.bin_view(ctx, prims, cam, settings)?;
        let Some((values, ranges)) = binned.lists else {
            return Ok(grads);
        };
        let n = prims.len();
        // Floats of the parameter block (raster_common.glsl): every group but the SH colour.
        let param_count: usize = prims
            .groups()
            .iter()
            .filter(|(name, _)| *name != "sh")
            .map(|(_, v)| v.len())
            .sum();
        let up_buf = binned.scope.keep(ctx.upload("raster.upstream", &up)?);
        let acc = binned
            .scope
            .keep(ctx.upload("raster.grad_acc", &vec![0f32; ACC_STRIDE * n])?);
        let out = binned
            .scope
            .keep(ctx.upload("raster.grads", &vec![0f32; param_count])?);
        let scope = &binned.scope;
        let [tiles_x, tiles_y] = binned.tiles;
        self.submit(ctx, |rec| {
            rec.dispatch(
                &self.backward,
                &[
                    scope.get(binned.cam),
                    scope.get(binned.params),
                    scope.get(binned.views),
                    scope.get(values),
                    scope.get(ranges),
                    scope.get(up_buf),
                    scope.get(acc),
                    scope.get(out),
                ],
                &push_u32s(&[
                    n as u32,
                    prims.bands as u32,
                    width as u32,
                    height as u32,
                    tiles_x as u32,
                ]),
                [tiles_x as u32, tiles_y as u32, 1],
            )?;
            rec.compute_barrier();
            rec.dispatch(
                &self.finish,
                &[
                    scope.get(binned.cam),
                    scope.get(binned.params),
                    scope.get(acc),
                    scope.get(out),
                ],
                &push_u32s(&[n as u32, prims.bands as u32]),
                [n.div_ceil(PROJECT_WG) as u32, 1, 1],
            )
        })?;
        let flat: Vec<f32> = ctx.read(scope.get(out), param_count)?;
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

/// Buffers of one render, released together whatever path the render takes.
struct BufferScope<'a> {
    ctx: &'a GpuContext,
    buffers: Vec<GpuBuffer>,
}

impl BufferScope<'_> {
    fn keep(&mut self, b: GpuBuffer) -> usize {
        self.buffers.push(b);
        self.buffers.len() - 1
    }

    fn get(&self, handle: usize) -> &GpuBuffer {
        &self.buffers[handle]
    }
}

impl Drop for BufferScope<'_> {
    fn drop(&mut self) {
        for b in self.buffers.drain(..) {
            self.ctx.destroy_buffer(b);
        }
    }
}
