//! The views the rasteriser keeps on the GPU: a view's buffers while it is binned and rendered
//! ([`Transient`], returned to the pool if the work fails), the last rendered views kept for
//! the backward pass of the same view and parameters ([`BinnedView`], matched by camera block,
//! parameters and live band counts), and the handle the training step's kernels get
//! ([`KeptView`]).

use super::layout::parameter_block;
use super::{GpuRasterizer, Outputs, ParamSource, lock, poisoned};
use crate::gpu::context::{GpuBuffer, GpuContext};
use crate::gpu::error::GpuError;
use crate::gpu::pool::BufferPool;
use crate::primitive::Primitives;

/// Rendered views kept for the backward pass of the same view (the training step renders at
/// most two views before it back-propagates them).
pub(super) const KEPT_VIEWS: usize = 2;

/// What a view was binned from: the parameter values (host source) or the generation of a
/// resident parameter block.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum ParamKey {
    Values(Vec<f32>),
    Generation(u64),
}

impl ParamKey {
    pub(super) fn of(prims: &Primitives<f32>, src: ParamSource<'_>) -> Self {
        match src {
            ParamSource::Host => Self::Values(parameter_block(prims)),
            ParamSource::Device { generation, .. } => Self::Generation(generation),
        }
    }
}

/// A view binned (and, once rendered, with its forward planes) on the GPU. The buffers are
/// owned here and released with [`BinnedView::release`]; [`Transient`] does that on drop.
#[derive(Debug)]
pub(super) struct BinnedView {
    pub(super) buffers: Vec<GpuBuffer>,
    pub(super) cam: usize,
    pub(super) params: usize,
    pub(super) views: usize,
    pub(super) bands: usize,
    /// Live band counts (absent without primitives).
    pub(super) band_count_buf: Option<usize>,
    /// The key total (u32) the GPU computed when binning (absent without primitives).
    pub(super) total: Option<usize>,
    /// The (tile, depth) keys (absent when no primitive covers the view).
    pub(super) keys: Option<usize>,
    /// Sorted primitive indices and per-tile ranges; `None` when no primitive covers a tile.
    pub(super) lists: Option<(usize, usize)>,
    /// Output of `raster_forward` ([`super::layout::forward_planes`] planes), once rendered.
    pub(super) planes: Option<usize>,
    /// What `raster_forward` computed.
    pub(super) outputs: Outputs,
    /// Whether the view has the colours of its primitives (`colours`) and the R, G, B planes
    /// (the `*_rgb` kernels).
    pub(super) colour: bool,
    /// The primitives' colours in this view (with `colour`).
    pub(super) colours: Option<usize>,
    pub(super) tiles: [usize; 2],
    /// What was binned: the camera block, the parameters and the live band counts (the cache
    /// key of kept views).
    pub(super) camera_block: [f32; 32],
    pub(super) param_key: ParamKey,
    pub(super) band_count: Vec<u32>,
}

impl BinnedView {
    pub(super) fn keep(&mut self, b: GpuBuffer) -> usize {
        self.buffers.push(b);
        self.buffers.len() - 1
    }

    pub(super) fn get(&self, handle: usize) -> &GpuBuffer {
        &self.buffers[handle]
    }

    /// Whether this view's render serves a request for `outputs`, with the colour when
    /// `colour` (a view with colour serves requests without: its other planes are the same).
    pub(super) fn serves(&self, outputs: Outputs, colour: bool) -> bool {
        self.outputs.serves(outputs) && (self.colour || !colour)
    }

    /// The view's buffers for a `width × height` camera.
    pub(super) fn kept(&self, width: usize, height: usize) -> KeptView<'_> {
        KeptView {
            camera: self.get(self.cam),
            planes: self.planes.map(|h| self.get(h)),
            key_total: self.total.map(|h| self.get(h)),
            width,
            height,
            view: self,
        }
    }

    /// Whether this view was binned from this camera block, these parameters and `prims`' live
    /// band counts (the key of kept views).
    pub(super) fn is_view_of(
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
    pub(super) fn release(mut self, ctx: &GpuContext, pool: &BufferPool) {
        for b in self.buffers.drain(..) {
            pool.give(ctx, b);
        }
    }
}

/// The GPU buffers of a kept rendered view (see [`GpuRasterizer::submit_with_views`]).
#[derive(Debug, Clone, Copy)]
pub struct KeptView<'a> {
    /// The camera block ([`super::camera_block`]).
    pub camera: &'a GpuBuffer,
    /// `raster_forward`'s planes (the six of [`super::PLANES`], then the end plane, then for a view
    /// with colour R, G, B); `None` when no primitive covers the view (every plane is then
    /// zero).
    pub planes: Option<&'a GpuBuffer>,
    pub width: usize,
    pub height: usize,
    /// The view's key total (one u32) as the GPU computed it; `None` without primitives.
    pub key_total: Option<&'a GpuBuffer>,
    /// The kept view itself (for [`GpuRasterizer::record_backward`]).
    pub(super) view: &'a BinnedView,
}

/// A view's buffers before any work ([`GpuRasterizer::alloc_view`]).
pub(super) struct AllocatedView<'a, 'b> {
    pub(super) view: Transient<'a>,
    /// The resident parameter block to copy into the view's, and its bytes.
    pub(super) resident_copy: Option<(&'b GpuBuffer, u64)>,
    /// Handle of the tile-count buffer (absent without primitives).
    pub(super) counts: Option<usize>,
}

/// A view's buffers on the way to the cache or to release: returned to the pool if the render
/// fails.
pub(super) struct Transient<'a> {
    pub(super) ctx: &'a GpuContext,
    pub(super) pool: &'a BufferPool,
    pub(super) view: Option<BinnedView>,
}

impl<'a> Transient<'a> {
    /// A view with no buffers yet.
    pub(super) fn new(
        ctx: &'a GpuContext,
        pool: &'a BufferPool,
        tiles: [usize; 2],
        (outputs, colour): (Outputs, bool),
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
                colour,
                colours: None,
                tiles,
                camera_block,
                param_key,
                band_count,
            }),
        }
    }

    pub(super) fn view(&self) -> Result<&BinnedView, GpuError> {
        self.view.as_ref().ok_or_else(|| poisoned("binned view"))
    }

    pub(super) fn view_mut(&mut self) -> Result<&mut BinnedView, GpuError> {
        self.view.as_mut().ok_or_else(|| poisoned("binned view"))
    }

    pub(super) fn take(mut self) -> Option<BinnedView> {
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

impl GpuRasterizer {
    /// Keeps a rendered view for the backward pass of the same view and parameters.
    pub(super) fn keep_view(&self, ctx: &GpuContext, view: BinnedView) -> Result<(), GpuError> {
        let mut kept = lock(&self.kept)?;
        kept.push_back(view);
        while kept.len() > KEPT_VIEWS {
            if let Some(old) = kept.pop_front() {
                old.release(ctx, &self.pool);
            }
        }
        Ok(())
    }
}
