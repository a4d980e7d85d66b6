//! Proves the rasteriser's GPU building blocks against CPU references on lavapipe: exclusive
//! prefix sum (exact), stable 64-bit radix sort (exact, including ties and the bit limit), float
//! scatter-add with float atomics AND with the CAS fallback forced on (within f32 rounding of an
//! f64 sum), and per-dispatch timestamps. Does NOT measure speed (the bench command does).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use rand::{Rng, SeedableRng};
use s3tir_trainer::gpu::accumulate::{AccumulateVariant, GpuAccumulate};
use s3tir_trainer::gpu::scan::GpuScan;
use s3tir_trainer::gpu::sort::{GpuRadixSort, ItemCount};
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice, GpuContext, GpuError};

fn lavapipe(disable_float_atomics: bool) -> GpuContext {
    GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics,
    })
    .expect("lavapipe (Mesa llvmpipe) must be available: install mesa-vulkan-drivers")
}

fn rng(seed: u64) -> rand_chacha::ChaCha8Rng {
    rand_chacha::ChaCha8Rng::seed_from_u64(seed)
}

#[test]
fn exclusive_scan_is_exact_across_block_and_level_boundaries() {
    let ctx = lavapipe(false);
    let max = 4_200_000;
    let scan = GpuScan::new(&ctx, max).unwrap();
    // 2048 per block; 2049 needs a second level, 2048*2048 + 1 = 4194305 a third.
    for (seed, n) in [1usize, 5, 2048, 2049, 262_145, 4_194_304, 4_194_305, max]
        .into_iter()
        .enumerate()
    {
        let mut r = rng(seed as u64);
        let values: Vec<u32> = (0..n).map(|_| r.random_range(0..1000)).collect();
        let buf = ctx.upload("scan.data", &values).unwrap();
        ctx.submit(|rec| scan.record(rec, &buf, n)).unwrap();
        let got: Vec<u32> = ctx.read(&buf, n).unwrap();
        let mut acc = 0u32;
        for (i, (&v, &g)) in values.iter().zip(&got).enumerate() {
            assert_eq!(g, acc, "n = {n}: exclusive scan at {i} is {g}, want {acc}");
            acc += v;
        }
        ctx.destroy_buffer(buf);
    }
    let too_many = ctx.upload("scan.big", &[0u32; 4]).unwrap();
    assert!(matches!(
        ctx.submit(|rec| scan.record(rec, &too_many, max + 1)),
        Err(GpuError::BufferRange { .. })
    ));
    ctx.destroy_buffer(too_many);
    scan.destroy(&ctx);
}

#[test]
fn radix_sort_matches_a_stable_cpu_sort() {
    let ctx = lavapipe(false);
    let sort = GpuRadixSort::new(&ctx, 301_000).unwrap();
    // (count, key bits, distinct tiles): few distinct keys stress stability.
    for (seed, (n, key_bits, tiles)) in [
        (1usize, 44u32, 1u32),
        (127, 44, 3),
        (128, 44, 3),
        (129, 40, 7),
        (70_000, 44, 300),
        (300_000, 64, 4096),
    ]
    .into_iter()
    .enumerate()
    {
        let mut r = rng(100 + seed as u64);
        let mask = if key_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << key_bits) - 1
        };
        let keys: Vec<u64> = (0..n)
            .map(|_| {
                let tile = u64::from(r.random_range(0..tiles));
                let depth = u64::from(r.random_range(0u32..64)); // many ties
                ((tile << 32) | depth) & mask
            })
            .collect();
        let words: Vec<[u32; 2]> = keys.iter().map(|k| [*k as u32, (k >> 32) as u32]).collect();
        let values: Vec<u32> = (0..n as u32).collect();
        let kbuf = ctx.upload("sort.keys", &words).unwrap();
        let vbuf = ctx.upload("sort.values", &values).unwrap();
        // The count is read on the GPU: every other case records work for 1000 more items
        // than the count buffer holds (a key total the host never read).
        let cbuf = ctx.upload("sort.count", &[u32::MAX, n as u32]).unwrap();
        let count = ItemCount {
            at_most: n + (seed % 2) * 1000,
            buffer: &cbuf,
            index: 1,
        };
        ctx.submit(|rec| sort.record(rec, &kbuf, &vbuf, count, key_bits))
            .unwrap();
        let got_keys: Vec<[u32; 2]> = ctx.read(&kbuf, n).unwrap();
        let got_values: Vec<u32> = ctx.read(&vbuf, n).unwrap();
        let mut want: Vec<(u64, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
        want.sort_by_key(|(k, _)| *k); // stable
        for (i, ((k, v), (gk, gv))) in want
            .iter()
            .zip(got_keys.iter().zip(&got_values))
            .enumerate()
        {
            let gk = u64::from(gk[0]) | (u64::from(gk[1]) << 32);
            assert_eq!(
                (gk, *gv),
                (*k, *v),
                "n = {n}, bits = {key_bits}: item {i} is ({gk:#x}, {gv}), want ({k:#x}, {v})"
            );
        }
        ctx.destroy_buffer(kbuf);
        ctx.destroy_buffer(vbuf);
        ctx.destroy_buffer(cbuf);
    }
    sort.destroy(&ctx);
}

fn check_accumulate(ctx: &GpuContext, variant: AccumulateVariant) {
    let acc = GpuAccumulate::new(ctx, variant).unwrap();
    let mut r = rng(7);
    let n = 200_000;
    let bins = 37; // heavy contention: ~5400 contributions per bin
    let bin_of: Vec<u32> = (0..n).map(|_| r.random_range(0..bins)).collect();
    let contribution: Vec<f32> = (0..n).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let mut want = vec![0f64; bins as usize];
    let mut abs = vec![0f64; bins as usize];
    for (&b, &c) in bin_of.iter().zip(&contribution) {
        want[b as usize] += f64::from(c);
        abs[b as usize] += f64::from(c).abs();
    }
    let ib = ctx.upload("acc.bins", &bin_of).unwrap();
    let cb = ctx.upload("acc.values", &contribution).unwrap();
    let ab = ctx.upload("acc.accum", &vec![0f32; bins as usize]).unwrap();
    ctx.submit(|rec| acc.record(rec, &ib, &cb, &ab, n)).unwrap();
    let got: Vec<f32> = ctx.read(&ab, bins as usize).unwrap();
    for b in 0..bins as usize {
        // Sequential f32 accumulation in arbitrary order: |error| <= n_b * eps * sum|c|.
        let count = bin_of.iter().filter(|&&x| x as usize == b).count() as f64;
        let tol = count * f64::from(f32::EPSILON) * abs[b];
        let err = (f64::from(got[b]) - want[b]).abs();
        assert!(
            err <= tol,
            "{variant:?}: bin {b} = {}, want {} (|error| {err} > bound {tol})",
            got[b],
            want[b]
        );
        // and far tighter in practice:
        assert!(
            err <= 1e-2 * abs[b].max(1.0),
            "{variant:?}: bin {b} error {err} is implausibly large"
        );
    }
    for b in [ib, cb, ab] {
        ctx.destroy_buffer(b);
    }
    acc.destroy(ctx);
}

#[test]
fn scatter_add_with_float_atomics_matches_cpu() {
    let ctx = lavapipe(false);
    assert_eq!(
        AccumulateVariant::best_for(ctx.capabilities()),
        AccumulateVariant::FloatAtomic
    );
    check_accumulate(&ctx, AccumulateVariant::FloatAtomic);
}

#[test]
fn scatter_add_fallback_without_float_atomics_matches_cpu() {
    let ctx = lavapipe(true);
    assert_eq!(
        AccumulateVariant::best_for(ctx.capabilities()),
        AccumulateVariant::CompareAndSwap
    );
    match GpuAccumulate::new(&ctx, AccumulateVariant::FloatAtomic) {
        Err(GpuError::MissingFeature { feature, .. }) => {
            assert!(
                feature.contains("shaderBufferFloat32AtomicAdd"),
                "feature: {feature}"
            )
        }
        other => panic!("float-atomic kernel must be refused without float atomics, got {other:?}"),
    }
    check_accumulate(&ctx, AccumulateVariant::CompareAndSwap);
}

#[test]
fn profiled_submission_times_every_dispatch() {
    let ctx = lavapipe(false);
    assert!(
        ctx.capabilities().compute_timestamps,
        "lavapipe has compute timestamps"
    );
    const N: usize = 5_000_000;
    let scan = GpuScan::new(&ctx, N).unwrap();
    let buf = ctx.upload("scan.data", &vec![1u32; N]).unwrap();
    let timings = ctx
        .submit_profiled(|rec| scan.record(rec, &buf, N))
        .unwrap();
    // 5e6 values: level 0 (2442 blocks), level 1 (2 blocks), level 2 (1 block), two adds.
    let names: Vec<&str> = timings.iter().map(|t| t.kernel.as_str()).collect();
    assert_eq!(
        names,
        [
            "scan_blocks",
            "scan_blocks",
            "scan_blocks",
            "scan_add",
            "scan_add"
        ]
    );
    assert!(
        timings
            .iter()
            .all(|t| t.duration_ns.is_finite() && t.duration_ns >= 0.0)
    );
    assert!(
        timings[0].duration_ns > 0.0,
        "the big level must take measurable time"
    );
    let got: Vec<u32> = ctx.read(&buf, N).unwrap();
    assert_eq!(got[N - 1], (N - 1) as u32);
    ctx.destroy_buffer(buf);
    scan.destroy(&ctx);
}
