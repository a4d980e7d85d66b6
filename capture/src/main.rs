//! `s3tir-capture`: thermal + RGB capture for s3tir rigs.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use s3tir_capture::backend::FrameSource;
use s3tir_capture::backend::sim_backend::{self, SimSource, SimSpec};
use s3tir_capture::daemon::{self, Counters, DaemonConfig, SourceSpec};
use s3tir_capture::device::Role;
use s3tir_capture::frame::ThermalUnits;
use s3tir_capture::session::pairing::{DEFAULT_TOLERANCE_NS, PairingMode};
use s3tir_capture::session::{SessionInfo, SessionRecord};
use s3tir_capture::tools;
use s3tir_capture::wire::serial;

/// Capture radiometric thermal (Y16) and RGB video from a rig's cameras over V4L2 (or the
/// simulated rig) into a crash-safe MCAP session; inspect, replay and export sessions.
///
/// Record:  s3tir-capture --device /dev/video0 --rgb /dev/video2 --out session.mcap
///          s3tir-capture --device sim --rgb sim --out session.mcap --duration 10
#[derive(Debug, Parser)]
#[command(
    name = "s3tir-capture",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    record: RecordArgs,
}

#[derive(Debug, Args)]
struct RecordArgs {
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
    /// --trigger-rate, it triggers both cameras; its pulse timestamps are mapped to the camera
    /// clock (offset + drift, fitted over matched pulses, recorded on /rig/clock) and frames
    /// are paired by trigger pulse.
    #[arg(long)]
    rig_serial: Option<String>,
    /// Hardware trigger rate in Hz (needs --rig-serial).
    #[arg(long)]
    trigger_rate: Option<f64>,
    /// Output session file (MCAP).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long, value_parser = positive_seconds)]
    duration: Option<f64>,
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
    /// --duration seconds of the walk's clock (default 20) instead of facing the board; the
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

#[derive(Debug, Subcommand)]
enum Command {
    /// List V4L2 capture devices: path, driver, card, formats with sizes and rates, role guess.
    List {
        /// Print one JSON array instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// Summarise a session: streams, counts, duration, drops, FFC frames, sync statistics,
    /// and whether the file was truncated (recorder killed): it is read up to its last
    /// complete chunk. A file with corrupt data that is all there (bad CRC, impossible
    /// lengths: damage, not a cut) is summarised up to the damage, then exits non-zero naming
    /// the byte offset.
    Info {
        file: PathBuf,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Push every recorded frame through the live capture pipeline again (parse, drop
    /// detection, pairing); prints the frame digest, which equals `info`'s when every frame
    /// is byte-identical.
    Replay {
        file: PathBuf,
        /// Pace frames at their recorded rate.
        #[arg(long)]
        realtime: bool,
        /// Write what the pipeline produces as a new session.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Export a session. `--out DIR`: paired frames in the s3tir-calib board-folder layout
    /// (thermal/NNNN.png 16-bit, rgb/NNNN.png, pair k under the same name). `--dataset DIR`:
    /// a posed thermal dataset for s3tir-train (COLMAP layout, radiometric 16-bit images
    /// untouched), made by `s3tir-calib poses` (run from this program's folder: COLMAP on the
    /// RGB keyframes, thermal poses composed with the calibrated extrinsic; `--with-rgb`: the
    /// posed RGB keyframes too, for joint training); see its --help.
    Export {
        file: PathBuf,
        /// Board-folder layout of the pairs.
        #[arg(long, required_unless_present = "dataset")]
        out: Option<PathBuf>,
        /// Posed dataset for s3tir-train (needs the rig's calibration).
        #[arg(long)]
        dataset: Option<PathBuf>,
        /// The rig's calibration.yaml for --dataset [default: the one attached to the session].
        #[arg(long, requires = "dataset")]
        calibration: Option<PathBuf>,
        /// AprilTag map for --dataset (s3tir-calib poses --tags): metric scale, and poses
        /// without COLMAP where mapped tags are in view.
        #[arg(long, requires = "dataset")]
        tags: Option<PathBuf>,
        /// The calibration board standing in the scene, for --dataset (s3tir-calib poses
        /// --board): metric scale, and poses without COLMAP where it is in view.
        #[arg(long, requires = "dataset", conflicts_with = "tags")]
        board: Option<PathBuf>,
        /// With --tags or --board: run COLMAP anyway (the fiducials then give the metric scale
        /// and check COLMAP's model; s3tir-calib poses --no-tag-poses).
        #[arg(long)]
        no_tag_poses: bool,
        /// The dataset also holds the posed RGB keyframes (a second camera, poses in the
        /// thermal views' world) for joint RGB + thermal training (s3tir-calib poses
        /// --with-rgb); an error on a session without RGB.
        #[arg(long, requires = "dataset")]
        with_rgb: bool,
        /// Print one JSON object (pairs exported, the dataset folder and its poses.json);
        /// s3tir-calib poses' own output then goes to stderr.
        #[arg(long)]
        json: bool,
    },
    /// Measure the recorder's sustained throughput on Boson 640×512 Y16 @ 60 Hz + RGB 1080p
    /// MJPEG @ 30 Hz (synthetic buffers), as a ratio to real time, and what the writer's
    /// once-a-second fdatasync costs (the same load without syncs, run first, is the reference).
    Bench {
        /// Seconds of camera time to record.
        #[arg(long, default_value_t = 10.0, value_parser = positive_seconds)]
        seconds: f64,
        /// Where to write the bench session (must not exist; deleted afterwards). Put it on the
        /// rig's recording disk: the fdatasync cost depends on it (a tmpfs makes it free).
        #[arg(long)]
        out: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::List { json }) => list(json),
        Some(Command::Info { file, json }) => info(&file, json),
        Some(Command::Replay {
            file,
            realtime,
            out,
            json,
        }) => replay(&file, realtime, out, json),
        Some(Command::Export {
            file,
            out,
            dataset,
            calibration,
            tags,
            board,
            no_tag_poses,
            with_rgb,
            json,
        }) => {
            let mut summary = serde_json::json!({ "session": file });
            if let Some(out) = out {
                let bar = progress_spinner("exported {pos} pairs");
                let n = tools::export_with_progress(&file, &out, |k| bar.set_position(k))?;
                bar.finish_and_clear();
                if json {
                    summary["board_folder"] = serde_json::json!({ "dir": out, "pairs": n });
                } else {
                    println!("exported {n} pairs to {}", out.display());
                }
            }
            if let Some(dataset) = dataset {
                let opts = PosesOptions {
                    calibration: calibration.as_deref(),
                    tags: tags.as_deref(),
                    board: board.as_deref(),
                    no_tag_poses,
                    with_rgb,
                    json,
                };
                export_dataset(&file, &dataset, &opts)?;
                if json {
                    summary["dataset"] = serde_json::json!({
                        "dir": dataset,
                        "report": dataset.join("poses.json"),
                    });
                }
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            }
            Ok(())
        }
        Some(Command::Bench { seconds, out, json }) => bench(seconds, out, json),
        None => record(cli.record),
    }
}

/// Stops the recording when the simulated walk has announced `walk_done: thermal=N rgb=M` and
/// the writer has recorded that many frames of each stream (or 10 s after the announcement,
/// when some were rejected on the way).
fn watch_walk_end(
    announced: Arc<std::sync::Mutex<std::collections::BTreeMap<String, String>>>,
    counters: Arc<Counters>,
    stop: Arc<AtomicBool>,
) {
    std::thread::spawn(move || {
        let done = loop {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            let v = announced
                .lock()
                .ok()
                .and_then(|m| m.get("walk_done").cloned());
            if let Some(v) = v {
                break v;
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let want = |key: &str| -> u64 {
            done.split_whitespace()
                .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('=')?.parse().ok())
                .unwrap_or(0)
        };
        let (thermal, rgb) = (want("thermal"), want("rgb"));
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while std::time::Instant::now() < deadline {
            let got = |k: usize| counters.frames[k].load(Ordering::Relaxed);
            if got(0) >= thermal && got(1) >= rgb {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        tracing::info!("the simulated walk ended ({done}): stopping");
        stop.store(true, Ordering::Relaxed);
    });
}

/// The `export --dataset` options passed on to `s3tir-calib poses`.
struct PosesOptions<'a> {
    calibration: Option<&'a std::path::Path>,
    tags: Option<&'a std::path::Path>,
    board: Option<&'a std::path::Path>,
    no_tag_poses: bool,
    with_rgb: bool,
    /// Our stdout carries one JSON object: the child's stdout goes to stderr.
    json: bool,
}

/// `export --dataset`: capture sits below calib (ARCHITECTURE.md), so the poses stage runs as
/// the `s3tir-calib poses` process installed beside this program.
fn export_dataset(
    session: &std::path::Path,
    dataset: &std::path::Path,
    opts: &PosesOptions<'_>,
) -> Result<()> {
    let PosesOptions {
        calibration,
        tags,
        board,
        no_tag_poses,
        with_rgb,
        json,
    } = *opts;
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(std::path::Path::to_path_buf))
        .unwrap_or_default();
    let calib = exe_dir.join("s3tir-calib");
    if !calib.is_file() {
        bail!(
            "export --dataset runs s3tir-calib poses, and {} is not installed (build the workspace: cargo build --workspace --bins)",
            calib.display()
        );
    }
    let mut cmd = std::process::Command::new(&calib);
    cmd.arg("poses").arg(session).arg("--out").arg(dataset);
    if let Some(c) = calibration {
        cmd.arg("--calibration").arg(c);
    }
    if let Some(t) = tags {
        cmd.arg("--tags").arg(t);
    }
    if let Some(b) = board {
        cmd.arg("--board").arg(b);
    }
    if no_tag_poses {
        cmd.arg("--no-tag-poses");
    }
    if with_rgb {
        cmd.arg("--with-rgb");
    }
    if json {
        cmd.stdout(std::io::stderr());
    }
    let status = cmd
        .status()
        .with_context(|| format!("running {}", calib.display()))?;
    if !status.success() {
        bail!(
            "s3tir-calib poses failed ({status}): no dataset written to {}",
            dataset.display()
        );
    }
    Ok(())
}

fn info(file: &std::path::Path, json: bool) -> Result<()> {
    let s = tools::info(file)?;
    // Damage (corrupt data that is all in the file, unlike a crash's cut) is an error after
    // the summary of what could be read.
    let damaged = |s: &tools::SessionSummary| match &s.damage {
        Some(d) => Err(anyhow::anyhow!(
            "{} is damaged at byte {}: {} ({} chunks before it were read)",
            file.display(),
            d.offset,
            d.reason,
            s.chunks
        )),
        None => Ok(()),
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return damaged(&s);
    }
    println!("{}", s.path.display());
    if s.truncated {
        println!(
            "  TRUNCATED: read up to the last complete chunk ({})",
            s.truncation_reason.as_deref().unwrap_or("")
        );
    }
    println!(
        "  duration {:.2} s, {} chunks, device {}",
        s.duration_s, s.chunks, s.thermal_device
    );
    for (name, st) in &s.streams {
        println!(
            "  {name:8} frames {:6}  drops {:4} (recorder queue {}, source {})  ffc {:4}  rejected {}",
            st.frames, st.drops, st.queue_drops, st.source_drops, st.ffc_frames, st.rejected
        );
        println!(
            "           {:.3} Hz over {:.2} s (device stamps), delivery lag up to {:.1} ms",
            st.rate_hz, st.span_s, st.max_delivery_lag_ms
        );
    }
    println!(
        "  pairs {}  sync error mean {:.3} ms, rms {:.3} ms, max |{:.3}| ms",
        s.pairs,
        s.sync.mean_ns / 1e6,
        s.sync.rms_ns / 1e6,
        s.sync.max_abs_ns as f64 / 1e6
    );
    if let Some(m) = &s.clock {
        println!(
            "  rig controller clock: {} triggers, drift {:+.2} ppm, sync residual rms {:.1} us, max {:.1} us ({} pulses matched, {} outliers)",
            s.triggers,
            m.drift_ppm,
            m.residual_rms_ns / 1e3,
            m.residual_max_ns / 1e3,
            m.matched,
            m.outliers
        );
    }
    println!(
        "  reconnects {}  stalls {}  frame digest {}",
        s.reconnects, s.stalls, s.frame_digest
    );
    damaged(&s)
}

/// A spinner on stderr with the elapsed time and `msg` (an indicatif template: `{pos}` is the
/// count); drawn only when stderr is a terminal, like the recorder's status line.
fn progress_spinner(msg: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new_spinner();
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!("{{spinner}} {{elapsed}} {msg}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    b
}

fn replay(file: &std::path::Path, realtime: bool, out: Option<PathBuf>, json: bool) -> Result<()> {
    let bar = progress_spinner("replayed {pos} frames");
    let r = tools::replay(file, out.as_deref(), realtime, None, |rec| {
        if matches!(rec, SessionRecord::Frame { .. }) {
            bar.inc(1);
        }
    });
    bar.finish_and_clear();
    let r = r?;
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "replayed {} frames ({} rejected), {} pairs ({} differ from the recording), {} drops{}; frame digest {}",
            r.frames,
            r.rejected,
            r.pairs,
            r.pair_mismatches,
            r.drops,
            if r.truncated {
                ", source truncated"
            } else {
                ""
            },
            r.frame_digest
        );
    }
    if r.pair_mismatches > 0 {
        bail!(
            "replay paired {} frames differently from the recording",
            r.pair_mismatches
        );
    }
    Ok(())
}

fn bench(seconds: f64, out: Option<PathBuf>, json: bool) -> Result<()> {
    let dir = tempfile_dir()?;
    let path = out.unwrap_or_else(|| dir.join("bench.mcap"));
    // The reference run (no fdatasync) beside the measured one, in the same folder and process.
    let mut reference_path = path.as_os_str().to_owned();
    reference_path.push(".reference");
    let reference_path = PathBuf::from(reference_path);
    for p in [&path, &reference_path] {
        if p.exists() {
            bail!(
                "{} exists: the bench writes and then deletes its own files there; give a new --out",
                p.display()
            );
        }
    }
    let reference = s3tir_capture::bench::run(&reference_path, seconds, (1920, 1080), false);
    let _ = std::fs::remove_file(&reference_path);
    let r = s3tir_capture::bench::run(&path, seconds, (1920, 1080), true);
    let _ = std::fs::remove_file(&path);
    let _ = std::fs::remove_dir(&dir);
    let (reference, r) = (reference?, r?);
    let sync_cost = 1.0 - r.frames_per_s / reference.frames_per_s;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "synced": r,
                "reference_without_sync": reference,
                "sync_cost": sync_cost,
            }))?
        );
    } else {
        println!(
            "recorded {:.1} s of Boson 640x512 Y16@60 + RGB 1920x1080 MJPEG@30 ({} frames) in {:.2} s wall, {:.2} s CPU",
            r.simulated_s, r.frames, r.wall_s, r.cpu_s
        );
        println!(
            "  {:.1} frames/s sustained = {:.2}x real time; {:.0} us CPU per frame; {:.1} MB at {:.1} MB/s",
            r.frames_per_s, r.realtime_ratio, r.cpu_us_per_frame, r.file_mb, r.write_mb_per_s
        );
        println!(
            "  fdatasync every {:.1} s: {} syncs, mean {:.1} ms, max {:.1} ms; without them {:.2}x real time \
             (the syncs cost {:.1} % of throughput)",
            s3tir_capture::session::SYNC_INTERVAL.as_secs_f64(),
            r.syncs,
            r.sync_ms_mean,
            r.sync_ms_max,
            reference.realtime_ratio,
            100.0 * sync_cost
        );
    }
    Ok(())
}

/// A duration in seconds: finite and above zero (`Duration::from_secs_f64` panics otherwise).
fn positive_seconds(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|e| format!("{s:?} is not a number of seconds: {e}"))?;
    if v.is_finite() && v > 0.0 && v < 1e9 {
        Ok(v)
    } else {
        Err(format!("{s} s: must be a positive number of seconds"))
    }
}

/// Locks a mutex, taking the data of a poisoned one (the rig client holds no invariant a
/// panic could break).
fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn tempfile_dir() -> Result<PathBuf> {
    let d = std::env::temp_dir().join(format!("s3tir-bench-{}", std::process::id()));
    std::fs::create_dir_all(&d).with_context(|| format!("create {}", d.display()))?;
    Ok(d)
}

fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once('x')
        .with_context(|| format!("size {s:?} must be WIDTHxHEIGHT"))?;
    Ok((w.parse()?, h.parse()?))
}

fn record(a: RecordArgs) -> Result<()> {
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
    let mut pairing = PairingMode::Nearest {
        tolerance_ns: (a.pair_tolerance_ms * 1e6).round() as u64,
    };
    let counters = Arc::new(Counters::default());
    let mut sources = Vec::new();
    let mut _sim_process = None;
    let units = if a.tlinear {
        ThermalUnits::CentiKelvin
    } else {
        ThermalUnits::RawCounts
    };
    if a.walk.is_some() && SimSpec::parse(&device).is_none() {
        bail!("--walk moves the simulated rig: it needs --device sim[:PROFILE], not {device}");
    }
    let walking = a.walk.is_some();
    if let Some(spec) = SimSpec::parse(&device) {
        let mut spec = spec?;
        if let Some(kind) = &a.walk {
            let stem = out
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "walk".into());
            spec.walk = Some(sim_backend::SimWalk {
                kind: kind.clone(),
                duration_s: a.duration.unwrap_or(20.0),
                truth_dir: out.with_file_name(format!("{stem}-truth")),
                tags: a.walk_tags.clone(),
                board: a.walk_board,
            });
        }
        let socket = a
            .sim_socket
            .clone()
            .map_or_else(sim_backend::default_socket, Ok)?;
        _sim_process = sim_backend::ensure_sim_rig(&spec, a.rgb.is_some(), &socket)?;
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
    } else {
        sources.push(v4l2_source(&device, Role::Thermal, None, units)?);
        if let Some(r) = &a.rgb {
            let max = parse_size(&a.rgb_max_size)?;
            match s3tir_capture::backend::nokhwa_backend::parse_spec(r) {
                Some(index) => sources.push(nokhwa_source(index, max)?),
                None => sources.push(v4l2_source(r, Role::Rgb, Some(max), units)?),
            }
        }
    }
    // A simulated rig started here serves the Boson FSLP firmware on a pty: use it.
    let serial_port = a.serial.clone().or_else(|| {
        _sim_process
            .as_ref()
            .and_then(|p: &sim_backend::SimRigProcess| p.announced("fslp_pty"))
    });
    let mut ffc_poll: Option<daemon::FfcPoller> = None;
    if let Some(port) = &serial_port {
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
                ffc_poll = Some(Box::new(move || {
                    use s3tir_capture::frame::FfcState;
                    use s3tir_capture::wire::fslp::FfcStateCode;
                    Ok(match c.ffc_state()? {
                        FfcStateCode::InProgress => FfcState::InProgress,
                        FfcStateCode::Imminent => FfcState::Imminent,
                        FfcStateCode::NeverCommanded | FfcStateCode::Complete => FfcState::Idle,
                    })
                }));
            }
            Err(e) => {
                counters
                    .serial_errors
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                tracing::warn!("Boson serial control unavailable: {e}");
            }
        }
    }
    let mut rig = None;
    let mut trigger_poll: Option<daemon::TriggerPoller> = None;
    let mut rough_clock = None;
    if let Some(port) = &a.rig_serial {
        let port = if port == "sim" {
            _sim_process
                .as_ref()
                .and_then(|p| p.announced("rig_pty"))
                .context(
                    "--rig-serial sim needs a simulated rig started by this program (--device sim)",
                )?
        } else {
            port.clone()
        };
        let p = serial::open_port(&port)?;
        let c = Arc::new(std::sync::Mutex::new(serial::RigClient::new(p, &port)));
        if let Some(hz) = a.trigger_rate {
            // Rough controller → camera clock map: the controller's clock at the midpoint of
            // one status exchange (error ≤ half the round trip).
            let t0 = s3tir_capture::backend::stamp::monotonic_now_ns();
            let st = lock(&c).status()?;
            let t1 = s3tir_capture::backend::stamp::monotonic_now_ns();
            let rough = s3tir_capture::session::clock_sync::ClockMap::rough(
                st.uptime_ns,
                t0 + (t1 - t0) / 2,
            );
            tracing::info!(
                "rig controller clock {} ns at camera clock {} ns (status round trip {:.2} ms)",
                st.uptime_ns,
                rough.mono_anchor_ns,
                (t1 - t0) as f64 / 1e6
            );
            rough_clock = Some((rough, st.trigger_count));
            lock(&c).start_trigger((hz * 1000.0).round() as u32)?;
            pairing = PairingMode::TriggerCounter;
            let poller = c.clone();
            trigger_poll = Some(Box::new(move |since| {
                lock(&poller).triggers(since).map(|(_, events)| events)
            }));
        }
        rig = Some(c);
    }
    info.pairing = serde_json::to_string(&pairing)?;
    let calibration = match &a.calibration {
        Some(p) => Some((
            // The name carries the file's extension, so readers know its format
            // (calibration.yaml from s3tir-calib).
            format!(
                "calibration{}",
                p.extension()
                    .map(|e| format!(".{}", e.to_string_lossy()))
                    .unwrap_or_default()
            ),
            std::fs::read(p).with_context(|| format!("read {}", p.display()))?,
        )),
        None => None,
    };
    let cfg = DaemonConfig {
        sources,
        out: out.clone(),
        info,
        pairing,
        // A walk ends when its last frame is recorded (watch_walk_end), not by the wall clock.
        duration: if walking {
            None
        } else {
            a.duration.map(Duration::from_secs_f64)
        },
        queue_frames: a.queue_frames,
        status_line: true,
        calibration,
        slow_disk: None,
        stall_timeout: Duration::from_secs_f64(a.stall_timeout_s),
        ffc_poll,
        trigger_poll,
        rough_clock,
    };
    let stop = Arc::new(AtomicBool::new(false));
    if walking && let Some(p) = &_sim_process {
        watch_walk_end(p.announcements(), counters.clone(), stop.clone());
    }
    let report = daemon::run(cfg, stop, counters)?;
    if let Some(c) = rig
        && a.trigger_rate.is_some()
        && let Err(e) = lock(&c).stop_trigger()
    {
        tracing::warn!("could not stop the trigger: {e}");
    }
    if a.json {
        #[derive(serde::Serialize)]
        struct RecordSummary<'a> {
            session: &'a std::path::Path,
            #[serde(flatten)]
            report: &'a daemon::DaemonReport,
        }
        let summary = RecordSummary {
            session: &out,
            report: &report,
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

#[cfg(feature = "v4l")]
fn list(json: bool) -> Result<()> {
    let mut devices = Vec::new();
    for entry in s3tir_capture::backend::v4l2::list_devices() {
        match entry {
            Ok(d) => devices.push(d),
            // Reported, not fatal: one unreadable node must not hide the others.
            Err(e) => eprintln!("warning: {e}"),
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&devices)?);
        return Ok(());
    }
    if devices.is_empty() {
        println!("no V4L2 capture devices found (no /dev/video* node can capture video)");
        return Ok(());
    }
    for d in &devices {
        println!(
            "{}  [{}]  {} ({}, {})",
            d.path, d.role, d.card, d.driver, d.bus
        );
        for f in &d.formats {
            println!("    {}  {}", f.fourcc, f.description);
            for s in &f.sizes {
                let rates: Vec<String> = s.rates_hz.iter().map(|r| format!("{r:.2}")).collect();
                println!("        {}x{} @ {} Hz", s.width, s.height, rates.join(", "));
            }
        }
    }
    Ok(())
}

#[cfg(not(feature = "v4l"))]
fn list(_json: bool) -> Result<()> {
    anyhow::bail!(
        "this s3tir-capture was built without the `v4l` feature: it cannot list V4L2 devices"
    )
}
