//! Proves that the CPU paths that run on several cores (the renderer's prepare, forward and
//! backward passes, the SSIM blur, the multi-view consistency loss) give the same bits on 1, 2 and 5 threads: rows and tiles are
//! fixed partitions and every sum across them is added in one fixed order
//! (`render/backward.rs`). A run on the CPU backend is reproducible whatever machine it runs on.
//! That the tile-ordered sums are still the right gradients is `finite_diff_render.rs`'s job.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{FieldScene, field_scene};

use s3tir_trainer::camera::PinholeCamera;
use s3tir_trainer::loss::consistency::{ConsistencyOptions, consistency_loss};
use s3tir_trainer::loss::photometric::ssim;
use s3tir_trainer::primitive::Primitives;
use s3tir_trainer::render::{
    GBuffers, RenderSettings, prepare, render_backward_prepared, render_prepared,
};

const W: usize = 96;
const H: usize = 72;

fn scene() -> (Primitives<f64>, PinholeCamera) {
    let cam = PinholeCamera::look_at([0.0; 3], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], 80.0, W, H);
    let spec = FieldScene {
        n: 600,
        bands: 3,
        sh_degree: Some(1),
        scale: 0.03..0.15,
        beta_max: 12.0,
    };
    (field_scene(7, &spec), cam)
}

/// Every plane and gradient of one forward + backward pass, an SSIM gradient and the
/// consistency loss against a second view (its value, valid pixels and both views' Ψ
/// gradients), as bits.
fn run(prims: &Primitives<f32>, cam: &PinholeCamera) -> (Vec<Vec<u32>>, Vec<Vec<u32>>, u64) {
    let prep = prepare(prims, cam, &RenderSettings::default()).unwrap();
    let out = render_prepared(prims, &prep);
    let mut up = GBuffers::<f32>::zeros(W, H, true);
    for (_, plane) in up.planes_mut() {
        for (k, v) in plane.iter_mut().enumerate() {
            *v = ((k * 7919) % 13) as f32 / 13.0 - 0.5;
        }
    }
    let target: Vec<f32> = out.thermal.iter().map(|v| 0.9 * v + 0.05).collect();
    let mut g_ssim = vec![0.0f32; W * H];
    let s = ssim(&out.thermal, &target, W, H, Some((&mut g_ssim, 1.0)));
    let grads = render_backward_prepared(prims, &prep, &up);
    // A second view 0.2 m to the side, the consistency loss of the first against it.
    let cam_j = PinholeCamera::look_at(
        [0.2, 0.0, 0.0],
        [0.2, 0.0, 1.0],
        [0.0, -1.0, 0.0],
        80.0,
        W,
        H,
    );
    let out_j = render_prepared(
        prims,
        &prepare(prims, &cam_j, &RenderSettings::default()).unwrap(),
    );
    let mut gi = GBuffers::<f32>::zeros(W, H, true);
    let mut gj = GBuffers::<f32>::zeros(W, H, true);
    let opt = ConsistencyOptions {
        min_alpha: 0.3,
        ..ConsistencyOptions::default()
    };
    let c = consistency_loss(&out, cam, &out_j, &cam_j, &opt, 1.0, &mut gi, &mut gj).unwrap();
    assert!(
        c.valid_px > W * H / 10,
        "the two views must overlap on over a tenth of the pixels, {} valid",
        c.valid_px
    );
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let mut planes: Vec<Vec<u32>> = out.planes().iter().map(|(_, p)| bits(p)).collect();
    planes.push(bits(&g_ssim));
    planes.push(vec![
        c.loss.to_bits() as u32,
        (c.loss.to_bits() >> 32) as u32,
        c.valid_px as u32,
    ]);
    for g in [&gi.psi_high, &gi.psi_beta, &gj.psi_high, &gj.psi_beta] {
        planes.push(bits(g));
    }
    let g = vec![
        bits(&grads.means),
        bits(&grads.log_scales),
        bits(&grads.quats),
        bits(&grads.opacity_logits),
        bits(&grads.beta_raw),
        bits(&grads.omega_low),
        bits(&grads.band_amp),
        bits(&grads.band_phase),
        bits(&grads.band_freq),
        bits(&grads.sh),
    ];
    (planes, g, s.to_bits())
}

fn on_threads<R: Send>(n: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .expect("thread pool")
        .install(f)
}

#[test]
fn cpu_render_backward_and_ssim_are_bit_identical_on_any_thread_count() {
    let (p64, cam) = scene();
    let prims = p64.cast::<f32>();
    let one = on_threads(1, || run(&prims, &cam));
    assert!(
        one.0[0].iter().any(|&b| f32::from_bits(b) != 0.0),
        "the thermal plane must show the scene"
    );
    assert!(
        one.1[0].iter().any(|&b| f32::from_bits(b) != 0.0),
        "the means must get gradients"
    );
    for n in [2, 5] {
        let many = on_threads(n, || run(&prims, &cam));
        assert_eq!(one.2, many.2, "SSIM on {n} threads differs from 1 thread");
        for (k, (a, b)) in one.0.iter().zip(&many.0).enumerate() {
            let diff = a.iter().zip(b).filter(|(x, y)| x != y).count();
            assert_eq!(diff, 0, "plane {k}: {diff} values differ on {n} threads");
        }
        for (k, (a, b)) in one.1.iter().zip(&many.1).enumerate() {
            let diff = a.iter().zip(b).filter(|(x, y)| x != y).count();
            assert_eq!(diff, 0, "gradient {k}: {diff} values differ on {n} threads");
        }
    }
}
