//! Proves: the joint RGB + thermal scene layout (`scene --rgb-scale K`) writes every file at
//! its size, one COLMAP model with both cameras and both images of every instant (thermal pose
//! = RGB pose shifted by the rig's 3 cm), the hold-out of instants 0 and 8; its
//! super-resolved thermal truth averages down to the thermal-resolution truth, the RGB
//! camera's depth truth to the thermal camera's; low light darkens the RGB input and makes it
//! noisier against its noise-free truth; bad flags are refused.
//! Does not prove the trainer can use the layout, nor the physics of the images (tests/sensor.rs,
//! tests/scene_set.rs and src/scene/mod.rs's tests cover those for the shared renderer).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use glam::DVec3;
use s3tir_calib::model::colmap::read_model;
use s3tir_firmware_sim::scene::joint::{JointOptions, write_joint_scene_set};
use s3tir_firmware_sim::scene::response::ResponseEffects;
use s3tir_firmware_sim::scene::{SceneConfig, SceneLayout, scene_camera};

const W: u32 = 40;
const H: u32 = 30;
const K: u32 = 4;
const VIEWS: usize = 10;
const SEED: u64 = 3;

fn config(dir: &Path) -> SceneConfig {
    SceneConfig {
        out_dir: dir.to_path_buf(),
        views: VIEWS,
        width_px: W,
        height_px: H,
        seed: SEED,
    }
}

fn write(dir: &Path, low_light: bool) {
    let joint = JointOptions::from_flags(K, low_light)
        .unwrap()
        .expect("rgb_scale 4 selects the joint layout");
    let mut calls = Vec::new();
    write_joint_scene_set(
        &config(dir),
        SceneLayout::Objects,
        ResponseEffects::default(),
        &joint,
        &mut |done, total| calls.push((done, total)),
    )
    .unwrap();
    let want: Vec<(usize, usize)> = (1..=VIEWS).map(|k| (k, VIEWS)).collect();
    assert_eq!(calls, want, "one progress call per instant");
}

fn u16_png(path: &Path) -> (u32, u32, Vec<u16>) {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .into_luma16();
    (img.width(), img.height(), img.into_raw())
}

fn rgb_png(path: &Path) -> Vec<u8> {
    let img = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .into_rgb8();
    img.into_raw()
}

/// Every file of every instant exists at its size; the default layout's folders do not.
fn check_files(dir: &Path) {
    let (kw, kh) = (K * W, K * H);
    for k in 0..VIEWS {
        let n = format!("{k:04}.png");
        for (path, size, what) in [
            (format!("images/thermal/{n}"), (W, H), "thermal input"),
            (format!("images/rgb/{n}"), (kw, kh), "RGB input"),
            (
                format!("truth/apparent/thermal/{n}"),
                (W, H),
                "apparent truth",
            ),
            (
                format!("truth/apparent_sr/thermal/{n}"),
                (kw, kh),
                "super-resolved apparent truth",
            ),
            (format!("truth/depth/thermal/{n}"), (W, H), "thermal depth"),
            (format!("truth/depth/rgb/{n}"), (kw, kh), "RGB depth"),
            (format!("truth/rgb/rgb/{n}"), (kw, kh), "noise-free RGB"),
        ] {
            let p = dir.join(&path);
            let got = image::image_dimensions(&p)
                .unwrap_or_else(|e| panic!("{what} {path} should exist and be a PNG: {e}"));
            assert_eq!(got, size, "{what} {path}: expected {size:?} px");
        }
    }
    for gone in ["images/0000.png", "rgb", "depth", "temperature"] {
        assert!(
            !dir.join(gone).exists(),
            "the joint layout must not write the default layout's {gone}"
        );
    }
    for file in [
        "sparse/0/cameras.txt",
        "sparse/0/images.txt",
        "sparse/0/points3D.txt",
        "holdout.txt",
        "scene.json",
    ] {
        assert!(dir.join(file).is_file(), "{file} should exist");
    }
}

/// Cameras 1 and 2, images 2k+1 / 2k+2, the rig's pose relation, the hold-out, scene.json.
fn check_model(dir: &Path, low_light: bool) {
    let model = read_model(&dir.join("sparse/0")).unwrap();
    assert_eq!(model.cameras.len(), 2, "two cameras (thermal, RGB)");
    let cam = |id: u32| {
        model
            .cameras
            .iter()
            .find(|c| c.id == id)
            .unwrap_or_else(|| panic!("camera {id} missing"))
    };
    for (id, want) in [(1, scene_camera(W, H)), (2, scene_camera(K * W, K * H))] {
        let c = cam(id);
        assert_eq!(c.model_name, "PINHOLE", "camera {id} model");
        assert_eq!(
            (c.model.width_px, c.model.height_px),
            (want.width_px, want.height_px),
            "camera {id} size"
        );
        let (a, b) = (c.model.intrinsics, want.intrinsics);
        for (got, exp, what) in [
            (a.fx, b.fx, "fx"),
            (a.fy, b.fy, "fy"),
            (a.cx, b.cx, "cx"),
            (a.cy, b.cy, "cy"),
        ] {
            // The reader takes COLMAP's +0.5 px back off cx, cy.
            assert!(
                (got - exp).abs() < 1e-9,
                "camera {id} {what}: read {got}, expected scene_camera's {exp}"
            );
        }
    }
    assert_eq!(model.images.len(), 2 * VIEWS, "two images per instant");
    assert_eq!(
        model.points.len(),
        2000,
        "points3D as in the default layout"
    );
    let image = |id: u32| {
        model
            .images
            .iter()
            .find(|i| i.id == id)
            .unwrap_or_else(|| panic!("image {id} missing"))
    };
    let probes = [
        DVec3::new(0.0, 0.0, 0.15),
        DVec3::new(0.3, -0.2, 0.4),
        DVec3::new(-1.5, 1.0, 0.0),
    ];
    for k in 0..VIEWS {
        let (t, c) = (image(2 * k as u32 + 1), image(2 * k as u32 + 2));
        assert_eq!(
            (t.name.as_str(), t.camera_id),
            (format!("thermal/{k:04}.png").as_str(), 1),
            "image {} should be instant {k}'s thermal image on camera 1",
            t.id
        );
        assert_eq!(
            (c.name.as_str(), c.camera_id),
            (format!("rgb/{k:04}.png").as_str(), 2),
            "image {} should be instant {k}'s RGB image on camera 2",
            c.id
        );
        for p in probes {
            let want = c.cam_from_world.transform_point(p) + DVec3::new(0.03, 0.0, 0.0);
            let got = t.cam_from_world.transform_point(p);
            assert!(
                (got - want).length() < 1e-9,
                "instant {k}: world point {p} is at {got} in the thermal frame, expected its \
                 RGB-frame coordinates + (0.03, 0, 0) = {want}"
            );
        }
    }
    let holdout: Vec<String> = std::fs::read_to_string(dir.join("holdout.txt"))
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect();
    assert_eq!(
        holdout,
        [
            "thermal/0000.png",
            "rgb/0000.png",
            "thermal/0008.png",
            "rgb/0008.png"
        ],
        "holdout.txt: both images of instants 0 and 8"
    );
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("scene.json")).unwrap()).unwrap();
    let joint = &meta["joint"];
    assert_eq!(joint["rgb_scale"], K, "scene.json joint.rgb_scale");
    assert_eq!(joint["low_light"], low_light, "scene.json joint.low_light");
    let exposure = if low_light { 0.02 } else { 1.0 };
    assert_eq!(
        joint["rgb_exposure"], exposure,
        "scene.json joint.rgb_exposure"
    );
    assert_eq!(
        joint["thermal_from_rgb"]["translation_m"],
        serde_json::json!([0.03, 0.0, 0.0]),
        "scene.json joint.thermal_from_rgb"
    );
    assert_eq!(
        joint["truth"].as_object().map(|m| m.len()),
        Some(5),
        "scene.json joint.truth describes the five truth folders"
    );
}

/// Mean over instants of (mean |box-downsampled super-resolved truth − thermal truth|, K) over
/// pixels whose centre ray hits a surface, and the same for the RGB depth against the thermal
/// depth (mm) over pixels where both see a surface in the whole block.
fn truth_agreement(dir: &Path) -> (f64, f64) {
    let (w, h, k) = (W as usize, H as usize, K as usize);
    let block_mean = |img: &[u16], x: usize, y: usize| {
        let mut s = 0.0;
        let mut all = true;
        for dy in 0..k {
            for dx in 0..k {
                let v = img[(y * k + dy) * (w * k) + x * k + dx];
                all &= v > 0;
                s += f64::from(v);
            }
        }
        (s / (k * k) as f64, all)
    };
    let (mut t_sum, mut t_n, mut d_sum, mut d_n) = (0.0, 0usize, 0.0, 0usize);
    for view in 0..VIEWS {
        let n = format!("{view:04}.png");
        let (_, _, low) = u16_png(&dir.join("truth/apparent/thermal").join(&n));
        let (_, _, sr) = u16_png(&dir.join("truth/apparent_sr/thermal").join(&n));
        let (_, _, depth_t) = u16_png(&dir.join("truth/depth/thermal").join(&n));
        let (_, _, depth_c) = u16_png(&dir.join("truth/depth/rgb").join(&n));
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if depth_t[i] == 0 {
                    continue;
                }
                let (sr_mean, _) = block_mean(&sr, x, y);
                t_sum += (sr_mean - f64::from(low[i])).abs() / 100.0;
                t_n += 1;
                let (dc, all) = block_mean(&depth_c, x, y);
                if all {
                    d_sum += (dc - f64::from(depth_t[i])).abs();
                    d_n += 1;
                }
            }
        }
    }
    assert!(
        t_n > VIEWS * W as usize * H as usize / 2,
        "most thermal pixels should see a surface, {t_n}"
    );
    (t_sum / t_n as f64, d_sum / d_n.max(1) as f64)
}

/// Every thermal depth pixel reprojected into the RGB camera (the point `z · ray` of its centre
/// in the thermal frame, minus (`shift_m`, 0, 0) in the RGB frame) against the RGB depth there
/// (bilinear between 4 pixels on a surface): (median relative |Δz|, fraction within 1 %).
fn reprojected_depth(dir: &Path, shift_m: f64) -> (f64, f64) {
    let (tc, cc) = (scene_camera(W, H), scene_camera(K * W, K * H));
    let (ti, ci) = (tc.intrinsics, cc.intrinsics);
    let mut diffs = Vec::new();
    for view in 0..VIEWS {
        let n = format!("{view:04}.png");
        let (_, _, depth_t) = u16_png(&dir.join("truth/depth/thermal").join(&n));
        let (_, _, depth_c) = u16_png(&dir.join("truth/depth/rgb").join(&n));
        for (i, &z_mm) in depth_t.iter().enumerate() {
            if z_mm == 0 {
                continue;
            }
            let (x, y) = ((i % W as usize) as f64, (i / W as usize) as f64);
            let z = f64::from(z_mm) / 1000.0;
            let p = DVec3::new((x - ti.cx) / ti.fx * z, (y - ti.cy) / ti.fy * z, z)
                - DVec3::new(shift_m, 0.0, 0.0);
            let (u, v) = (ci.fx * p.x / p.z + ci.cx, ci.fy * p.y / p.z + ci.cy);
            // Bilinear between the 4 RGB pixel centres around (u, v), all on a surface.
            let (u0, v0) = (u.floor(), v.floor());
            if u0 < 0.0 || v0 < 0.0 || u0 + 1.0 >= f64::from(K * W) || v0 + 1.0 >= f64::from(K * H)
            {
                continue;
            }
            let at = |du: usize, dv: usize| {
                f64::from(depth_c[(v0 as usize + dv) * (K * W) as usize + u0 as usize + du])
            };
            let corners = [at(0, 0), at(1, 0), at(0, 1), at(1, 1)];
            if corners.contains(&0.0) {
                continue;
            }
            let (fu, fv) = (u - u0, v - v0);
            let zc = (corners[0] * (1.0 - fu) + corners[1] * fu) * (1.0 - fv)
                + (corners[2] * (1.0 - fu) + corners[3] * fu) * fv;
            diffs.push((zc - f64::from(z_mm)).abs() / f64::from(z_mm));
        }
    }
    assert!(
        !diffs.is_empty(),
        "no thermal depth pixel lands in the RGB image"
    );
    let within = diffs.iter().filter(|&&d| d < 0.01).count() as f64 / diffs.len() as f64;
    diffs.sort_by(f64::total_cmp);
    (diffs[diffs.len() / 2], within)
}

/// (mean sRGB code of the RGB inputs, RMS of input − noise-free truth over the truth's mean).
fn rgb_figures(dir: &Path) -> (f64, f64) {
    let (mut sum_in, mut sum_truth, mut sq, mut n) = (0.0, 0.0, 0.0, 0usize);
    for view in 0..VIEWS {
        let name = format!("{view:04}.png");
        let input = rgb_png(&dir.join("images/rgb").join(&name));
        let truth = rgb_png(&dir.join("truth/rgb/rgb").join(&name));
        assert_eq!(input.len(), truth.len(), "input and truth sizes");
        for (a, b) in input.iter().zip(&truth) {
            let (a, b) = (f64::from(*a), f64::from(*b));
            sum_in += a;
            sum_truth += b;
            sq += (a - b) * (a - b);
            n += 1;
        }
    }
    let n = n as f64;
    (sum_in / n, (sq / n).sqrt() / (sum_truth / n))
}

#[test]
fn joint_layout_writes_both_cameras_with_consistent_truth() {
    let normal = tempfile::tempdir().unwrap();
    let dark = tempfile::tempdir().unwrap();
    write(normal.path(), false);
    write(dark.path(), true);
    for (dir, low_light) in [(normal.path(), false), (dark.path(), true)] {
        check_files(dir);
        check_model(dir, low_light);
    }
    let (t_err_k, d_err_mm) = truth_agreement(normal.path());
    eprintln!(
        "super-resolved truth box-downsampled ×{K} vs thermal truth: mean |ΔT| {t_err_k:.4} K; \
         RGB depth box-downsampled vs thermal depth: mean |Δz| {d_err_mm:.1} mm"
    );
    // Measured: 0.0882 K (the residual: averaging temperature instead of radiance across
    // silhouettes and emissivity edges, and centikelvin rounding).
    assert!(
        t_err_k < 0.5,
        "box-downsampled apparent_sr should match apparent within 0.5 K mean, got {t_err_k:.4} K"
    );
    // Measured: 37.2 mm. The z of a point is the same in both frames (they differ by a
    // translation along x), but 3 cm at ≈ 1.7 m is a parallax of ≈ 0.65 thermal pixels
    // (f = 36.8 px at 40 px width): depth edges and slanted surfaces move by that much.
    assert!(
        d_err_mm < 80.0,
        "box-downsampled RGB depth should match the thermal depth within 80 mm mean, got \
         {d_err_mm:.1} mm"
    );
    // The parallax itself: thermal depth pixels reprojected into the RGB camera through the
    // rig land on the same depth. Measured: 97.2 % within 1 % of the depth (median 0.016 %)
    // with the rig's (0.03, 0, 0); 76.2 % without a shift, 66.1 % with the opposite shift.
    let (median, within) = reprojected_depth(normal.path(), 0.03);
    let (_, within_none) = reprojected_depth(normal.path(), 0.0);
    let (_, within_wrong) = reprojected_depth(normal.path(), -0.03);
    eprintln!(
        "thermal depth reprojected into the RGB depth: within 1 %: {within:.4} through the rig \
         (median {median:.5}), {within_none:.4} without a shift, {within_wrong:.4} with the \
         opposite shift"
    );
    assert!(
        within > 0.95 && median < 0.002,
        "thermal depth reprojected through the rig should land on the RGB depth: {within:.4} \
         within 1 % (expected > 0.95), median relative error {median:.5} (expected < 0.002)"
    );
    assert!(
        within > within_none + 0.1 && within > within_wrong + 0.1,
        "the rig's shift should explain the parallax better than none ({within_none:.4}) or the \
         opposite one ({within_wrong:.4}): {within:.4}"
    );
    let (mean_normal, noise_normal) = rgb_figures(normal.path());
    let (mean_dark, noise_dark) = rgb_figures(dark.path());
    eprintln!(
        "RGB mean sRGB code: normal {mean_normal:.1}, low light {mean_dark:.1}; relative RMS \
         noise against the noise-free truth: normal {noise_normal:.4}, low light {noise_dark:.4}"
    );
    // Measured: normal 145.9, low light 17.3 (ratio 0.12).
    assert!(
        mean_dark < 0.3 * mean_normal,
        "low light should darken the RGB input well below the normal one: mean {mean_dark:.1} \
         vs {mean_normal:.1}"
    );
    // Measured: normal 0.0127, low light 0.1159 (ratio 9.1).
    assert!(
        noise_dark > 4.0 * noise_normal,
        "low light should be noisier against its noise-free truth: relative RMS {noise_dark:.4} \
         vs normal {noise_normal:.4}"
    );
}

#[test]
fn bad_joint_flags_are_refused() {
    let too_big = JointOptions::from_flags(9, false).expect_err("--rgb-scale 9 is out of range");
    assert!(
        too_big.to_string().contains("--rgb-scale") && too_big.to_string().contains('9'),
        "the error should name --rgb-scale and the value 9: {too_big}"
    );
    let alone =
        JointOptions::from_flags(0, true).expect_err("--low-light without --rgb-scale is refused");
    assert!(
        alone.to_string().contains("--low-light") && alone.to_string().contains("--rgb-scale"),
        "the error should say --low-light needs --rgb-scale: {alone}"
    );
    assert_eq!(
        JointOptions::from_flags(0, false).unwrap(),
        None,
        "--rgb-scale 0: the default layout"
    );
    assert!(
        JointOptions::from_flags(8, true).unwrap().is_some(),
        "--rgb-scale 8 --low-light is valid"
    );
    // The writer checks options built by hand too, before it creates anything.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("never");
    let bad = JointOptions {
        rgb_scale: 9,
        low_light: false,
    };
    let err = write_joint_scene_set(
        &config(&out),
        SceneLayout::Objects,
        ResponseEffects::default(),
        &bad,
        &mut |_, _| {},
    )
    .expect_err("rgb_scale 9 is refused by the writer");
    assert!(err.to_string().contains("rgb_scale"), "writer error: {err}");
    assert!(!out.exists(), "a refused write creates nothing");
    // And the binary reports them.
    let bin = env!("CARGO_BIN_EXE_s3tir-firmware-sim");
    for (args, expect) in [
        (&["--rgb-scale", "9"][..], "--rgb-scale"),
        (&["--low-light"][..], "--low-light"),
    ] {
        let o = std::process::Command::new(bin)
            .arg("scene")
            .arg("--out")
            .arg(&out)
            .args(args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && stderr.contains(expect),
            "scene {args:?} should fail naming {expect}; status {}, stderr {stderr}",
            o.status
        );
        assert!(
            !out.exists(),
            "scene {args:?} must not create {}",
            out.display()
        );
    }
}
