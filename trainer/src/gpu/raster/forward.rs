//! Binning and the forward pass of views: buffer allocation, `raster_project` → scan of the
//! tile counts → `raster_emit` → sort → `raster_ranges` → `raster_forward`, in two submissions
//! for any number of views.

use super::layout::{
    BAND_VIEW_BYTES, COLOUR_BYTES, KeySizing, PRIM_VIEW_BYTES, PROJECT_WG, RANGES_WG, camera_block,
    forward_planes, grown, parameter_count,
};
use super::view_cache::{AllocatedView, KEPT_VIEWS, ParamKey, Transient};
use super::{GpuRasterizer, Outputs, ParamSource, has_colour, lock, poisoned};
use crate::camera::PinholeCamera;
use crate::gpu::context::{GpuContext, MemoryLocation};
use crate::gpu::error::GpuError;
use crate::gpu::scan::GpuScan;
use crate::gpu::shaders::push_u32s;
use crate::gpu::sort::{GpuRadixSort, ItemCount};
use crate::primitive::Primitives;
use crate::render::{RenderSettings, TILE_SIZE};

impl GpuRasterizer {
    /// The buffers of one view before any work: camera, parameters (uploaded from the host, or
    /// the resident block to copy in the first submission), primitive views, band views, with
    /// `colour` the primitives' colours, live band counts, tile counts.
    // Why this stays long: one allocation per buffer of a view, each sized by its own rule
    // (parameters, primitive and band views, colour, tile counts); a list of sizes, in the
    // order the kernels bind them.
    pub(super) fn alloc_view<'a, 'b>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'b>,
        cam: &PinholeCamera,
        (outputs, colour): (Outputs, bool),
        settings: &RenderSettings,
    ) -> Result<AllocatedView<'a, 'b>, GpuError> {
        let invalid = |reason: String| GpuError::InvalidInput { reason };
        if colour && !has_colour(prims) {
            return Err(invalid(
                "a view with colour of primitives without an SH colour".to_owned(),
            ));
        }
        match src {
            // The host values are the ones rendered: check them.
            ParamSource::Host => prims.validate().map_err(invalid_scene)?,
            // Resident values: only the structure is on the host.
            ParamSource::Device { buffer, .. } => {
                if has_colour(prims) {
                    return Err(invalid(
                        "a resident parameter block holds no SH colour: primitives with colour \
                         render from the host's values"
                            .to_owned(),
                    ));
                }
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
        cam.validate().map_err(invalid_scene)?;
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
            (outputs, colour),
            camera_block,
            ParamKey::of(prims, src),
            band_count,
        );
        let pool = &self.pool;
        // Per-primitive buffers have room for the run's budget (see BufferPool).
        let cap = pool.prims_capacity(n) as u64;
        let m = prims.bands as u64;
        let param_bytes = (parameter_count(prims) * 4) as u64;
        let param_cap = cap * (13 + 5 * m + 3 * prims.sh_k() as u64) * 4;
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
        if colour {
            binned.colours = Some(binned.keep(pool.take(
                ctx,
                "raster.colours",
                n.max(1) as u64 * COLOUR_BYTES,
                cap * COLOUR_BYTES,
                MemoryLocation::DeviceOnly,
            )?));
        }
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
    /// its render computes and whether it has the colour (the `*_rgb` kernels: the colours of
    /// the primitives and the R, G, B planes).
    // Why this stays long: it records the two submissions of a render in dispatch order
    // (projection, counts, scan | keys, sort, ranges, raster) with the barriers between them;
    // the buffers allocated between the two and the one read of the key totals tie them
    // together, and the sequence reads as the GPU does it.
    pub(super) fn bin_and_render_views<'a>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cams: &[(&PinholeCamera, (Outputs, bool))],
        settings: &RenderSettings,
        sizing: KeySizing,
    ) -> Result<Vec<Transient<'a>>, GpuError> {
        let n = prims.len();
        let mut outs = Vec::with_capacity(cams.len());
        let mut copies = Vec::with_capacity(cams.len());
        let mut counts = Vec::with_capacity(cams.len());
        // Kernels of the variants in use (the colour set is built on first use).
        for &(_, (_, colour)) in cams {
            self.stages(ctx, colour)?;
        }
        for &(cam, what) in cams {
            let a = self.alloc_view(ctx, prims, src, cam, what, settings)?;
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
                    let mut bound = vec![
                        b.get(b.cam),
                        b.get(b.params),
                        b.get(b.views),
                        b.get(c),
                        b.get(b.bands),
                        b.get(bc),
                    ];
                    let mut push =
                        vec![n as u32, prims.bands as u32, tiles_x as u32, tiles_y as u32];
                    if let Some(colours) = b.colours {
                        bound.push(b.get(colours));
                        push.push(prims.sh_k() as u32);
                    }
                    rec.dispatch(
                        &self.built_stages(b.colour)?.project,
                        &bound,
                        &push_u32s(&push),
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
                forward_planes(binned.colour) as u64 * npix * 4,
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
                let mut bound = vec![
                    b.get(b.cam),
                    b.get(b.views),
                    b.get(b.bands),
                    b.get(values),
                    b.get(ranges),
                    b.get(planes),
                ];
                if let Some(colours) = b.colours {
                    bound.push(b.get(colours));
                }
                rec.dispatch(
                    &self.built_stages(b.colour)?.forward,
                    &bound,
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

    /// Bins `prims` for `cam` and runs the forward kernel (with or without the colour); the
    /// planes stay on the GPU.
    pub(super) fn bin_and_render<'a>(
        &'a self,
        ctx: &'a GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cam: &PinholeCamera,
        what: (Outputs, bool),
        settings: &RenderSettings,
    ) -> Result<Transient<'a>, GpuError> {
        self.bin_and_render_views(ctx, prims, src, &[(cam, what)], settings, KeySizing::Exact)?
            .pop()
            .ok_or_else(|| poisoned("rendered view"))
    }
}

/// [`GpuError::InvalidScene`] of a check of the CPU renderer's that the primitives or the camera
/// failed.
fn invalid_scene(source: crate::error::RenderError) -> GpuError {
    GpuError::InvalidScene {
        source: Box::new(source),
    }
}
