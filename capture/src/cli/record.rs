//! Recording, the binary's job without a subcommand: the record options, the sources (V4L2,
//! nokhwa, the simulated rig), Boson and rig-controller serial control, the daemon run with
//! its status line and signal handling ([`super::live`]), and the summary.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use s3tir_capture::Chain;
use s3tir_capture::backend::FrameSource;
use s3tir_capture::backend::sim_backend::{self, SimSource, SimSpec};
use s3tir_capture::daemon::{self, Counters, DaemonConfig, SourceSpec};
use s3tir_capture::device::Role;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::session::SessionInfo;
use s3tir_capture::session::pairing::{DEFAULT_TOLERANCE_NS, PairingMode};
use s3tir_capture::wire::serial;

use super::live;
use super::positive_seconds;

/// The record options (`s3tir-capture --device … --out …`, no subcommand).
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Thermal camera: a V4L2 node (/dev/video0, /dev/s3tir/boson) or the simulated rig
    /// (`sim`, `sim:boson640`, `sim:lepton35`; started from beside this program when none runs).
    #[arg(long)]
    device: Option<String>,
    /// RGB camera: a V4L2 node, `sim` for the simulated rig's RGB camera, or `nokhwa:N` for
    /// camera N through nokhwa (builds with the `nokhwa` feature; frames stamped on arrival).
    #[arg(long)]
    rgb: Option<String>,
    /// Boson FSLP serial port (CDC-ACM, e.g. /dev/s3tir/boson-serial): serial number and FPA
    /// temperature are recorded in the session metadata.
    #[arg(long)]
    serial: Option<String>,
    /// Rig controller serial port (`sim`: the simulated rig's controller): with
    /// --trigger-rate-hz, it triggers both cameras; its pulse timestamps are mapped to the camera
    /// clock (offset + drift, fitted over matched pulses, recorded on /rig/clock) and frames
    /// are paired by trigger pulse.
    #[arg(long)]
    rig_serial: Option<String>,
    /// Hardware trigger rate in Hz (needs --rig-serial).
    #[arg(long, alias = "trigger-rate")]
    trigger_rate_hz: Option<f64>,
    /// Output session file (MCAP).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long, alias = "duration", value_parser = positive_seconds)]
    duration_s: Option<f64>,
    /// Socket of the simulated rig (default: $XDG_RUNTIME_DIR/s3tir-sim-UID.sock, else
    /// s3tir-UID/sim.sock in a private temp folder).
    #[arg(long)]
    sim_socket: Option<PathBuf>,
    /// Thermal↔RGB pairing tolerance in milliseconds (nearest-timestamp pairing).
    #[arg(long, default_value_t = DEFAULT_TOLERANCE_NS as f64 / 1e6)]
    pair_tolerance_ms: f64,
    /// Capacity of the reader→writer queue in frames; when the disk falls behind, frames
    /// beyond it are dropped and counted.
    #[arg(long, default_value_t = 64)]
    queue_frames: usize,
    /// A device that delivers no frame for this many seconds is closed and reopened (the stall
    /// watchdog; UVC bridges can stall without an error), and counted in `stalls`.
    #[arg(long, default_value_t = s3tir_capture::daemon::DEFAULT_STALL_TIMEOUT.as_secs_f64(), value_parser = positive_seconds)]
    stall_timeout_s: f64,
    /// Thermal words are TLinear centikelvin (else raw counts); recorded in the metadata.
    #[arg(long)]
    tlinear: bool,
    /// Largest RGB size to negotiate, WIDTHxHEIGHT.
    #[arg(long, default_value = "1920x1080")]
    rgb_max_size: String,
    /// Simulated rig only: the rig walks through a textured scene (`orbit` or `handheld`), or
    /// stands while the board is waved in front of it (`board`: a calibration session), for
    /// --duration-s seconds of the walk's clock (default 20) instead of facing the board; the
    /// recording ends when the walk's last frame is recorded (rendering may run slower than
    /// real time), and the simulator writes the truth trajectory to OUT_STEM-truth/truth.json
    /// beside the session. No serial control in a walk.
    #[arg(long, value_parser = ["orbit", "handheld", "board"])]
    walk: Option<String>,
    /// Simulated walks only: how the room's AprilTags are made. `printed` (paper: the RGB
    /// camera sees them) or `heated` (aluminium foil over a heated panel: the thermal camera
    /// sees them too, inverted; the fiducials of a rig without RGB, for the poses stage's
    /// --tags).
    #[arg(long, value_parser = ["printed", "heated"], default_value = "printed", requires = "walk")]
    walk_tags: String,
    /// Simulated walks only: the emissivity board (9 × 6 squares of 60 mm, warmer than the
    /// room) stands in the room, in view over about half a lap; its board.toml goes beside the
    /// truth (the poses stage's --board).
    #[arg(long, requires = "walk")]
    walk_board: bool,
    /// Calibration file (s3tir-calib's calibration.yaml) attached to the session, so the poses
    /// stage (`export --dataset`, `s3tir-train SESSION.mcap`) finds it without --calibration.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Print the recording's summary as one JSON object on stdout (the session path, counts per
    /// stream, pairs, status counters, bytes, seconds, the last clock map) instead of the
    /// summary lines on stderr.
    #[arg(long)]
    json: bool,
}

impl RecordArgs {
    /// `--duration-s` (alias `--duration`).
    #[cfg(test)]
    pub fn duration_s(&self) -> Option<f64> {
        self.duration_s
    }

    /// `--trigger-rate-hz` (alias `--trigger-rate`).
    #[cfg(test)]
    pub fn trigger_rate_hz(&self) -> Option<f64> {
        self.trigger_rate_hz
    }
}

/// Runs a recording: the sources opened (a V4L2 camera pair or the simulated rig), the Boson
/// and rig controller serial links when given, then the daemon until the duration ends, the
/// walk ends or a signal stops it; a summary at the end.
pub fn run(a: RecordArgs) -> Result<()> {
    let Some(device) = a.device.clone() else {
        bail!(
            "nothing to do: give --device DEVICE --out FILE to record, or a subcommand (see --help)"
        );
    };
    let Some(out) = a.out.clone() else {
        bail!("--out FILE is required to record");
    };
    // Before any device or simulator is touched (the session writer refuses it too).
    if out.exists() {
        return Err(s3tir_capture::CaptureError::SessionExists { path: out }.into());
    }
    let mut info = SessionInfo {
        tool: format!("s3tir-capture {}", env!("CARGO_PKG_VERSION")),
        thermal_device: device.clone(),
        rgb_device: a.rgb.clone(),
        ..SessionInfo::default()
    };
    let counters = Arc::new(Counters::default());
    let (sources, sim_process) = open_sources(&a, &device, &out, &mut info)?;
    // A simulated rig started here serves the Boson FSLP firmware on a pty: use it.
    let serial_port = a.serial.clone().or_else(|| {
        sim_process
            .as_ref()
            .and_then(|p: &sim_backend::SimRigProcess| p.announced("fslp_pty"))
    });
    let ffc_poll = serial_port
        .as_deref()
        .and_then(|port| boson_control(port, &counters, &mut info));
    let rig = rig_control(&a, sim_process.as_ref())?;
    let pairing = if rig.trigger_poll.is_some() {
        PairingMode::TriggerCounter
    } else {
        PairingMode::Nearest {
            tolerance_ns: (a.pair_tolerance_ms * 1e6).round() as u64,
        }
    };
    info.pairing = serde_json::to_string(&pairing)?;
    let walking = a.walk.is_some();
    let cfg = DaemonConfig {
        sources,
        out: out.clone(),
        info,
        pairing,
        // A walk ends when its last frame is recorded (live::watch_walk_end), not by the wall clock.
        duration: if walking {
            None
        } else {
            a.duration_s.map(Duration::from_secs_f64)
        },
        queue_frames: a.queue_frames,
        calibration: attached_calibration(&a)?,
        slow_disk: None,
        stall_timeout: Duration::from_secs_f64(a.stall_timeout_s),
        ffc_poll,
        trigger_poll: rig.trigger_poll,
        rough_clock: rig.rough_clock,
    };
    let stop = Arc::new(AtomicBool::new(false));
    if walking && let Some(p) = &sim_process {
        live::watch_walk_end(p.announcements(), counters.clone(), stop.clone());
    }
    live::stop_on_signals(&stop)?;
    let mut status_line = live::StatusLine::new();
    let report = daemon::run_with_events(cfg, stop, counters, |e| status_line.show(&e));
    status_line.finish();
    let report = report?;
    if let Some(c) = rig.client
        && a.trigger_rate_hz.is_some()
        && let Err(e) = lock(&c).stop_trigger()
    {
        tracing::warn!("could not stop the trigger: {}", Chain(&e));
    }
    print_summary(a.json, &out, &report)
}

/// The frame sources of `device` (and `--rgb`): the simulated rig (started here when none runs;
/// returned so that it lives as long as the recording) or V4L2 / nokhwa cameras.
fn open_sources(
    a: &RecordArgs,
    device: &str,
    out: &std::path::Path,
    info: &mut SessionInfo,
) -> Result<(Vec<SourceSpec>, Option<sim_backend::SimRigProcess>)> {
    let units = if a.tlinear {
        ThermalUnits::CentiKelvin
    } else {
        ThermalUnits::RawCounts
    };
    if a.walk.is_some() && SimSpec::parse(device).is_none() {
        bail!("--walk moves the simulated rig: it needs --device sim[:PROFILE], not {device}");
    }
    let mut sources = Vec::new();
    let Some(spec) = SimSpec::parse(device) else {
        sources.push(v4l2_source(device, Role::Thermal, None, units)?);
        if let Some(r) = &a.rgb {
            let max = parse_size(&a.rgb_max_size)?;
            match s3tir_capture::backend::nokhwa_backend::parse_spec(r) {
                Some(index) => sources.push(nokhwa_source(index, max)?),
                None => sources.push(v4l2_source(r, Role::Rgb, Some(max), units)?),
            }
        }
        return Ok((sources, None));
    };
    let mut spec = spec?;
    if let Some(kind) = &a.walk {
        let stem = out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "walk".into());
        spec.walk = Some(sim_backend::SimWalk {
            kind: kind.clone(),
            duration_s: a.duration_s.unwrap_or(20.0),
            truth_dir: out.with_file_name(format!("{stem}-truth")),
            tags: a.walk_tags.clone(),
            board: a.walk_board,
        });
    }
    let socket = a
        .sim_socket
        .clone()
        .map_or_else(sim_backend::default_socket, Ok)?;
    let sim_process = sim_backend::ensure_sim_rig(&spec, a.rgb.is_some(), &socket)?;
    info.notes = format!("simulated rig, profile {}", spec.profile);
    sources.push(SourceSpec {
        name: format!("sim:{}", socket.display()),
        open: Box::new(move || {
            SimSource::connect(&socket).map(|s| Box::new(s) as Box<dyn FrameSource>)
        }),
    });
    if let Some(r) = &a.rgb
        && r != "sim"
    {
        bail!("--device sim takes its RGB camera from the simulated rig: use --rgb sim");
    }
    Ok((sources, sim_process))
}

/// The Boson's FSLP link on `port`: its serial number and FPA temperature into the session
/// metadata, and the FFC-state poller. A link that does not answer is counted and warned
/// about; the recording goes on without it.
fn boson_control(
    port: &str,
    counters: &Counters,
    info: &mut SessionInfo,
) -> Option<daemon::FfcPoller> {
    let opened = serial::open_port(port).and_then(|p| {
        let mut c = serial::BosonClient::new(p, port);
        let sn = c.serial_number()?;
        let fpa = c.fpa_temp_ck()?;
        Ok((c, sn, fpa))
    });
    match opened {
        Ok((mut c, sn, fpa)) => {
            tracing::info!("Boson serial {sn}, FPA {:.2} K", fpa as f64 / 100.0);
            info.thermal_serial = Some(sn.to_string());
            Some(Box::new(move || {
                use s3tir_capture::frame::FfcState;
                use s3tir_capture::wire::fslp::FfcStateCode;
                Ok(match c.ffc_state()? {
                    FfcStateCode::InProgress => FfcState::InProgress,
                    FfcStateCode::Imminent => FfcState::Imminent,
                    FfcStateCode::NeverCommanded | FfcStateCode::Complete => FfcState::Idle,
                })
            }))
        }
        Err(e) => {
            counters
                .serial_errors
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            tracing::warn!("Boson serial control unavailable: {}", Chain(&e));
            None
        }
    }
}

/// The rig controller's client on its serial port.
type RigClient = serial::RigClient<Box<dyn serialport::SerialPort>>;

/// The rig controller, when `--rig-serial` names one: with `--trigger-rate-hz` it triggers both
/// cameras, and frames pair by trigger counter.
struct RigControl {
    client: Option<Arc<std::sync::Mutex<RigClient>>>,
    trigger_poll: Option<daemon::TriggerPoller>,
    rough_clock: Option<(s3tir_capture::session::clock_sync::ClockMap, u32)>,
}

/// Opens the rig controller (`sim`: the simulated rig's) and starts its trigger when asked,
/// with a rough controller → camera clock map from one status exchange.
fn rig_control(
    a: &RecordArgs,
    sim_process: Option<&sim_backend::SimRigProcess>,
) -> Result<RigControl> {
    let mut rig = RigControl {
        client: None,
        trigger_poll: None,
        rough_clock: None,
    };
    let Some(port) = &a.rig_serial else {
        return Ok(rig);
    };
    let port = if port == "sim" {
        sim_process.and_then(|p| p.announced("rig_pty")).context(
            "--rig-serial sim needs a simulated rig started by this program (--device sim)",
        )?
    } else {
        port.clone()
    };
    let p = serial::open_port(&port)?;
    let c = Arc::new(std::sync::Mutex::new(serial::RigClient::new(p, &port)));
    if let Some(hz) = a.trigger_rate_hz {
        // Rough controller → camera clock map: the controller's clock at the midpoint of
        // one status exchange (error ≤ half the round trip).
        let t0 = s3tir_capture::backend::stamp::monotonic_now_ns();
        let st = lock(&c).status()?;
        let t1 = s3tir_capture::backend::stamp::monotonic_now_ns();
        let rough =
            s3tir_capture::session::clock_sync::ClockMap::rough(st.uptime_ns, t0 + (t1 - t0) / 2);
        tracing::info!(
            "rig controller clock {} ns at camera clock {} ns (status round trip {:.2} ms)",
            st.uptime_ns,
            rough.mono_anchor_ns,
            (t1 - t0) as f64 / 1e6
        );
        rig.rough_clock = Some((rough, st.trigger_count));
        lock(&c).start_trigger((hz * 1000.0).round() as u32)?;
        let poller = c.clone();
        rig.trigger_poll = Some(Box::new(move |since| {
            lock(&poller).triggers(since).map(|(_, events)| events)
        }));
    }
    rig.client = Some(c);
    Ok(rig)
}

/// `--calibration FILE` as the session's attachment: its name keeps the file's extension, so
/// readers know its format (calibration.yaml from s3tir-calib).
fn attached_calibration(a: &RecordArgs) -> Result<Option<(String, Vec<u8>)>> {
    let Some(p) = &a.calibration else {
        return Ok(None);
    };
    let name = format!(
        "calibration{}",
        p.extension()
            .map(|e| format!(".{}", e.to_string_lossy()))
            .unwrap_or_default()
    );
    let bytes = std::fs::read(p).with_context(|| format!("read {}", p.display()))?;
    Ok(Some((name, bytes)))
}

/// What was recorded: the `--json` object on stdout, or summary lines on stderr.
fn print_summary(json: bool, out: &std::path::Path, report: &daemon::DaemonReport) -> Result<()> {
    if json {
        #[derive(serde::Serialize)]
        struct RecordSummary<'a> {
            session: &'a std::path::Path,
            #[serde(flatten)]
            report: &'a daemon::DaemonReport,
        }
        let summary = RecordSummary {
            session: out,
            report,
        };
        println!("{}", serde_json::to_string_pretty(&summary)?);
        return Ok(());
    }
    eprintln!(
        "recorded {}: thermal {} frames ({} drops, {} FFC, {} rejected), rgb {} frames ({} drops, {} rejected), {} pairs, {} queue drops, {} reconnects, {} stalls, {:.1} MB in {:.1} s",
        out.display(),
        report.thermal.frames,
        report.thermal.drops,
        report.thermal.ffc_frames,
        report.thermal.rejected,
        report.rgb.frames,
        report.rgb.drops,
        report.rgb.rejected,
        report.pairs,
        report.status.queue_drops_thermal + report.status.queue_drops_rgb,
        report.status.reconnects,
        report.status.stalls,
        report.bytes_written as f64 / 1e6,
        report.elapsed_s
    );
    if let Some(m) = report.clock {
        eprintln!(
            "rig controller clock: drift {:+.2} ppm, sync residual rms {:.1} us, max {:.1} us over {} pulses ({} outliers)",
            m.drift_ppm,
            m.residual_rms_ns / 1e3,
            m.residual_max_ns / 1e3,
            m.matched,
            m.outliers
        );
    }
    Ok(())
}

/// Locks a mutex, taking the data of a poisoned one (the rig client holds no invariant a
/// panic could break).
fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once('x')
        .with_context(|| format!("size {s:?} must be WIDTHxHEIGHT"))?;
    Ok((w.parse()?, h.parse()?))
}

#[cfg(feature = "v4l")]
fn v4l2_source(
    path: &str,
    role: Role,
    max_size: Option<(u32, u32)>,
    units: ThermalUnits,
) -> Result<SourceSpec> {
    let p = path.to_owned();
    Ok(SourceSpec {
        name: path.to_owned(),
        open: Box::new(move || {
            s3tir_capture::backend::v4l2_stream::V4l2Source::open(&p, role, max_size, units)
                .map(|s| Box::new(s) as Box<dyn FrameSource>)
        }),
    })
}

#[cfg(not(feature = "v4l"))]
fn v4l2_source(
    path: &str,
    _role: Role,
    _max_size: Option<(u32, u32)>,
    _units: ThermalUnits,
) -> Result<SourceSpec> {
    bail!("{path}: this s3tir-capture was built without the `v4l` feature (use --device sim)")
}

#[cfg(feature = "nokhwa")]
fn nokhwa_source(index: u32, max: (u32, u32)) -> Result<SourceSpec> {
    Ok(SourceSpec {
        name: format!("nokhwa:{index}"),
        open: Box::new(move || {
            s3tir_capture::backend::nokhwa_backend::NokhwaSource::open(index, Some(max))
                .map(|s| Box::new(s) as Box<dyn FrameSource>)
        }),
    })
}

#[cfg(not(feature = "nokhwa"))]
fn nokhwa_source(index: u32, _max: (u32, u32)) -> Result<SourceSpec> {
    bail!(
        "nokhwa:{index}: this s3tir-capture was built without the `nokhwa` feature \
         (cargo build -p s3tir-capture --features nokhwa)"
    )
}
