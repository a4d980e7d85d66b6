//! Proves, through the `s3tir-train` binary, one behaviour per test: a run killed with SIGKILL
//! continues from its last checkpoint with `--resume` (iteration count carries on, no restart
//! from 0; `--json` prints the run's summary); Ctrl-C (SIGINT) writes a checkpoint and exits
//! with 130; `eval --json` prints the documented object and `compare` overlays runs into a PNG;
//! a run folder is never overwritten and a bad dataset path fails with a message naming it. Does NOT check training quality (pipeline_modes.rs does).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_s3tir-train"))
}

fn checkpoint_iteration(run: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(run.join("checkpoint.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v["iteration"].as_u64()
}

fn wait_for_checkpoint_past(run: &Path, min_iter: u64) -> u64 {
    let t0 = Instant::now();
    loop {
        if let Some(i) = checkpoint_iteration(run)
            && i > min_iter
        {
            return i;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "no checkpoint past {min_iter} within 90 s"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn train_args(data: &Path, run: &Path) -> Vec<String> {
    [
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--warmup",
        "20",
        "--budget",
        "120",
        "--checkpoint-every-s",
        "0.2",
        "--eval-every-s",
        "0.5",
        "--seed",
        "4",
        // The CPU reference: these runs are a few steps on 24×18 images, and the figures
        // asserted below were measured on it (`--backend auto` would take lavapipe).
        "--backend",
        "cpu",
    ]
    .iter()
    .map(|s| (*s).to_owned())
    .collect()
}

/// A small radiometric scene (9 views of 24×18, 2 held out) in `dir/scene`.
fn synth_scene(dir: &Path) -> std::path::PathBuf {
    let data = dir.join("scene");
    let st = bin()
        .args([
            "synth",
            data.to_str().unwrap(),
            "--views",
            "9",
            "--width",
            "24",
            "--height",
            "18",
        ])
        .status()
        .unwrap();
    assert!(st.success(), "synth failed");
    data
}

/// A finished run of `iters` iterations of `data` in `run`.
fn finished_run(data: &Path, run: &Path, iters: u64) {
    finished_run_with(data, run, &["--iters", &iters.to_string()]);
}

/// A finished run of `data` in `run` with the test's options and `extra`.
fn finished_run_with(data: &Path, run: &Path, extra: &[&str]) {
    let out = bin()
        .args(train_args(data, run))
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "training failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_killed_run_resumes_from_its_last_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    // 1. Start a long run and SIGKILL it after two checkpoints.
    let mut child = bin()
        .args(train_args(&data, &run))
        .args(["--iters", "1000000"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let first = wait_for_checkpoint_past(&run, 0);
    wait_for_checkpoint_past(&run, first);
    child.kill().unwrap();
    child.wait().unwrap();
    let killed_at = checkpoint_iteration(&run).unwrap();
    assert!(killed_at > 0);

    // 2. Resume to a fixed end.
    let target = killed_at + 25;
    let out = bin()
        .args(train_args(&data, &run))
        .args(["--resume", "--iters", &target.to_string(), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "resume failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // --json: stdout is one object (the human lines went to stderr).
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "train --json stdout is not one JSON object ({e}): {}",
            String::from_utf8_lossy(&out.stdout)
        )
    });
    assert_eq!(summary["outcome"], "finished", "{summary}");
    assert_eq!(summary["iterations"].as_u64(), Some(target), "{summary}");
    assert!(
        summary["eval"]["psnr"].as_f64().is_some_and(|p| p > 10.0),
        "the summary carries the held-out figures: {summary}"
    );
    assert!(
        summary["files"].as_array().is_some_and(|f| f
            .iter()
            .any(|p| p.as_str().is_some_and(|p| p.ends_with("point_cloud.ply")))),
        "the summary lists the files written: {summary}"
    );
    assert_eq!(
        checkpoint_iteration(&run),
        Some(target),
        "resumed run ends at {target}"
    );
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let iters: Vec<u64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(
        iters.iter().filter(|&&i| i == 0).count(),
        1,
        "resume must not restart from 0: {iters:?}"
    );
    assert_eq!(
        *iters.last().unwrap(),
        target,
        "last metrics row: {iters:?}"
    );
    assert!(
        csv.starts_with("iteration,seconds,loss,psnr,ssim,kelvin_mae,"),
        "header: {csv}"
    );
    for f in [
        "point_cloud.ply",
        "error_vs_time.png",
        "beta_hist.png",
        "eval.json",
        "capacity.json",
    ] {
        assert!(run.join(f).exists(), "{f} missing");
    }
    let gb = std::fs::read_dir(run.join("gbuffers")).unwrap().count();
    assert_eq!(
        gb,
        2 * 9,
        "4 G-buffer PNGs and 5 .npy planes per held-out view (2 views)"
    );
}

#[test]
fn ctrl_c_writes_a_checkpoint_and_exits_130() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    // Ctrl-C: checkpoint, then exit 130.
    let child = bin()
        .args(train_args(&data, &run))
        .args(["--iters", "1000000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for_checkpoint_past(&run, 0);
    let st = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "Ctrl-C exit code");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("interrupted at iteration"),
        "stdout: {stdout}"
    );
    assert!(checkpoint_iteration(&run).unwrap() > 0);
}

#[test]
fn eval_json_and_compare_read_a_finished_run() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    finished_run(&data, &run, 40);
    let out = bin()
        .args(["eval", run.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "eval: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in ["psnr", "ssim", "kelvin_mae", "views", "primitives"] {
        assert!(v.get(key).is_some(), "eval --json lacks `{key}`: {v}");
    }
    assert!(v["psnr"].as_f64().unwrap() > 10.0, "psnr {}", v["psnr"]);
    assert!(
        v["kelvin_mae"].as_f64().is_some(),
        "radiometric data: kelvin_mae is a number"
    );
    assert_eq!(v["views"].as_array().unwrap().len(), 2);

    let png = tmp.path().join("cmp.png");
    let out = bin()
        .args([
            "compare",
            run.to_str().unwrap(),
            run.to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "compare: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        std::fs::metadata(&png).unwrap().len() > 1000,
        "compare plot is empty"
    );

    // Groups of repeated runs: the mean-and-range curves and the leads, as JSON.
    let (r, png2) = (run.to_str().unwrap(), tmp.path().join("groups.png"));
    let out = bin()
        .args([
            "compare",
            &format!("twice={r},{r}"),
            &format!("once={r}"),
            "--json",
            "--out",
            png2.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "compare with groups: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let curves = v["curves"].as_array().expect("`curves` is an array");
    assert_eq!(curves.len(), 2, "one curve per group: {v}");
    assert_eq!(curves[0]["label"], "twice");
    assert_eq!(curves[0]["runs"], 2, "the first group holds two runs");
    let p = &curves[0]["points"].as_array().unwrap().last().unwrap()["psnr"];
    assert_eq!(p["min"], p["max"], "the same run twice has no range: {p}");
    let leads = v["leads"].as_array().expect("`leads` is an array");
    assert!(!leads.is_empty(), "the first group against the second: {v}");
    let l = &leads[0];
    assert_eq!(l["ahead"], l["evaluations"], "a run equals itself: {l}");
    assert!(
        l["ahead_in_every_pair"].is_null(),
        "groups of 2 and 1 runs are not paired: {l}"
    );
    assert!(
        std::fs::metadata(&png2).unwrap().len() > 1000,
        "group plot is empty"
    );

    // An entry that is neither a run folder nor a group is named.
    let missing = tmp.path().join("no_such_run");
    let out = bin()
        .args(["compare", missing.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success(), "compare of a missing folder fails");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no_such_run") && err.contains("no such run folder"),
        "the error names the entry: {err}"
    );
}

/// `--consist-weight` sets λc (and `--band-ramp` the bands' ramp) in the run's config (what
/// `--resume` and `compare` read back); a weight that is not finite and ≥ 0 is refused with the
/// flag named, before anything is written.
#[test]
fn the_consistency_weight_is_recorded_and_a_bad_one_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    finished_run_with(
        &data,
        &run,
        &[
            "--iters",
            "5",
            "--consist-weight",
            "0.002",
            "--band-ramp",
            "3",
        ],
    );
    // Read back as `--resume` reads it.
    let cfg: s3tir_trainer::train::TrainConfig =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(
        cfg.weights.consist, 0.002,
        "config.json should record λc = 0.002: {:?}",
        cfg.weights
    );
    assert_eq!(cfg.band_ramp, 3, "config.json should record --band-ramp 3");

    let bad = tmp.path().join("bad");
    let out = bin()
        .args(train_args(&data, &bad))
        .args(["--iters", "5", "--consist-weight=-1"])
        .output()
        .unwrap();
    assert!(!out.status.success(), "a negative λc must be refused");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--consist-weight"),
        "the error should name the flag: {err}"
    );
    assert!(!bad.exists(), "nothing should be written for a refused run");
    for (flag, value) in [("--band-l1", "-1"), ("--band-budget", "1.5")] {
        let out = bin()
            .args(train_args(&data, &bad))
            .args(["--iters", "5", &format!("{flag}={value}")])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(flag),
            "{flag} {value} must be refused, naming the flag: {err}"
        );
        assert!(!bad.exists(), "nothing should be written for a refused run");
    }
}

#[test]
fn a_run_is_never_overwritten_and_a_bad_dataset_path_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    finished_run(&data, &run, 5);
    // A new run into a folder that holds one is refused (no silent overwrite).
    let out = bin()
        .args(train_args(&data, &run))
        .args(["--iters", "5"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--resume"),
        "error should point to --resume: {err}"
    );

    // A bad dataset path.
    let out = bin()
        .args([
            tmp.path().join("nope").to_str().unwrap(),
            "--out",
            tmp.path().join("r2").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope"), "error should name the path: {err}");
}

#[test]
fn devices_subcommand_still_parses() {
    let out = bin().args(["devices", "--help"]).output().unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("--json"));
    let out = bin().args(["--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    for s in [
        "devices", "eval", "compare", "--mode", "--budget", "--resume",
    ] {
        assert!(help.contains(s), "--help lacks {s}");
    }
}

/// `bench --mesh` at a small size: the scene-size flags it is given are the ones it uses (not
/// the training bench's), and it reports the stages, the mesh and the peak memory.
#[test]
fn bench_mesh_reports_seconds_memory_and_the_mesh_at_the_size_given() {
    let out = bin()
        .args([
            "bench",
            "--mesh",
            "--json",
            "--width",
            "96",
            "--height",
            "72",
            "--views",
            "4",
            "--primitives",
            "400",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "bench --mesh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (
            v["width"].as_u64(),
            v["height"].as_u64(),
            v["views_rendered"].as_u64()
        ),
        (Some(96), Some(72), Some(4)),
        "the mesh bench should use the size given, even the training bench's defaults: {v}"
    );
    assert!(
        v["triangles"].as_u64().unwrap_or(0) > 0 && v["peak_rss_bytes"].as_u64().unwrap_or(0) > 0,
        "the mesh bench should mesh the wall and report the peak memory: {v}"
    );
}

/// A run whose checkpoint is of format 1 (all JSON, as written before the arrays moved to a
/// safetensors file) still resumes with `--resume`, and its next checkpoint is of format 2.
#[test]
fn a_format_1_checkpoint_still_resumes() {
    use s3tir_trainer::checkpoint::{self, CHECKPOINT_VERSION, CHECKPOINT_VERSION_JSON};
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    let run = tmp.path().join("run");
    let st = bin()
        .args(["synth", data.to_str().unwrap()])
        .args(["--views", "9", "--width", "24", "--height", "18"])
        .status()
        .unwrap();
    assert!(st.success(), "synth failed");
    let out = bin()
        .args(train_args(&data, &run))
        .args(["--iters", "30"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // Rewrite the checkpoint as format 1 and drop its arrays file.
    let header = run.join("checkpoint.json");
    let mut ck = checkpoint::load(&header).unwrap();
    ck.version = CHECKPOINT_VERSION_JSON;
    std::fs::write(&header, serde_json::to_vec(&ck).unwrap()).unwrap();
    for e in std::fs::read_dir(&run).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "safetensors") {
            std::fs::remove_file(p).unwrap();
        }
    }
    assert_eq!(checkpoint_iteration(&run), Some(30));

    let out = bin()
        .args(train_args(&data, &run))
        .args(["--resume", "--iters", "40"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "resuming a format-1 checkpoint failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = checkpoint::load(&header).unwrap();
    assert_eq!((back.iteration, back.version), (40, CHECKPOINT_VERSION));
    assert_eq!(back.primitives.bands, ck.primitives.bands);
}

/// A checkpoint whose loop state does not read is refused by `--resume` with the file named,
/// and the run is left as it was (no silent restart with a default state).
#[test]
fn a_damaged_checkpoint_state_is_refused_and_the_run_left_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let data = synth_scene(tmp.path());
    let run = tmp.path().join("run");
    finished_run(&data, &run, 30);
    let header = run.join("checkpoint.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&header).unwrap()).unwrap();
    v["state"] = serde_json::json!({"capacity": 5});
    let damaged = serde_json::to_vec(&v).unwrap();
    std::fs::write(&header, &damaged).unwrap();
    let out = bin()
        .args(train_args(&data, &run))
        .args(["--resume", "--iters", "40"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a damaged state must not resume");
    assert!(
        stderr.contains("checkpoint.json") && stderr.contains("loop state does not read"),
        "the error names the file and the problem: {stderr}"
    );
    assert_eq!(
        std::fs::read(&header).unwrap(),
        damaged,
        "the refused checkpoint is left as it was"
    );
}

/// Without the `session` feature a recorded session is refused, saying what to do instead.
#[cfg(not(feature = "session"))]
#[test]
fn a_session_input_without_the_session_feature_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let session = tmp.path().join("walk.mcap");
    std::fs::write(&session, b"").unwrap();
    let out = bin()
        .args([session.to_str().unwrap(), "--out"])
        .arg(tmp.path().join("run"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("walk.mcap")
            && err.contains("`session` feature")
            && err.contains("s3tir-calib poses"),
        "{err}"
    );
}
