//! CPU reference renderer: forward and backward time per megapixel-primitive.
//!
//! `cargo bench -p s3tir-trainer --no-default-features --bench cpu_render`
//!
//! Criterion's throughput is set to `width × height × primitives` elements, so its
//! "elem/s" figure converts to time per megapixel-primitive as `1e6 / (elem/s)` seconds.
//! The scene: 2 000 random primitives (β ∈ [2, 20], M = 4 bands, no colour) filling a
//! 256 × 192 view, so tile culling is exercised as in a real frame. On rayon's pool (every
//! core; `RAYON_NUM_THREADS=1` for one thread).
//!
//! Group `cpu_render_shortcuts` (f32, forward + backward of one view, what a training step costs
//! the renderer): the same scene after capacity adaptation has put half of the primitives on the
//! cheap Gaussian path (β frozen at 2, no live band) and dropped two of the four bands of the
//! others, with the renderer's shortcuts (`with_shortcuts`) and forced through the general path
//! (`general_path`, `Prepared::without_shortcuts`); and the all-Gaussian scene of 3dgs mode.

#![allow(clippy::unwrap_used)] // a benchmark, like a test, may panic on setup failure

#[path = "../tests/common/mod.rs"]
mod common;

use common::{FieldScene, field_scene};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::primitive::{BETA_RAW_FROZEN, Primitives};
use s3tir_trainer::real::Real;
use s3tir_trainer::render::{
    GBuffers, RenderSettings, prepare, render_backward, render_backward_prepared, render_prepared,
};

const W: usize = 256;
const H: usize = 192;
const N: usize = 2000;

fn scene() -> (Primitives<f64>, PinholeCamera) {
    let cam = PinholeCamera::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], 200.0, W, H);
    let spec = FieldScene {
        n: N,
        bands: 4,
        sh_degree: None,
        scale: 0.02..0.12,
        beta_max: 20.0,
    };
    (field_scene(1, &spec), cam)
}

fn bench_type<T: Real>(c: &mut Criterion, name: &str) {
    let (p64, cam) = scene();
    let prims = p64.cast::<T>();
    let settings = RenderSettings::default();
    let mut up = GBuffers::<T>::zeros(W, H, false);
    for (_, plane) in up.planes_mut() {
        for (k, v) in plane.iter_mut().enumerate() {
            *v = T::from_f64(((k * 7919) % 13) as f64 / 13.0 - 0.5);
        }
    }
    let mut g = c.benchmark_group(format!("cpu_render_{name}"));
    g.sample_size(10);
    g.throughput(Throughput::Elements((W * H * N) as u64));
    g.bench_function(BenchmarkId::new("forward", format!("{W}x{H}x{N}")), |b| {
        b.iter(|| s3tir_trainer::render::render(&prims, &cam, &settings))
    });
    g.bench_function(BenchmarkId::new("backward", format!("{W}x{H}x{N}")), |b| {
        b.iter(|| render_backward(&prims, &cam, &settings, &up))
    });
    g.bench_function(BenchmarkId::new("prepare", format!("{W}x{H}x{N}")), |b| {
        b.iter(|| prepare(&prims, &cam, &settings))
    });
    g.finish();
}

/// The scene after capacity adaptation: even primitives frozen Gaussians without bands (all
/// of them when `all_gaussian`), odd ones with their last two band slots dropped.
fn adapted(all_gaussian: bool) -> Primitives<f32> {
    let (mut p, _) = scene();
    for i in 0..p.len() {
        let gaussian = all_gaussian || i % 2 == 0;
        let live = if gaussian { 0 } else { 2 };
        if gaussian {
            p.beta_raw[i] = BETA_RAW_FROZEN;
        }
        p.band_count[i] = live as u32;
        for j in live..4 {
            let s = 4 * i + j;
            p.band_amp[s] = 0.0;
            p.band_phase[s] = 0.0;
            p.band_freq[3 * s..3 * s + 3].fill(0.0);
        }
    }
    p.cast::<f32>()
}

fn bench_shortcuts(c: &mut Criterion) {
    let (_, cam) = scene();
    let settings = RenderSettings::default();
    let mut g = c.benchmark_group("cpu_render_shortcuts");
    g.sample_size(10);
    for (label, all) in [("half_gaussian", false), ("all_gaussian", true)] {
        let prims = adapted(all);
        let prep = prepare(&prims, &cam, &settings).unwrap();
        let general = prep.without_shortcuts(prims.bands);
        let mut up = GBuffers::<f32>::zeros(W, H, false);
        for (_, plane) in up.planes_mut() {
            for (k, v) in plane.iter_mut().enumerate() {
                *v = ((k * 7919) % 13) as f32 / 13.0 - 0.5;
            }
        }
        for (name, p) in [("with_shortcuts", &prep), ("general_path", &general)] {
            g.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| {
                    let out = render_prepared(&prims, p);
                    let grads = render_backward_prepared(&prims, p, &up);
                    (out, grads)
                })
            });
        }
    }
    g.finish();
}

fn benches(c: &mut Criterion) {
    bench_shortcuts(c);
    bench_type::<f32>(c, "f32");
    bench_type::<f64>(c, "f64");
}

criterion_group!(cpu_render, benches);
criterion_main!(cpu_render);
