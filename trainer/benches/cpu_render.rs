//! CPU reference renderer: forward and backward time per megapixel-primitive.
//!
//! `cargo bench -p s3tir-trainer --no-default-features --bench cpu_render`
//!
//! Criterion's throughput is set to `width × height × primitives` elements, so its
//! "elem/s" figure converts to time per megapixel-primitive as `1e6 / (elem/s)` seconds.
//! The scene: 2 000 random primitives (β ∈ [2, 20], M = 4 bands, no colour) filling a
//! 256 × 192 view, so tile culling is exercised as in a real frame. Single-threaded.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::primitive::{PrimitiveInit, Primitives};
use s3tir_trainer::real::Real;
use s3tir_trainer::render::{GBuffers, RenderSettings, prepare, render_backward};

const W: usize = 256;
const H: usize = 192;
const N: usize = 2000;

fn scene() -> (Primitives<f64>, PinholeCamera) {
    let cam = PinholeCamera::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], 200.0, W, H);
    let mut r = ChaCha8Rng::seed_from_u64(1);
    let mut p = Primitives::new(4, None);
    for _ in 0..N {
        let z: f64 = r.random_range(2.0..6.0);
        let s = r.random_range(0.02..0.12) * z / 3.0;
        p.push(&PrimitiveInit {
            mean_m: [
                r.random_range(-0.6..0.6) * z,
                r.random_range(-0.45..0.45) * z,
                z,
            ],
            scale_m: [
                s,
                s * r.random_range(0.3..1.0),
                s * r.random_range(0.3..1.0),
            ],
            quat: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                1.0,
            ],
            opacity: r.random_range(0.2..0.9),
            beta: r.random_range(2.0..20.0),
            omega_low: r.random_range(0.2..0.8),
            bands: (0..4)
                .map(|_| {
                    (
                        r.random_range(-0.1..0.1),
                        [r.random_range(-2.0..2.0), r.random_range(-2.0..2.0), 0.0],
                        0.3,
                    )
                })
                .collect(),
            sh: vec![],
        });
    }
    (p, cam)
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

fn benches(c: &mut Criterion) {
    bench_type::<f32>(c, "f32");
    bench_type::<f64>(c, "f64");
}

criterion_group!(cpu_render, benches);
criterion_main!(cpu_render);
