//! Proves `s3tir-train devices` works as a user runs it: lists lavapipe with the properties the
//! trainer needs (text and JSON), and exits non-zero with a clear message when the Vulkan
//! loader finds no driver; `--resume` keeps a Vulkan run on Vulkan unless `--backend` says
//! otherwise; `eval --backend vulkan` matches the CPU reference. Does NOT cover a machine with no loader library at all (the loader
//! is installed system-wide here; that path is the `LoaderMissing` error of `VulkanInstance`).
#![cfg(feature = "vulkan")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

fn train() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_s3tir-train"));
    cmd.env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE");
    cmd
}

/// The built-in synthetic scene, 6 views of 24×18, in `dir/scene`.
fn small_scene(dir: &std::path::Path) -> std::path::PathBuf {
    let data = dir.join("scene");
    let st = train()
        .args(["synth", data.to_str().unwrap(), "--views", "6"])
        .args(["--width", "24", "--height", "18"])
        .output()
        .unwrap();
    assert!(st.status.success(), "synth failed");
    data
}

/// A short training run of `data` into `run` (2 warm-up iterations, 60 primitives, no
/// evaluation before the end).
fn short_run(data: &std::path::Path, run: &std::path::Path, iters: &str) -> Command {
    let mut c = train();
    c.arg(data).arg("--out").arg(run).args([
        "--warmup",
        "2",
        "--budget",
        "60",
        "--eval-every-s",
        "1000",
        "--iters",
        iters,
    ]);
    c
}

#[test]
fn devices_lists_lavapipe_with_limits_subgroups_and_atomics() {
    let out = train().arg("devices").output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "exit {:?}, stderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    for needle in [
        "llvmpipe",
        "Vulkan API",
        "max range 128 MiB",
        "32 KiB shared memory",
        "subgroups         size 8",
        "arithmetic",
        "buffer add yes",
    ] {
        assert!(
            text.contains(needle),
            "`devices` output lacks {needle:?}:\n{text}"
        );
    }
}

#[test]
fn devices_json_is_one_array_with_the_documented_fields() {
    let out = train().args(["devices", "--json"]).output().unwrap();
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("stdout must be JSON");
    let lvp = v
        .as_array()
        .and_then(|a| {
            a.iter()
                .find(|d| d["name"].as_str().is_some_and(|n| n.contains("llvmpipe")))
        })
        .unwrap_or_else(|| panic!("no llvmpipe in {v}"));
    assert_eq!(lvp["max_storage_buffer_range_bytes"], 134_217_728u64);
    assert_eq!(lvp["float_atomics"]["buffer_f32_add"], true);
    assert!(lvp["subgroup_size"].as_u64().unwrap() >= 4);
    assert!(lvp["driver_name"].is_string() && lvp["api_version"].is_string());
}

#[test]
fn devices_without_a_driver_fails_with_the_reason() {
    let out = train()
        .arg("devices")
        .env("VK_ICD_FILENAMES", "/nonexistent/s3tir-no-driver.json")
        .env("VK_DRIVER_FILES", "/nonexistent/s3tir-no-driver.json")
        .output()
        .unwrap();
    assert!(!out.status.success(), "must exit non-zero without a driver");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("found no device") && err.contains("mesa-vulkan-drivers"),
        "stderr: {err}"
    );
}

#[test]
fn bench_json_reports_both_backends_both_modes_and_kernels() {
    let out = train()
        .args([
            "bench", "--json", "--width", "32", "--height", "24", "--views", "4",
        ])
        .args(["--primitives", "150", "--steps", "2", "--warmup-steps", "1"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "bench failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("stdout must be one JSON object");
    for key in [
        "cpu_steps_per_s",
        "vulkan_steps_per_s",
        "s3tir_steps_per_s",
        "gaussian_steps_per_s",
    ] {
        let x = v[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} missing in {v}"));
        assert!(x.is_finite() && x > 0.0, "{key} = {x}");
    }
    assert!(
        v["device"].as_str().is_some_and(|d| d.contains("llvmpipe")),
        "device: {}",
        v["device"]
    );
    let kernels: Vec<&str> = v["kernels"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|k| k["kernel"].as_str())
        .collect();
    for k in ["raster_forward", "raster_project", "radix_scatter"] {
        assert!(
            kernels.contains(&k),
            "kernel breakdown lacks {k}: {kernels:?}"
        );
    }
    assert!(
        kernels.iter().any(|k| k.starts_with("raster_backward_")),
        "no backward kernel in {kernels:?}"
    );
}

/// `--resume` continues on the run's own backend: a Vulkan run resumed without `--backend`
/// stays on Vulkan (the flag's default used to switch it to the CPU silently); an explicit
/// `--backend` still switches, and says so.
#[test]
fn resume_keeps_the_runs_backend_unless_told_otherwise() {
    let tmp = tempfile::tempdir().unwrap();
    let data = small_scene(tmp.path());
    let run = tmp.path().join("run");
    let common = |iters: &str| short_run(&data, &run, iters);
    let first = common("3").args(["--backend", "vulkan"]).output().unwrap();
    let text = String::from_utf8_lossy(&first.stdout);
    assert!(
        first.status.success() && text.contains("training on the vulkan backend"),
        "first run: {text}\n{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let resumed = common("5").arg("--resume").output().unwrap();
    let text = String::from_utf8_lossy(&resumed.stdout);
    assert!(
        resumed.status.success() && text.contains("training on the vulkan backend"),
        "a resumed Vulkan run must stay on Vulkan: {text}\n{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    let switched = common("6")
        .args(["--resume", "--backend", "cpu"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&switched.stdout);
    assert!(
        switched.status.success()
            && text.contains("switching from the run's vulkan backend to cpu")
            && text.contains("training on the cpu backend"),
        "an explicit --backend switches and says so: {text}\n{}",
        String::from_utf8_lossy(&switched.stderr)
    );
}

/// A new run without `--backend` takes `auto`: lavapipe passes the trainer's checks here, so
/// the run trains on Vulkan, says why, and config.json keeps "vulkan" (so `--resume` stays on
/// it); with no Vulkan driver at all the run falls back to the CPU and names the reason.
#[test]
fn backend_auto_takes_vulkan_when_it_passes_and_the_cpu_otherwise() {
    let tmp = tempfile::tempdir().unwrap();
    let data = small_scene(tmp.path());
    let run = |name: &str, no_driver: bool| {
        let dir = tmp.path().join(name);
        let mut c = short_run(&data, &dir, "3");
        if no_driver {
            c.env("VK_ICD_FILENAMES", "/nonexistent/s3tir-no-driver.json")
                .env("VK_DRIVER_FILES", "/nonexistent/s3tir-no-driver.json");
        }
        let out = c.output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{name}: {text}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let cfg: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("config.json")).unwrap())
                .unwrap();
        (text, cfg["backend"].as_str().unwrap_or_default().to_owned())
    };
    let (text, backend) = run("auto", false);
    assert!(
        text.contains("training on the vulkan backend (--backend auto: llvmpipe")
            && text.contains("passes the trainer's checks"),
        "auto with lavapipe: {text}"
    );
    assert_eq!(backend, "vulkan", "config.json keeps the backend auto took");
    let (text, backend) = run("no-driver", true);
    assert!(
        text.contains("training on the cpu backend (--backend auto: no Vulkan device"),
        "auto without a driver falls back to the CPU and says why: {text}"
    );
    assert_eq!(backend, "cpu");
}

/// `eval --backend vulkan` renders the held-out views on the GPU: the same views and figures
/// as the CPU reference to float noise (PSNR within 0.05 dB), and the JSON says which backend.
#[test]
fn eval_on_vulkan_matches_the_cpu_reference() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    let run = tmp.path().join("run");
    let st = train()
        .args(["synth", data.to_str().unwrap(), "--views", "9"])
        .output()
        .unwrap();
    assert!(st.status.success(), "synth failed");
    let t = train()
        .arg(&data)
        .arg("--out")
        .arg(&run)
        .args(["--iters", "60", "--warmup", "20", "--budget", "200"])
        .args(["--eval-every-s", "1000"])
        .output()
        .unwrap();
    assert!(
        t.status.success(),
        "training failed: {}",
        String::from_utf8_lossy(&t.stderr)
    );
    let eval = |backend: &str| -> serde_json::Value {
        let out = train()
            .args([
                "eval",
                run.to_str().unwrap(),
                "--json",
                "--backend",
                backend,
            ])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "eval --backend {backend}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).expect("eval --json prints JSON")
    };
    let (cpu, gpu) = (eval("cpu"), eval("vulkan"));
    assert_eq!(cpu["backend"], "cpu");
    assert_eq!(gpu["backend"], "vulkan");
    assert_eq!(
        cpu["view_count"], gpu["view_count"],
        "the same held-out views"
    );
    let (a, b) = (cpu["psnr"].as_f64().unwrap(), gpu["psnr"].as_f64().unwrap());
    assert!(
        (a - b).abs() < 0.05 && a > 10.0,
        "held-out PSNR on Vulkan {b:.3} dB vs CPU {a:.3} dB (expected within 0.05 dB)"
    );
}
