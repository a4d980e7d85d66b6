//! The frames of the running rig: the board rendered once per epoch in its own thread
//! ([`render_radiance`]), the thermal and RGB streams sensed and paced in theirs
//! ([`frame_loop`]), every frame broadcast to the socket's clients.

use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use glam::{DQuat, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use s3tir_calib::Rigid3;
use s3tir_capture::device::FourCc;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::wire::simwire::{self, StreamId, WireFrame};

use super::clock::{Pacer, StreamClock, StreamStats};
use super::firmware::{Shared, TRIGGER_LATENCY_NS, lock};
use super::{RgbFormat, ServeConfig, monotonic_ns};
use crate::board::{BoardSpec, BoardThermal};
use crate::error::SimError;
use crate::render::{RayGrid, gaussian_blur, render_plane};
use crate::rig::{
    BACKGROUND_REFLECTANCE, Rig, SUBPIXELS, ThermalBoardTexture, VisibleBoardTexture,
};
use crate::sensor::{
    LinearizedRadiance, RgbProfile, StaticRgbExposer, ThermalOutput, ThermalProfile,
    ThermalSensorFrame, rgb_to_jpeg, rgb_to_yuyv,
};

/// The board pose the running rig looks at: 0.8 m ahead, slightly tilted.
fn run_board_pose(board: &BoardSpec) -> Rigid3 {
    let (x0, y0, x1, y1) = board.extent_m();
    let centre = DVec3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
    let rotation = DQuat::from_euler(glam::EulerRot::ZYX, 0.05, 0.2, -0.15);
    Rigid3::new(rotation, DVec3::new(0.0, 0.0, 0.8) - rotation * centre)
}

fn broadcast(clients: &Mutex<Vec<UnixStream>>, frame: &WireFrame, socket: &Path) {
    let peer = socket.display().to_string();
    let mut cs = clients
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    cs.retain_mut(|c| match frame.write_to(c, &peer) {
        Ok(()) => true,
        Err(e) => {
            tracing::info!("client left {peer}: {}", s3tir_capture::Chain(&e));
            false
        }
    });
}

/// The board's radiance is re-rendered once per epoch of sensor time (it changes slowly: the
/// apparent contrast moves by < 0.1 K per second), in its own thread: epoch k+1 is rendered
/// while epoch k is served, from the board as it was when epoch k began.
const RENDER_EPOCH_S: f64 = 1.0;

/// Rendered thermal radiance images by epoch (the current and the next one).
type RadianceSlots = Mutex<std::collections::BTreeMap<u64, Arc<LinearizedRadiance>>>;

/// Renders the board's blurred radiance as seen by the thermal core, linearised for
/// [`ThermalSensor::next_frame_fast`].
fn render_radiance(
    board: &BoardThermal,
    radiometry: &crate::physics::Radiometry,
    profile: &ThermalProfile,
    tgrid: &RayGrid,
    thermal_from_board: &Rigid3,
) -> LinearizedRadiance {
    let texture = ThermalBoardTexture {
        thermal: board,
        radiometry,
    };
    let background = radiometry.radiance(board.env_k);
    let img = render_plane(tgrid, thermal_from_board, SUBPIXELS, &texture, background);
    let blurred = gaussian_blur(&img, tgrid.width(), tgrid.height(), profile.psf_sigma_px);
    LinearizedRadiance::new(radiometry, profile, &blurred)
}

/// What the frame loop needs rendered before the first frame: done before the socket is
/// bound, so a client that connects gets frames at once.
pub(super) struct Prepared {
    tgrid: RayGrid,
    thermal_from_board: Rigid3,
    rgb_exposer: Option<StaticRgbExposer>,
    slots: RadianceSlots,
}

pub(super) fn prepare(
    cfg: &ServeConfig,
    profile: ThermalProfile,
    shared: &Mutex<Shared>,
) -> Prepared {
    let rig = Rig::new(profile, cfg.rgb.unwrap_or_else(RgbProfile::hd720));
    let thermal_from_board = run_board_pose(&BoardSpec::default());
    let tgrid = RayGrid::new(&profile.camera);
    let rgb_exposer = match &cfg.rgb {
        Some(r) => {
            // The board does not move and visible reflectance does not change with temperature:
            // render the linear image once, expose (noise) every frame.
            let grid = RayGrid::new(&r.camera);
            let board = BoardSpec::default();
            let img = render_plane(
                &grid,
                &rig.rgb_from_thermal.compose(&thermal_from_board),
                SUBPIXELS,
                &VisibleBoardTexture { board: &board },
                BACKGROUND_REFLECTANCE,
            );
            let blurred = gaussian_blur(&img, grid.width(), grid.height(), r.psf_sigma_px);
            let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x004E_4F49);
            Some(StaticRgbExposer::new(
                r,
                &blurred,
                [1.0, 0.97, 0.92],
                grid.width(),
                &mut rng,
            ))
        }
        None => None,
    };
    let slots: RadianceSlots = Mutex::new(std::collections::BTreeMap::new());
    slots
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .insert(
            0,
            Arc::new({
                let sh = lock(shared);
                render_radiance(
                    &sh.board,
                    sh.sensor.radiometry(),
                    &profile,
                    &tgrid,
                    &thermal_from_board,
                )
            }),
        );
    Prepared {
        tgrid,
        thermal_from_board,
        rgb_exposer,
        slots,
    }
}

/// Produces frames in real time until `stop` or the duration ends: the thermal stream, the
/// RGB stream and the thermal renderer each run in their own thread (two cores serve a Boson
/// at 60 Hz and 720p MJPEG at 30 Hz in the dev build; see firmware-sim/README.md `run`).
pub(super) fn frame_loop(
    cfg: &ServeConfig,
    profile: ThermalProfile,
    shared: &Mutex<Shared>,
    clients: &Mutex<Vec<UnixStream>>,
    stop: &AtomicBool,
    prepared: Prepared,
) -> Result<(), SimError> {
    let Prepared {
        tgrid,
        thermal_from_board,
        rgb_exposer,
        slots,
    } = prepared;
    let end = cfg
        .duration_s
        .map(|d| Instant::now() + Duration::from_secs_f64(d));
    let streams = Streams {
        cfg,
        shared,
        clients,
        stop,
        end,
    };
    streams.wait_for_first_client();
    let start = Instant::now();
    let start_mono_ns = monotonic_ns();
    let thermal_pacer = Pacer {
        start,
        start_mono_ns,
        period_ns: 1e9 / profile.rate_hz,
        phase_ns: 0,
    };
    thread::scope(|scope| -> Result<(), SimError> {
        // Renderer: the image of epoch k+1 from the board as it was when epoch k began (the
        // thermal stream hands it over), so the frames do not depend on thread timing.
        let (to_renderer, renderer_rx) = std::sync::mpsc::channel::<RenderJob>();
        let (slots_r, tgrid_r, pose_r) = (&slots, &tgrid, &thermal_from_board);
        let renderer =
            scope.spawn(move || render_epochs(renderer_rx, slots_r, &profile, tgrid_r, pose_r));
        let rgb = rgb_exposer
            .as_ref()
            .zip(cfg.rgb.as_ref())
            .map(|(exposer, r)| {
                // RGB exposures are a quarter frame (of 60 Hz) after the thermal ones, so the
                // pairing has a sync error to report.
                let pacer = Pacer {
                    start,
                    start_mono_ns,
                    period_ns: 1e9 / r.rate_hz,
                    phase_ns: 4_166_667,
                };
                scope.spawn(move || streams.rgb(exposer, r, pacer))
            });
        // Thermal stream, on this thread.
        streams.thermal(&profile, thermal_pacer, &slots, &to_renderer);
        // Stop the renderer (and RGB, if the thermal stream ended first).
        stop.store(true, Ordering::Relaxed);
        drop(to_renderer);
        let _ = renderer.join();
        match rgb.map(|h| h.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(SimError::Encode {
                what: "RGB stream",
                reason: "the RGB thread panicked".into(),
            }),
            None => Ok(()),
        }
    })
}

/// What the thermal stream hands the renderer: the epoch to render, the board and the
/// radiometry as they were when the epoch before it began.
type RenderJob = (u64, BoardThermal, crate::physics::Radiometry);

/// Renders each epoch's radiance as the thermal stream asks for it, keeping the two latest
/// in `slots`; returns when the thermal stream drops its sender.
fn render_epochs(
    jobs: std::sync::mpsc::Receiver<RenderJob>,
    slots: &RadianceSlots,
    profile: &ThermalProfile,
    tgrid: &RayGrid,
    thermal_from_board: &Rigid3,
) {
    while let Ok((epoch, board, radiometry)) = jobs.recv() {
        let img = render_radiance(&board, &radiometry, profile, tgrid, thermal_from_board);
        let mut sl = slots
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        sl.insert(epoch, Arc::new(img));
        while sl.len() > 2 {
            sl.pop_first();
        }
    }
}

/// What both streams share: the configuration, the rig's state, the socket's clients, and
/// when to stop.
#[derive(Clone, Copy)]
struct Streams<'a> {
    cfg: &'a ServeConfig,
    shared: &'a Mutex<Shared>,
    clients: &'a Mutex<Vec<UnixStream>>,
    stop: &'a AtomicBool,
    end: Option<Instant>,
}

impl Streams<'_> {
    /// Waits for the first client: streaming starts when it connects (as V4L2 streaming
    /// starts on STREAMON), so a recorder gets both streams from their first frame.
    fn wait_for_first_client(&self) {
        while self
            .clients
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .is_empty()
            && !self.stop.load(Ordering::Relaxed)
            && self.end.is_none_or(|e| Instant::now() < e)
        {
            thread::sleep(Duration::from_millis(2));
        }
    }

    /// The RGB stream: exposes the board image (noise) at every due time, encodes it as
    /// `cfg.rgb_format` and broadcasts it, until the stream's clock ends.
    fn rgb(
        &self,
        exposer: &StaticRgbExposer,
        r: &RgbProfile,
        pacer: Pacer,
    ) -> Result<(), SimError> {
        let cfg = self.cfg;
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x0052_4742);
        let (rw, rh) = (r.camera.width_px, r.camera.height_px);
        let mut stats = StreamStats::default();
        let mut n = 0u64;
        let mut clock = StreamClock::new(pacer, TRIGGER_LATENCY_NS[1], cfg.seed ^ 0x0052_4A54);
        while let Some(stamp_ns) = clock.next(self.shared, self.stop, self.end, &mut stats) {
            let rgb = exposer.expose(&mut rng);
            let (fourcc, payload, bpl) = match cfg.rgb_format {
                RgbFormat::Mjpeg => (FourCc::MJPG, rgb_to_jpeg(&rgb, rw, rh)?, 0),
                RgbFormat::Yuyv => (
                    FourCc::YUYV,
                    rgb_to_yuyv(&rgb, rw as usize, rh as usize),
                    rw * 2,
                ),
            };
            let frame = WireFrame {
                stream: StreamId::Rgb,
                flags: 0,
                fourcc,
                width: rw,
                height: rh,
                bytes_per_line: bpl,
                sequence: n as u32,
                monotonic_ns: stamp_ns,
                payload,
            };
            broadcast(self.clients, &frame, &cfg.socket);
            n += 1;
        }
        stats.log("rgb");
        Ok(())
    }

    /// The thermal stream: at every due time advances the board's heat model by one frame,
    /// senses the epoch's radiance image (asking the renderer for the next epoch's at each
    /// epoch start) and broadcasts the frame, until the stream's clock ends.
    fn thermal(
        &self,
        profile: &ThermalProfile,
        pacer: Pacer,
        slots: &RadianceSlots,
        to_renderer: &std::sync::mpsc::Sender<RenderJob>,
    ) {
        let mut stats = StreamStats::default();
        let mut n = 0u64;
        let frames_per_epoch = (profile.rate_hz * RENDER_EPOCH_S).round().max(1.0) as u64;
        let frame_s = 1.0 / profile.rate_hz;
        let mut clock = StreamClock::new(pacer, TRIGGER_LATENCY_NS[0], self.cfg.seed ^ 0x0054_4A54);
        while let Some(stamp_ns) = clock.next(self.shared, self.stop, self.end, &mut stats) {
            let epoch = n / frames_per_epoch;
            // The image of this epoch, or the latest one when the renderer is behind.
            let img = {
                let sl = slots
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                sl.range(..=epoch).next_back().map(|(_, v)| v.clone())
            };
            let Some(img) = img else {
                n += 1;
                continue;
            };
            let out = {
                let mut s = lock(self.shared);
                // The heat model runs in sensor time (the controller's setpoint acts on it).
                s.board.advance(frame_s);
                if n.is_multiple_of(frames_per_epoch) {
                    let _ = to_renderer.send((
                        epoch + 1,
                        s.board.clone(),
                        s.sensor.radiometry().clone(),
                    ));
                }
                s.sensor.next_frame_fast(&img)
            };
            if let ThermalOutput::Frame(f) = out {
                let frame = thermal_wire_frame(profile, &f, stamp_ns);
                broadcast(self.clients, &frame, &self.cfg.socket);
            }
            n += 1;
        }
        stats.log("thermal");
    }
}

/// A sensed thermal frame as the simwire carries it: Y16 little-endian words, flagged for
/// FFC, telemetry rows and TLinear units.
fn thermal_wire_frame(
    profile: &ThermalProfile,
    f: &ThermalSensorFrame,
    stamp_ns: u64,
) -> WireFrame {
    let w = profile.camera.width_px;
    let mut flags = 0;
    if f.ffc_frozen {
        flags |= simwire::FLAG_FFC_FROZEN;
    }
    if profile.telemetry_rows > 0 {
        flags |= simwire::FLAG_TELEMETRY;
    }
    if profile.units == ThermalUnits::CentiKelvin {
        flags |= simwire::FLAG_TLINEAR;
    }
    let mut payload = Vec::with_capacity(f.words.len() * 2);
    for v in &f.words {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    WireFrame {
        stream: StreamId::Thermal,
        flags,
        fourcc: FourCc::Y16,
        width: w,
        height: profile.output_height(),
        bytes_per_line: w * 2,
        sequence: f.sequence,
        monotonic_ns: stamp_ns,
        payload,
    }
}
