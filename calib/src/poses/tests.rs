//! The stage end to end on a small session written by capture's own writer (thermal Y16 + RGB
//! YUYV on one clock) with the RGB camera's true poses given as the user's COLMAP model, in a
//! world unknown to the stage (scaled, turned and shifted from the metric truth; its scale
//! given as `metres_per_unit`): `--with-rgb` adds exactly the posed RGB keyframes, through
//! their own camera, in the thermal views' world, and holds them out around the held-out
//! thermal views. No COLMAP runs (`tests/tests/session_to_dataset.rs` covers the thermal side
//! and the trainer's loading against the same kind of session).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use s3tir_capture::frame::{
    CapturedFrame, FfcState, FrameTime, RgbFrame, RgbPayload, ThermalFrame, ThermalUnits,
};
use s3tir_capture::session::{SessionInfo, SessionRecord, SessionWriter};

use super::frames::Stream;
use super::{PosesError, PosesOptions, session_to_dataset};
use crate::model::calfile::CalibrationFile;
use crate::model::colmap::{ColmapCamera, ColmapImage, ColmapModel, read_model, write_text_model};
use crate::{BrownConrady, CameraModel, Intrinsics, Rigid3};

const T_W: u32 = 80;
const T_H: u32 = 60;
const R_W: u32 = 64;
const R_H: u32 = 48;
const T0_NS: u64 = 5_000_000_000;
const DURATION_S: f64 = 6.0;
const THERMAL_HZ: f64 = 8.7;
const RGB_HZ: f64 = 10.0;
/// The orbit's turn rate, rad/s, and its radius, metres.
const OMEGA: f64 = 0.3;
const RADIUS_M: f64 = 2.0;
/// World units per metre of the user's model (COLMAP's world has its own unit).
const UNITS_PER_M: f64 = 0.37;
/// Every this-many-th RGB frame is missing from the user's model (never posed).
const UNPOSED_EVERY: usize = 7;

fn rig() -> CalibrationFile {
    let rot = DQuat::from_euler(glam::EulerRot::XYZ, 0.014, -0.009, 0.005);
    let centre = DVec3::new(0.065, 0.002, -0.003);
    CalibrationFile {
        thermal: Some(CameraModel {
            width_px: T_W,
            height_px: T_H,
            intrinsics: Intrinsics {
                fx: 74.0,
                fy: 74.0,
                cx: 39.5,
                cy: 29.5,
            },
            distortion: BrownConrady {
                k1: -0.28,
                ..BrownConrady::default()
            },
        }),
        rgb: Some(CameraModel {
            width_px: R_W,
            height_px: R_H,
            intrinsics: Intrinsics {
                fx: 45.0,
                fy: 46.0,
                cx: 31.5,
                cy: 23.5,
            },
            // k3 ≠ 0: FULL_OPENCV, another COLMAP model than the thermal camera's OPENCV.
            distortion: BrownConrady {
                k1: -0.12,
                k2: 0.03,
                p1: 0.001,
                p2: -0.002,
                k3: 0.01,
            },
        }),
        rgb_from_thermal: Some(Rigid3::new(rot, -(rot * centre))),
    }
}

fn rgb_from_thermal() -> Rigid3 {
    rig().rgb_from_thermal.expect("the rig has an extrinsic")
}

/// The rig's true pose in metres: an orbit around the origin, looking at it.
fn world_from_thermal_m(t_ns: u64) -> Rigid3 {
    let a = OMEGA * (t_ns - T0_NS) as f64 * 1e-9;
    let eye = DVec3::new(RADIUS_M * a.cos(), RADIUS_M * a.sin(), 0.6);
    let z = (-eye).normalize();
    let x = z.cross(DVec3::Z).normalize();
    let y = z.cross(x);
    Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(x, y, z)), eye)
}

/// The user's world: metres scaled by [`UNITS_PER_M`], turned and shifted.
fn to_user_world(world_from_cam_m: Rigid3) -> Rigid3 {
    let turn = DQuat::from_euler(glam::EulerRot::ZYX, 0.7, -0.2, 0.1);
    let shift = DVec3::new(1.5, -0.4, 3.0);
    Rigid3::new(
        turn * world_from_cam_m.rotation,
        turn * (UNITS_PER_M * world_from_cam_m.translation_m) + shift,
    )
}

fn world_from_thermal(t_ns: u64) -> Rigid3 {
    to_user_world(world_from_thermal_m(t_ns))
}

fn world_from_rgb(t_ns: u64) -> Rigid3 {
    to_user_world(world_from_thermal_m(t_ns).compose(&rgb_from_thermal().inverse()))
}

/// The extrinsic with its translation in the user's world units.
fn rgb_from_thermal_units() -> Rigid3 {
    let e = rgb_from_thermal();
    Rigid3::new(e.rotation, e.translation_m * UNITS_PER_M)
}

fn thermal_words(seq: u32) -> Vec<u16> {
    let mut state = u64::from(seq).wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..T_W * T_H)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let (x, y) = (i % T_W, i / T_W);
            (29_000 + 4 * x + 3 * y + ((x / 6 + y / 6) % 2) * 400 + (state % 50) as u32) as u16
        })
        .collect()
}

fn rgb_frame(seq: u32, t_ns: u64) -> RgbFrame {
    let yuyv = (0..R_W * R_H / 2)
        .flat_map(|i| {
            let (x, y) = ((2 * i) % R_W, (2 * i) / R_W);
            let luma = if ((x + seq) / 4 + y / 4).is_multiple_of(2) {
                40
            } else {
                200
            };
            // Some chroma, so that the decoded colour is not grey.
            [luma, 100 + (y % 50) as u8, luma, 150]
        })
        .collect();
    RgbFrame {
        width: R_W,
        height: R_H,
        payload: RgbPayload::Yuyv(yuyv),
        time: FrameTime {
            sequence: seq,
            monotonic_ns: t_ns,
            wall_unix_ns: 1_700_000_000_000_000_000 + t_ns,
        },
    }
}

struct Recorded {
    session: PathBuf,
    /// `(sequence, monotonic_ns)` per stream.
    thermal: Vec<(u32, u64)>,
    rgb: Vec<(u32, u64)>,
}

fn record(dir: &Path, with_rgb: bool) -> Recorded {
    let session = dir.join(if with_rgb {
        "walk.mcap"
    } else {
        "thermal.mcap"
    });
    let mut w = SessionWriter::create(&session, &SessionInfo::default()).expect("create session");
    let mut frames: Vec<(u64, bool, u32)> = Vec::new();
    for s in 0..(DURATION_S * THERMAL_HZ) as u32 {
        let t = T0_NS + 3_000_000 + (f64::from(s) * 1e9 / THERMAL_HZ) as u64;
        frames.push((t, true, s));
    }
    if with_rgb {
        for s in 0..(DURATION_S * RGB_HZ) as u32 {
            frames.push((T0_NS + (f64::from(s) * 1e9 / RGB_HZ) as u64, false, s));
        }
    }
    frames.sort();
    let (mut thermal, mut rgb) = (Vec::new(), Vec::new());
    for (t, is_thermal, seq) in frames {
        let frame = if is_thermal {
            thermal.push((seq, t));
            CapturedFrame::Thermal(ThermalFrame {
                width: T_W,
                height: T_H,
                pixels: thermal_words(seq),
                units: ThermalUnits::CentiKelvin,
                time: FrameTime {
                    sequence: seq,
                    monotonic_ns: t,
                    wall_unix_ns: 1_700_000_000_000_000_000 + t,
                },
                ffc: FfcState::Idle,
                telemetry_words: Vec::new(),
                telemetry: None,
            })
        } else {
            rgb.push((seq, t));
            CapturedFrame::Rgb(rgb_frame(seq, t))
        };
        w.write(&SessionRecord::Frame {
            frame,
            ffc_hint: FfcState::Idle,
        })
        .expect("write frame");
    }
    w.finish().expect("finish session");
    Recorded {
        session,
        thermal,
        rgb,
    }
}

/// The RGB camera's true poses in the user's world, every [`UNPOSED_EVERY`]-th frame left out.
fn user_model(dir: &Path, rec: &Recorded) -> PathBuf {
    let model = ColmapModel {
        cameras: vec![ColmapCamera {
            id: 1,
            model_name: "FULL_OPENCV".into(),
            model: rig().rgb.expect("rgb camera"),
        }],
        images: rec
            .rgb
            .iter()
            .enumerate()
            .filter(|(i, _)| i % UNPOSED_EVERY != 3)
            .map(|(i, &(seq, t))| ColmapImage {
                id: i as u32 + 1,
                camera_id: 1,
                name: Stream::Rgb.file_name(seq),
                cam_from_world: world_from_rgb(t).inverse(),
            })
            .collect(),
        points: Vec::new(),
    };
    let out = dir.join("user-model");
    write_text_model(&out, &model).expect("write the user's model");
    out
}

fn opts(model: &Path) -> PosesOptions {
    PosesOptions {
        user_model: Some(model.to_path_buf()),
        metres_per_unit: Some(1.0 / UNITS_PER_M),
        holdout_every: 4,
        with_rgb: true,
        ..PosesOptions::default()
    }
}

/// `(angle between the rotations in degrees, distance between the centres)`.
fn apart(a: &Rigid3, b: &Rigid3) -> (f64, f64) {
    (
        a.rotation.angle_between(b.rotation).to_degrees(),
        (a.translation_m - b.translation_m).length(),
    )
}

#[test]
fn with_rgb_the_posed_rgb_keyframes_join_in_the_thermal_views_world() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), true);
    let model = user_model(tmp.path(), &rec);
    let out = tmp.path().join("dataset");
    let report = session_to_dataset(&rec.session, Some(&rig()), &out, &opts(&model))
        .unwrap_or_else(|e| {
            panic!(
                "posing the session with --with-rgb: {}",
                s3tir_capture::Chain(&e)
            )
        });
    let posed_rgb: BTreeMap<u32, u64> = rec
        .rgb
        .iter()
        .enumerate()
        .filter(|(i, _)| i % UNPOSED_EVERY != 3)
        .map(|(_, &p)| p)
        .collect();
    assert_eq!(report.registered, posed_rgb.len());
    assert_eq!(
        report.rgb_views,
        posed_rgb.len(),
        "every posed RGB keyframe is written, and only those"
    );

    // Two cameras, through the one codec: the calibrated models as they are.
    let ds = read_model(&out.join("sparse/0")).expect("the dataset's model reads back");
    assert_eq!(ds.cameras.len(), 2, "{:?}", ds.cameras);
    let cam = |id: u32| ds.cameras.iter().find(|c| c.id == id).expect("camera");
    assert_eq!(cam(1).model_name, "OPENCV");
    assert_eq!(cam(2).model_name, "FULL_OPENCV");
    let want = rig().rgb.expect("rgb");
    let got = cam(2).model;
    assert_eq!((got.width_px, got.height_px), (R_W, R_H));
    assert_eq!(got.distortion, want.distortion);
    assert!(
        (got.intrinsics.cx - want.intrinsics.cx).abs() < 1e-12
            && (got.intrinsics.fy - want.intrinsics.fy).abs() < 1e-12,
        "{got:?}"
    );

    // Each image through its own camera; the RGB views are exactly the posed keyframes.
    let thermal_t: BTreeMap<u32, u64> = rec.thermal.iter().copied().collect();
    let mut thermal: Vec<(u64, Rigid3)> = Vec::new();
    let mut rgb: Vec<(u64, Rigid3)> = Vec::new();
    let mut rgb_names = BTreeSet::new();
    for im in &ds.images {
        let (stream, seq) = Stream::parse_file_name(&im.name).expect("the stage's name");
        let world_from_cam = im.cam_from_world.inverse();
        match stream {
            Stream::Thermal => {
                assert_eq!(im.camera_id, 1, "{}", im.name);
                thermal.push((thermal_t[&seq], world_from_cam));
            }
            Stream::Rgb => {
                assert_eq!(im.camera_id, 2, "{}", im.name);
                assert!(im.name.ends_with(".png"), "{}", im.name);
                rgb.push((posed_rgb[&seq], world_from_cam));
                rgb_names.insert(seq);
            }
        }
    }
    assert_eq!(rgb_names, posed_rgb.keys().copied().collect());
    thermal.sort_by_key(|v| v.0);
    rgb.sort_by_key(|v| v.0);
    assert!(thermal.len() >= 8, "thermal views: {}", thermal.len());

    // The RGB images: the recorded frames decoded, at the RGB camera's size, as RGB.
    for &seq in &rgb_names {
        let p = out.join("images").join(Stream::Rgb.dataset_file_name(seq));
        let img = image::open(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(
            matches!(img, image::DynamicImage::ImageRgb8(_)),
            "{}: 8-bit RGB",
            p.display()
        );
        assert_eq!((img.width(), img.height()), (R_W, R_H), "{}", p.display());
    }
    let seq = *rgb_names.first().expect("some RGB view");
    let t = posed_rgb[&seq];
    let recorded = rgb_frame(seq, t).to_rgb8("test").expect("decode");
    let written = image::open(out.join("images").join(Stream::Rgb.dataset_file_name(seq)))
        .expect("image")
        .into_rgb8()
        .into_raw();
    assert_eq!(written, recorded, "the recorded frame, not undistorted");

    // One world: each RGB view is the user's pose (the world untouched), each thermal view the
    // truth in that world (the lever arm scaled by metres_per_unit).
    let (mut worst_rgb, mut worst_thermal) = ((0.0f64, 0.0f64), (0.0f64, 0.0f64));
    for &(t, p) in &rgb {
        let (d, m) = apart(&p, &world_from_rgb(t));
        worst_rgb = (worst_rgb.0.max(d), worst_rgb.1.max(m));
    }
    for &(t, p) in &thermal {
        let (d, m) = apart(&p, &world_from_thermal(t));
        worst_thermal = (worst_thermal.0.max(d), worst_thermal.1.max(m));
    }
    // (1e-4°: the quaternion's text digits and acos near 1, not a difference of pose.)
    assert!(
        worst_rgb.0 < 1e-4 && worst_rgb.1 < 1e-9,
        "RGB views are the posed keyframes: {worst_rgb:?}"
    );
    assert!(
        worst_thermal.0 < 0.05 && worst_thermal.1 < 0.002 * UNITS_PER_M,
        "thermal views are the truth up to interpolation: {worst_thermal:?}"
    );

    // The rig is rigid: thermal ≈ RGB ∘ extrinsic. Exactly so through the RGB views around
    // each thermal view (interpolated to its time); within the motion between the two capture
    // times through the nearest one.
    let e = rgb_from_thermal_units();
    let track = super::interp::Track::new(&rgb, f64::INFINITY);
    let (mut worst_exact, mut worst_nearest, mut worst_dt_s) = ((0.0f64, 0.0f64), 0.0f64, 0.0f64);
    for &(t, world_from_thermal) in &thermal {
        let bracketed = track.world_from_cam(t).expect("between RGB views");
        let (d, m) = apart(&bracketed.compose(&e), &world_from_thermal);
        worst_exact = (worst_exact.0.max(d), worst_exact.1.max(m));
        let &(tn, nearest) = rgb
            .iter()
            .min_by_key(|r| r.0.abs_diff(t))
            .expect("RGB views");
        let dt_s = tn.abs_diff(t) as f64 * 1e-9;
        let (d, m) = apart(&nearest.compose(&e), &world_from_thermal);
        // The rig turns OMEGA and moves OMEGA × RADIUS (+ the lever arm's swing) per second.
        let (max_deg, max_m) = (
            (OMEGA * dt_s).to_degrees() + 1e-6,
            (OMEGA * (RADIUS_M + 0.1)) * dt_s * UNITS_PER_M + 1e-6,
        );
        assert!(
            d <= max_deg && m <= max_m,
            "thermal view at {t} ns vs the RGB view {dt_s:.3} s away: {d:.4}° (≤ {max_deg:.4}), {m:.5} (≤ {max_m:.5})"
        );
        worst_nearest = worst_nearest.max(d);
        worst_dt_s = worst_dt_s.max(dt_s);
    }
    assert!(
        worst_exact.0 < 1e-4 && worst_exact.1 < 1e-9,
        "interpolated RGB ∘ extrinsic = thermal: {worst_exact:?}"
    );
    eprintln!(
        "{} thermal, {} RGB views; RGB ∘ extrinsic vs thermal: bracketed {:.1e}° {:.1e} units, nearest ≤ {worst_nearest:.3}° ({worst_dt_s:.3} s apart); thermal vs truth {:.4}°, {:.2e} units",
        thermal.len(),
        rgb.len(),
        worst_exact.0,
        worst_exact.1,
        worst_thermal.0,
        worst_thermal.1
    );

    // holdout.txt: the held-out thermal views and the RGB views of their instants.
    let held: Vec<String> = std::fs::read_to_string(out.join("holdout.txt"))
        .expect("holdout.txt")
        .lines()
        .map(str::to_owned)
        .collect();
    let held_t = |stream: Stream| -> Vec<u64> {
        held.iter()
            .filter_map(|n| Stream::parse_file_name(n))
            .filter(|(s, _)| *s == stream)
            .map(|(_, seq)| match stream {
                Stream::Thermal => thermal_t[&seq],
                Stream::Rgb => posed_rgb[&seq],
            })
            .collect()
    };
    let (held_thermal, held_rgb) = (held_t(Stream::Thermal), held_t(Stream::Rgb));
    assert_eq!(held_thermal.len(), report.held_out);
    assert_eq!(held_rgb.len(), report.rgb_held_out);
    assert!(!held_thermal.is_empty() && !held_rgb.is_empty(), "{held:?}");
    let window_ns = (PosesOptions::default().max_sync_s * 1e9) as u64;
    for &t in &held_thermal {
        let near: Vec<u64> = rgb
            .iter()
            .map(|r| r.0)
            .filter(|&r| r.abs_diff(t) <= window_ns)
            .collect();
        assert!(
            !near.is_empty() && near.iter().all(|r| held_rgb.contains(r)),
            "every RGB view within {window_ns} ns of the held-out thermal view at {t} is held out"
        );
    }
    for &r in &held_rgb {
        assert!(
            held_thermal.iter().any(|&t| r.abs_diff(t) <= window_ns),
            "the held-out RGB view at {r} is near a held-out thermal view"
        );
    }
    assert!(
        held_rgb.len() < rgb.len() / 2,
        "most RGB views train: {held_rgb:?}"
    );
    // poses.json carries the count.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("poses.json")).expect("json"))
            .expect("poses.json is JSON");
    assert_eq!(json["rgb_views"], posed_rgb.len());
    assert!(super::summary(&report).contains("posed RGB keyframes"));

    // Without --with-rgb: the thermal dataset as before.
    let plain = tmp.path().join("thermal-only-dataset");
    let o = PosesOptions {
        with_rgb: false,
        ..opts(&model)
    };
    let r = session_to_dataset(&rec.session, Some(&rig()), &plain, &o).expect("posing");
    let m = read_model(&plain.join("sparse/0")).expect("model");
    assert_eq!((m.cameras.len(), r.rgb_views), (1, 0));
    assert!(m.images.iter().all(|im| im.name.starts_with("thermal_")));
    assert_eq!(m.images.len(), thermal.len());
}

#[test]
fn with_rgb_on_a_thermal_only_session_is_an_error_naming_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), false);
    let out = tmp.path().join("dataset");
    let o = PosesOptions {
        colmap: PathBuf::from("/nonexistent/colmap"),
        ..opts(Path::new("/nonexistent/model"))
    };
    let e = session_to_dataset(&rec.session, Some(&rig()), &out, &o).expect_err("no RGB");
    assert!(
        matches!(&e, PosesError::Nothing { path, .. } if *path == rec.session)
            && e.to_string().contains("--with-rgb")
            && e.to_string().contains("thermal.mcap"),
        "{e}"
    );
    assert!(
        !out.exists() && !tmp.path().join("dataset.partial").exists(),
        "nothing created"
    );
}
