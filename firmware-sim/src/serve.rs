//! `run`: the simulated rig in real time.
//!
//! - Frames (thermal, and RGB with `--rgb`) go to every client of a Unix stream socket in the
//!   simwire format (`s3tir_capture::simwire`) from the first client's connection on, paced
//!   by frame sequence (`Pacer`: stamped on CLOCK_MONOTONIC at their due time, sent late
//!   rather than skipped when the machine is loaded), each stream in its own thread; while
//!   the rig controller's trigger runs, every pulse triggers one frame of each camera
//!   (`StreamClock`).
//! - The Boson command firmware (FSLP) and the rig controller firmware each serve a
//!   pseudo-terminal. Running FFC over FSLP freezes the thermal stream for the profile's
//!   `ffc_frames`; the rig controller's board setpoint sets the temperature of the board's
//!   surroundings (a heater/cooler panel) and so drives the board heat model. The controller
//!   keeps its own clock ([`CONTROLLER_DRIFT_PPM`] fast, offset by
//!   [`CONTROLLER_CLOCK_AT_START_NS`]).
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
use rand::{Rng, SeedableRng};
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
    LinearizedRadiance, RgbProfile, StaticRgbExposer, ThermalOutput, ThermalProfile, ThermalSensor,
    rgb_to_jpeg, rgb_to_yuyv,
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

/// The rig controller's crystal runs this much fast against the host clock, ppm (a typical
/// 20–50 ppm part): its trigger timestamps must be mapped to the camera clock, never taken as
/// host time.
pub const CONTROLLER_DRIFT_PPM: f64 = 37.0;
/// The controller's clock reads this when the simulator starts (it booted earlier), ns.
pub const CONTROLLER_CLOCK_AT_START_NS: u64 = 123_456_789_012;
/// While the trigger runs, each pulse exposes one frame per camera this long after the pulse
/// edge (thermal, RGB), nanoseconds, with a uniform jitter of ± [`TRIGGER_JITTER_NS`] from
/// the seeded generator: the stamp the camera reports.
pub const TRIGGER_LATENCY_NS: [u64; 2] = [350_000, 120_000];
/// See [`TRIGGER_LATENCY_NS`].
pub const TRIGGER_JITTER_NS: u64 = 25_000;

/// State of the rig controller firmware.
#[derive(Debug)]
struct Controller {
    running: bool,
    rate_mhz: u32,
    count: u32,
    /// Controller-clock time of the next pulse (pulses are exact multiples of the period on
    /// the controller's own clock).
    next_pulse_ctrl_ns: u64,
    events: std::collections::VecDeque<TriggerEvent>,
    setpoint_ck: u16,
    boot_ns: u64,
}

const MAX_EVENT_LOG: usize = 4096;

impl Controller {
    /// The controller's clock at host monotonic time `mono_ns`.
    fn ctrl_ns(&self, mono_ns: u64) -> u64 {
        let dt = mono_ns.saturating_sub(self.boot_ns) as f64;
        CONTROLLER_CLOCK_AT_START_NS + (dt * (1.0 + CONTROLLER_DRIFT_PPM * 1e-6)).round() as u64
    }

    /// The host monotonic time at which the controller's clock reads `ctrl_ns`.
    fn mono_ns(&self, ctrl_ns: u64) -> u64 {
        let dc = ctrl_ns.saturating_sub(CONTROLLER_CLOCK_AT_START_NS) as f64;
        self.boot_ns + (dc / (1.0 + CONTROLLER_DRIFT_PPM * 1e-6)).round() as u64
    }

    fn start(&mut self, rate_mhz: u32, now_mono_ns: u64) {
        self.running = true;
        self.rate_mhz = rate_mhz;
        self.next_pulse_ctrl_ns = self.ctrl_ns(now_mono_ns);
    }

    fn update(&mut self, now_mono_ns: u64) {
        if !self.running || self.rate_mhz == 0 {
            return;
        }
        let period_ns = ((1e12 / f64::from(self.rate_mhz)) as u64).max(1);
        let now = self.ctrl_ns(now_mono_ns);
        while self.next_pulse_ctrl_ns <= now {
            self.count = self.count.wrapping_add(1);
            self.events.push_back(TriggerEvent {
                count: self.count,
                time_ns: self.next_pulse_ctrl_ns,
            });
            if self.events.len() > MAX_EVENT_LOG {
                self.events.pop_front();
            }
            self.next_pulse_ctrl_ns += period_ns;
        }
    }

    /// The host monotonic time of pulse `count`, if it has happened and is still logged.
    fn pulse_mono_ns(&self, count: u32) -> Option<u64> {
        let first = self.events.front()?.count;
        let e = self.events.get(count.wrapping_sub(first) as usize)?;
        (e.count == count).then(|| self.mono_ns(e.time_ns))
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
            // The controller's own clock (the one its trigger timestamps use).
            uptime_ns: s.controller.ctrl_ns(now),
        }),
        RigMessage::StartTrigger { rate_mhz } => {
            if (100..=240_000).contains(rate_mhz) {
                s.controller.start(*rate_mhz, now);
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

/// Sets up what stops the rig (signals when `handle_signals`, stdin EOF when
/// `stop_on_stdin_eof` and stdin is a pipe): returns the stop flag they set.
pub fn watch_stop(cfg: &ServeConfig) -> Result<Arc<AtomicBool>, SimError> {
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
    Ok(stop)
}

/// Runs the rig until stopped. `announce(key, value)` receives the `key: value` lines
/// (`socket`, `fslp_pty`, `rig_pty`, `thermal`, `rgb`, `ready`).
pub fn serve(cfg: ServeConfig, announce: &mut dyn FnMut(&str, &str)) -> Result<(), SimError> {
    let stop = watch_stop(&cfg)?;
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
            next_pulse_ctrl_ns: 0,
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

    // Render what the first frames need before clients can connect.
    let prepared = prepare(&cfg, profile, &shared);
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
                        // A client that reads nothing for 2 s is dropped (a frame half-written
                        // cannot be resumed); a recorder that is merely slow is not.
                        let _ = stream.set_write_timeout(Some(Duration::from_secs(2)));
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

    let result = frame_loop(&cfg, profile, &shared, &clients, &stop, prepared);
    stop.store(true, Ordering::Relaxed);
    for t in threads {
        let _ = t.join();
    }
    let _ = std::fs::remove_file(&cfg.socket);
    result
}

/// Sequence pacing of one stream: frame `n` is due at `start + phase + n·period` and stamped
/// with the CLOCK_MONOTONIC time of that instant (the moment of exposure), whenever it is
/// actually sent. A stream that falls behind (a loaded machine) sends its late frames as soon
/// as it can, in order, and never skips a sequence number for being late: a sequence gap in
/// what a client receives is a frame the sensor model dropped (`drop_probability`) or one the
/// client failed to read in time, never simulator lateness. Lateness is counted instead and
/// logged at exit ([`StreamStats`]).
#[derive(Debug, Clone, Copy)]
struct Pacer {
    start: Instant,
    start_mono_ns: u64,
    period_ns: f64,
    phase_ns: u64,
}

impl Pacer {
    fn offset_ns(&self, n: u64) -> u64 {
        self.phase_ns + (n as f64 * self.period_ns).round() as u64
    }

    fn due(&self, n: u64) -> Instant {
        self.start + Duration::from_nanos(self.offset_ns(n))
    }

    fn stamp_ns(&self, n: u64) -> u64 {
        self.start_mono_ns + self.offset_ns(n)
    }
}

/// When a stream's frames happen: free-running on its [`Pacer`], or, while the rig
/// controller's trigger runs, one frame per pulse, stamped at the pulse's host time plus the
/// camera's latency and jitter ([`TRIGGER_LATENCY_NS`]). When the trigger stops the stream
/// free-runs again from that moment.
#[derive(Debug)]
struct StreamClock {
    pacer: Pacer,
    n_free: u64,
    /// The next pulse this camera exposes on (while triggered).
    next_pulse: Option<u32>,
    latency_ns: u64,
    jitter: ChaCha8Rng,
}

impl StreamClock {
    fn new(pacer: Pacer, latency_ns: u64, seed: u64) -> Self {
        Self {
            pacer,
            n_free: 0,
            next_pulse: None,
            latency_ns,
            jitter: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Waits for the next frame and returns its stamp (CLOCK_MONOTONIC, ns); `None` when
    /// stopped (flag or duration) first. Records lateness in `stats`.
    fn next(
        &mut self,
        shared: &Mutex<Shared>,
        stop: &AtomicBool,
        end: Option<Instant>,
        stats: &mut StreamStats,
    ) -> Option<u64> {
        loop {
            if stop.load(Ordering::Relaxed) {
                return None;
            }
            let now = Instant::now();
            if end.is_some_and(|e| now >= e) {
                return None;
            }
            let triggered = {
                let mut s = lock(shared);
                let now_mono = monotonic_ns();
                s.controller.update(now_mono);
                let c = &s.controller;
                if c.running {
                    let mut want = *self.next_pulse.get_or_insert(c.count.wrapping_add(1));
                    // A camera that fell out of the controller's log skips to its oldest pulse
                    // (those triggers were missed: no frames, like a camera too busy to
                    // re-arm).
                    if let Some(first) = c.events.front().map(|e| e.count)
                        && (want.wrapping_sub(first) as i32) < 0
                    {
                        want = first;
                    }
                    self.next_pulse = Some(want);
                    let wait_ns = c
                        .mono_ns(c.next_pulse_ctrl_ns)
                        .saturating_sub(now_mono)
                        .clamp(200_000, 20_000_000);
                    Some((c.pulse_mono_ns(want).map(|m| (want, m)), now_mono, wait_ns))
                } else {
                    None
                }
            };
            match triggered {
                Some((Some((count, pulse_mono)), now_mono, _)) => {
                    self.next_pulse = Some(count.wrapping_add(1));
                    let lag = Duration::from_nanos(now_mono.saturating_sub(pulse_mono));
                    stats.frames += 1;
                    stats.max_lag = stats.max_lag.max(lag);
                    let j = self.jitter.random_range(0..=2 * TRIGGER_JITTER_NS);
                    return Some(pulse_mono + self.latency_ns + j - TRIGGER_JITTER_NS);
                }
                Some((None, _, wait_ns)) => {
                    thread::sleep(Duration::from_nanos(wait_ns));
                    continue;
                }
                None => {}
            }
            if self.next_pulse.take().is_some() {
                // The trigger stopped: free-run again from now.
                self.pacer.start = now;
                self.pacer.start_mono_ns = monotonic_ns();
                self.n_free = 0;
            }
            let due = self.pacer.due(self.n_free);
            if now >= due {
                let lag = now - due;
                stats.frames += 1;
                stats.max_lag = stats.max_lag.max(lag);
                if lag.as_nanos() as f64 > self.pacer.period_ns {
                    stats.late += 1;
                }
                let stamp = self.pacer.stamp_ns(self.n_free);
                self.n_free += 1;
                return Some(stamp);
            }
            thread::sleep((due - now).min(Duration::from_millis(20)));
        }
    }
}

/// What one stream did, logged when `run` ends.
#[derive(Debug, Default, Clone, Copy)]
struct StreamStats {
    frames: u64,
    /// Frames sent more than one period after they were due.
    late: u64,
    max_lag: Duration,
}

impl StreamStats {
    fn log(&self, stream: &str) {
        tracing::info!(
            "{stream}: {} frames, {} sent more than a frame period late, max lag {:.1} ms",
            self.frames,
            self.late,
            self.max_lag.as_secs_f64() * 1e3
        );
    }
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
struct Prepared {
    tgrid: RayGrid,
    thermal_from_board: Rigid3,
    rgb_exposer: Option<StaticRgbExposer>,
    slots: RadianceSlots,
}

fn prepare(cfg: &ServeConfig, profile: ThermalProfile, shared: &Mutex<Shared>) -> Prepared {
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
fn frame_loop(
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
    // Streaming starts when the first client connects (as V4L2 streaming starts on STREAMON):
    // a recorder gets both streams from their first frame.
    while clients
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .is_empty()
        && !stop.load(Ordering::Relaxed)
        && end.is_none_or(|e| Instant::now() < e)
    {
        thread::sleep(Duration::from_millis(2));
    }
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
        let (to_renderer, renderer_rx) =
            std::sync::mpsc::channel::<(u64, BoardThermal, crate::physics::Radiometry)>();
        let (slots_r, tgrid_r, pose_r) = (&slots, &tgrid, &thermal_from_board);
        let renderer = scope.spawn(move || {
            while let Ok((epoch, board, radiometry)) = renderer_rx.recv() {
                let img = render_radiance(&board, &radiometry, &profile, tgrid_r, pose_r);
                let mut sl = slots_r
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                sl.insert(epoch, Arc::new(img));
                while sl.len() > 2 {
                    sl.pop_first();
                }
            }
        });
        let rgb = rgb_exposer
            .as_ref()
            .zip(cfg.rgb.as_ref())
            .map(|(exposer, r)| {
                scope.spawn(move || -> Result<(), SimError> {
                    // RGB exposures are a quarter frame (of 60 Hz) after the thermal ones, so the
                    // pairing has a sync error to report.
                    let pacer = Pacer {
                        start,
                        start_mono_ns,
                        period_ns: 1e9 / r.rate_hz,
                        phase_ns: 4_166_667,
                    };
                    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x0052_4742);
                    let (rw, rh) = (r.camera.width_px, r.camera.height_px);
                    let mut stats = StreamStats::default();
                    let mut n = 0u64;
                    let mut clock =
                        StreamClock::new(pacer, TRIGGER_LATENCY_NS[1], cfg.seed ^ 0x0052_4A54);
                    while let Some(stamp_ns) = clock.next(shared, stop, end, &mut stats) {
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
                        broadcast(clients, &frame, &cfg.socket);
                        n += 1;
                    }
                    stats.log("rgb");
                    Ok(())
                })
            });
        // Thermal stream, on this thread.
        let w = profile.camera.width_px;
        let mut stats = StreamStats::default();
        let mut n = 0u64;
        let frames_per_epoch = (profile.rate_hz * RENDER_EPOCH_S).round().max(1.0) as u64;
        let frame_s = 1.0 / profile.rate_hz;
        let mut clock =
            StreamClock::new(thermal_pacer, TRIGGER_LATENCY_NS[0], cfg.seed ^ 0x0054_4A54);
        while let Some(stamp_ns) = clock.next(shared, stop, end, &mut stats) {
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
                let mut s = lock(shared);
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
                let frame = WireFrame {
                    stream: StreamId::Thermal,
                    flags,
                    fourcc: FourCc::Y16,
                    width: w,
                    height: profile.output_height(),
                    bytes_per_line: w * 2,
                    sequence: f.sequence,
                    monotonic_ns: stamp_ns,
                    payload,
                };
                broadcast(clients, &frame, &cfg.socket);
            }
            n += 1;
        }
        stats.log("thermal");
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
