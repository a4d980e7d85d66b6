//! `run`: the simulated rig in real time.
//!
//! - Frames (thermal, and RGB with `--rgb`) go to every client of a Unix stream socket in the
//!   simwire format (`s3tir_capture::simwire`), paced by the frame rate, timestamped with
//!   CLOCK_MONOTONIC.
//! - The Boson command firmware (FSLP) and the rig controller firmware each serve a
//!   pseudo-terminal. Running FFC over FSLP freezes the thermal stream for the profile's
//!   `ffc_frames`; the rig controller's board setpoint sets the temperature of the board's
//!   surroundings (a heater/cooler panel) and so drives the board heat model.
//! - The camera sees the emissivity board at a fixed pose 0.8 m in front of it. The board
//!   starts as in the TGA-GS induction: at 25 °C, surroundings at the ambient −20 °C.
//!
//! Stops on SIGINT/SIGTERM (when `handle_signals`), stdin EOF (when `stop_on_stdin_eof` and
//! stdin is a pipe or socket, i.e. a parent process holds it), the `stop` flag, or after
//! `duration_s`.

use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread;
use std::time::{Duration, Instant};

use glam::{DQuat, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use s3tir_calib::Rigid3;
use s3tir_capture::device::FourCc;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::fslp::{self, FfcModeCode, FfcStateCode, FslpPacket, FslpStreamDecoder};
use s3tir_capture::rig_protocol::{
    self, RigFrame, RigMessage, RigStatus, RigStreamDecoder, TriggerEvent, nack_code,
};
use s3tir_capture::simwire::{self, StreamId, WireFrame};

use crate::board::{BoardSpec, BoardThermal};
use crate::error::SimError;
use crate::physics::ZERO_CELSIUS_K;
use crate::render::{RayGrid, gaussian_blur, render_plane};
use crate::rig::{
    BACKGROUND_REFLECTANCE, Rig, SUBPIXELS, ThermalBoardTexture, VisibleBoardTexture,
};
use crate::sensor::{
    RgbProfile, ThermalOutput, ThermalProfile, ThermalSensor, expose_rgb, rgb_to_jpeg, rgb_to_yuyv,
};

/// The simulated core's serial number (GET_SERIAL).
pub const SIM_SERIAL: u32 = 0x0005_3354;
/// Ambient temperature around the board when the heater/cooler is off, kelvin.
pub const AMBIENT_K: f64 = ZERO_CELSIUS_K - 20.0;

/// RGB output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RgbFormat {
    Mjpeg,
    Yuyv,
}

/// How to run.
#[derive(Debug, Clone)]
pub struct ServeConfig {
    pub thermal: ThermalProfile,
    pub rgb: Option<RgbProfile>,
    pub rgb_format: RgbFormat,
    pub socket: PathBuf,
    pub duration_s: Option<f64>,
    pub seed: u64,
    /// Stop when stdin reaches EOF (the parent process closed it or died).
    pub stop_on_stdin_eof: bool,
    /// Block SIGINT/SIGTERM and stop cleanly when one arrives (binary only: it changes the
    /// process's signal mask).
    pub handle_signals: bool,
    /// External stop flag (tests).
    pub stop: Arc<AtomicBool>,
}

/// CLOCK_MONOTONIC in nanoseconds.
pub fn monotonic_ns() -> u64 {
    match nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC) {
        Ok(ts) => (ts.tv_sec() as u64).saturating_mul(1_000_000_000) + ts.tv_nsec() as u64,
        Err(_) => 0,
    }
}

/// True when stdin is a pipe or socket (a parent process holds its other end). Stdin EOF
/// only means "stop" then: a rig started with stdin from /dev/null or a file keeps running.
fn stdin_is_pipe() -> bool {
    use std::os::unix::fs::FileTypeExt;
    std::fs::metadata("/proc/self/fd/0")
        .map(|m| m.file_type().is_fifo() || m.file_type().is_socket())
        .unwrap_or(false)
}

/// State of the rig controller firmware.
#[derive(Debug)]
struct Controller {
    running: bool,
    rate_mhz: u32,
    count: u32,
    /// Monotonic time of the next pulse.
    next_pulse_ns: u64,
    events: std::collections::VecDeque<TriggerEvent>,
    setpoint_ck: u16,
    boot_ns: u64,
}

const MAX_EVENT_LOG: usize = 4096;

impl Controller {
    fn update(&mut self, now_ns: u64) {
        if !self.running || self.rate_mhz == 0 {
            return;
        }
        let period_ns = (1e12 / f64::from(self.rate_mhz)) as u64;
        while self.next_pulse_ns <= now_ns {
            self.count = self.count.wrapping_add(1);
            self.events.push_back(TriggerEvent {
                count: self.count,
                time_ns: self.next_pulse_ns - self.boot_ns,
            });
            if self.events.len() > MAX_EVENT_LOG {
                self.events.pop_front();
            }
            self.next_pulse_ns += period_ns.max(1);
        }
    }
}

/// Everything the threads share.
#[derive(Debug)]
struct Shared {
    sensor: ThermalSensor,
    board: BoardThermal,
    controller: Controller,
    ffc_mode: FfcModeCode,
    auto_ffc_period_s: f64,
}

fn lock(m: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    // A panicking thread leaves consistent data behind (all updates are single assignments).
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Handles one FSLP request; returns the reply.
fn handle_fslp(shared: &Mutex<Shared>, req: &FslpPacket) -> FslpPacket {
    use fslp::{command, status};
    let mut s = lock(shared);
    let need = |n: usize| -> Result<(), u32> {
        match req.payload.len() {
            l if l < n => Err(status::INSUFFICIENT_BYTES),
            l if l > n => Err(status::EXCESS_BYTES),
            _ => Ok(()),
        }
    };
    let result: Result<Vec<u8>, u32> = match req.command {
        command::GET_SERIAL => need(0).map(|()| SIM_SERIAL.to_be_bytes().to_vec()),
        command::RUN_FFC => need(0).map(|()| {
            s.sensor.request_ffc();
            Vec::new()
        }),
        command::GET_FFC_STATE => need(0).map(|()| {
            let st = if s.sensor.ffc_in_progress() {
                FfcStateCode::InProgress
            } else if s.sensor.ffc_ever() {
                FfcStateCode::Complete
            } else {
                FfcStateCode::NeverCommanded
            };
            (st as u32).to_be_bytes().to_vec()
        }),
        command::SET_FFC_MODE => need(4).and_then(|()| {
            let v = u32::from_be_bytes([
                req.payload[0],
                req.payload[1],
                req.payload[2],
                req.payload[3],
            ]);
            let mode = FfcModeCode::from_u32(v).ok_or(status::BAD_PAYLOAD)?;
            s.ffc_mode = mode;
            s.sensor.profile.auto_ffc_period_s = if mode == FfcModeCode::Auto {
                s.auto_ffc_period_s
            } else {
                0.0
            };
            Ok(Vec::new())
        }),
        command::GET_FFC_MODE => need(0).map(|()| (s.ffc_mode as u32).to_be_bytes().to_vec()),
        command::GET_FPA_TEMP => need(0).map(|()| {
            let deci_c = ((s.sensor.fpa_temp_k - ZERO_CELSIUS_K) * 10.0).round() as i16;
            deci_c.to_be_bytes().to_vec()
        }),
        _ => Err(status::BAD_COMMAND),
    };
    match result {
        Ok(payload) => req.reply(status::OK, payload),
        Err(code) => req.reply(code, Vec::new()),
    }
}

/// Handles one rig-controller request; returns the reply.
fn handle_rig(shared: &Mutex<Shared>, req: &RigFrame) -> RigFrame {
    let mut s = lock(shared);
    let now = monotonic_ns();
    s.controller.update(now);
    let t = req.message.type_byte();
    let nack = |code| RigMessage::Nack {
        request_type: t,
        code,
    };
    let reply = match &req.message {
        RigMessage::GetStatus => RigMessage::Status(RigStatus {
            trigger_running: s.controller.running,
            trigger_rate_mhz: if s.controller.running {
                s.controller.rate_mhz
            } else {
                0
            },
            trigger_count: s.controller.count,
            board_setpoint_ck: s.controller.setpoint_ck,
            board_temp_ck: (s.board.mean_uncoated_temp_k() * 100.0).round() as u16,
            ambient_ck: (AMBIENT_K * 100.0).round() as u16,
            uptime_ns: now.saturating_sub(s.controller.boot_ns),
        }),
        RigMessage::StartTrigger { rate_mhz } => {
            if (100..=240_000).contains(rate_mhz) {
                let c = &mut s.controller;
                c.running = true;
                c.rate_mhz = *rate_mhz;
                c.next_pulse_ns = now;
                RigMessage::Ack { request_type: t }
            } else {
                nack(nack_code::OUT_OF_RANGE)
            }
        }
        RigMessage::StopTrigger => {
            s.controller.running = false;
            RigMessage::Ack { request_type: t }
        }
        RigMessage::GetTriggers { since_count } => {
            let events: Vec<TriggerEvent> = s
                .controller
                .events
                .iter()
                .filter(|e| e.count > *since_count)
                .take(rig_protocol::MAX_TRIGGER_EVENTS)
                .copied()
                .collect();
            RigMessage::Triggers {
                total_count: s.controller.count,
                events,
            }
        }
        RigMessage::SetBoardSetpoint { setpoint_ck } => {
            if *setpoint_ck == 0 || (23_315..=37_315).contains(setpoint_ck) {
                s.controller.setpoint_ck = *setpoint_ck;
                s.board.env_k = if *setpoint_ck == 0 {
                    AMBIENT_K
                } else {
                    f64::from(*setpoint_ck) / 100.0
                };
                RigMessage::Ack { request_type: t }
            } else {
                nack(nack_code::OUT_OF_RANGE)
            }
        }
        // Replies sent to the controller are not requests.
        _ => nack(nack_code::UNKNOWN_TYPE),
    };
    RigFrame::new(req.seq, reply)
}

/// A pseudo-terminal: the master we serve and the slave a client opens by path.
struct Pty {
    master: OwnedFd,
    /// Kept open so the master does not see EIO while no client has the slave open.
    _slave: OwnedFd,
    path: PathBuf,
}

fn open_pty(what: &'static str) -> Result<Pty, SimError> {
    let err = |e: nix::Error| SimError::Io {
        path: PathBuf::from("/dev/ptmx"),
        what,
        source: std::io::Error::from(e),
    };
    let pair = nix::pty::openpty(None, None).map_err(err)?;
    // Raw mode: bytes pass unchanged (no echo, no CR/LF translation).
    let mut tio = nix::sys::termios::tcgetattr(pair.slave.as_fd()).map_err(err)?;
    nix::sys::termios::cfmakeraw(&mut tio);
    nix::sys::termios::tcsetattr(pair.slave.as_fd(), nix::sys::termios::SetArg::TCSANOW, &tio)
        .map_err(err)?;
    let path = nix::unistd::ttyname(pair.slave.as_fd()).map_err(err)?;
    Ok(Pty {
        master: pair.master,
        _slave: pair.slave,
        path,
    })
}

/// Serves one pty until `stop`: reads bytes, hands them to `on_bytes`, writes its output.
fn pty_loop(pty: Pty, stop: Arc<AtomicBool>, mut on_bytes: impl FnMut(&[u8]) -> Vec<u8>) {
    let mut file = std::fs::File::from(pty.master);
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let ready = {
            let mut fds = [nix::poll::PollFd::new(
                file.as_fd(),
                nix::poll::PollFlags::POLLIN,
            )];
            nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(50u16)).unwrap_or(0)
        };
        if ready <= 0 {
            continue;
        }
        match file.read(&mut buf) {
            Ok(0) => thread::sleep(Duration::from_millis(20)),
            Ok(n) => {
                let out = on_bytes(&buf[..n]);
                if !out.is_empty()
                    && let Err(e) = file.write_all(&out)
                {
                    tracing::warn!(pty = %pty.path.display(), "write failed: {e}");
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => thread::sleep(Duration::from_millis(20)),
        }
    }
}

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
            tracing::info!("client left {peer}: {e}");
            false
        }
    });
}

/// Runs the rig until stopped. `announce(key, value)` receives the `key: value` lines
/// (`socket`, `fslp_pty`, `rig_pty`, `thermal`, `rgb`, `ready`).
pub fn serve(cfg: ServeConfig, announce: &mut dyn FnMut(&str, &str)) -> Result<(), SimError> {
    let stop = cfg.stop.clone();
    if cfg.handle_signals {
        let mut set = nix::sys::signal::SigSet::empty();
        set.add(nix::sys::signal::Signal::SIGINT);
        set.add(nix::sys::signal::Signal::SIGTERM);
        set.thread_block().map_err(|e| SimError::Io {
            path: PathBuf::from("<signals>"),
            what: "block SIGINT/SIGTERM",
            source: e.into(),
        })?;
        let stop = stop.clone();
        // Detached: it lives until a signal arrives or the process exits.
        thread::spawn(move || {
            if let Ok(sig) = set.wait() {
                tracing::info!("{sig:?}: stopping");
            }
            stop.store(true, Ordering::Relaxed);
        });
    }
    if cfg.stop_on_stdin_eof && stdin_is_pipe() {
        let stop = stop.clone();
        thread::spawn(move || {
            let mut sink = [0u8; 256];
            let mut stdin = std::io::stdin();
            while let Ok(n) = stdin.read(&mut sink) {
                if n == 0 {
                    break;
                }
            }
            tracing::info!("stdin closed: stopping");
            stop.store(true, Ordering::Relaxed);
        });
    }
    if cfg.socket.exists() {
        std::fs::remove_file(&cfg.socket).map_err(|source| SimError::Io {
            path: cfg.socket.clone(),
            what: "remove stale socket",
            source,
        })?;
    }
    let listener = UnixListener::bind(&cfg.socket).map_err(|source| SimError::Io {
        path: cfg.socket.clone(),
        what: "bind",
        source,
    })?;
    listener
        .set_nonblocking(true)
        .map_err(|source| SimError::Io {
            path: cfg.socket.clone(),
            what: "set non-blocking",
            source,
        })?;
    let fslp_pty = open_pty("open FSLP pty")?;
    let rig_pty = open_pty("open rig controller pty")?;

    let board_spec = BoardSpec::default();
    let mut profile = cfg.thermal;
    let auto_ffc_period_s = profile.auto_ffc_period_s;
    profile.auto_ffc_period_s = if auto_ffc_period_s > 0.0 {
        auto_ffc_period_s
    } else {
        0.0
    };
    let boot_ns = monotonic_ns();
    let shared = Arc::new(Mutex::new(Shared {
        sensor: ThermalSensor::new(profile, cfg.seed),
        board: BoardThermal::new(
            board_spec,
            Default::default(),
            ZERO_CELSIUS_K + 25.0,
            AMBIENT_K,
        ),
        controller: Controller {
            running: false,
            rate_mhz: 0,
            count: 0,
            next_pulse_ns: boot_ns,
            events: Default::default(),
            setpoint_ck: 0,
            boot_ns,
        },
        ffc_mode: if auto_ffc_period_s > 0.0 {
            FfcModeCode::Auto
        } else {
            FfcModeCode::Manual
        },
        auto_ffc_period_s,
    }));

    announce("socket", &cfg.socket.display().to_string());
    announce("fslp_pty", &fslp_pty.path.display().to_string());
    announce("rig_pty", &rig_pty.path.display().to_string());
    let c = profile.camera;
    announce(
        "thermal",
        &format!(
            "{} {}x{} Y16 {} Hz",
            profile.name,
            c.width_px,
            profile.output_height(),
            profile.rate_hz
        ),
    );
    if let Some(r) = &cfg.rgb {
        let f = match cfg.rgb_format {
            RgbFormat::Mjpeg => "MJPG",
            RgbFormat::Yuyv => "YUYV",
        };
        announce(
            "rgb",
            &format!(
                "{}x{} {f} {} Hz",
                r.camera.width_px, r.camera.height_px, r.rate_hz
            ),
        );
    }

    let mut threads = Vec::new();
    {
        let (shared, stop) = (shared.clone(), stop.clone());
        threads.push(thread::spawn(move || {
            let mut dec = FslpStreamDecoder::new();
            pty_loop(fslp_pty, stop, |bytes| {
                let mut out = Vec::new();
                for r in dec.push(bytes) {
                    match r {
                        Ok(req) if req.is_request() => {
                            let reply = handle_fslp(&shared, &req);
                            tracing::debug!("FSLP {req} -> {reply}");
                            match reply.encode() {
                                Ok(b) => out.extend(b),
                                Err(e) => tracing::warn!("FSLP reply not encodable: {e}"),
                            }
                        }
                        Ok(other) => tracing::debug!("FSLP: ignoring non-request {other}"),
                        // A real Boson drops malformed packets without a reply.
                        Err(e) => tracing::warn!("FSLP: dropped malformed packet: {e}"),
                    }
                }
                out
            });
        }));
    }
    {
        let (shared, stop) = (shared.clone(), stop.clone());
        threads.push(thread::spawn(move || {
            let mut dec = RigStreamDecoder::new();
            pty_loop(rig_pty, stop, |bytes| {
                let mut out = Vec::new();
                for r in dec.push(bytes) {
                    match r {
                        Ok(req) => match handle_rig(&shared, &req).encode() {
                            Ok(b) => out.extend(b),
                            Err(e) => tracing::warn!("rig reply not encodable: {e}"),
                        },
                        Err(e) => tracing::warn!("rig controller: dropped malformed frame: {e}"),
                    }
                }
                out
            });
        }));
    }
    let clients: Arc<Mutex<Vec<UnixStream>>> = Arc::default();
    {
        let (clients, stop) = (clients.clone(), stop.clone());
        threads.push(thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((stream, _)) => {
                        let _ = stream.set_write_timeout(Some(Duration::from_millis(500)));
                        clients
                            .lock()
                            .unwrap_or_else(std::sync::PoisonError::into_inner)
                            .push(stream);
                    }
                    Err(_) => thread::sleep(Duration::from_millis(10)),
                }
            }
        }));
    }
    announce("ready", "1");

    let result = frame_loop(&cfg, profile, &shared, &clients, &stop);
    stop.store(true, Ordering::Relaxed);
    for t in threads {
        let _ = t.join();
    }
    let _ = std::fs::remove_file(&cfg.socket);
    result
}

/// Produces frames in real time until `stop` or the duration ends.
fn frame_loop(
    cfg: &ServeConfig,
    profile: ThermalProfile,
    shared: &Mutex<Shared>,
    clients: &Mutex<Vec<UnixStream>>,
    stop: &AtomicBool,
) -> Result<(), SimError> {
    let rig = Rig::new(profile, cfg.rgb.unwrap_or_else(RgbProfile::hd720));
    let thermal_from_board = run_board_pose(&BoardSpec::default());
    let tgrid = RayGrid::new(&profile.camera);
    let rgb_cache = match &cfg.rgb {
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
            Some(gaussian_blur(
                &img,
                grid.width(),
                grid.height(),
                r.psf_sigma_px,
            ))
        }
        None => None,
    };
    let mut rgb_rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x0052_4742);
    let start = Instant::now();
    let thermal_period = Duration::from_secs_f64(1.0 / profile.rate_hz);
    let rgb_period = cfg.rgb.map(|r| Duration::from_secs_f64(1.0 / r.rate_hz));
    let mut next_thermal = start;
    let mut next_rgb = start;
    let mut rgb_seq: u32 = 0;
    let mut radiance_cache: Option<(f64, Vec<f64>)> = None;
    let mut last_board_s = 0.0;
    let w = profile.camera.width_px;
    let (w_us, h_us) = (tgrid.width(), tgrid.height());
    while !stop.load(Ordering::Relaxed) {
        let elapsed = start.elapsed().as_secs_f64();
        if cfg.duration_s.is_some_and(|d| elapsed >= d) {
            break;
        }
        let now = Instant::now();
        if now >= next_thermal {
            next_thermal += thermal_period;
            if next_thermal + thermal_period < now {
                // Rendering cannot keep up (a large profile in a debug build): run slower
                // rather than bursting.
                next_thermal = now + thermal_period;
            }
            let mut s = lock(shared);
            s.board.advance(elapsed - last_board_s);
            last_board_s = elapsed;
            s.controller.update(monotonic_ns());
            // The board changes slowly: re-render its radiance at most every 0.5 s.
            let stale = radiance_cache
                .as_ref()
                .is_none_or(|(t, _)| elapsed - t >= 0.5);
            if stale {
                let radiometry = s.sensor.radiometry().clone();
                let texture = ThermalBoardTexture {
                    thermal: &s.board,
                    radiometry: &radiometry,
                };
                let background = radiometry.radiance(s.board.env_k);
                let img =
                    render_plane(&tgrid, &thermal_from_board, SUBPIXELS, &texture, background);
                radiance_cache = Some((
                    elapsed,
                    gaussian_blur(&img, w_us, h_us, profile.psf_sigma_px),
                ));
            }
            let out = match &radiance_cache {
                Some((_, img)) => s.sensor.next_frame(img),
                None => continue,
            };
            drop(s);
            if let ThermalOutput::Frame(f) = out {
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
                let frame = WireFrame {
                    stream: StreamId::Thermal,
                    flags,
                    fourcc: FourCc::Y16,
                    width: w,
                    height: profile.output_height(),
                    bytes_per_line: w * 2,
                    sequence: f.sequence,
                    monotonic_ns: monotonic_ns(),
                    payload: f.words.iter().flat_map(|v| v.to_le_bytes()).collect(),
                };
                broadcast(clients, &frame, &cfg.socket);
            }
        }
        if let (Some(r), Some(period), Some(img)) = (&cfg.rgb, rgb_period, &rgb_cache)
            && Instant::now() >= next_rgb
        {
            next_rgb += period;
            let (rw, rh) = (r.camera.width_px, r.camera.height_px);
            let rgb = expose_rgb(r, img, [1.0, 0.97, 0.92], &mut rgb_rng);
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
                sequence: rgb_seq,
                monotonic_ns: monotonic_ns(),
                payload,
            };
            rgb_seq = rgb_seq.wrapping_add(1);
            broadcast(clients, &frame, &cfg.socket);
            // If we fell more than a frame behind, skip the missed slots (dropped frames).
            while next_rgb + period < Instant::now() {
                next_rgb += period;
                rgb_seq = rgb_seq.wrapping_add(1);
            }
        }
        let next = match rgb_period {
            Some(_) if rgb_cache.is_some() => next_thermal.min(next_rgb),
            _ => next_thermal,
        };
        let now = Instant::now();
        if next > now {
            thread::sleep((next - now).min(Duration::from_millis(20)));
        }
    }
    Ok(())
}
