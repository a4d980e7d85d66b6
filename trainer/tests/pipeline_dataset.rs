//! Proves that COLMAP text and binary models load to the same views, that distorted cameras are
//! undistorted at load (checked against an analytic image), that thermal values are normalised
//! with the scene range kept (kelvin round trip), the every-8th hold-out, the image kinds, and
//! that bad inputs (missing image, unsupported camera model, NaN in points3D, empty dataset) give
//! errors naming the problem. Does NOT test real COLMAP output files (none ship with the repo):
//! the binary files are written here from COLMAP's documented layout.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::fs;
use std::path::Path;

use s3tir_calib::model::palette::Colormap;
use s3tir_trainer::dataset::colmap::{
    ColmapError, ColmapModel, read_binary_model, read_text_model,
};
use s3tir_trainer::dataset::images::{ColourMode, ImageKind, load_image};
use s3tir_trainer::dataset::synth::{self, SynthConfig};
use s3tir_trainer::dataset::{Dataset, DatasetError, LoadOptions};

fn small_scene(dir: &Path) {
    let cfg = SynthConfig {
        views: 9,
        width: 24,
        height: 18,
        f_px: 20.0,
        points: 50,
        seed: 1,
    };
    synth::write_scene(dir, &cfg).unwrap();
}

/// COLMAP binary writer from the documented layout (independent of the reader).
fn write_binary(dir: &Path, m: &ColmapModel) {
    let mut b = Vec::new();
    b.extend((m.cameras.len() as u64).to_le_bytes());
    for c in &m.cameras {
        let i = c.model.intrinsics;
        b.extend((c.id as i32).to_le_bytes());
        b.extend(1i32.to_le_bytes()); // PINHOLE
        b.extend(u64::from(c.model.width_px).to_le_bytes());
        b.extend(u64::from(c.model.height_px).to_le_bytes());
        for p in [i.fx, i.fy, i.cx + 0.5, i.cy + 0.5] {
            b.extend(p.to_le_bytes());
        }
    }
    fs::write(dir.join("cameras.bin"), &b).unwrap();
    let mut b = Vec::new();
    b.extend((m.images.len() as u64).to_le_bytes());
    for im in &m.images {
        b.extend((im.id as i32).to_le_bytes());
        let q = im.cam_from_world.rotation;
        let t = im.cam_from_world.translation_m;
        for v in [q.w, q.x, q.y, q.z, t.x, t.y, t.z] {
            b.extend(v.to_le_bytes());
        }
        b.extend((im.camera_id as i32).to_le_bytes());
        b.extend(im.name.as_bytes());
        b.push(0);
        b.extend(1u64.to_le_bytes()); // one 2-D point
        b.extend(1.5f64.to_le_bytes());
        b.extend(2.5f64.to_le_bytes());
        b.extend((-1i64).to_le_bytes());
    }
    fs::write(dir.join("images.bin"), &b).unwrap();
    let mut b = Vec::new();
    b.extend((m.points.len() as u64).to_le_bytes());
    for p in &m.points {
        b.extend(p.id.to_le_bytes());
        for v in p.position_m {
            b.extend(v.to_le_bytes());
        }
        b.extend(p.rgb);
        b.extend(0.5f64.to_le_bytes());
        b.extend(2u64.to_le_bytes());
        for v in [1i32, 0, 2, 0] {
            b.extend(v.to_le_bytes());
        }
    }
    fs::write(dir.join("points3D.bin"), &b).unwrap();
}

#[test]
fn text_and_binary_models_load_identically() {
    let tmp = tempfile::tempdir().unwrap();
    small_scene(tmp.path());
    let sparse = tmp.path().join("sparse/0");
    let text = read_text_model(&sparse).unwrap();
    assert_eq!(text.images.len(), 9, "images in images.txt");
    assert_eq!(text.points.len(), 50, "points in points3D.txt");
    let bin_dir = tmp.path().join("bin");
    fs::create_dir_all(&bin_dir).unwrap();
    write_binary(&bin_dir, &text);
    let bin = read_binary_model(&bin_dir).unwrap();
    assert_eq!(bin.cameras, text.cameras, "cameras differ text vs binary");
    assert_eq!(bin.points, text.points, "points differ text vs binary");
    for (a, b) in bin.images.iter().zip(&text.images) {
        assert_eq!(a.name, b.name);
        let d = a.cam_from_world.translation_m - b.cam_from_world.translation_m;
        assert!(d.length() < 1e-12, "translation differs by {d}");
        assert!(
            a.cam_from_world
                .rotation
                .abs_diff_eq(b.cam_from_world.rotation, 1e-12)
        );
    }
    // A whole dataset from the binary model: move the text files away.
    for f in ["cameras", "images", "points3D"] {
        fs::remove_file(sparse.join(format!("{f}.txt"))).unwrap();
        fs::copy(
            bin_dir.join(format!("{f}.bin")),
            sparse.join(format!("{f}.bin")),
        )
        .unwrap();
    }
    let d = Dataset::load(tmp.path(), &LoadOptions::default()).unwrap();
    assert_eq!(d.views.len(), 9);
}

#[test]
fn thermal_is_normalised_with_the_scene_range_and_every_8th_view_held_out() {
    let tmp = tempfile::tempdir().unwrap();
    small_scene(tmp.path());
    let d = Dataset::load(tmp.path(), &LoadOptions::default()).unwrap();
    assert_eq!(d.test, vec![0, 8], "every 8th view (index 0, 8) held out");
    assert_eq!(d.train.len(), 7);
    let r = d.range.unwrap();
    assert!(r.radiometric());
    assert_eq!(r.kind, ImageKind::Thermal16);
    // The scene spans 296 K (left wall) to at most 320 K (pipe ridge on the right half).
    assert!(
        (r.kelvin(0.0).unwrap() - 296.0).abs() < 0.011,
        "min {} K",
        r.kelvin(0.0).unwrap()
    );
    assert!(r.kelvin(1.0).unwrap() <= 320.0 + 0.011);
    let (lo, hi) = d
        .views
        .iter()
        .flat_map(|v| v.thermal.as_ref().unwrap().iter())
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    assert!(
        lo.abs() < 1e-6 && (hi - 1.0).abs() < 1e-6,
        "normalised range [{lo}, {hi}]"
    );
    // Round trip of one pixel: word → normalised → kelvin.
    let img = image::open(tmp.path().join("images/0003.png"))
        .unwrap()
        .to_luma16();
    let word = f64::from(img.as_raw()[5]);
    let n = d.views[3].thermal.as_ref().unwrap()[5];
    let k = r.kelvin(f64::from(n)).unwrap();
    assert!((k - word / 100.0).abs() < 1e-3, "kelvin {k} vs word {word}");
    // No hold-out.
    let d = Dataset::load(
        tmp.path(),
        &LoadOptions {
            holdout_every: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(d.test.is_empty() && d.train.len() == 9);
}

#[test]
fn opencv_camera_is_undistorted_at_load() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (w, h, f, cx, cy) = (64usize, 48usize, 50.0, 31.5, 23.5);
    let (k1, k2, p1, p2) = (-0.25, 0.05, 0.001, -0.002);
    let dist = s3tir_calib::BrownConrady {
        k1,
        k2,
        p1,
        p2,
        k3: 0.0,
    };
    // Value at undistorted normalised coordinates (x, y): a linear ramp (bilinear-exact).
    let field = |x: f64, y: f64| 20000.0 + 8000.0 * x + 5000.0 * y;
    let mut words = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let pd = glam::DVec2::new((u as f64 - cx) / f, (v as f64 - cy) / f);
            let p = dist.undistort(pd).unwrap();
            words.push(field(p.x, p.y).round() as u16);
        }
    }
    fs::create_dir_all(root.join("images")).unwrap();
    fs::create_dir_all(root.join("sparse/0")).unwrap();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w as u32, h as u32, words)
        .unwrap()
        .save(root.join("images/a.png"))
        .unwrap();
    fs::write(
        root.join("sparse/0/cameras.txt"),
        format!(
            "1 OPENCV {w} {h} {f} {f} {} {} {k1} {k2} {p1} {p2}\n",
            cx + 0.5,
            cy + 0.5
        ),
    )
    .unwrap();
    fs::write(
        root.join("sparse/0/images.txt"),
        "1 1 0 0 0 0 0 0 1 a.png\n\n",
    )
    .unwrap();
    let d = Dataset::load(
        root,
        &LoadOptions {
            holdout_every: 0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(d.undistorted_models, vec!["OPENCV".to_owned()]);
    let r = d.range.unwrap();
    let img = d.views[0].thermal.as_ref().unwrap();
    let cam = d.views[0].camera;
    assert!(
        (cam.cx_px - cx).abs() < 1e-12,
        "cx {} (½-px convention)",
        cam.cx_px
    );
    let mut worst: f64 = 0.0;
    for v in 8..h - 8 {
        for u in 8..w - 8 {
            let want = field((u as f64 - cx) / f, (v as f64 - cy) / f);
            let got = r.raw(f64::from(img[v * w + u]));
            worst = worst.max((got - want).abs());
        }
    }
    // Rounding to u16 (0.5) + bilinear error of a curved map (< 1.5 words).
    assert!(
        worst < 2.0,
        "undistorted image differs from the pinhole truth by {worst} words"
    );
}

#[test]
fn image_kinds_are_recognised() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("g.png");
    image::GrayImage::from_raw(2, 1, vec![10, 200])
        .unwrap()
        .save(&p)
        .unwrap();
    let g = load_image(&p, ColourMode::Rgb).unwrap();
    assert_eq!(
        (g.kind, g.values.clone()),
        (ImageKind::Grey8, vec![10.0, 200.0])
    );
    let p = tmp.path().join("c.png");
    let lut = Colormap::Ironbow.lut_u8();
    image::RgbImage::from_raw(2, 1, [lut[40], lut[220]].concat())
        .unwrap()
        .save(&p)
        .unwrap();
    let c = load_image(&p, ColourMode::Pseudo).unwrap();
    assert_eq!(
        (c.kind, c.values.clone()),
        (ImageKind::PseudoColour8, vec![40.0, 220.0])
    );
    let c = load_image(&p, ColourMode::Rgb).unwrap();
    assert_eq!(c.kind, ImageKind::Rgb8);
    assert_eq!(c.values.len(), 6, "three planes");
    assert_eq!(
        c.values[2],
        f64::from(lut[40][1]),
        "G plane of pixel 0 (planar layout)"
    );
}

fn err_of(root: &Path) -> String {
    match Dataset::load(root, &LoadOptions::default()) {
        Ok(_) => panic!("loading {} should fail", root.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_inputs_give_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("s");
    small_scene(&root);
    let sparse = root.join("sparse/0");

    fs::rename(root.join("images/0004.png"), root.join("x.png")).unwrap();
    let e = err_of(&root);
    assert!(
        e.contains("image not found") && e.contains("0004.png"),
        "missing image: {e}"
    );
    fs::rename(root.join("x.png"), root.join("images/0004.png")).unwrap();

    let cams = fs::read_to_string(sparse.join("cameras.txt")).unwrap();
    fs::write(
        sparse.join("cameras.txt"),
        "1 OPENCV_FISHEYE 24 18 20 20 12 9 0 0 0 0\n",
    )
    .unwrap();
    let e = err_of(&root);
    assert!(
        e.contains("OPENCV_FISHEYE") && e.contains("not supported"),
        "unsupported model: {e}"
    );
    fs::write(sparse.join("cameras.txt"), cams).unwrap();

    let pts = fs::read_to_string(sparse.join("points3D.txt")).unwrap();
    fs::write(
        sparse.join("points3D.txt"),
        format!("{pts}77 0.1 nan 2.0 1 2 3 0.0\n"),
    )
    .unwrap();
    let e = err_of(&root);
    assert!(
        e.contains("point 77") && e.contains("NaN"),
        "NaN point: {e}"
    );
    assert!(matches!(
        Dataset::load(&root, &LoadOptions::default()),
        Err(DatasetError::Colmap(ColmapError::NonFinitePoint {
            point_id: 77,
            ..
        }))
    ));
    fs::write(sparse.join("points3D.txt"), pts).unwrap();

    fs::write(sparse.join("images.txt"), "# no images\n").unwrap();
    let e = err_of(&root);
    assert!(
        e.contains("empty") && e.contains("no images"),
        "empty dataset: {e}"
    );

    let e = err_of(&tmp.path().join("nowhere"));
    assert!(
        e.contains("dataset folder not found"),
        "missing folder: {e}"
    );
    fs::create_dir_all(tmp.path().join("bare")).unwrap();
    let e = err_of(&tmp.path().join("bare"));
    assert!(e.contains("COLMAP sparse model"), "no model: {e}");
}
