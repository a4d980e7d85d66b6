//! Proves the poses stage's hand-offs and decisions on a session with known truth, without
//! COLMAP: a session written by capture's own writer (thermal Y16 + RGB YUYV on one clock, an
//! FFC freeze, a blurred frame), the RGB camera's true poses given as the user's COLMAP model
//! (`--poses`), then: the thermal poses in the dataset equal the truth (interpolation and the
//! calibrated extrinsic composed right, at a known scale), the images are the recorded words
//! byte for byte, the trainer's loader reads the dataset and tests on exactly `holdout.txt`,
//! and every bad input (no calibration, another rig's calibration, no COLMAP, too few
//! registered frames, a truncated session, an existing dataset) gives its clear error or note
//! without losing anything. Does NOT test COLMAP's own accuracy (the simulated walk tests do).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use s3tir_calib::model::calfile::CalibrationFile;
use s3tir_calib::model::colmap::{
    ColmapCamera, ColmapImage, ColmapModel, read_model, write_text_model,
};
use s3tir_calib::poses::{self, PosesError, PosesOptions};
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics, Rigid3};
use s3tir_capture::frame::{
    CapturedFrame, FfcState, FrameTime, RgbFrame, RgbPayload, ThermalFrame, ThermalUnits,
};
use s3tir_capture::session::{SessionInfo, SessionRecord, SessionWriter};
use s3tir_tests::thermal_sequence;
use s3tir_trainer::dataset::{Dataset, LoadOptions};

const T_W: u32 = 160;
const T_H: u32 = 120;
const R_W: u32 = 64;
const R_H: u32 = 48;
const T0_NS: u64 = 5_000_000_000;
const DURATION_S: f64 = 6.0;
const THERMAL_HZ: f64 = 8.7;
const RGB_HZ: f64 = 10.0;
/// The thermal frame that is FFC-frozen and the one that is blurred (flat).
const FROZEN_SEQ: u32 = 20;
const BLURRED_SEQ: u32 = 33;

fn rig() -> CalibrationFile {
    let rot = DQuat::from_euler(glam::EulerRot::XYZ, 0.014, -0.009, 0.005);
    let centre = DVec3::new(0.065, 0.002, -0.003);
    CalibrationFile {
        thermal: Some(CameraModel {
            width_px: T_W,
            height_px: T_H,
            intrinsics: Intrinsics {
                fx: 147.0,
                fy: 147.0,
                cx: 79.5,
                cy: 59.5,
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
                fy: 45.0,
                cx: 31.5,
                cy: 23.5,
            },
            distortion: BrownConrady::default(),
        }),
        rgb_from_thermal: Some(Rigid3::new(rot, -(rot * centre))),
    }
}

/// The rig's true pose: an orbit of radius 2 m around the origin, 0.3 rad/s, looking at it.
fn world_from_thermal(t_ns: u64) -> Rigid3 {
    let t = (t_ns - T0_NS) as f64 * 1e-9;
    let a = 0.3 * t;
    let eye = DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.6);
    let z = (-eye).normalize();
    let x = z.cross(DVec3::Z).normalize();
    let y = z.cross(x);
    Rigid3::new(DQuat::from_mat3(&DMat3::from_cols(x, y, z)), eye)
}

fn world_from_rgb(t_ns: u64) -> Rigid3 {
    let rgb_from_thermal = rig().rgb_from_thermal.expect("rig has an extrinsic");
    world_from_thermal(t_ns).compose(&rgb_from_thermal.inverse())
}

/// A textured frame, different per sequence; `flat` is a smooth ramp (no detail: blurred).
fn thermal_words(seq: u32, flat: bool) -> Vec<u16> {
    let mut state = u64::from(seq).wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..T_W * T_H)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let (x, y) = (i % T_W, i / T_W);
            let ramp = 29_000 + 4 * x + 3 * y;
            if flat {
                ramp as u16
            } else {
                (ramp + ((x / 6 + y / 6) % 2) * 400 + (state % 50) as u32) as u16
            }
        })
        .collect()
}

fn rgb_yuyv(seq: u32) -> Vec<u8> {
    (0..R_W * R_H / 2)
        .flat_map(|i| {
            let (x, y) = ((2 * i) % R_W, (2 * i) / R_W);
            let luma = if ((x + seq) / 4 + y / 4).is_multiple_of(2) {
                40
            } else {
                200
            };
            // A tint (U, V off 128): without any colour the trainer reads an 8-bit RGB image
            // as a grey thermal one (with_rgb_the_trainer_loads_both_image_sets).
            [luma, 110, luma, 150]
        })
        .collect()
}

struct Recorded {
    session: PathBuf,
    thermal: Vec<(u32, u64)>,
    rgb: Vec<(u32, u64)>,
}

fn record(dir: &Path, attach: Option<&str>) -> Recorded {
    let session = dir.join("walk.mcap");
    let mut w = SessionWriter::create(&session, &SessionInfo::default()).expect("create session");
    if let Some(text) = attach {
        w.attach("calibration.yaml", "application/yaml", text.as_bytes())
            .expect("attach");
    }
    let mut frames: Vec<(u64, bool, u32)> = Vec::new();
    let n_t = (DURATION_S * THERMAL_HZ) as u32;
    let n_r = (DURATION_S * RGB_HZ) as u32;
    for s in 0..n_t {
        frames.push((
            T0_NS + 3_000_000 + (f64::from(s) * 1e9 / THERMAL_HZ) as u64,
            true,
            s,
        ));
    }
    for s in 0..n_r {
        frames.push((T0_NS + (f64::from(s) * 1e9 / RGB_HZ) as u64, false, s));
    }
    frames.sort();
    let (mut thermal, mut rgb) = (Vec::new(), Vec::new());
    for (k, (t, is_thermal, seq)) in frames.into_iter().enumerate() {
        if k % 10 == 9 {
            // End a chunk every 10 frames (a live recorder ends one per second), so that a cut
            // file keeps complete chunks.
            w.flush().expect("flush");
        }
        let time = FrameTime {
            sequence: seq,
            monotonic_ns: t,
            wall_unix_ns: 1_700_000_000_000_000_000 + t,
        };
        let frame = if is_thermal {
            thermal.push((seq, t));
            let ffc = if seq == FROZEN_SEQ {
                FfcState::InProgress
            } else {
                FfcState::Idle
            };
            CapturedFrame::Thermal(ThermalFrame {
                width: T_W,
                height: T_H,
                pixels: thermal_words(seq, seq == BLURRED_SEQ),
                units: ThermalUnits::CentiKelvin,
                time,
                ffc,
                telemetry_words: Vec::new(),
                telemetry: None,
            })
        } else {
            rgb.push((seq, t));
            CapturedFrame::Rgb(RgbFrame {
                width: R_W,
                height: R_H,
                payload: RgbPayload::Yuyv(rgb_yuyv(seq)),
                time,
            })
        };
        let ffc_hint = match &frame {
            CapturedFrame::Thermal(f) => f.ffc,
            CapturedFrame::Rgb(_) => FfcState::Idle,
        };
        w.write(&SessionRecord::Frame { frame, ffc_hint })
            .expect("write frame");
    }
    w.finish().expect("finish session");
    Recorded {
        session,
        thermal,
        rgb,
    }
}

/// The RGB camera's true poses as a COLMAP model of the stage's own image names.
fn truth_model(dir: &Path, rec: &Recorded, every: usize) -> PathBuf {
    let rgb = rig().rgb.expect("rgb camera");
    let model = ColmapModel {
        cameras: vec![ColmapCamera {
            id: 1,
            model_name: "PINHOLE".into(),
            model: rgb,
        }],
        images: rec
            .rgb
            .iter()
            .step_by(every)
            .enumerate()
            .map(|(i, &(seq, t))| ColmapImage {
                id: i as u32 + 1,
                camera_id: 1,
                name: format!("rgb_{seq:08}.jpg"),
                cam_from_world: world_from_rgb(t).inverse(),
            })
            .collect(),
        points: Vec::new(),
    };
    let out = dir.join("user-model");
    write_text_model(&out, &model).expect("write the user's model");
    out
}

fn opts(user_model: &Path) -> PosesOptions {
    PosesOptions {
        user_model: Some(user_model.to_path_buf()),
        metres_per_unit: Some(1.0),
        holdout_every: 4,
        ..PosesOptions::default()
    }
}

#[test]
fn thermal_poses_from_user_rgb_model_match_truth_and_the_trainer_reads_them() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), None);
    let model = truth_model(tmp.path(), &rec, 1);
    let out = tmp.path().join("dataset");
    let report = poses::session_to_dataset(&rec.session, Some(&rig()), &out, &opts(&model))
        .unwrap_or_else(|e| panic!("posing the session: {}", s3tir_capture::Chain(&e)));
    assert_eq!(report.sfm_stream, "rgb");
    assert_eq!(
        report.registered,
        rec.rgb.len(),
        "every RGB frame of the user's model joins"
    );
    assert!(!report.session_truncated);

    // Every posed view is the truth at its capture time.
    let posed = read_model(&out.join("sparse/0")).expect("the dataset's model reads back");
    assert!(posed.images.len() >= 10, "views: {}", posed.images.len());
    let by_seq: std::collections::BTreeMap<u32, u64> = rec.thermal.iter().copied().collect();
    let (mut worst_deg, mut worst_m) = (0.0f64, 0.0f64);
    for im in &posed.images {
        let seq = thermal_sequence(&im.name);
        let truth = world_from_thermal(by_seq[&seq]);
        let got = im.cam_from_world.inverse();
        worst_deg = worst_deg.max(got.rotation.angle_between(truth.rotation).to_degrees());
        worst_m = worst_m.max((got.translation_m - truth.translation_m).length());
    }
    assert!(
        worst_deg < 0.05 && worst_m < 0.002,
        "interpolated + composed poses must equal the truth: worst {worst_deg:.4}° and {worst_m:.5} m"
    );
    assert_eq!(
        posed.cameras[0].model_name, "OPENCV",
        "distortion kept for the trainer"
    );

    // Decisions: the frozen and the blurred frame are skipped with their reasons.
    let decision = |seq: u32| {
        report
            .frames
            .iter()
            .find(|d| d.stream == "thermal" && d.sequence == seq)
            .map(|d| d.decision.clone())
            .unwrap_or_default()
    };
    assert_eq!(decision(FROZEN_SEQ), "skipped: FFC-frozen");
    assert_eq!(decision(BLURRED_SEQ), "skipped: motion-blurred");
    assert!(out.join("poses.json").is_file());

    // Images: the recorded words, untouched.
    let first = &posed.images[0].name;
    let seq = thermal_sequence(first);
    let img = image::open(out.join("images").join(first))
        .expect("dataset image")
        .into_luma16();
    assert_eq!(
        img.into_raw(),
        thermal_words(seq, false),
        "{first} must be the recorded words"
    );

    // The trainer reads the dataset and holds out exactly holdout.txt.
    let ds = Dataset::load(&out, &LoadOptions::default()).expect("the trainer loads the dataset");
    let held: Vec<String> = std::fs::read_to_string(out.join("holdout.txt"))
        .expect("holdout.txt")
        .lines()
        .map(str::to_owned)
        .collect();
    assert_eq!(held.len(), report.held_out);
    assert!(!held.is_empty(), "some views held out");
    let test_names: Vec<&str> = ds.test.iter().map(|&i| ds.views[i].name.as_str()).collect();
    assert_eq!(test_names.len(), held.len(), "test views: {test_names:?}");
    assert!(held.iter().all(|h| test_names.contains(&h.as_str())));
    assert_eq!(ds.undistorted_models, vec!["OPENCV".to_owned()]);
}

#[test]
fn without_metric_scale_the_lever_arm_is_left_out_and_the_report_says_so() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), None);
    let model = truth_model(tmp.path(), &rec, 1);
    let out = tmp.path().join("dataset");
    let o = PosesOptions {
        metres_per_unit: None,
        ..opts(&model)
    };
    let report = poses::session_to_dataset(&rec.session, Some(&rig()), &out, &o)
        .unwrap_or_else(|e| panic!("posing: {}", s3tir_capture::Chain(&e)));
    assert!(
        report.scale_source.starts_with("unknown"),
        "{}",
        report.scale_source
    );
    let posed = read_model(&out.join("sparse/0")).expect("model");
    let by_seq: std::collections::BTreeMap<u32, u64> = rec.thermal.iter().copied().collect();
    let lever = rig()
        .rgb_from_thermal
        .expect("extrinsic")
        .translation_m
        .length();
    for im in &posed.images {
        let seq = thermal_sequence(&im.name);
        let rgb_centre = world_from_rgb(by_seq[&seq]).translation_m;
        let got = im.cam_from_world.inverse().translation_m;
        assert!(
            (got - rgb_centre).length() < 0.002,
            "thermal centre must be the RGB centre without scale"
        );
        let err = (got - world_from_thermal(by_seq[&seq]).translation_m).length();
        assert!(
            (err - lever).abs() < 0.003,
            "error {err} m is the lever arm {lever} m"
        );
    }
}

#[test]
fn bad_inputs_give_clear_errors_and_lose_nothing() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), None);
    let model = truth_model(tmp.path(), &rec, 1);
    let fresh = |name: &str| tmp.path().join(name);

    // No calibration given, none attached.
    let e = poses::session_to_dataset(&rec.session, None, &fresh("a"), &opts(&model))
        .expect_err("no calibration");
    assert!(matches!(e, PosesError::MissingCalibration { .. }), "{e}");
    assert!(
        e.to_string().contains("--calibration"),
        "says what to pass: {e}"
    );
    assert!(!fresh("a").exists(), "nothing created on an input error");

    // The calibration attached to a session is found.
    let attached_dir = tmp.path().join("attached");
    std::fs::create_dir_all(&attached_dir).expect("dir");
    let rec2 = record(&attached_dir, Some(&rig().to_yaml()));
    poses::session_to_dataset(&rec2.session, None, &fresh("b"), &opts(&model)).unwrap_or_else(
        |e| {
            panic!(
                "the attached calibration must be used: {}",
                s3tir_capture::Chain(&e)
            )
        },
    );

    // Another rig's calibration.
    let mut other = rig();
    if let Some(t) = other.thermal.as_mut() {
        t.width_px = 640;
        t.height_px = 512;
    }
    let e = poses::session_to_dataset(&rec.session, Some(&other), &fresh("c"), &opts(&model))
        .expect_err("other rig");
    assert!(
        e.to_string().contains("another rig") && e.to_string().contains("640×512"),
        "{e}"
    );

    // No COLMAP.
    let o = PosesOptions {
        user_model: None,
        colmap: PathBuf::from("/nonexistent/colmap"),
        ..opts(&model)
    };
    let e = poses::session_to_dataset(&rec.session, Some(&rig()), &fresh("d"), &o)
        .expect_err("no colmap");
    assert!(
        matches!(e, PosesError::ColmapMissing { .. }) && e.to_string().contains("colmap package"),
        "{e}"
    );
    assert!(
        !fresh("d").exists(),
        "nothing created when COLMAP is missing"
    );

    // Too few registered frames: a model with 3 images.
    let sparse = truth_model(&tmp.path().join("few"), &rec, 20);
    let e = poses::session_to_dataset(&rec.session, Some(&rig()), &fresh("e"), &opts(&sparse))
        .expect_err("too few");
    assert!(
        matches!(e, PosesError::TooFewRegistered { registered: 3, .. }),
        "{e}"
    );
    assert!(
        !fresh("e").exists(),
        "no half dataset under the output name"
    );
    assert!(
        fresh("e.partial").join("colmap").is_dir(),
        "the failed run's workspace stays in OUT.partial for inspection"
    );
    // COLMAP's mapper finds no pair to start from (it exits with failure, as on the simulated
    // walk's thermal-only frames): too few registered, not a crash. A stand-in `colmap` that
    // prints what COLMAP 3.8 prints then.
    let fake = tmp.path().join("colmap-no-initial-pair");
    std::fs::write(
        &fake,
        "#!/bin/sh\ncase \"$1\" in\n  mapper) echo '  => No good initial image pair found.'; echo 'ERROR: failed to create sparse model'; exit 1;;\n  *) echo 'COLMAP 3.8 (stand-in)';;\nesac\n",
    )
    .expect("write the stand-in colmap");
    {
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    }
    let o = PosesOptions {
        user_model: None,
        colmap: fake,
        ..opts(&model)
    };
    let e = poses::session_to_dataset(&rec.session, Some(&rig()), &fresh("f"), &o)
        .expect_err("no initial pair");
    assert!(
        matches!(e, PosesError::TooFewRegistered { registered: 0, .. })
            && e.to_string().contains("too bland"),
        "a mapper without an initial pair must say that nothing registered and why: {e}"
    );

    // The next run clears that unfinished folder.
    poses::session_to_dataset(&rec.session, Some(&rig()), &fresh("e"), &opts(&model))
        .unwrap_or_else(|e| panic!("a run after a failed one: {}", s3tir_capture::Chain(&e)));
    assert!(fresh("e").join("sparse/0/images.txt").is_file() && !fresh("e.partial").exists());

    // An existing dataset is never overwritten.
    let existing = fresh("f");
    std::fs::create_dir_all(&existing).expect("dir");
    std::fs::write(existing.join("keep.txt"), "mine").expect("write");
    let e = poses::session_to_dataset(&rec.session, Some(&rig()), &existing, &opts(&model))
        .expect_err("existing");
    assert!(e.to_string().contains("never overwrites"), "{e}");
    assert_eq!(
        std::fs::read_to_string(existing.join("keep.txt")).expect("kept"),
        "mine"
    );

    // A session cut mid-chunk: what is readable is used, and the report says how much.
    let bytes = std::fs::read(&rec.session).expect("session bytes");
    let cut = tmp.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 4]).expect("write cut");
    let report = poses::session_to_dataset(&cut, Some(&rig()), &fresh("g"), &opts(&model))
        .unwrap_or_else(|e| {
            panic!(
                "a truncated session must still pose: {}",
                s3tir_capture::Chain(&e)
            )
        });
    assert!(report.session_truncated);
    let note = report.session_note.clone().unwrap_or_default();
    assert!(
        note.contains("truncated") && note.contains("thermal"),
        "{note}"
    );
    assert!(
        report.thermal_frames < rec.thermal.len(),
        "fewer frames read"
    );
    assert!(report.views > 0);
}

/// `--with-rgb` (calib's `poses::tests` checks the poses, images and hold-out in detail): the
/// trainer loads both image sets of the joint dataset, each through its own camera, and tests
/// on the RGB views `holdout.txt` names as well as the thermal ones.
#[test]
fn with_rgb_the_trainer_loads_both_image_sets() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let rec = record(tmp.path(), None);
    let model = truth_model(tmp.path(), &rec, 1);
    let out = tmp.path().join("dataset");
    let o = PosesOptions {
        with_rgb: true,
        ..opts(&model)
    };
    let report = poses::session_to_dataset(&rec.session, Some(&rig()), &out, &o)
        .unwrap_or_else(|e| panic!("posing with --with-rgb: {}", s3tir_capture::Chain(&e)));
    assert_eq!(report.rgb_views, rec.rgb.len(), "every posed RGB frame");
    assert!(report.rgb_held_out > 0);

    let ds = Dataset::load(&out, &LoadOptions::default()).expect("the trainer loads it");
    let rgb: Vec<&str> = ds
        .views
        .iter()
        .filter(|v| v.rgb.is_some())
        .map(|v| v.name.as_str())
        .collect();
    assert_eq!(rgb.len(), report.rgb_views);
    assert!(rgb.iter().all(|n| n.starts_with("rgb_")), "{rgb:?}");
    assert_eq!(
        ds.views.len(),
        report.rgb_views + report.views + report.held_out
    );
    for v in &ds.views {
        let want = if v.rgb.is_some() { R_W } else { T_W };
        assert_eq!(
            v.camera.width, want as usize,
            "{} through its camera",
            v.name
        );
    }
    let tested_rgb = ds
        .test
        .iter()
        .filter(|&&i| ds.views[i].rgb.is_some())
        .count();
    assert_eq!(
        tested_rgb, report.rgb_held_out,
        "held-out RGB views are tested"
    );
}
