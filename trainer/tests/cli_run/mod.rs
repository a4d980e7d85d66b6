//! Shared helpers of the tests that drive the `s3tir-train` binary and open its pages as a user
//! does (`run_report.rs`, `viewer.rs`): a small trained run, and headless Chromium. Not a test by
//! itself.
#![allow(dead_code, clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_s3tir-train"))
}

/// A small radiometric scene (9 views of 24×18, 2 held out) trained 30 iterations on the
/// CPU reference (a few steps on tiny images: `--backend auto` would take lavapipe for no
/// gain); returns (data, run, the run's stdout).
pub fn finished_run(dir: &Path) -> (PathBuf, PathBuf, String) {
    let data = dir.join("scene");
    let st = bin()
        .args(["synth", data.to_str().unwrap(), "--views", "9"])
        .args(["--width", "24", "--height", "18"])
        .status()
        .unwrap();
    assert!(st.success(), "synth failed");
    let run = dir.join("run");
    let out = bin()
        .args([data.to_str().unwrap(), "--out", run.to_str().unwrap()])
        .args(["--iters", "30", "--warmup", "10", "--budget", "120"])
        .args(["--seed", "4", "--backend", "cpu"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "training failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (data, run, String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Debian's `chromium` (installed by scripts/install-deps.sh), or `None` after a visible skip
/// (a failure where `S3TIR_REQUIRE` names `chromium`).
pub fn chromium() -> Option<&'static str> {
    let found = ["chromium", "chromium-browser"].into_iter().find(|c| {
        Command::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if found.is_none() {
        s3tir_capture::skip::skip("chromium", "no chromium on PATH (scripts/install-deps.sh)");
    }
    found
}

/// Headless Chromium with its own profile in `profile`, a window of `size` ("W,H"), WebGL on
/// its software rasteriser (SwiftShader: no GPU here), and its console on stderr.
pub fn headless(chromium: &str, profile: &Path, size: &str) -> Command {
    let mut c = Command::new(chromium);
    c.args([
        "--headless",
        "--no-sandbox",
        "--hide-scrollbars",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--enable-logging=stderr",
        "--v=0",
    ])
    .arg(format!("--window-size={size}"))
    .arg(format!("--user-data-dir={}", profile.display()));
    c
}

/// A screenshot of `url` (`extra`: more flags, e.g. a virtual time budget) into `shot`, which
/// must succeed; returns the page's console messages and the image.
pub fn screenshot(
    chromium: &str,
    profile: &Path,
    size: &str,
    extra: &[&str],
    url: &str,
    shot: &Path,
) -> (Vec<String>, image::RgbImage) {
    let out = headless(chromium, profile, size)
        .args(extra)
        .arg(format!("--screenshot={}", shot.display()))
        .arg(url)
        .output()
        .unwrap();
    assert!(
        out.status.success() && shot.is_file(),
        "chromium failed on {url}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (
        console_messages(&out.stderr),
        image::open(shot).unwrap().to_rgb8(),
    )
}

/// The page's console messages in Chromium's stderr.
pub fn console_messages(stderr: &[u8]) -> Vec<String> {
    String::from_utf8_lossy(stderr)
        .lines()
        .filter(|l| l.contains("CONSOLE"))
        .map(str::to_owned)
        .collect()
}

/// Pixels of `img` within 6 of one of ironbow's saturated entries (its grey ends excluded).
pub fn ironbow_pixels(img: &image::RgbImage) -> usize {
    let lut = s3tir_calib::model::palette::Colormap::Ironbow.lut_u8();
    let vivid: Vec<[u8; 3]> = lut
        .iter()
        .copied()
        .filter(|c| c.iter().max().unwrap() - c.iter().min().unwrap() > 80)
        .collect();
    img.pixels()
        .filter(|p| {
            vivid.iter().any(|c| {
                c.iter()
                    .zip(p.0)
                    .all(|(&a, b)| (i32::from(a) - i32::from(b)).abs() <= 6)
            })
        })
        .count()
}

/// Pixels of `img` darker than 200 in some channel (ink on the report's white page).
pub fn inked_pixels(img: &image::RgbImage) -> usize {
    img.pixels()
        .filter(|p| p.0.iter().any(|&c| c < 200))
        .count()
}
