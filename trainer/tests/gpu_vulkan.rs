//! Proves the Vulkan shader pipeline end to end on a real driver (lavapipe in CI): devices are
//! enumerated with the properties the trainer needs, every compiled shader builds a pipeline,
//! the parallel sum matches an f64 CPU sum in both the subgroup and the shared-memory variant,
//! and limits are checked before any GPU work. Does NOT measure speed (benchmarks do).
//!
//! Needs a Vulkan loader and driver; `make test` installs mesa-vulkan-drivers (lavapipe). These
//! tests fail, rather than skip, without one: every CI machine must run them.
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use rand::{Rng, SeedableRng};
use s3tir_trainer::gpu::context::ContextOptions;
use s3tir_trainer::gpu::reduce::{ReduceVariant, sum_f32};
use s3tir_trainer::gpu::shaders::{self, KERNELS, SHADERS};
use s3tir_trainer::gpu::{DeviceChoice, GpuContext, GpuError, MemoryLocation, VulkanInstance};

fn lavapipe() -> GpuContext {
    GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics: false,
    })
    .expect("lavapipe (Mesa llvmpipe) must be available: install mesa-vulkan-drivers")
}

#[test]
fn lavapipe_is_listed_with_the_properties_the_trainer_needs() {
    let instance = VulkanInstance::new().expect("Vulkan loader must load");
    let reports = instance.reports().unwrap();
    let lvp = reports
        .iter()
        .find(|r| r.name.contains("llvmpipe"))
        .unwrap_or_else(|| {
            panic!(
                "no llvmpipe among {:?}",
                reports.iter().map(|r| &r.name).collect::<Vec<_>>()
            )
        });
    assert_eq!(lvp.device_type, "cpu");
    assert!(
        lvp.api_version.starts_with("1.3"),
        "lavapipe API {}",
        lvp.api_version
    );
    assert!(
        lvp.max_storage_buffer_range_bytes >= 128 << 20,
        "storage range {}",
        lvp.max_storage_buffer_range_bytes
    );
    assert!(lvp.max_compute_shared_memory_bytes >= 32 << 10);
    assert!(
        lvp.subgroup_size >= 4,
        "subgroup size {}",
        lvp.subgroup_size
    );
    assert!(
        lvp.has_subgroup_arithmetic(),
        "ops {:?}",
        lvp.subgroup_operations
    );
    assert!(
        lvp.float_atomics.buffer_f32_add,
        "lavapipe offers float32 atomic add on buffers"
    );
    assert!(!lvp.memory_heaps.is_empty() && lvp.memory_heaps[0].size_bytes > 0);
}

#[test]
fn every_shader_builds_a_pipeline() {
    let ctx = lavapipe();
    let compiled: Vec<&str> = SHADERS.iter().map(|(n, _)| *n).collect();
    for name in &compiled {
        assert!(
            KERNELS.iter().any(|k| k.name == *name),
            "shader {name} is compiled but has no KernelSpec in gpu/shaders.rs"
        );
    }
    for spec in KERNELS {
        assert!(
            compiled.contains(&spec.name),
            "KernelSpec {} has no shader file",
            spec.name
        );
        let kernel = shaders::build(&ctx, spec.name)
            .unwrap_or_else(|e| panic!("kernel {} does not build: {e}", spec.name));
        ctx.destroy_kernel(kernel);
    }
}

#[test]
fn spirv_passes_spirv_val_when_available() {
    let Ok(status) = std::process::Command::new("spirv-val")
        .arg("--version")
        .output()
    else {
        s3tir_capture::skip::skip(
            "spirv-val",
            "spirv-val not installed (Debian package spirv-tools)",
        );
        return;
    };
    assert!(status.status.success());
    let dir = std::path::Path::new(env!("S3TIR_SPIRV_DIR"));
    for (name, _) in SHADERS {
        let path = dir.join(format!("{name}.spv"));
        let out = std::process::Command::new("spirv-val")
            .args(["--target-env", "vulkan1.2"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "spirv-val rejects {}: {}",
            path.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

fn random_values(n: usize, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(-1.0f32..2.0)).collect()
}

#[test]
fn gpu_sum_matches_f64_cpu_sum_in_both_variants() {
    let ctx = lavapipe();
    // Sizes around the pass boundaries (2048 per workgroup): 1, one group, one more, multi-pass.
    for (i, n) in [1usize, 7, 2048, 2049, 100_000, 4_200_000]
        .into_iter()
        .enumerate()
    {
        let values = random_values(n, i as u64);
        let exact: f64 = values.iter().map(|&v| f64::from(v)).sum();
        let abs_sum: f64 = values.iter().map(|&v| f64::from(v).abs()).sum();
        for variant in [ReduceVariant::Subgroup, ReduceVariant::SharedMemory] {
            let got = f64::from(sum_f32(&ctx, &values, variant).unwrap());
            // Pairwise f32 summation: error bound ~ log2(n) * eps * sum|x|; allow 4x margin.
            let tol = 4.0 * (n as f64).log2().max(1.0) * f64::from(f32::EPSILON) * abs_sum;
            assert!(
                (got - exact).abs() <= tol,
                "{variant:?}, n = {n}: GPU sum {got}, exact {exact}, |error| {} > tolerance {tol}",
                (got - exact).abs()
            );
        }
    }
    assert_eq!(
        sum_f32(&ctx, &[], ReduceVariant::SharedMemory).unwrap(),
        0.0
    );
}

#[test]
fn default_variant_follows_capabilities_and_fallback_is_forced_by_switch() {
    let ctx = lavapipe();
    assert_eq!(
        ReduceVariant::best_for(ctx.capabilities()),
        ReduceVariant::Subgroup
    );
    assert!(ctx.capabilities().float_atomic_add);
    let no_atomics = GpuContext::new(&ContextOptions {
        device: DeviceChoice::NameContains("llvmpipe".into()),
        disable_float_atomics: true,
    })
    .unwrap();
    assert!(
        !no_atomics.capabilities().float_atomic_add,
        "switch must disable float atomics"
    );
}

#[test]
fn limits_and_bad_choices_are_typed_errors() {
    let ctx = lavapipe();
    let too_big = ctx.report().max_storage_buffer_range_bytes + 4;
    match ctx.create_buffer("huge", too_big, MemoryLocation::DeviceOnly) {
        Err(GpuError::LimitTooSmall {
            limit, required, ..
        }) => {
            assert_eq!(limit, "maxStorageBufferRange");
            assert_eq!(required, too_big);
        }
        other => panic!("want LimitTooSmall for {too_big} bytes, got {other:?}"),
    }
    match GpuContext::new(&ContextOptions {
        device: DeviceChoice::Index(999),
        disable_float_atomics: false,
    }) {
        Err(GpuError::DeviceIndexOutOfRange { index: 999, count }) => assert!(count >= 1),
        other => panic!("want DeviceIndexOutOfRange, got {other:?}"),
    }
    // Interface mismatch is caught before recording.
    let kernel = shaders::build(&ctx, "reduce_shared").unwrap();
    let buf = ctx.upload("one", &[1.0f32]).unwrap();
    let err = ctx
        .submit(|rec| rec.dispatch(&kernel, &[&buf], &0u32.to_le_bytes(), [1, 1, 1]))
        .unwrap_err();
    assert!(err.to_string().contains("1 buffers bound"), "got: {err}");
    ctx.destroy_buffer(buf);
    ctx.destroy_kernel(kernel);
}

#[test]
fn peak_memory_is_tracked() {
    let ctx = lavapipe();
    let before = ctx.peak_allocated_bytes();
    let a = ctx
        .create_buffer("a", 1 << 20, MemoryLocation::Upload)
        .unwrap();
    let b = ctx
        .create_buffer("b", 1 << 20, MemoryLocation::Readback)
        .unwrap();
    assert!(ctx.allocated_bytes() >= 2 << 20);
    ctx.destroy_buffer(a);
    ctx.destroy_buffer(b);
    assert!(
        ctx.peak_allocated_bytes() >= before + (2 << 20),
        "peak {}",
        ctx.peak_allocated_bytes()
    );
    assert_eq!(ctx.allocated_bytes(), 0, "all buffers freed");
}
