//! Rendering benchmarks. The peer is a plain 4×4 point-sampling renderer written here: the
//! printed ratio says what exact area integration of edge pixels costs against it.
#![allow(clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{DQuat, DVec3};
use rand::SeedableRng;
use s3tir_calib::Rigid3;
use s3tir_firmware_sim::board::{BoardSpec, BoardThermal};
use s3tir_firmware_sim::physics::Radiometry;
use s3tir_firmware_sim::render::{PlaneTexture, RayGrid, render_plane};
use s3tir_firmware_sim::rig::{ThermalBoardTexture, VisibleBoardTexture};
use s3tir_firmware_sim::sensor::{
    LinearizedRadiance, RgbProfile, StaticRgbExposer, ThermalProfile, ThermalSensor, rgb_to_jpeg,
};

fn pose(board: &BoardSpec) -> Rigid3 {
    let (x0, y0, x1, y1) = board.extent_m();
    let c = DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
    let r = DQuat::from_euler(glam::EulerRot::ZYX, 0.1, 0.3, -0.2);
    Rigid3::new(r, DVec3::new(0.0, 0.0, 0.9) - r * c)
}

/// The peer: 4×4 point samples per pixel, no area integration.
fn point_sampled(
    grid: &RayGrid,
    cam_from_plane: &Rigid3,
    tex: &dyn PlaneTexture,
    bg: f64,
) -> Vec<f64> {
    let plane_from_cam = cam_from_plane.inverse();
    let mut out = vec![0.0; grid.width() * grid.height()];
    for v in 0..grid.height() {
        for u in 0..grid.width() {
            let mut acc = 0.0;
            for j in 0..4 {
                for i in 0..4 {
                    let d = plane_from_cam.transform_vector(grid.sub_ray(
                        u,
                        v,
                        (i as f64 + 0.5) / 4.0,
                        (j as f64 + 0.5) / 4.0,
                    ));
                    let o = plane_from_cam.translation_m;
                    let t = -o.z / d.z;
                    let p = o + d * t;
                    acc += if t > 0.0 {
                        tex.value(p.x, p.y).unwrap_or(bg)
                    } else {
                        bg
                    };
                }
            }
            out[v * grid.width() + u] = acc / 16.0;
        }
    }
    out
}

fn bench(c: &mut Criterion) {
    let board = BoardSpec::default();
    let p = pose(&board);
    let rgb = RgbProfile::hd720();
    let rgrid = RayGrid::new(&rgb.camera);
    let tex = VisibleBoardTexture { board: &board };
    c.bench_function("rgb720_board_area_integrated", |b| {
        b.iter(|| render_plane(&rgrid, &p, 4, &tex, 0.3))
    });
    c.bench_function("rgb720_board_point_sampled_peer", |b| {
        b.iter(|| point_sampled(&rgrid, &p, &tex, 0.3))
    });
    let lepton = ThermalProfile::lepton35();
    let tgrid = RayGrid::new(&lepton.camera);
    let radiometry = Radiometry::new();
    let mut thermal = BoardThermal::cooled(board);
    thermal.advance(120.0);
    let ttex = ThermalBoardTexture {
        thermal: &thermal,
        radiometry: &radiometry,
    };
    c.bench_function("lepton_board_area_integrated", |b| {
        b.iter(|| render_plane(&tgrid, &p, 4, &ttex, 1.0))
    });
    let boson = ThermalProfile::boson640();
    let mut sensor = ThermalSensor::new(boson, 1);
    let flat = vec![radiometry.radiance(300.0); 640 * 512];
    c.bench_function("boson640_sensor_frame", |b| {
        b.iter(|| sensor.next_frame(&flat))
    });
    // The live rig's per-frame work (`run`): the fast thermal path and one RGB frame.
    let lin = LinearizedRadiance::new(&radiometry, &boson, &flat);
    c.bench_function("boson640_sensor_frame_fast", |b| {
        b.iter(|| sensor.next_frame_fast(&lin))
    });
    let rgb360 = RgbProfile::hd720().binned2();
    let (rw, rh) = (rgb360.camera.width_px, rgb360.camera.height_px);
    let refl = vec![0.5; (rw * rh) as usize];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let exposer = StaticRgbExposer::new(&rgb360, &refl, [1.0, 0.97, 0.92], rw as usize, &mut rng);
    c.bench_function("rgb360_live_frame_expose_and_jpeg", |b| {
        b.iter(|| rgb_to_jpeg(&exposer.expose(&mut rng), rw, rh).unwrap())
    });
    c.bench_function("board_heat_model_60s", |b| {
        b.iter(|| thermal.clone().advance(60.0))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
