//! Proves `board --json` and `scene --json` print one JSON object on stdout (nothing else there)
//! that names what was written: the paths exist, the view and image counts match the files in
//! the folders, image sizes are the requested ones, and `files`/`bytes` count the output.
//! Does not re-check the contents of the files (board_set.rs, scene_set.rs, joint_scene.rs do).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn run_json(args: &[&str]) -> Value {
    let o = Command::new(env!("CARGO_BIN_EXE_s3tir-firmware-sim"))
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let stdout = String::from_utf8(o.stdout).unwrap();
    serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("stdout is not one JSON object: {e}\n{stdout}"))
}

fn path(v: &Value) -> PathBuf {
    PathBuf::from(v.as_str().unwrap_or_else(|| panic!("{v} is not a path")))
}

fn pngs(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "png")
        })
        .count()
}

/// Files and bytes under `dir`.
fn tally(dir: &Path) -> (u64, u64) {
    let mut out = (0, 0);
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        if m.is_dir() {
            let (f, b) = tally(&e.path());
            out = (out.0 + f, out.1 + b);
        } else {
            out = (out.0 + 1, out.1 + m.len());
        }
    }
    out
}

fn check_images(set: &Value, views: usize, size: (u64, u64)) {
    let dir = path(&set["dir"]);
    assert_eq!(set["images"].as_u64(), Some(views as u64), "{set}");
    assert_eq!(pngs(&dir), views, "PNGs in {}", dir.display());
    assert_eq!(
        (set["width_px"].as_u64(), set["height_px"].as_u64()),
        (Some(size.0), Some(size.1)),
        "{set}"
    );
}

fn check_written(v: &Value, out: &Path) {
    let (files, bytes) = tally(out);
    assert_eq!(v["files"].as_u64(), Some(files), "files");
    assert_eq!(v["bytes"].as_u64(), Some(bytes), "bytes");
    assert!(v["seconds"].as_f64().unwrap() >= 0.0);
}

#[test]
fn scene_json_names_what_was_written() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("scene");
    let o = out.to_str().unwrap();
    let v = run_json(&[
        "scene", "--out", o, "--views", "3", "--width", "16", "--height", "12", "--agc",
    ]);
    assert_eq!(v["command"], "scene");
    assert_eq!(path(&v["out"]), out);
    assert_eq!(
        (v["layout"].as_str(), v["views"].as_u64()),
        (Some("objects"), Some(3))
    );
    assert!(v["joint"].is_null() && v["holdout"].is_null(), "{v}");
    check_images(&v["thermal"], 3, (16, 12));
    check_images(&v["rgb"], 3, (16, 12));
    assert_eq!(v["colmap_images"].as_u64(), Some(3));
    for key in ["colmap_model", "scene_json", "truth_surface", "response"] {
        assert!(path(&v[key]).exists(), "{key}: {}", v[key]);
    }
    assert!(path(&v["colmap_model"]).join("images.txt").is_file());
    check_written(&v, &out);

    // The joint layout: two cameras, the RGB one at K× the size, the hold-out list.
    let out = tmp.path().join("joint");
    let o = out.to_str().unwrap();
    let v = run_json(&[
        "scene",
        "--out",
        o,
        "--views",
        "2",
        "--width",
        "8",
        "--height",
        "6",
        "--rgb-scale",
        "2",
        "--layout",
        "wall",
    ]);
    assert_eq!(v["layout"], "wall");
    assert_eq!(v["joint"]["rgb_scale"].as_u64(), Some(2));
    assert_eq!(v["joint"]["low_light"], false);
    check_images(&v["thermal"], 2, (8, 6));
    check_images(&v["rgb"], 2, (16, 12));
    assert_eq!(v["colmap_images"].as_u64(), Some(4));
    assert!(
        path(&v["holdout"]).is_file() && v["response"].is_null(),
        "{v}"
    );
    check_written(&v, &out);
}

#[test]
fn board_json_names_what_was_written() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("board");
    let o = out.to_str().unwrap();
    let v = run_json(&["board", "--out", o, "--views", "2", "--rgb-size", "640x360"]);
    assert_eq!(v["command"], "board");
    assert_eq!(path(&v["out"]), out);
    assert_eq!(v["views"].as_u64(), Some(2));
    assert_eq!(
        (v["profile"].as_str(), v["polarity"].as_str()),
        (Some("lepton35"), Some("cooled"))
    );
    check_images(&v["thermal"], 2, (160, 120));
    check_images(&v["rgb"], 2, (640, 360));
    for key in ["board_toml", "truth"] {
        assert!(path(&v[key]).is_file(), "{key}: {}", v[key]);
    }
    check_written(&v, &out);
}
