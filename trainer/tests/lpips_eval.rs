//! LPIPS in a run's evaluations, through the `s3tir-train` binary: with the weights installed
//! every `metrics.csv` row and `eval.json` view carries it (and `eval --json` prints it); with
//! them missing the run warns once and writes no LPIPS column or key — never a made-up value.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_s3tir-train"))
}

/// 9 views of 48×40 (2 held out): over LPIPS's 31-px minimum.
fn scene(dir: &Path) -> PathBuf {
    let data = dir.join("scene");
    let st = bin()
        .args(["synth", data.to_str().unwrap()])
        .args(["--views", "9", "--width", "48", "--height", "40"])
        .status()
        .unwrap();
    assert!(st.success(), "synth failed");
    data
}

/// Trains 30 iterations with an evaluation every 0.2 s; returns stderr.
fn train(data: &Path, run: &Path, weights: Option<&Path>) -> String {
    let mut cmd = bin();
    cmd.args([data.to_str().unwrap(), "--out", run.to_str().unwrap()])
        .args(["--iters", "30", "--warmup", "10", "--budget", "200"])
        .args(["--eval-every-s", "0.2", "--seed", "3", "--backend", "cpu"]);
    if let Some(w) = weights {
        cmd.env("S3TIR_LPIPS_WEIGHTS", w);
    }
    let out = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "training failed: {stderr}");
    stderr
}

fn header(run: &Path) -> Vec<String> {
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    csv.lines()
        .next()
        .unwrap()
        .split(',')
        .map(str::to_owned)
        .collect()
}

#[test]
fn every_evaluation_reports_lpips_with_the_weights_installed() {
    if let Err(e) = s3tir_trainer::lpips::Lpips::load_installed() {
        s3tir_capture::skip::skip("lpips", &e.to_string());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let data = scene(tmp.path());
    let run = tmp.path().join("run");
    let stderr = train(&data, &run, None);
    assert!(
        !stderr.contains("no LPIPS"),
        "installed weights must not warn: {stderr}"
    );
    let cols = header(&run);
    let c = cols
        .iter()
        .position(|h| h == "lpips")
        .unwrap_or_else(|| panic!("metrics.csv has an lpips column: {cols:?}"));
    let rows = s3tir_trainer::report::read_rows(&run.join("metrics.csv")).unwrap();
    assert!(!rows.is_empty(), "at least the final evaluation");
    for r in &rows {
        let l = r
            .lpips
            .unwrap_or_else(|| panic!("row {r:?} lacks LPIPS (column {c})"));
        assert!(
            l > 0.0 && l < 1.5,
            "LPIPS {l} outside the metric's range for a partly trained model"
        );
    }
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval.json")).unwrap()).unwrap();
    let views = eval["views"].as_array().unwrap();
    assert_eq!(views.len(), 2, "the two held-out views");
    let per_view: Vec<f64> = views
        .iter()
        .map(|v| v["lpips"].as_f64().expect("each view's LPIPS"))
        .collect();
    let mean = eval["lpips"].as_f64().expect("the mean LPIPS");
    assert!(
        (mean - per_view.iter().sum::<f64>() / 2.0).abs() < 1e-9,
        "mean {mean} of {per_view:?}"
    );
    // `eval` scores the finished run again: the same figure (the same renders, CPU backend).
    let out = bin()
        .args(["eval", run.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let again: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let l = again["lpips"]
        .as_f64()
        .unwrap_or_else(|| panic!("eval --json prints lpips (the summary is flattened): {again}"));
    assert!(
        (l - mean).abs() < 1e-4,
        "eval's LPIPS {l} against the run's {mean}"
    );
}

#[test]
fn without_weights_a_run_warns_and_writes_no_lpips() {
    let tmp = tempfile::tempdir().unwrap();
    let data = scene(tmp.path());
    let run = tmp.path().join("run");
    let missing = tmp.path().join("not-installed.safetensors");
    let stderr = train(&data, &run, Some(&missing));
    assert_eq!(
        stderr.matches("no LPIPS in evaluations").count(),
        1,
        "one warning naming what is missing: {stderr}"
    );
    assert!(
        stderr.contains("install-lpips.py"),
        "the warning says how to install: {stderr}"
    );
    assert!(
        !header(&run).iter().any(|h| h == "lpips"),
        "no LPIPS column without the weights"
    );
    let eval = std::fs::read_to_string(run.join("eval.json")).unwrap();
    assert!(
        !eval.contains("lpips"),
        "no LPIPS key in eval.json without the weights: {eval}"
    );
}
