//! `run`: the simulated rig in real time.
//!
//! - Frames (thermal, and RGB with `--rgb`) go to every client of a Unix stream socket in the
//!   simwire format (`s3tir_capture::wire::simwire`) from the first client's connection on, paced
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
//! Stops on the `stop` flag, stdin EOF (when `stop_on_stdin_eof` and stdin is a pipe or
//! socket, i.e. a parent process holds it), or after `duration_s`. Signals are the binary's
//! business: `s3tir-firmware-sim run` sets the `stop` flag on SIGINT/SIGTERM.
//!
//! **Modules** (private; their public constants are re-exported here): `firmware` (the Boson
//! FSLP command set and the rig controller: clock, trigger, board setpoint), `pty` (serving
//! them on pseudo-terminals), `clock` (when each stream's frames are due and how they are
//! stamped), `frames` (rendering, sensing and broadcasting the frames).

use std::io::Read;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::Duration;

use s3tir_capture::wire::fslp::FslpStreamDecoder;
use s3tir_capture::wire::rig_protocol::RigStreamDecoder;

use crate::board::BoardSpec;
use crate::error::SimError;
use crate::sensor::{RgbProfile, ThermalProfile, ThermalSensor};

mod clock;
mod firmware;
mod frames;
mod pty;

pub use firmware::{
    AMBIENT_K, CONTROLLER_CLOCK_AT_START_NS, CONTROLLER_DRIFT_PPM, SIM_SERIAL, TRIGGER_JITTER_NS,
    TRIGGER_LATENCY_NS,
};
use firmware::{Shared, handle_fslp, handle_rig};
use frames::{frame_loop, prepare};
use pty::{Pty, open_pty, pty_loop};

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
    /// Stop flag: setting it stops the rig cleanly (the binary sets it on SIGINT/SIGTERM,
    /// tests directly).
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

/// Sets up what else stops the rig (stdin EOF when `stop_on_stdin_eof` and stdin is a pipe):
/// returns the stop flag it sets, `cfg.stop`.
pub fn watch_stop(cfg: &ServeConfig) -> Arc<AtomicBool> {
    let stop = cfg.stop.clone();
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
    stop
}

/// Runs the rig until stopped. `announce(key, value)` receives the `key: value` lines
/// (`socket`, `fslp_pty`, `rig_pty`, `thermal`, `rgb`, `ready`).
pub fn serve(cfg: ServeConfig, announce: &mut dyn FnMut(&str, &str)) -> Result<(), SimError> {
    let stop = watch_stop(&cfg);
    let fslp_pty = open_pty("open FSLP pty")?;
    let rig_pty = open_pty("open rig controller pty")?;
    let (profile, shared) = rig_state(&cfg);

    // Render what the first frames need before clients can connect.
    let prepared = prepare(&cfg, profile, &shared);
    let listener = bind_socket(&cfg)?;
    announce("socket", &cfg.socket.display().to_string());
    announce("fslp_pty", &fslp_pty.path.display().to_string());
    announce("rig_pty", &rig_pty.path.display().to_string());
    announce_streams(&cfg, &profile, announce);

    let clients: Arc<Mutex<Vec<UnixStream>>> = Arc::default();
    let threads = vec![
        serve_fslp(fslp_pty, shared.clone(), stop.clone()),
        serve_rig_controller(rig_pty, shared.clone(), stop.clone()),
        accept_clients(listener, clients.clone(), stop.clone()),
    ];
    announce("ready", "1");

    let result = frame_loop(&cfg, profile, &shared, &clients, &stop, prepared);
    stop.store(true, Ordering::Relaxed);
    for t in threads {
        let _ = t.join();
    }
    let _ = std::fs::remove_file(&cfg.socket);
    result
}

/// The thermal profile as served (a non-positive automatic FFC period turns automatic FFC
/// off) and the rig's shared state: the thermal core, the board, the controller.
fn rig_state(cfg: &ServeConfig) -> (ThermalProfile, Arc<Mutex<Shared>>) {
    let board_spec = BoardSpec::default();
    let mut profile = cfg.thermal;
    let auto_ffc_period_s = profile.auto_ffc_period_s;
    profile.auto_ffc_period_s = if auto_ffc_period_s > 0.0 {
        auto_ffc_period_s
    } else {
        0.0
    };
    let shared = Arc::new(Mutex::new(Shared::new(
        ThermalSensor::new(profile, cfg.seed),
        board_spec,
        auto_ffc_period_s,
        monotonic_ns(),
    )));
    (profile, shared)
}

/// Binds the frame socket (replacing a stale one), non-blocking so the accept loop sees
/// the stop flag.
fn bind_socket(cfg: &ServeConfig) -> Result<UnixListener, SimError> {
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
    Ok(listener)
}

/// Announces the streams: `thermal` (profile, size, rate) and, with `--rgb`, `rgb`.
fn announce_streams(
    cfg: &ServeConfig,
    profile: &ThermalProfile,
    announce: &mut dyn FnMut(&str, &str),
) {
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
}

/// Serves the Boson FSLP firmware on its pty until `stop`, in its own thread.
fn serve_fslp(pty: Pty, shared: Arc<Mutex<Shared>>, stop: Arc<AtomicBool>) -> JoinHandle<()> {
    thread::spawn(move || {
        let mut dec = FslpStreamDecoder::new();
        pty_loop(pty, stop, |bytes| {
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
    })
}

/// Serves the rig controller firmware on its pty until `stop`, in its own thread.
fn serve_rig_controller(
    pty: Pty,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
) -> JoinHandle<()> {
    thread::spawn(move || {
        let mut dec = RigStreamDecoder::new();
        pty_loop(pty, stop, |bytes| {
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
    })
}

/// Accepts the socket's clients until `stop`, in its own thread.
fn accept_clients(
    listener: UnixListener,
    clients: Arc<Mutex<Vec<UnixStream>>>,
    stop: Arc<AtomicBool>,
) -> JoinHandle<()> {
    thread::spawn(move || {
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
    })
}
