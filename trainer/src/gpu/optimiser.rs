//! The resident optimiser: parameters, Adam moments and densification statistics that stay on
//! the GPU between training steps, and the `adam` kernel that steps them (the host optimiser,
//! [`crate::train::adam`], with the same rules: frozen β and dropped band slots held, β stepped in
//! β units, log-scales clamped; see `trainer/shaders/adam.comp`).
//!
//! The training loop uploads its state once ([`GpuOptimiser::upload`]), runs steps whose
//! gradients never leave the GPU, and downloads the state ([`GpuOptimiser::download`]) only when
//! it reads or changes it on the host: density control, band dropping, evaluation, checkpoints.
//! Buffers are device-local; uploads and downloads go through host-visible staging buffers.

use super::context::{ComputeKernel, GpuBuffer, GpuContext, MemoryLocation, Recorder};
use super::error::GpuError;
use super::raster::{GpuRasterizer, parameter_block, parameter_count};
use super::shaders::{self, ADAM_PUSH_BYTES};
use crate::camera::PinholeCamera;
use crate::primitive::{Group, Primitives};
use crate::train::adam::{AdamParams, AdamState, GroupLrs};

const ADAM_WG: usize = 128;

/// The state on the GPU.
#[derive(Debug)]
struct Resident {
    n: usize,
    bands: usize,
    params: GpuBuffer,
    m: GpuBuffer,
    v: GpuBuffer,
    grads_i: GpuBuffer,
    grads_j: GpuBuffer,
    band_count: GpuBuffer,
    stats_accum: GpuBuffer,
    stats_count: GpuBuffer,
    /// Backward-pass scratch of the two views ([`GpuRasterizer::backward_scratch_floats`]).
    acc_i: GpuBuffer,
    acc_j: GpuBuffer,
}

impl Resident {
    fn buffers(self) -> [GpuBuffer; 10] {
        [
            self.acc_i,
            self.acc_j,
            self.params,
            self.m,
            self.v,
            self.grads_i,
            self.grads_j,
            self.band_count,
            self.stats_accum,
            self.stats_count,
        ]
    }
}

/// Adam settings of one step, as the host optimiser computes them.
#[derive(Debug, Clone, Copy)]
pub struct AdamStep {
    /// Each group's step size, bias corrections included ([`AdamState::step_sizes`]; 0: the
    /// group is frozen).
    pub sizes: GroupLrs,
    pub hp: AdamParams,
    /// Lower bound of every log-scale after the update.
    pub min_log_scale: f32,
    /// The band amplitudes' proximal shrink before its division by `√v + ε`
    /// ([`AdamState::band_shrink`]; 0: none).
    pub band_shrink: f64,
}

/// Parameters, moments and statistics on the GPU, and the kernel that steps them.
/// Skips a recorded Adam step on the GPU when the step's render was incomplete: the first
/// `views` u32 of `totals` are the key totals of the step's views, and a total above `capacity`
/// (the key lists' room, [`super::raster::KeySizing::Capacity`]) leaves the whole state as it was.
#[derive(Debug, Clone, Copy)]
pub struct KeyGate<'a> {
    pub totals: &'a GpuBuffer,
    pub capacity: u32,
    pub views: u32,
}

#[derive(Debug)]
pub struct GpuOptimiser {
    kernel: ComputeKernel,
    state: Option<Resident>,
    generation: u64,
}

/// A device-local buffer holding `data` (through a staging buffer).
fn device_buffer<T: bytemuck::Pod>(
    ctx: &GpuContext,
    name: &str,
    data: &[T],
) -> Result<GpuBuffer, GpuError> {
    let bytes = std::mem::size_of_val(data) as u64;
    let buffer = ctx.create_buffer(name, bytes.max(4), MemoryLocation::DeviceOnly)?;
    if bytes == 0 {
        return Ok(buffer);
    }
    let copied = ctx.upload(name, data).and_then(|staging| {
        let r = ctx.submit(|rec| rec.copy_buffer(&staging, &buffer, bytes));
        ctx.destroy_buffer(staging);
        r
    });
    match copied {
        Ok(()) => Ok(buffer),
        Err(e) => {
            ctx.destroy_buffer(buffer);
            Err(e)
        }
    }
}

/// The first `count` elements of a device-local buffer (through a staging buffer).
fn read_device<T: bytemuck::Pod>(
    ctx: &GpuContext,
    buffer: &GpuBuffer,
    count: usize,
) -> Result<Vec<T>, GpuError> {
    let bytes = (count * std::mem::size_of::<T>()) as u64;
    if bytes == 0 {
        return Ok(Vec::new());
    }
    let staging = ctx.create_buffer(buffer.name(), bytes, MemoryLocation::Readback)?;
    let out = ctx
        .submit(|rec| rec.copy_buffer(buffer, &staging, bytes))
        .and_then(|()| ctx.read(&staging, count));
    ctx.destroy_buffer(staging);
    out
}

/// Copies a parameter block (the layout of [`parameter_block`]) into `p`'s groups.
fn scatter_block(block: &[f32], p: &mut Primitives<f32>) {
    let mut rest = block;
    for (name, dst) in p.groups_mut() {
        if name == Group::Sh {
            continue;
        }
        let (head, tail) = rest.split_at(dst.len().min(rest.len()));
        dst.copy_from_slice(head);
        rest = tail;
    }
}

impl GpuOptimiser {
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self {
            kernel: shaders::build(ctx, "adam")?,
            state: None,
            generation: 0,
        })
    }

    /// Whether a state is on the GPU.
    pub fn is_resident(&self) -> bool {
        self.state.is_some()
    }

    /// The resident parameter block and its generation (changes with every upload and step),
    /// for [`super::raster::ParamSource::Device`].
    pub fn params(&self) -> Option<(&GpuBuffer, u64)> {
        self.state.as_ref().map(|s| (&s.params, self.generation))
    }

    /// The two gradient buffers a step's backward passes write (reference view, paired view).
    pub fn grads(&self) -> Option<(&GpuBuffer, &GpuBuffer)> {
        self.state.as_ref().map(|s| (&s.grads_i, &s.grads_j))
    }

    /// The backward-pass scratch of the two views.
    pub fn scratch(&self) -> Option<(&GpuBuffer, &GpuBuffer)> {
        self.state.as_ref().map(|s| (&s.acc_i, &s.acc_j))
    }

    /// Puts `prims` (thermal only: no SH colour), the Adam moments and the densification
    /// statistics on the GPU, replacing any state there.
    pub fn upload(
        &mut self,
        ctx: &GpuContext,
        prims: &Primitives<f32>,
        adam: &AdamState,
        grad_accum: &[f64],
        grad_count: &[u32],
    ) -> Result<(), GpuError> {
        let n = prims.len();
        let invalid = |reason: String| GpuError::InvalidInput { reason };
        if prims.sh_degree.is_some() {
            return Err(invalid(
                "the resident optimiser holds thermal primitives only (these carry SH colour)"
                    .to_owned(),
            ));
        }
        if adam.m.len() != n || adam.v.len() != n || adam.m.bands != prims.bands {
            return Err(invalid(format!(
                "Adam moments for {} primitives with {} bands, the parameters have {n} with {}",
                adam.m.len(),
                adam.m.bands,
                prims.bands
            )));
        }
        if grad_accum.len() != n || grad_count.len() != n {
            return Err(invalid(format!(
                "densification statistics for {}/{} primitives, the parameters have {n}",
                grad_accum.len(),
                grad_count.len()
            )));
        }
        self.release(ctx);
        let band_count: Vec<u32> = (0..n)
            .map(|i| u32::try_from(prims.live_bands(i)).unwrap_or(u32::MAX))
            .collect();
        let accum: Vec<f32> = grad_accum.iter().map(|&x| x as f32).collect();
        let zeros = vec![0f32; parameter_count(prims)];
        let bytes = |v: &[f32]| bytemuck::cast_slice::<f32, u8>(v).to_vec();
        let blocks: [(&str, Vec<u8>); 8] = [
            ("optimiser.params", bytes(&parameter_block(prims))),
            ("optimiser.adam_m", bytes(&parameter_block(&adam.m))),
            ("optimiser.adam_v", bytes(&parameter_block(&adam.v))),
            ("optimiser.grads_i", bytes(&zeros)),
            ("optimiser.grads_j", bytes(&zeros)),
            (
                "optimiser.band_count",
                bytemuck::cast_slice::<u32, u8>(&band_count).to_vec(),
            ),
            ("optimiser.stats_accum", bytes(&accum)),
            (
                "optimiser.stats_count",
                bytemuck::cast_slice::<u32, u8>(grad_count).to_vec(),
            ),
        ];
        let mut made: Vec<GpuBuffer> = Vec::with_capacity(blocks.len());
        for (name, data) in &blocks {
            match device_buffer(ctx, name, data) {
                Ok(b) => made.push(b),
                Err(e) => {
                    made.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    return Err(e);
                }
            }
        }
        let scratch_bytes = GpuRasterizer::backward_scratch_floats(prims).max(1) as u64 * 4;
        for name in ["optimiser.acc_i", "optimiser.acc_j"] {
            match ctx.create_buffer(name, scratch_bytes, MemoryLocation::DeviceOnly) {
                Ok(b) => made.push(b),
                Err(e) => {
                    made.into_iter().for_each(|b| ctx.destroy_buffer(b));
                    return Err(e);
                }
            }
        }
        let [
            params,
            m,
            v,
            grads_i,
            grads_j,
            band_count,
            stats_accum,
            stats_count,
            acc_i,
            acc_j,
        ]: [GpuBuffer; 10] = match made.try_into() {
            Ok(all) => all,
            Err(partial) => {
                let partial: Vec<GpuBuffer> = partial;
                partial.into_iter().for_each(|b| ctx.destroy_buffer(b));
                return Err(invalid("optimiser buffer list incomplete".to_owned()));
            }
        };
        self.state = Some(Resident {
            n,
            bands: prims.bands,
            params,
            m,
            v,
            grads_i,
            grads_j,
            band_count,
            stats_accum,
            stats_count,
            acc_i,
            acc_j,
        });
        self.generation += 1;
        Ok(())
    }

    /// Copies the state back into the host's (same shapes as uploaded) and keeps it resident.
    pub fn download(
        &self,
        ctx: &GpuContext,
        prims: &mut Primitives<f32>,
        adam: &mut AdamState,
        grad_accum: &mut [f64],
        grad_count: &mut [u32],
    ) -> Result<(), GpuError> {
        let Some(s) = &self.state else {
            return Err(GpuError::InvalidInput {
                reason: "no optimiser state on the GPU to download".to_owned(),
            });
        };
        let n = s.n;
        if prims.len() != n
            || prims.bands != s.bands
            || adam.m.len() != n
            || adam.v.len() != n
            || grad_accum.len() != n
            || grad_count.len() != n
        {
            return Err(GpuError::InvalidInput {
                reason: format!(
                    "the host state changed shape while the optimiser state was on the GPU \
                     ({n} primitives with {} bands there, {} with {} on the host)",
                    s.bands,
                    prims.len(),
                    prims.bands
                ),
            });
        }
        let count = parameter_count(prims);
        scatter_block(&read_device::<f32>(ctx, &s.params, count)?, prims);
        scatter_block(&read_device::<f32>(ctx, &s.m, count)?, &mut adam.m);
        scatter_block(&read_device::<f32>(ctx, &s.v, count)?, &mut adam.v);
        let accum = read_device::<f32>(ctx, &s.stats_accum, n)?;
        for (h, d) in grad_accum.iter_mut().zip(accum) {
            *h = f64::from(d);
        }
        grad_count.copy_from_slice(&read_device::<u32>(ctx, &s.stats_count, n)?);
        Ok(())
    }

    /// Writes host-computed gradients into the step's gradient buffers (reference view `g_i`,
    /// paired view `g_j`; same shape as the resident parameters). For steps whose gradients
    /// come from elsewhere, and for tests.
    pub fn write_grads(
        &self,
        ctx: &GpuContext,
        g_i: &Primitives<f32>,
        g_j: Option<&Primitives<f32>>,
    ) -> Result<(), GpuError> {
        let Some(s) = &self.state else {
            return Err(GpuError::InvalidInput {
                reason: "no optimiser state on the GPU to write gradients to".to_owned(),
            });
        };
        for (g, dst) in [(Some(g_i), &s.grads_i), (g_j, &s.grads_j)] {
            let Some(g) = g else { continue };
            if g.len() != s.n || g.bands != s.bands {
                return Err(GpuError::InvalidInput {
                    reason: format!(
                        "gradient of {} primitives with {} bands for a resident state of {} \
                         with {}",
                        g.len(),
                        g.bands,
                        s.n,
                        s.bands
                    ),
                });
            }
            let block = parameter_block(g);
            let bytes = std::mem::size_of_val(block.as_slice()) as u64;
            if bytes == 0 {
                continue;
            }
            let staging = ctx.upload(dst.name(), &block)?;
            let r = ctx.submit(|rec| rec.copy_buffer(&staging, dst, bytes));
            ctx.destroy_buffer(staging);
            r?;
        }
        Ok(())
    }

    /// Records the Adam step: gradients of the reference view in `grads_i` (`grads_i_written`
    /// false: no primitive covered it, zero) plus the paired view's in `grads_j`
    /// (`grads_j_written` false or no pair: zero); densification statistics measured in `cam_i`.
    pub fn record_step(
        &self,
        rec: &mut Recorder<'_>,
        adam: &AdamStep,
        cam_i: &PinholeCamera,
        grads_i_written: bool,
        grads_j_written: bool,
        gate: Option<&KeyGate<'_>>,
    ) -> Result<(), GpuError> {
        let Some(s) = &self.state else {
            return Err(GpuError::InvalidInput {
                reason: "no optimiser state on the GPU to step".to_owned(),
            });
        };
        if s.n == 0 {
            return Ok(());
        }
        if !grads_i_written {
            rec.fill_zero(&s.grads_i);
        }
        if !grads_j_written {
            rec.fill_zero(&s.grads_j);
        }
        let hp = adam.hp;
        let l = adam.sizes;
        let r = cam_i.rotation_cam_from_world();
        let tz = cam_i.cam_from_world.translation_m.z;
        let mut push: Vec<u8> = Vec::with_capacity(ADAM_PUSH_BYTES as usize);
        let (gate_buffer, capacity, views) = match gate {
            Some(g) => (g.totals, g.capacity, g.views),
            None => (&s.band_count, u32::MAX, 0),
        };
        for u in [s.n as u32, s.bands as u32, capacity, views] {
            push.extend_from_slice(&u.to_le_bytes());
        }
        let floats = [
            l.means,
            l.log_scales,
            l.quats,
            l.opacity_logits,
            l.beta,
            l.omega_low,
            l.band_amp,
            l.band_freq,
            l.band_phase,
            hp.beta1,
            hp.beta2,
            hp.eps,
            f64::from(adam.min_log_scale),
            r[0],
            r[1],
            r[2],
            r[3],
            r[4],
            r[5],
            r[6],
            r[7],
            r[8],
            tz,
            cam_i.width as f64 / (2.0 * cam_i.fx_px),
            cam_i.height as f64 / (2.0 * cam_i.fy_px),
            adam.band_shrink,
        ];
        for f in floats {
            push.extend_from_slice(&(f as f32).to_le_bytes());
        }
        rec.compute_barrier();
        rec.dispatch(
            &self.kernel,
            &[
                &s.params,
                &s.m,
                &s.v,
                &s.grads_i,
                &s.grads_j,
                &s.band_count,
                &s.stats_accum,
                &s.stats_count,
                gate_buffer,
            ],
            &push,
            [s.n.div_ceil(ADAM_WG) as u32, 1, 1],
        )
    }

    /// Marks the parameters changed (after a recorded step has run).
    pub fn advance(&mut self) {
        self.generation += 1;
    }

    /// Drops the GPU state (the host's copy is the truth again).
    pub fn release(&mut self, ctx: &GpuContext) {
        if let Some(s) = self.state.take() {
            for b in s.buffers() {
                ctx.destroy_buffer(b);
            }
        }
    }

    pub fn destroy(mut self, ctx: &GpuContext) {
        self.release(ctx);
        ctx.destroy_kernel(self.kernel);
    }
}
