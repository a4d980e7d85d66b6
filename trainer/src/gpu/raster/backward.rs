//! The backward pass of a view: `raster_backward_*` (per-pixel walk, gradient sums per
//! primitive) and `raster_backward_finish` (the chain to the parameters), on a kept view or
//! after binning and rendering it again; with the colour's upstream (R, G, B planes) the
//! `*_rgb` variants, which add the colour's share of every sample's weight and chain the
//! colour's sums to the SH coefficients and the means.

use super::layout::{
    PROJECT_WG, acc_fields, camera_block, parameter_count, thermal_parameter_count, upstream_planes,
};
use super::view_cache::{BinnedView, KeptView, ParamKey};
use super::{GpuRasterizer, Outputs, ParamSource, has_colour, lock, poisoned, thermal_only};
use crate::camera::PinholeCamera;
use crate::gpu::context::{GpuBuffer, GpuContext, MemoryLocation, Recorder};
use crate::gpu::error::GpuError;
use crate::gpu::shaders::push_u32s;
use crate::primitive::Primitives;
use crate::render::{GBuffers, RenderSettings};

impl GpuRasterizer {
    /// Gradient of `Σ upstream · buffers` w.r.t. every parameter of `prims` (same layout as
    /// `prims`). `upstream` gives dL/d(thermal, psi_low, psi_high, psi_beta, depth, alpha) and,
    /// for primitives with an SH colour, dL/d(rgb) (three planes, planar as the CPU
    /// reference's); an empty plane counts as zero. When the same view of the same parameters
    /// was just rendered, its binning and forward planes are reused; otherwise the view is
    /// binned and rendered first.
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
        let check = |name: &str, plane: &[f32], len: usize| {
            if plane.is_empty() || plane.len() == len {
                Ok(())
            } else {
                Err(GpuError::InvalidInput {
                    reason: format!(
                        "upstream {name} has {} values, the {width}x{height} view needs {len}",
                        plane.len()
                    ),
                })
            }
        };
        check("rgb", &upstream.rgb, 3 * npix)?;
        // The colour's kernels only when its upstream reaches the primitives' colour (without
        // colour the CPU reference's RGB values are zero: the planes add nothing).
        let colour = has_colour(prims) && upstream.rgb.iter().any(|&g| g != 0.0);
        let mut up = vec![0f32; upstream_planes(colour) * npix];
        let sources = [
            ("thermal", &upstream.thermal),
            ("psi_low", &upstream.psi_low),
            ("psi_high", &upstream.psi_high),
            ("psi_beta", &upstream.psi_beta),
            ("depth", &upstream.depth),
            ("alpha", &upstream.alpha),
        ];
        for ((name, src), dst) in sources.into_iter().zip(up.chunks_exact_mut(npix)) {
            check(name, src, npix)?;
            if !src.is_empty() {
                dst.copy_from_slice(src);
            }
        }
        if colour {
            up[6 * npix..].copy_from_slice(&upstream.rgb);
        }
        // Without thermal upstream the band phases need not be evaluated (same gradients).
        let outputs = if upstream.thermal.iter().all(|&g| g == 0.0) {
            Outputs::GBuffers
        } else {
            Outputs::All
        };
        let up_buf = self.pool.upload(ctx, "raster.upstream", &up, 0)?;
        let result = self.backward_read(ctx, prims, cam, (outputs, colour), settings, &up_buf);
        self.pool.give(ctx, up_buf);
        result
    }

    /// [`GpuRasterizer::render_backward`] with the upstream gradient planes already on the GPU
    /// (6 planes of `cam.width × cam.height` floats, the order of [`super::PLANES`]); with
    /// [`Outputs::GBuffers`] the thermal plane of `up_buf` is taken as zero. Thermal and
    /// G-buffers only (the training step's device path): primitives with an SH colour are
    /// refused.
    pub fn render_backward_device(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        outputs: Outputs,
        settings: &RenderSettings,
        up_buf: &GpuBuffer,
    ) -> Result<Primitives<f32>, GpuError> {
        thermal_only(prims, "render_backward_device")?;
        self.backward_read(ctx, prims, cam, (outputs, false), settings, up_buf)
    }

    /// The backward pass of `cam` with the upstream planes in `up_buf` (with `colour`, the R,
    /// G, B planes too), its gradients read back into a [`Primitives`]; without `colour` the SH
    /// group stays zero (no colour upstream: its gradient is zero).
    fn backward_read(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        cam: &PinholeCamera,
        what: (Outputs, bool),
        settings: &RenderSettings,
        up_buf: &GpuBuffer,
    ) -> Result<Primitives<f32>, GpuError> {
        let mut grads = prims.zeros_like();
        let param_count = parameter_count(prims);
        // Without colour the finish kernel writes the block up to the SH section.
        let written_count = if what.1 {
            param_count
        } else {
            thermal_parameter_count(prims)
        };
        let out = self.pool.take(
            ctx,
            "raster.grads",
            (param_count.max(1) * 4) as u64,
            0,
            MemoryLocation::Readback,
        )?;
        let result = self
            .backward_view(
                ctx,
                prims,
                ParamSource::Host,
                cam,
                what,
                settings,
                up_buf,
                &out,
            )
            .and_then(|written| {
                if written {
                    ctx.read::<f32>(&out, written_count)
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
            &mut grads.sh,
        ];
        for target in targets {
            let (head, tail) = rest.split_at(target.len().min(rest.len()));
            target[..head.len()].copy_from_slice(head);
            rest = tail;
        }
        Ok(grads)
    }

    /// The backward pass of `cam` with the upstream planes in `up_buf`, writing the parameter
    /// gradients into `out` on the GPU (the parameter-block layout, [`parameter_count`] floats;
    /// nothing is read back). Returns `false` when no primitive covers the view: `out` is then
    /// not written and the caller treats the gradient as zero. With [`Outputs::GBuffers`] the
    /// thermal upstream is taken as zero (see [`Outputs`]). Thermal and G-buffers only:
    /// primitives with an SH colour are refused.
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
        thermal_only(prims, "backward_into")?;
        self.backward_view(
            ctx,
            prims,
            src,
            cam,
            (outputs, false),
            settings,
            up_buf,
            out,
        )
    }

    /// [`Self::backward_into`] with or without the colour (`what.1`): with it, `up_buf` holds
    /// the R, G, B planes after the six and `out` gets the SH section too.
    #[allow(clippy::too_many_arguments)]
    fn backward_view(
        &self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        src: ParamSource<'_>,
        cam: &PinholeCamera,
        (outputs, colour): (Outputs, bool),
        settings: &RenderSettings,
        up_buf: &GpuBuffer,
        out: &GpuBuffer,
    ) -> Result<bool, GpuError> {
        let (width, height) = (cam.width, cam.height);
        let npix = width * height;
        let up_bytes = (upstream_planes(colour) * npix * 4) as u64;
        if up_buf.size_bytes() < up_bytes {
            return Err(GpuError::InvalidInput {
                reason: format!(
                    "upstream buffer of {} bytes, the {width}x{height} view needs {up_bytes}",
                    up_buf.size_bytes(),
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
            .position(|v| v.serves(outputs, colour) && v.is_view_of(&key_cam, &key_params, prims));
        let mut fresh = None;
        let view: &mut BinnedView = match position {
            Some(at) => &mut kept[at],
            None => {
                drop(kept);
                fresh =
                    Some(self.bin_and_render(ctx, prims, src, cam, (outputs, colour), settings)?);
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
            scratch_floats(prims, colour).max(1) as u64 * 4,
            0,
            MemoryLocation::DeviceOnly,
        )?;
        let kept_view = view.kept(width, height);
        let recorded = self.submit(ctx, |rec| {
            self.record_view_backward(rec, prims, &kept_view, (outputs, colour), up_buf, &acc, out)
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
        scratch_floats(prims, false)
    }

    /// Records the backward pass of a kept view (inside [`Self::submit_with_views`]) with the
    /// upstream planes in `up_buf`, writing the parameter gradients into `out` (the
    /// parameter-block layout, [`parameter_count`] floats) and using `acc`
    /// ([`Self::backward_scratch_floats`]) as scratch. Returns `false` when no primitive covers
    /// the view: nothing is recorded and the caller treats the gradient as zero. With
    /// [`Outputs::GBuffers`] the thermal upstream is taken as zero (see [`Outputs`]); a view
    /// rendered without its thermal image cannot take thermal upstream. Thermal and G-buffers
    /// only (the resident step): primitives with an SH colour are refused.
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
        thermal_only(prims, "record_backward")?;
        self.record_view_backward(rec, prims, view, (outputs, false), up_buf, acc, out)
    }

    /// [`Self::record_backward`] with or without the colour (the `*_rgb` kernels: `up_buf`
    /// holds R, G, B after the six planes, `acc` has the colour's fields and `out` the SH
    /// section).
    #[allow(clippy::too_many_arguments)]
    fn record_view_backward(
        &self,
        rec: &mut Recorder<'_>,
        prims: &Primitives<f32>,
        view: &KeptView<'_>,
        (outputs, colour): (Outputs, bool),
        up_buf: &GpuBuffer,
        acc: &GpuBuffer,
        out: &GpuBuffer,
    ) -> Result<bool, GpuError> {
        let (width, height) = (view.width, view.height);
        let npix = width * height;
        let need = [
            (up_buf, (upstream_planes(colour) * npix * 4) as u64),
            (acc, (scratch_floats(prims, colour) * 4) as u64),
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
        if !v.serves(outputs, colour) {
            return Err(GpuError::InvalidInput {
                reason: "record_backward: thermal (or colour) upstream for a view rendered \
                         without its thermal image (or colour)"
                    .to_owned(),
            });
        }
        let (Some((values, ranges)), Some(planes)) = (v.lists, v.planes) else {
            return Ok(false);
        };
        let stages = self.built_stages(colour)?;
        let n = prims.len();
        let [tiles_x, tiles_y] = v.tiles;
        let mut bound = vec![
            v.get(v.cam),
            v.get(v.views),
            v.get(v.bands),
            v.get(values),
            v.get(ranges),
            up_buf,
            v.get(planes),
            acc,
        ];
        let mut finish_push = vec![n as u32, prims.bands as u32];
        if colour {
            let colours = v.colours.ok_or_else(|| poisoned("colours"))?;
            bound.push(v.get(colours));
            finish_push.push(prims.sh_k() as u32);
        }
        rec.fill_zero(acc);
        rec.dispatch(
            &stages.backward,
            &bound,
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
            &stages.finish,
            &[v.get(v.cam), v.get(v.params), acc, out, v.get(v.views)],
            &push_u32s(&finish_push),
            [n.div_ceil(PROJECT_WG) as u32, 1, 1],
        )?;
        rec.compute_barrier();
        Ok(true)
    }
}

/// Floats of the view-space gradient sums of `prims`' backward pass, with or without colour.
fn scratch_floats(prims: &Primitives<f32>, colour: bool) -> usize {
    acc_fields(prims.bands, colour) * prims.len()
}
