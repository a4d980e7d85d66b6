//! Every frame of a walk, in time order ([`run_walk`]): the frame plan of both streams, the
//! motion-blurred thermal and RGB renders through the walk room, the sensor models and the
//! wire frames, and the board wave ([`super::WalkKind::Board`]).

use std::sync::atomic::{AtomicBool, Ordering};

use glam::DVec3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use s3tir_calib::Rigid3;
use s3tir_capture::device::FourCc;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::wire::simwire::{self, StreamId, WireFrame};

use super::path::WalkPath;
use super::room::{WalkRoom, trace_walk};
use super::truth::TruthFrame;
use super::{BOARD_HOLD_S, WalkKind, WalkRig, WalkSpec};
use crate::error::SimError;
use crate::physics::Radiometry;
use crate::render::{RayGrid, gaussian_blur};
use crate::rig::Rig;
use crate::scene::{BACKGROUND_K, ENV_K};
use crate::sensor::{RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, rgb_to_jpeg};

/// RGB frame rate during a walk.
pub const WALK_RGB_HZ: f64 = 10.0;

/// Renders the thermal radiance of one frame: 2 instants over the exposure, 2×2 sub-pixels.
fn render_thermal(
    grid: &RayGrid,
    poses: &[Rigid3],
    radiometry: &Radiometry,
    room: WalkRoom,
) -> Vec<f64> {
    let (w, h) = (grid.width(), grid.height());
    let l_env = radiometry.radiance(ENV_K);
    let l_bg = radiometry.radiance(BACKGROUND_K);
    let mut out = vec![0.0; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, px) in row.iter_mut().enumerate() {
            let mut acc = 0.0;
            let mut n = 0.0;
            for (k, pose) in poses.iter().enumerate() {
                for j in 0..2 {
                    for i in 0..2 {
                        let (a, b) = (0.25 + 0.5 * i as f64, 0.25 + 0.5 * j as f64);
                        let a = (a + 0.125 * k as f64).fract();
                        let d = pose.transform_vector(grid.sub_ray(u, v, a, b));
                        acc += match trace_walk(pose.translation_m, d, room) {
                            Some(s) => {
                                s.emissivity * radiometry.radiance(s.temp_k)
                                    + (1.0 - s.emissivity) * l_env
                            }
                            None => l_bg,
                        };
                        n += 1.0;
                    }
                }
            }
            *px = acc / n;
        }
    });
    out
}

/// Renders the linear RGB of one frame: one jittered ray per pixel and instant.
fn render_rgb(grid: &RayGrid, poses: &[Rigid3], room: WalkRoom) -> [Vec<f64>; 3] {
    let (w, h) = (grid.width(), grid.height());
    let light = DVec3::new(0.3, -0.4, 1.0).normalize();
    let jitter = [(0.3, 0.4), (0.7, 0.6), (0.5, 0.2), (0.2, 0.8)];
    let mut rgb = vec![[0.0f64; 3]; w * h];
    rgb.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, px) in row.iter_mut().enumerate() {
            let mut c = [0.0; 3];
            for (k, pose) in poses.iter().enumerate() {
                let (a, b) = jitter[k % jitter.len()];
                let d = pose.transform_vector(grid.sub_ray(u, v, a, b));
                match trace_walk(pose.translation_m, d, room) {
                    Some(s) => {
                        let shade = 0.35 + 0.65 * s.normal.dot(light).max(0.0);
                        for (ch, a) in c.iter_mut().zip(s.albedo) {
                            *ch += a * shade;
                        }
                    }
                    None => {
                        for ch in &mut c {
                            *ch += 0.3;
                        }
                    }
                }
            }
            for ch in &mut c {
                *ch /= poses.len() as f64;
            }
            *px = c;
        }
    });
    [0, 1, 2].map(|k| rgb.iter().map(|p| p[k]).collect())
}

/// Exposure instants (seconds, relative to the frame's stamp) of each camera.
const THERMAL_INSTANTS_S: [f64; 2] = [-0.006, 0.006];
const RGB_INSTANTS_S: [f64; 3] = [-0.008, 0.0, 0.008];

/// One frame of the walk, planned.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Planned {
    t_s: f64,
    stream: StreamId,
    sequence: u32,
}

/// Renders every frame of the walk in time order and hands each to `send` with its truth;
/// stops early when `stop` is set. Returns the truth of the frames sent.
pub fn run_walk(
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: &AtomicBool,
    mut send: impl FnMut(WireFrame, f64) -> Result<(), SimError>,
) -> Result<Vec<TruthFrame>, SimError> {
    if spec.kind == WalkKind::Board {
        return run_board_wave(rig, spec, stop, send);
    }
    let path = WalkPath::new(spec.kind, rig.seed);
    let thermal = rig.thermal;
    let rgb_profile = rig.rgb;
    let rgb_from_thermal =
        Rig::new(thermal, rgb_profile.unwrap_or_else(RgbProfile::hd720)).rgb_from_thermal;
    let thermal_from_rgb = rgb_from_thermal.inverse();
    let plan = plan_frames(rig, spec.duration_s);

    let mut sensor = ThermalSensor::new(
        ThermalProfile {
            auto_ffc_period_s: 0.0,
            ..thermal
        },
        rig.seed,
    );
    let radiometry = Radiometry::new();
    let tgrid = RayGrid::new(&thermal.camera);
    let rgrid = rgb_profile.map(|p| RayGrid::new(&p.camera));
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(rig.seed ^ 0x0C0F_FEE5);
    let ffc_at_s = 0.4 * spec.duration_s;
    let mut ffc_requested = false;
    let mut truth = Vec::with_capacity(plan.len());
    for item in plan {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let instants = |offsets: &[f64], from_thermal: Option<&Rigid3>| -> Vec<Rigid3> {
            offsets
                .iter()
                .map(|dt| {
                    let p = path.world_from_thermal((item.t_s + dt).max(0.0));
                    from_thermal.map_or(p, |t| p.compose(t))
                })
                .collect()
        };
        let (frame, world_from_cam, ffc_frozen) = match item.stream {
            StreamId::Thermal => {
                if !ffc_requested && item.t_s >= ffc_at_s {
                    sensor.request_ffc();
                    ffc_requested = true;
                }
                let poses = instants(&THERMAL_INSTANTS_S, None);
                let radiance = render_thermal(&tgrid, &poses, &radiometry, spec.room);
                let (w, h) = (
                    thermal.camera.width_px as usize,
                    thermal.camera.height_px as usize,
                );
                let blurred = gaussian_blur(&radiance, w, h, thermal.psf_sigma_px);
                let ThermalOutput::Frame(f) = sensor.next_frame(&blurred) else {
                    continue;
                };
                (
                    thermal_wire(&thermal, item.sequence, &f.words, f.ffc_frozen),
                    path.world_from_thermal(item.t_s),
                    f.ffc_frozen,
                )
            }
            StreamId::Rgb => {
                let (Some(p), Some(grid)) = (rgb_profile, rgrid.as_ref()) else {
                    continue;
                };
                let poses = instants(&RGB_INSTANTS_S, Some(&thermal_from_rgb));
                let lin = render_rgb(grid, &poses, spec.room);
                let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
                let blurred = lin.map(|c| gaussian_blur(&c, w, h, p.psf_sigma_px));
                let srgb = crate::sensor::expose_rgb_channels(
                    &p,
                    [&blurred[0], &blurred[1], &blurred[2]],
                    &mut rgb_rng,
                );
                let payload = rgb_to_jpeg(&srgb, p.camera.width_px, p.camera.height_px)?;
                (
                    rgb_wire(&p, item.sequence, payload),
                    path.world_from_thermal(item.t_s).compose(&thermal_from_rgb),
                    false,
                )
            }
        };
        let stream = frame.stream;
        let sequence = frame.sequence;
        send(frame, item.t_s)?;
        truth.push(TruthFrame::sent(
            stream,
            sequence,
            ffc_frozen,
            &world_from_cam,
        ));
    }
    Ok(truth)
}

/// The frame plan of a walk: every frame of both streams in time order.
fn plan_frames(rig: &WalkRig, duration_s: f64) -> Vec<Planned> {
    let thermal = rig.thermal;
    let mut plan: Vec<Planned> = Vec::new();
    let n_t = (duration_s * thermal.rate_hz).floor() as u32;
    plan.extend((0..n_t).map(|k| Planned {
        t_s: f64::from(k) / thermal.rate_hz,
        stream: StreamId::Thermal,
        sequence: k,
    }));
    if rig.rgb.is_some() {
        let n_r = (duration_s * WALK_RGB_HZ).floor() as u32;
        plan.extend((0..n_r).map(|k| Planned {
            t_s: f64::from(k) / WALK_RGB_HZ,
            stream: StreamId::Rgb,
            sequence: k,
        }));
    }
    plan.sort_by(|a, b| {
        a.t_s
            .total_cmp(&b.t_s)
            .then((a.stream as u8).cmp(&(b.stream as u8)))
    });
    plan
}

fn thermal_wire(profile: &ThermalProfile, sequence: u32, words: &[u16], frozen: bool) -> WireFrame {
    let mut flags = 0;
    if frozen {
        flags |= simwire::FLAG_FFC_FROZEN;
    }
    if profile.telemetry_rows > 0 {
        flags |= simwire::FLAG_TELEMETRY;
    }
    if profile.units == ThermalUnits::CentiKelvin {
        flags |= simwire::FLAG_TLINEAR;
    }
    WireFrame {
        stream: StreamId::Thermal,
        flags,
        fourcc: FourCc::Y16,
        width: profile.camera.width_px,
        height: profile.output_height(),
        bytes_per_line: profile.camera.width_px * 2,
        sequence,
        monotonic_ns: 0,
        payload: words.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

fn rgb_wire(profile: &RgbProfile, sequence: u32, payload: Vec<u8>) -> WireFrame {
    WireFrame {
        stream: StreamId::Rgb,
        flags: 0,
        fourcc: FourCc::MJPG,
        width: profile.camera.width_px,
        height: profile.camera.height_px,
        bytes_per_line: 0,
        sequence,
        monotonic_ns: 0,
        payload,
    }
}

/// [`WalkKind::Board`]: the rig still, the board waved through the board set's poses. The
/// truth's world frame is the board's (`world_from_cam = board_from_cam`).
fn run_board_wave(
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: &AtomicBool,
    mut send: impl FnMut(WireFrame, f64) -> Result<(), SimError>,
) -> Result<Vec<TruthFrame>, SimError> {
    use crate::board::{BoardSpec, BoardThermal};
    use crate::rig::{plan_board_views, render_rgb_board, render_thermal_board};
    let board = BoardSpec::default();
    let rgb_profile = rig.rgb.unwrap_or_else(|| RgbProfile::hd720().binned2());
    let the_rig = Rig::new(rig.thermal, rgb_profile);
    let n_views = ((spec.duration_s / BOARD_HOLD_S).ceil() as usize).max(1);
    let views = plan_board_views(&the_rig, &board, n_views, rig.seed)?;
    let mut heat = BoardThermal::cooled(board);
    let first_view_s = 60.0;
    let mut sensor = ThermalSensor::new(
        ThermalProfile {
            auto_ffc_period_s: 0.0,
            ..rig.thermal
        },
        rig.seed,
    );
    let tgrid = RayGrid::new(&rig.thermal.camera);
    let rgrid = RayGrid::new(&rgb_profile.camera);
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(rig.seed ^ 0x0052_4742);
    let thermal_from_rgb = the_rig.rgb_from_thermal.inverse();
    let ffc_at_s = 0.4 * spec.duration_s;
    let mut ffc_requested = false;
    let mut truth = Vec::new();
    for item in plan_frames(rig, spec.duration_s) {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let view = &views[((item.t_s / BOARD_HOLD_S) as usize).min(views.len() - 1)];
        let board_from_thermal = view.thermal_from_board.inverse();
        let (frame, world_from_cam, frozen) = match item.stream {
            StreamId::Thermal => {
                if !ffc_requested && item.t_s >= ffc_at_s {
                    sensor.request_ffc();
                    ffc_requested = true;
                }
                heat.advance(first_view_s + item.t_s - heat.time_s);
                let frozen = sensor.ffc_in_progress();
                let Some(words) =
                    render_thermal_board(&tgrid, &mut sensor, &heat, &view.thermal_from_board)
                else {
                    continue;
                };
                (
                    thermal_wire(&rig.thermal, item.sequence, &words, frozen),
                    board_from_thermal,
                    frozen,
                )
            }
            StreamId::Rgb => {
                let rgb_from_board = the_rig.rgb_from_thermal.compose(&view.thermal_from_board);
                let px =
                    render_rgb_board(&rgrid, &rgb_profile, &board, &rgb_from_board, &mut rgb_rng);
                let jpeg = rgb_to_jpeg(
                    &px,
                    rgb_profile.camera.width_px,
                    rgb_profile.camera.height_px,
                )?;
                (
                    rgb_wire(&rgb_profile, item.sequence, jpeg),
                    board_from_thermal.compose(&thermal_from_rgb),
                    false,
                )
            }
        };
        let stream = frame.stream;
        send(frame, item.t_s)?;
        truth.push(TruthFrame::sent(
            stream,
            item.sequence,
            frozen,
            &world_from_cam,
        ));
    }
    Ok(truth)
}
