//! Proves the simulated walk (`run --walk`, `src/walk.rs`): the hand-held path goes around the
//! scene, keeps it in view and moves smoothly; the truth poses agree with the rendered thermal
//! images (a point of the hot pipe and a point of the far wall, projected with the truth pose and
//! the camera model, land on pixels of their temperatures); the same seed gives the same
//! frame bytes; the walk's FFC freezes frames and flags them. Does NOT test the socket serving
//! or the capture path (tests/tests/walk_to_model.rs records a walk through s3tir-capture).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::atomic::AtomicBool;

use glam::DVec3;
use s3tir_capture::wire::simwire::{self, StreamId, WireFrame};
use s3tir_firmware_sim::sensor::{RgbProfile, ThermalProfile};
use s3tir_firmware_sim::walk::{
    TruthFrame, WALK_TARGET, WalkKind, WalkPath, WalkRig, WalkSpec, run_walk,
};

fn rig() -> WalkRig {
    WalkRig {
        thermal: ThermalProfile::lepton35(),
        rgb: Some(RgbProfile::hd720().binned2()),
        seed: 1,
    }
}

fn walk(duration_s: f64) -> (Vec<(WireFrame, f64)>, Vec<TruthFrame>) {
    let mut frames = Vec::new();
    let spec = WalkSpec {
        kind: WalkKind::Handheld,
        duration_s,
        truth_dir: None,
        room: Default::default(),
    };
    let truth = run_walk(&rig(), &spec, &AtomicBool::new(false), |f, t| {
        frames.push((f, t));
        Ok(())
    })
    .expect("walk renders");
    (frames, truth)
}

#[test]
fn handheld_path_goes_around_the_scene_smoothly_and_keeps_it_in_view() {
    let path = WalkPath::new(WalkKind::Handheld, 1);
    let cam = ThermalProfile::lepton35().camera;
    let mut azimuth_total = 0.0;
    let mut last_azimuth: Option<f64> = None;
    let mut worst_step_deg: f64 = 0.0;
    let mut prev = path.world_from_thermal(0.0);
    for k in 1..=200 {
        let t = k as f64 * 0.1; // 20 s
        let p = path.world_from_thermal(t);
        let c = p.translation_m;
        let az = c.y.atan2(c.x);
        if let Some(a) = last_azimuth {
            let mut d = az - a;
            if d > std::f64::consts::PI {
                d -= std::f64::consts::TAU;
            }
            if d < -std::f64::consts::PI {
                d += std::f64::consts::TAU;
            }
            azimuth_total += d;
        }
        last_azimuth = Some(az);
        worst_step_deg = worst_step_deg.max(p.rotation.angle_between(prev.rotation).to_degrees());
        prev = p;
        let target_in_cam = p.inverse().transform_point(WALK_TARGET);
        let px = cam
            .project(target_in_cam)
            .unwrap_or_else(|| panic!("the scene's centre is behind the camera at {t} s"));
        assert!(
            px.x > 20.0 && px.x < 140.0 && px.y > 15.0 && px.y < 105.0,
            "the scene's centre at {px} px must stay well inside the 160×120 image at {t} s"
        );
    }
    let deg = azimuth_total.to_degrees().abs();
    assert!(
        deg > 250.0,
        "a 20 s walk must go most of the way around: {deg:.0}°"
    );
    assert!(
        worst_step_deg < 3.0,
        "smooth: at most 3° of turn per 0.1 s, got {worst_step_deg:.2}°"
    );
}

#[test]
fn truth_poses_agree_with_the_rendered_thermal_images() {
    let (frames, truth) = walk(1.0);
    let cam = ThermalProfile::lepton35().camera;
    let mut checked = 0;
    for ((f, _), tr) in frames.iter().zip(&truth) {
        if f.stream != StreamId::Thermal {
            continue;
        }
        let r = tr.world_from_cam.rotation;
        let m = glam::DMat3::from_cols_array_2d(&r).transpose();
        let world_from_cam = s3tir_calib::Rigid3::new(
            glam::DQuat::from_mat3(&m),
            DVec3::from_array(tr.world_from_cam.translation_m),
        );
        let cam_from_world = world_from_cam.inverse();
        let kelvin_at = |p: DVec3| -> Option<f64> {
            let px = cam.project(cam_from_world.transform_point(p))?;
            let (u, v) = (px.x.round() as i64, px.y.round() as i64);
            if u < 2 || v < 2 || u >= 158 || v >= 118 {
                return None;
            }
            let k = 2 * (v as usize * 160 + u as usize);
            Some(f64::from(u16::from_le_bytes([f.payload[k], f.payload[k + 1]])) / 100.0)
        };
        // The pipe's upper surface near its hot end (333 K at x = -0.6, ε 0.9: > 322 K
        // apparent), and the far wall above everything (289.75 K at 0.5 m, ε 0.9, reflecting 290 K).
        let pipe = DVec3::new(-0.45, 0.3, 0.45);
        let wall = DVec3::new(0.2, -3.0, 0.5);
        if let (Some(hot), Some(cold)) = (kelvin_at(pipe), kelvin_at(wall)) {
            assert!(hot > 322.0, "the pipe's hot end must read hot: {hot:.1} K");
            assert!(
                (cold - 289.8).abs() < 1.0,
                "the far wall must read about 289.8 K: {cold:.1} K"
            );
            checked += 1;
        }
    }
    assert!(
        checked >= 5,
        "both points in view in at least 5 frames: {checked}"
    );
}

#[test]
fn same_seed_same_frames_and_the_walks_ffc_is_flagged() {
    let (a, truth) = walk(3.0);
    let (b, _) = walk(3.0);
    assert_eq!(a.len(), b.len());
    for ((fa, ta), (fb, tb)) in a.iter().zip(&b) {
        assert_eq!(ta, tb);
        assert!(
            fa.payload == fb.payload,
            "frame {} differs between runs",
            fa.sequence
        );
    }
    let thermal = a
        .iter()
        .filter(|(f, _)| f.stream == StreamId::Thermal)
        .count();
    let rgb = a.iter().filter(|(f, _)| f.stream == StreamId::Rgb).count();
    assert_eq!((thermal, rgb), (26, 30), "3 s at 8.7 Hz and 10 Hz");
    let frozen: Vec<u32> = a
        .iter()
        .filter(|(f, _)| f.flags & simwire::FLAG_FFC_FROZEN != 0)
        .map(|(f, _)| f.sequence)
        .collect();
    // The FFC is requested at 40 % of the walk (1.2 s: thermal frame 11) and freezes 23 frames.
    assert_eq!(frozen.first(), Some(&11), "frozen frames: {frozen:?}");
    assert_eq!(frozen.len(), 26 - 11, "frozen frames: {frozen:?}");
    assert!(
        truth.iter().filter(|t| t.ffc_frozen).count() == frozen.len(),
        "the truth flags the same frames"
    );
}

/// The walk room's board (`--walk-board`): `walk_board_pose` places board points where the
/// tracer finds the board's pattern, coated squares where `material_at` says, seen from the
/// front; the back is plain. Heated tags are warm where their ink is and foil elsewhere;
/// printed tags keep the wall's thermal field.
#[test]
fn the_walk_board_and_heated_tags_are_where_their_files_say() {
    use s3tir_firmware_sim::board::{BoardMaterial, BoardSpec};
    use s3tir_firmware_sim::walk::fiducials::{FOIL_EMISSIVITY, HEATED_TAG_K, TagInk, room_tags};
    use s3tir_firmware_sim::walk::{WALK_BOARD_K, WalkRoom, trace_walk, walk_board_pose};

    let board = BoardSpec::default();
    let pose = walk_board_pose();
    let room = WalkRoom {
        board: true,
        ..WalkRoom::default()
    };
    // Board z points into the printed face: a viewer in front sits at negative board z.
    let mut checked = 0;
    for (x, y) in [
        (0.03, 0.03),
        (0.09, 0.03),
        (0.21, 0.15),
        (0.39, 0.21),
        (-0.03, -0.03),
    ] {
        let target = pose.transform_point(DVec3::new(x, y, 0.0));
        for (side, front) in [(-1.0, true), (1.0, false)] {
            let eye = pose.transform_point(DVec3::new(x, y, side * 0.1));
            let d = (target - eye).normalize();
            let hit = trace_walk(eye, d, room).expect("the board is hit");
            assert!(
                (eye + d * hit.t - target).length() < 1e-9,
                "({x}, {y}) seen from the {}: hit {:.4} m away from the board point",
                if front { "front" } else { "back" },
                (eye + d * hit.t - target).length()
            );
            assert_eq!(hit.temp_k, WALK_BOARD_K);
            let m = board.material_at(x, y).expect("on the board");
            let want = if front { board.emissivity(m) } else { 0.95 };
            assert_eq!(hit.emissivity, want, "({x}, {y}) front {front}: {m:?}");
            if front {
                assert_eq!(
                    hit.albedo[0] < 0.5,
                    m == BoardMaterial::Coated,
                    "coated squares are black in RGB"
                );
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 10);
    // Without the board the same ray goes through to the scene behind it.
    let eye = pose.transform_point(DVec3::new(0.21, 0.15, -0.8));
    let d = (pose.transform_point(DVec3::new(0.21, 0.15, 0.0)) - eye).normalize();
    let through = trace_walk(eye, d, WalkRoom::default()).expect("the room");
    assert!(
        through.temp_k != WALK_BOARD_K,
        "no board without --walk-board"
    );

    // A floor tag's centre cell region: heated ink or foil, printed: the floor's own field.
    let tag = room_tags()[20];
    let above = tag.centre + DVec3::Z * 1.0;
    let mut inks = (0, 0);
    for (dx, dy) in [
        (0.0, 0.0),
        (0.17, 0.17),
        (-0.17, 0.17),
        (0.22, 0.0),
        (0.19, -0.19),
    ] {
        let p = tag.centre + tag.right * dx + tag.up * dy;
        let d = (p - above).normalize();
        let heated = trace_walk(
            above,
            d,
            WalkRoom {
                tags: TagInk::Heated,
                board: false,
            },
        )
        .expect("floor");
        let printed = trace_walk(above, d, WalkRoom::default()).expect("floor");
        assert_eq!(heated.temp_k, HEATED_TAG_K, "heated tag at ({dx}, {dy})");
        assert!(
            printed.temp_k < HEATED_TAG_K - 5.0,
            "printed tags are at the floor's temperature"
        );
        if heated.emissivity == FOIL_EMISSIVITY {
            inks.1 += 1;
        } else {
            inks.0 += 1;
        }
    }
    assert!(
        inks.0 >= 1 && inks.1 >= 1,
        "the border is ink, the quiet zone foil: {inks:?}"
    );
}
