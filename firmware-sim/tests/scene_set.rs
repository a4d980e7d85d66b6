//! Proves: the `scene` dataset is self-consistent in COLMAP's conventions — parsing
//! `cameras.txt` (PINHOLE, COLMAP pixel centres at +0.5) and `images.txt` (cam_from_world
//! quaternion + translation) and projecting the `points3D.txt` surface points lands them on
//! pixels whose ground-truth depth equals the point's depth; the thermal images are TLinear
//! centikelvin in a plausible range; the same seed gives identical bytes.
//! Does not prove the trainer can fit the scene, nor that the RGB shading is physically based.
#![allow(clippy::unwrap_used)]

use std::path::Path;

use glam::{DQuat, DVec3};
use s3tir_firmware_sim::scene::{SceneConfig, write_scene_set};

fn read_u16_png(path: &Path) -> (u32, u32, Vec<u16>) {
    let img = image::open(path).unwrap().into_luma16();
    (img.width(), img.height(), img.into_raw())
}

fn write(dir: &Path, seed: u64) {
    let cfg = SceneConfig {
        out_dir: dir.to_path_buf(),
        views: 4,
        width_px: 96,
        height_px: 72,
        seed,
    };
    write_scene_set(&cfg, &mut |_, _| {}).unwrap();
}

#[test]
fn colmap_model_projects_surface_points_onto_matching_depth() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write(dir, 3);
    let cams = std::fs::read_to_string(dir.join("sparse/0/cameras.txt")).unwrap();
    let line = cams.lines().find(|l| !l.starts_with('#')).unwrap();
    let f: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(f[1], "PINHOLE");
    let p: Vec<f64> = f[4..8].iter().map(|s| s.parse().unwrap()).collect();
    let (fx, fy, cx, cy) = (p[0], p[1], p[2], p[3]);
    let images = std::fs::read_to_string(dir.join("sparse/0/images.txt")).unwrap();
    let poses: Vec<(DQuat, DVec3, String)> = images
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split_whitespace().collect();
            let n: Vec<f64> = v[1..8].iter().map(|s| s.parse().unwrap()).collect();
            (
                DQuat::from_xyzw(n[1], n[2], n[3], n[0]),
                DVec3::new(n[4], n[5], n[6]),
                v[9].to_owned(),
            )
        })
        .collect();
    assert_eq!(poses.len(), 4, "four images");
    let points: Vec<DVec3> = std::fs::read_to_string(dir.join("sparse/0/points3D.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .skip(1)
                .take(3)
                .map(|s| s.parse().unwrap())
                .collect();
            DVec3::new(v[0], v[1], v[2])
        })
        .collect();
    assert_eq!(points.len(), 2000);
    let (mut checked, mut agree) = (0, 0);
    for (q, t, name) in &poses {
        let (w, h, depth) = read_u16_png(&dir.join("depth").join(name));
        for pw in &points {
            let pc = *q * *pw + *t;
            if pc.z <= 0.1 {
                continue;
            }
            // COLMAP pixel coordinates: top-left pixel centre at (0.5, 0.5).
            let (u, v) = (fx * pc.x / pc.z + cx - 0.5, fy * pc.y / pc.z + cy - 0.5);
            let (ui, vi) = (u.round() as i64, v.round() as i64);
            if ui < 1 || vi < 1 || ui >= i64::from(w) - 1 || vi >= i64::from(h) - 1 {
                continue;
            }
            let at = |du: i64, dv: i64| {
                f64::from(depth[((vi + dv) as u32 * w + (ui + du) as u32) as usize])
            };
            let d_mm = at(0, 0);
            if d_mm == 0.0 || d_mm < pc.z * 1000.0 - 30.0 {
                continue; // occluded (or background)
            }
            // Skip depth discontinuities (silhouettes), where rounding to a pixel can cross them.
            let nb: Vec<f64> = (-1..=1)
                .flat_map(|dv| (-1..=1).map(move |du| (du, dv)))
                .map(|(du, dv)| at(du, dv))
                .collect();
            let (lo, hi) = nb
                .iter()
                .fold((f64::MAX, f64::MIN), |a, &d| (a.0.min(d), a.1.max(d)));
            if hi - lo > 60.0 {
                continue;
            }
            checked += 1;
            // A visible point's depth must match the pixel's depth (up to the depth change
            // across half a pixel on slanted surfaces).
            if (d_mm - pc.z * 1000.0).abs() < 30.0 {
                agree += 1;
            }
        }
    }
    assert!(checked > 500, "enough visible points checked: {checked}");
    assert!(
        agree as f64 >= 0.99 * checked as f64,
        "{agree} of {checked} points agree with the depth maps"
    );
    let (_, _, th) = read_u16_png(&dir.join("images/0000.png"));
    let (lo, hi) = (*th.iter().min().unwrap(), *th.iter().max().unwrap());
    assert!(
        lo > 28_000 && hi < 34_000 && hi - lo > 2_000,
        "TLinear ck range {lo}..{hi}"
    );
}

#[test]
fn same_seed_writes_identical_scene_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    write(&tmp.path().join("a"), 5);
    write(&tmp.path().join("b"), 5);
    for rel in [
        "images/0002.png",
        "rgb/0002.png",
        "depth/0002.png",
        "temperature/0002.png",
        "sparse/0/images.txt",
        "sparse/0/points3D.txt",
    ] {
        let a = std::fs::read(tmp.path().join("a").join(rel)).unwrap();
        let b = std::fs::read(tmp.path().join("b").join(rel)).unwrap();
        assert!(a == b, "{rel} differs between two runs with the same seed");
    }
}
