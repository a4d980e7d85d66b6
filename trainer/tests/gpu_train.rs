//! Proves the Vulkan backend trains like the CPU backend: the same training loop (schedule,
//! losses, Adam, density control) on the synthetic thermal scene reaches a held-out PSNR within
//! 0.3 dB of the CPU backend's at equal iterations and budget, on lavapipe, with float atomics
//! and with the compare-and-swap fallback forced on. Does NOT measure speed (`s3tir-train bench`
//! does) and runs far fewer iterations than the paper (CI time).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::AtomicBool;

use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, LoadOptions};
use s3tir_trainer::gpu::backend::VulkanBackend;
use s3tir_trainer::gpu::{ContextOptions, DeviceChoice};
use s3tir_trainer::primitive::{Group, Primitives, beta_of_raw};
use s3tir_trainer::render::RenderSettings;
use s3tir_trainer::train::{
    Backend, ConsistPartner, CpuBackend, Mode, Outcome, ResponseKind, RunShape, TrainConfig,
    Trainer,
};

fn config(data: &std::path::Path) -> TrainConfig {
    let mut c = TrainConfig::new(data.to_path_buf());
    c.mode = Mode::S3tir;
    c.iters = 300;
    c.warmup = 100;
    c.budget = 300;
    c.seed = 5;
    c.eval_every_s = 1e9;
    c.checkpoint_every_s = 1e9;
    c.densify.from = 50;
    c.densify.until = 250;
    c.densify.every = 50;
    c.capacity.every = 150;
    c.lr.omega_low = 0.01;
    c.lr.beta = 0.05;
    c.consist_every = 4;
    c
}

/// The synthetic scene every test here trains on (40×30), in a temporary folder.
fn small_scene() -> (tempfile::TempDir, std::path::PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let data_dir = tmp.path().join("scene");
    let scfg = SynthConfig {
        width: 40,
        height: 30,
        f_px: 34.0,
        points: 300,
        ..SynthConfig::default()
    };
    synth::write_scene(&data_dir, &scfg).unwrap();
    (tmp, data_dir)
}

fn lavapipe(disable_float_atomics: bool) -> ContextOptions {
    ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics,
    }
}

fn train<B: Backend>(data_dir: &std::path::Path, run: &std::path::Path, backend: B) -> f64 {
    let data = Dataset::load(data_dir, &LoadOptions::default()).unwrap();
    let mut t = Trainer::new(config(data_dir), data, backend, run).unwrap();
    let out = t.run(&AtomicBool::new(false), &mut |_| {}).unwrap();
    assert_eq!(out, Outcome::Finished);
    assert_eq!(t.iteration, 300);
    t.evaluate().unwrap().psnr
}

#[test]
fn vulkan_backend_reaches_cpu_psnr_within_0_3_db() {
    let (tmp, data_dir) = small_scene();
    let cpu = train(&data_dir, &tmp.path().join("cpu"), CpuBackend::default());
    for disable_float_atomics in [false, true] {
        let options = lavapipe(disable_float_atomics);
        let backend = VulkanBackend::new(&options, RenderSettings::default())
            .expect("lavapipe must be available");
        let vk = train(
            &data_dir,
            &tmp.path().join(format!("vk{disable_float_atomics}")),
            backend,
        );
        eprintln!(
            "held-out PSNR: cpu {cpu:.3} dB, vulkan (float atomics off: {disable_float_atomics}) {vk:.3} dB"
        );
        assert!(
            (vk - cpu).abs() <= 0.3,
            "Vulkan backend (float atomics off: {disable_float_atomics}) PSNR {vk:.3} dB vs CPU {cpu:.3} dB: differ by more than 0.3 dB"
        );
    }
}

/// The three ways the Vulkan backend takes a step agree step by step: resident (parameters,
/// moments and densification statistics stay on the GPU, Adam runs there), device losses with
/// Adam on the host (gradients read back), and the host path (images read back, losses on the
/// host, as the CPU backend). Over 12 steps that cross the end of the warm-up, density control
/// and capacity checks (so the state goes to the host and back several times), the per-step
/// losses agree within 1e-3 relative and the final parameters within 1e-3 (absolute, 1e-3
/// relative above 1).
/// `p` with every primitive's live bands in a canonical order (by frequency vector), and the
/// primitives whose live band counts differ from `other`'s. Capacity adaptation stores a
/// primitive's kept bands by decreasing |amplitude|, so two bands of near-equal amplitude may
/// swap slots between runs whose float sums differ in order: the comparison is per band, not
/// per slot.
fn canonical_bands(p: &Primitives<f32>) -> Primitives<f32> {
    let mut out = p.clone();
    let m = p.bands;
    for i in 0..p.len() {
        let mut order: Vec<usize> = (0..p.live_bands(i)).collect();
        order.sort_by(|&a, &b| {
            let fa = &p.band_freq[3 * (m * i + a)..3 * (m * i + a) + 3];
            let fb = &p.band_freq[3 * (m * i + b)..3 * (m * i + b) + 3];
            fa.iter()
                .zip(fb)
                .map(|(x, y)| x.total_cmp(y))
                .find(|o| o.is_ne())
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        for (slot, &j) in order.iter().enumerate() {
            let (to, from) = (m * i + slot, m * i + j);
            out.band_amp[to] = p.band_amp[from];
            out.band_phase[to] = p.band_phase[from];
            out.band_freq[3 * to..3 * to + 3].copy_from_slice(&p.band_freq[3 * from..3 * from + 3]);
        }
    }
    out
}

#[test]
fn vulkan_resident_device_and_host_paths_take_the_same_steps() {
    paths_take_the_same_steps(ConsistPartner::Previous, ResponseKind::None);
}

/// As above with a learned gain and offset per view (`--response affine`): the response's
/// gradient sums come from the GPU loss kernels on the resident and device paths and from
/// the CPU reference on the host path, and the responses Adam makes of them agree within
/// 1e-5. Density control and capacity checks are off here: a band whose amplitude sits
/// within the atomics-order noise of the drop threshold (seen: one of 300) may drop on one
/// path and not the other once the trajectory changes, which says nothing about the response.
#[test]
fn vulkan_paths_take_the_same_steps_with_a_view_response() {
    paths_take_the_same_steps(ConsistPartner::Previous, ResponseKind::Affine);
}

/// As above with the consistency partner rendered in each step (both views' backward passes).
#[test]
fn vulkan_paths_take_the_same_steps_with_rendered_partner() {
    paths_take_the_same_steps(ConsistPartner::Render, ResponseKind::None);
}

fn paths_take_the_same_steps(partner: ConsistPartner, response: ResponseKind) {
    let (tmp, data_dir) = small_scene();
    let options = lavapipe(false);
    let mut losses = Vec::new();
    let mut finals = Vec::new();
    let mut responses = Vec::new();
    for (name, device_losses, resident) in [
        ("resident", true, true),
        ("device", true, false),
        ("host", false, false),
    ] {
        let mut backend = VulkanBackend::new(&options, RenderSettings::default())
            .expect("lavapipe must be available");
        backend.set_device_losses(device_losses);
        backend.set_resident_optimiser(resident);
        let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
        let mut c = config(&data_dir);
        c.warmup = 2; // β, bands and the consistency term from step 2 (the state syncs there)
        c.consist_every = 1;
        c.consist_partner = partner;
        // Opaque from the start, so views have depth (alpha ≥ 0.5) and the consistency term
        // is not zero in these first steps.
        c.init_opacity = 0.8;
        c.densify.from = 3;
        c.densify.every = 3;
        c.capacity.every = 4;
        c.response.kind = response;
        if response != ResponseKind::None {
            c.densify.every = 0;
            c.capacity.every = u64::MAX;
        }
        let mut t = Trainer::new(c, data, backend, &tmp.path().join(name)).unwrap();
        // The resident path starts three steps with key lists too small for their views:
        // each runs twice, the first run changing nothing (the Adam step is gated).
        let l: Vec<f64> = (0..12)
            .map(|step| {
                if resident && step % 4 == 1 {
                    t.backend.set_key_room(64);
                }
                t.step().unwrap()
            })
            .collect();
        losses.push((name, l));
        if resident {
            assert_eq!(
                t.backend.repeated_steps(),
                3,
                "resident path: steps repeated after their key lists ran out of room"
            );
        }
        let expected = if resident { 12 } else { 0 };
        assert_eq!(
            t.backend.resident_steps(),
            expected,
            "{name} path: steps taken with the optimiser state on the GPU"
        );
        t.sync_host().unwrap();
        finals.push(t.prims.clone());
        responses.push(t.response().cloned());
    }
    // The responses, updated on the host from each path's gradient sums, agree as the
    // parameters do (3 steps' worth of their learning rate per step).
    for (name, r) in [("resident", &responses[0]), ("device", &responses[1])] {
        let (Some(r), Some(host)) = (r, &responses[2]) else {
            assert!(
                response == ResponseKind::None && r.is_none() && responses[2].is_none(),
                "{name}: a response on one path only"
            );
            continue;
        };
        for (what, a, b) in [
            ("log-gain", &r.log_gain, &host.log_gain),
            ("offset", &r.offset, &host.offset),
        ] {
            let worst = a
                .iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            eprintln!("{name} vs host path, response {what}: largest difference {worst:.3e}");
            // Measured ≤ 6.2e-7 (f32 GPU sums against the CPU reference's f64).
            assert!(
                worst <= 1e-5,
                "{partner}: {name} path: response {what} differs from the host path's by {worst:.3e} (> 1e-5)"
            );
        }
        assert!(
            r.offset.iter().any(|&b| b != 0.0) && r.log_gain.iter().any(|&a| a != 0.0),
            "{name} path: the response never moved"
        );
    }
    let (ref_name, ref_losses) = &losses[2];
    for (name, l) in &losses[..2] {
        for (step, (a, b)) in l.iter().zip(ref_losses).enumerate() {
            assert!(
                (a - b).abs() <= 1e-3 * b.abs(),
                "{partner}: step {step}: {name}-path loss {a} vs {ref_name}-path loss {b} (relative 1e-3)"
            );
        }
    }
    // Adam normalises its steps, so the atomics-order noise of near-zero gradients (float
    // sums in another order each run) moves a value by up to about one learning rate per step
    // on any path: parameters are held within 3 steps' worth per iteration of their group's
    // learning rate (β in β units), and the losses above within 1e-3. The exact agreement of
    // the Adam kernel with the host optimiser is `gpu_adam.rs`'s.
    let host = &finals[2];
    let lr = config(&data_dir).lr;
    let steps = 12.0;
    let bound = |group: Group| -> f64 {
        let g = match group {
            Group::Means => 1e-3 / steps / 3.0, // lr × scene extent; observed ≤ 1e-4
            _ => lr.of(group),
        };
        3.0 * steps * g
    };
    let host = &canonical_bands(host);
    for (name, p) in [("resident", &finals[0]), ("device", &finals[1])] {
        assert_eq!(
            p.len(),
            host.len(),
            "{name}: primitive count after density control"
        );
        assert_eq!(p.bands, host.bands, "{name}: band slots after compaction");
        // Capacity adaptation drops a band whose |amplitude| is below the threshold: a band
        // that sits within the atomics-order noise of it may drop on one path and not the
        // other (CI saw one primitive of 300 keep 2 bands on the resident path and 3 on the
        // host's). Such a near-tie may differ by one band on at most 2 % of the primitives
        // (15 runs here, per path against the host's: 0 primitives in 21 of the 30
        // comparisons with capacity checks, 1 in 4, 2 in 5), and the band only one path
        // kept must be within the parameters' noise bound of the threshold; those
        // primitives' bands are then compared no further.
        let thr = config(&data_dir).capacity.band_amp_threshold;
        let mut p = canonical_bands(p);
        let differing: Vec<usize> = (0..p.len())
            .filter(|&i| p.band_count[i] != host.band_count[i])
            .collect();
        assert!(
            differing.len() <= p.len() / 50,
            "{name}: {} of {} primitives have other live band counts than the host path's \
             (at most 2 % may, as threshold near-ties): {differing:?}",
            differing.len(),
            p.len()
        );
        eprintln!(
            "{name} vs host path: {} primitives with other live band counts",
            differing.len()
        );
        let m = p.bands;
        for &i in &differing {
            let (a, b) = (p.live_bands(i), host.live_bands(i));
            assert!(
                a.abs_diff(b) == 1,
                "{name}: primitive {i} keeps {a} bands, the host path {b} (a near-tie differs by one)"
            );
            let keeper = if a > b { &p } else { host };
            let weakest = (0..keeper.live_bands(i))
                .map(|j| f64::from(keeper.band_amp[m * i + j].abs()))
                .fold(f64::INFINITY, f64::min);
            assert!(
                weakest <= thr + bound(Group::BandAmp),
                "{name}: primitive {i}: the path with {} bands keeps none near the drop \
                 threshold {thr:.1e} (weakest |amplitude| {weakest:.3e}): not a near-tie",
                a.max(b)
            );
            p.band_count[i] = host.band_count[i];
            for j in m * i..m * (i + 1) {
                p.band_amp[j] = host.band_amp[j];
                p.band_phase[j] = host.band_phase[j];
            }
            p.band_freq[3 * m * i..3 * m * (i + 1)]
                .copy_from_slice(&host.band_freq[3 * m * i..3 * m * (i + 1)]);
        }
        let p = &p;
        for ((group, a), (_, b)) in p.groups().into_iter().zip(host.groups()) {
            let value = |x: f32| {
                if group == Group::BetaRaw {
                    beta_of_raw(f64::from(x)).0
                } else {
                    f64::from(x)
                }
            };
            let worst = a
                .iter()
                .zip(b)
                .map(|(&x, &y)| (value(x) - value(y)).abs())
                .fold(0.0, f64::max);
            eprintln!("{name} vs host path, {group}: largest difference {worst:.3e}");
            assert!(
                worst <= bound(group),
                "{partner}: {name} path: {group} differs from the host path's by up to {worst:.3e}, more \
                 than {:.3e} (3 × 12 steps of its learning rate)",
                bound(group)
            );
        }
    }
}

/// A resident step reads the GPU once, 40 bytes: the key totals of both views (8 bytes), the
/// view's loss sums and its response's gradient (24 bytes) and the consistency sums (8 bytes);
/// no parameters, gradients or images, and no read in the middle of
/// the step (the key lists have the room earlier steps measured). A step whose views need more
/// room runs again (one more read); that is counted and bounded. Counted over steps with no
/// host work in between (no density control, no capacity checks, no evaluation), from the
/// context's traffic counters.
#[test]
fn vulkan_resident_step_reads_once_and_allocates_nothing() {
    for partner in [ConsistPartner::Previous, ConsistPartner::Render] {
        reads_once_and_allocates_nothing(partner);
    }
}

fn reads_once_and_allocates_nothing(partner: ConsistPartner) {
    const WARM: u64 = 5;
    let (tmp, data_dir) = small_scene();
    let options = lavapipe(false);
    let backend = VulkanBackend::new(&options, RenderSettings::default())
        .expect("lavapipe must be available");
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let mut c = config(&data_dir);
    c.warmup = 0;
    c.consist_every = 1; // the term every step (render) or every second step (previous)
    c.consist_partner = partner;
    c.densify.from = u64::MAX;
    c.capacity.every = u64::MAX;
    c.response.kind = ResponseKind::Offset;
    let mut t = Trainer::new(c, data, backend, &tmp.path().join("run")).unwrap();
    // Step 1 uploads the state and sizes its key lists exactly; the next steps give them the
    // measured room, and the rasteriser keeps the last two views, so once two views with that
    // room have been released (step 4 with a partner rendered per step, step 5 without) the
    // pool serves every view. Warm from then on.
    for _ in 0..WARM {
        t.step().unwrap();
    }
    let (r0, b0, _) = t.backend.context().traffic();
    let created0 = t.backend.raster_buffers_created();
    let steps = 8;
    for _ in 0..steps {
        t.step().unwrap();
    }
    let (r1, b1, _) = t.backend.context().traffic();
    let created = t.backend.raster_buffers_created() - created0;
    assert_eq!(
        t.backend.resident_steps(),
        steps + WARM,
        "every step resident"
    );
    let repeated = t.backend.repeated_steps();
    assert!(
        repeated <= 1,
        "{partner}: {repeated} of {steps} steps repeated: the measured room (+25 %) should fit this scene's \
         views"
    );
    let reads = steps + repeated;
    assert_eq!(
        (r1 - r0, b1 - b0),
        (reads, 40 * reads),
        "{partner}: host reads and bytes over {steps} resident steps, {repeated} repeated (expected 1 read, \
         40 bytes per run)"
    );
    if repeated == 0 {
        assert_eq!(
            created, 0,
            "{partner}: warm resident steps must reuse the rasteriser's buffers, {created} were created \
             over {steps} steps"
        );
    }
}

/// A run whose buffers would exceed the device's storage-buffer range is refused before the
/// run folder is written, with an error naming the buffer, the budget and the limit (lavapipe:
/// 128 MiB). The largest per-primitive buffer is the backward pass's scratch (16 + 5 · 4
/// floats per primitive with 4 bands): the budget here makes it one primitive too large, and
/// one primitive fewer passes the check. (The texel buffers, 7 texels per primitive against
/// lavapipe's 2^27, allow far more.)
#[test]
fn vulkan_run_too_large_for_the_device_is_refused_up_front() {
    let (tmp, data_dir) = small_scene();
    let backend = VulkanBackend::new(&lavapipe(false), RenderSettings::default())
        .expect("lavapipe must be available");
    let limit = backend.context().report().max_storage_buffer_range_bytes;
    let fits = (limit / (36 * 4)) as usize;
    let texel_limit = backend.context().report().max_texel_buffer_elements;
    assert!(
        7 * fits as u64 <= texel_limit,
        "the storage limit must be the binding one here ({texel_limit} texels)"
    );
    let mut c = config(&data_dir);
    c.bands = 4;
    let shape = |budget| RunShape {
        budget,
        bands: 4,
        width: 40,
        height: 30,
        sh_k: 0,
    };
    assert!(
        backend.check_run(&shape(fits)).is_ok(),
        "the buffers of {fits} primitives fit {limit} bytes"
    );
    c.budget = fits + 1;
    let run = tmp.path().join("too-large");
    let data = Dataset::load(&data_dir, &LoadOptions::default()).unwrap();
    let Err(err) = Trainer::new(c, data, backend, &run) else {
        panic!(
            "a budget of {} primitives must be refused on lavapipe",
            fits + 1
        );
    };
    let msg = err.to_string();
    for part in [
        "raster.grad_acc",
        "maxStorageBufferRange",
        &(fits + 1).to_string(),
        "--budget",
    ] {
        assert!(msg.contains(part), "error must name {part:?}: {msg}");
    }
    assert!(!run.exists(), "nothing may be written for a refused run");
}
