//! Proves the resident optimiser's `adam` kernel (trainer/shaders/adam.comp) takes the host
//! optimiser's step ([`AdamState::step`], the loop's log-scale clamp and densification
//! statistics) on lavapipe: randomised parameters, moments and gradients of two views, with
//! every rule the host applies — frozen β and dropped band slots held (moments zeroed, values
//! untouched), a group with learning rate 0 left alone (moments too), β on the 64 clamp, β at
//! the Gaussian init (−10), non-finite gradients counted as 0, log-scales clamped from below,
//! band amplitudes' proximal L1 step (some set to exactly zero, others moved on).
//! Tolerances: 2 ulps-ish (1e-6 relative) for every value but β, which the host maps through
//! f64 and the kernel through f32 (compared in β units, 1e-5 absolute).
//! Does NOT prove the training loop's use of it (`gpu_train.rs` does, step by step).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use rand::Rng;
use s3tir_trainer::gpu::GpuContext;
use s3tir_trainer::gpu::optimiser::{AdamStep, GpuOptimiser, KeyGate};
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice};
use s3tir_trainer::primitive::{
    BETA_RAW_FROZEN, BETA_RAW_GAUSSIAN, Group, PrimitiveInit, Primitives, beta_of_raw,
};
use s3tir_trainer::train::{AdamParams, AdamState, GroupLrs, Groups, view_space_gradient};

const N: usize = 300;
const M: usize = 3;

fn random_like(
    r: &mut rand_chacha::ChaCha8Rng,
    like: &Primitives<f32>,
    scale: f32,
) -> Primitives<f32> {
    let mut out = like.zeros_like();
    for (_, v) in out.groups_mut() {
        for x in v.iter_mut() {
            // Magnitudes over six decades, both signs.
            let mag = 10f32.powf(r.random_range(-6.0..0.0));
            *x = scale * mag * if r.random_bool(0.5) { 1.0 } else { -1.0 };
        }
    }
    out
}

#[test]
fn adam_kernel_takes_the_host_optimiser_step() {
    let mut r = common::rng(17);
    let mut p = Primitives::<f32>::new(M, None);
    for _ in 0..N {
        p.push(&PrimitiveInit::default());
    }
    for (name, v) in p.groups_mut() {
        for x in v.iter_mut() {
            *x = match name {
                Group::LogScales => r.random_range(-6.0..0.0),
                _ => r.random_range(-2.0..2.0),
            };
        }
    }
    p.band_count = (0..N).map(|_| r.random_range(0..=M as u32)).collect();
    for i in 0..N {
        p.beta_raw[i] = match i % 10 {
            0 => BETA_RAW_FROZEN as f32,
            1 | 2 => BETA_RAW_GAUSSIAN as f32,
            3 => 70.0, // β on the clamp (64)
            _ => r.random_range(-4.0..6.0),
        };
        // Dropped band slots hold zeros (as the trainer keeps them).
        for j in p.live_bands(i)..M {
            p.band_amp[M * i + j] = 0.0;
            p.band_phase[M * i + j] = 0.0;
            for a in 0..3 {
                p.band_freq[3 * (M * i + j) + a] = 0.0;
            }
        }
    }
    let min_log_scale = -4.0f32;
    let mut g_i = random_like(&mut r, &p, 1.0);
    let g_j = random_like(&mut r, &p, 1.0);
    g_i.means[7] = f32::NAN;
    g_i.log_scales[11] = f32::INFINITY;
    g_i.beta_raw[5] = f32::NAN;
    g_i.band_amp[4] = f32::NEG_INFINITY;
    let mut adam = AdamState::new(&p);
    adam.m = random_like(&mut r, &p, 0.1);
    adam.v = random_like(&mut r, &p, 0.01);
    for (_, v) in adam.v.groups_mut() {
        for x in v.iter_mut() {
            *x = x.abs();
        }
    }
    adam.step = 6;
    // Groups released later (the bands and β at the warm-up's end) count their own steps: the
    // kernel takes each group's bias corrections from the host's step sizes.
    adam.group_steps = Groups {
        beta: 2,
        band_amp: 0,
        band_freq: 1,
        ..Groups::splat(6)
    };
    let accum0: Vec<f64> = (0..N).map(|_| r.random_range(0.0..1e-3)).collect();
    let count0: Vec<u32> = (0..N).map(|_| r.random_range(0..20)).collect();
    let cam = common::front_camera(64, 48, 50.0);
    let lrs = GroupLrs {
        means: 1.6e-4,
        log_scales: 5e-3,
        quats: 1e-3,
        opacity_logits: 0.05,
        beta: 0.05,
        omega_low: 0.01,
        band_amp: 2.5e-3,
        band_freq: 1e-3,
        band_phase: 0.0, // a frozen group: values and moments untouched
        sh: 0.0,
    };
    // The band amplitudes' proximal L1 step: λ such that some live amplitudes end exactly at
    // zero and others move on (asserted below, so both branches are compared).
    let hp = AdamParams {
        band_l1: 50.0,
        ..AdamParams::default()
    };

    // Host reference (as Trainer::step): statistics, Adam, log-scale clamp.
    let mut g_sum = g_j.clone();
    for ((_, a), (_, b)) in g_sum.groups_mut().into_iter().zip(g_i.groups()) {
        for (x, y) in a.iter_mut().zip(b) {
            *x += *y;
        }
    }
    let (mut accum_h, mut count_h) = (accum0.clone(), count0.clone());
    for i in 0..N {
        let g = &g_sum.means[3 * i..3 * i + 3];
        let n = f64::from(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if n > 0.0 && n.is_finite() {
            let g = [0, 1, 2].map(|a| f64::from(g[a]));
            accum_h[i] += view_space_gradient(&cam, p.mean(i).map(f64::from), g);
            count_h[i] += 1;
        }
    }
    let (mut p_h, mut adam_h) = (p.clone(), adam.clone());
    adam_h.step(&mut p_h, &g_sum, &lrs, &hp);
    for s in &mut p_h.log_scales {
        *s = s.max(min_log_scale);
    }

    // The kernel.
    let ctx = GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics: false,
    })
    .expect("lavapipe must be available");
    let mut opt = GpuOptimiser::new(&ctx).unwrap();
    opt.upload(&ctx, &p, &adam, &accum0, &count0).unwrap();
    opt.write_grads(&ctx, &g_i, Some(&g_j)).unwrap();
    let step = AdamStep {
        sizes: adam.step_sizes(&lrs, &hp),
        hp,
        min_log_scale,
        band_shrink: adam.band_shrink(&lrs, &hp),
    };
    // A step gated by a key total over the lists' room changes nothing: it runs first, and
    // the real step after it must still match the host's single step.
    let totals = ctx.upload("adam.key_totals", &[100u32, 101]).unwrap();
    for capacity in [100, 101] {
        let gate = KeyGate {
            totals: &totals,
            capacity,
            views: 2,
        };
        ctx.submit(|rec| opt.record_step(rec, &step, &cam, true, true, Some(&gate)))
            .unwrap();
    }
    ctx.destroy_buffer(totals);
    let (mut p_d, mut adam_d) = (p.clone(), adam.clone());
    let (mut accum_d, mut count_d) = (vec![0.0; N], vec![0; N]);
    opt.download(&ctx, &mut p_d, &mut adam_d, &mut accum_d, &mut count_d)
        .unwrap();
    opt.destroy(&ctx);

    // Values moved at all (the test can fail): most means changed.
    let moved = (0..3 * N).filter(|&k| p_d.means[k] != p.means[k]).count();
    assert!(moved > 2 * N, "only {moved} of {} mean values moved", 3 * N);

    let close = |a: f32, b: f32, rel: f32| (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-3);
    for ((name, d), (_, h)) in p_d.groups().into_iter().zip(p_h.groups()) {
        for (k, (&x, &y)) in d.iter().zip(h).enumerate() {
            if name == Group::BetaRaw {
                let (bd, bh) = (beta_of_raw(f64::from(x)).0, beta_of_raw(f64::from(y)).0);
                assert!(
                    (bd - bh).abs() <= 1e-5 * bh.max(1.0),
                    "β of primitive {k}: kernel {bd} (raw {x}) vs host {bh} (raw {y})"
                );
                if y == BETA_RAW_FROZEN as f32 {
                    assert_eq!(x, y, "frozen β of primitive {k} must stay the sentinel");
                }
            } else {
                assert!(
                    close(x, y, 1e-6),
                    "{name}[{k}]: kernel {x} vs host {y} (relative 1e-6)"
                );
            }
        }
    }
    for (what, d, h) in [("m", &adam_d.m, &adam_h.m), ("v", &adam_d.v, &adam_h.v)] {
        for ((name, dv), (_, hv)) in d.groups().into_iter().zip(h.groups()) {
            for (k, (&x, &y)) in dv.iter().zip(hv).enumerate() {
                assert!(
                    close(x, y, 2e-5),
                    "Adam {what} of {name}[{k}]: kernel {x} vs host {y} (relative 2e-5)"
                );
            }
        }
    }
    // The proximal step took both branches: live amplitudes set to exactly zero, and others
    // moved on (the kernel matched the host on both, above).
    let live_amps: Vec<f32> = (0..N)
        .flat_map(|i| (0..p.live_bands(i)).map(move |j| M * i + j))
        .map(|k| p_d.band_amp[k])
        .collect();
    let zeroed = live_amps.iter().filter(|&&a| a == 0.0).count();
    assert!(
        zeroed > 10 && zeroed + 10 < live_amps.len(),
        "the L1 step should zero some of the {} live amplitudes and keep others: {zeroed} zeroed",
        live_amps.len()
    );
    // The held rules, exactly.
    assert_eq!(
        p_d.band_phase, p.band_phase,
        "band_phase (lr 0) must not move"
    );
    assert_eq!(
        adam_d.m.band_phase, adam.m.band_phase,
        "band_phase moments must not move"
    );
    for i in 0..N {
        for j in p.live_bands(i)..M {
            let k = M * i + j;
            assert_eq!(
                p_d.band_amp[k], 0.0,
                "dropped slot {j} of primitive {i} moved"
            );
            assert_eq!(
                adam_d.m.band_amp[k], 0.0,
                "dropped slot {j} of {i}: moment not zero"
            );
            assert_eq!(
                adam_d.v.band_freq[3 * k],
                0.0,
                "dropped slot {j} of {i}: moment not zero"
            );
        }
        if i % 10 == 0 {
            assert_eq!(
                adam_d.m.beta_raw[i], 0.0,
                "frozen β of {i}: moment not zero"
            );
        }
        assert!(
            p_d.log_scales[3 * i..3 * i + 3]
                .iter()
                .all(|&s| s >= min_log_scale)
        );
    }
    for i in 0..N {
        assert_eq!(count_d[i], count_h[i], "statistics count of primitive {i}");
        assert!(
            (accum_d[i] - accum_h[i]).abs() <= 1e-5 * accum_h[i].max(1e-9),
            "statistics sum of primitive {i}: kernel {} vs host {}",
            accum_d[i],
            accum_h[i]
        );
    }
}
