//! The simulated backend: frames of the simulated rig read from its Unix socket
//! ([`crate::wire::simwire`]), behind the same [`FrameSource`] trait as V4L2.
//!
//! `--device sim` (or `sim:boson640`, `sim:lepton35`) connects to a running simulated rig; when
//! none answers it starts `s3tir-firmware-sim run --profile P [--rgb] --socket PATH` from the
//! directory of the running executable and stops it at exit ([`SimRigProcess`]).
//!
//! [`FakeRig`] is an in-process rig speaking the same wire protocol with synthetic buffers
//! ([`crate::backend::synth`]): the tests' device, with faults on demand (vanish and return, corrupt
//! buffers, FFC freezes, drops).

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::backend::FrameSource;
use crate::backend::stamp::monotonic_now_ns;
use crate::backend::synth::{Script, SynthRig, ThermalSynth};
use crate::error::CaptureError;
use crate::frame::{FfcState, RawFrame, StreamKind, ThermalUnits};
use crate::wire::simwire::{self, StreamId, WireFrame};

/// A parsed `--device sim[:PROFILE]` (and, with `--walk`, the walk the rig makes).
#[derive(Debug, Clone, PartialEq)]
pub struct SimSpec {
    pub profile: String,
    /// The rig walks through a scene instead of facing the board (`s3tir-firmware-sim run
    /// --walk`).
    pub walk: Option<SimWalk>,
}

/// A simulated walk: its path (`orbit`, `handheld`), length in seconds of the walk's clock,
/// and where the simulator writes its truth.
#[derive(Debug, Clone, PartialEq)]
pub struct SimWalk {
    pub kind: String,
    pub duration_s: f64,
    pub truth_dir: PathBuf,
    /// How the walk room's AprilTags are made: `printed` (RGB only) or `heated` (thermal too).
    pub tags: String,
    /// The emissivity board stands in the walk room.
    pub board: bool,
}

impl SimSpec {
    /// `Some` for `sim`, `sim:boson640`, `sim:lepton35`; `None` for anything else (a V4L2 path).
    pub fn parse(device: &str) -> Option<Result<Self, CaptureError>> {
        let rest = device.strip_prefix("sim")?;
        let profile = match rest {
            "" => "boson640",
            ":boson640" => "boson640",
            ":lepton35" => "lepton35",
            _ => {
                return Some(Err(CaptureError::DeviceUnavailable {
                    device: device.to_owned(),
                    reason: "unknown simulated profile: use sim, sim:boson640 or sim:lepton35"
                        .into(),
                }));
            }
        };
        Some(Ok(Self {
            profile: profile.to_owned(),
            walk: None,
        }))
    }
}

/// Default socket of the simulated rig for this user: `$XDG_RUNTIME_DIR/s3tir-sim-UID.sock`
/// (a per-user, mode 0700 directory), else `s3tir-UID/sim.sock` in the temp folder, in a
/// directory this user creates with mode 0700 — a shared-temp path anyone can predict would let
/// another user put a fake rig (or a symlink) there first.
pub fn default_socket() -> Result<PathBuf, CaptureError> {
    let uid = nix::unistd::getuid();
    if let Some(dir) = std::env::var_os("XDG_RUNTIME_DIR").filter(|d| !d.is_empty()) {
        return Ok(PathBuf::from(dir).join(format!("s3tir-sim-{uid}.sock")));
    }
    let dir = std::env::temp_dir().join(format!("s3tir-{uid}"));
    private_dir(&dir, uid.as_raw())?;
    Ok(dir.join("sim.sock"))
}

/// Creates `dir` with mode 0700, or accepts it only if it is a real directory (not a symlink)
/// owned by `uid` with no group or other access.
fn private_dir(dir: &Path, uid: u32) -> Result<(), CaptureError> {
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    let unsafe_dir = |reason: String| CaptureError::DeviceUnavailable {
        device: dir.display().to_string(),
        reason: format!(
            "{reason}: refusing it as the simulated rig's socket folder (set XDG_RUNTIME_DIR or \
             --sim-socket)"
        ),
    };
    match std::fs::DirBuilder::new().mode(0o700).create(dir) {
        Ok(()) => return Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(source) => {
            return Err(CaptureError::Device {
                path: dir.to_owned(),
                what: "create the socket folder",
                source,
            });
        }
    }
    let m = std::fs::symlink_metadata(dir).map_err(|source| CaptureError::Device {
        path: dir.to_owned(),
        what: "inspect the socket folder",
        source,
    })?;
    if !m.file_type().is_dir() {
        return Err(unsafe_dir("it is not a directory (a symlink?)".into()));
    }
    if m.uid() != uid {
        return Err(unsafe_dir(format!(
            "it belongs to uid {}, not {uid}",
            m.uid()
        )));
    }
    if m.mode() & 0o077 != 0 {
        return Err(unsafe_dir(format!(
            "its mode is {:o}: others can reach it",
            m.mode() & 0o777
        )));
    }
    Ok(())
}

/// Converts a wire frame to the pipeline's device buffer.
pub fn raw_from_wire(w: WireFrame) -> RawFrame {
    let ffc_hint = if w.flags & simwire::FLAG_FFC_FROZEN != 0 {
        FfcState::InProgress
    } else if w.flags & simwire::FLAG_FFC_IMMINENT != 0 {
        FfcState::Imminent
    } else {
        FfcState::Idle
    };
    RawFrame {
        stream: match w.stream {
            StreamId::Thermal => StreamKind::Thermal,
            StreamId::Rgb => StreamKind::Rgb,
        },
        fourcc: w.fourcc,
        width: w.width,
        height: w.height,
        bytes_per_line: w.bytes_per_line,
        // The wire says "telemetry present"; Lepton telemetry footers are two rows.
        telemetry_rows: if w.flags & simwire::FLAG_TELEMETRY != 0 {
            2
        } else {
            0
        },
        units: if w.flags & simwire::FLAG_TLINEAR != 0 {
            ThermalUnits::CentiKelvin
        } else {
            ThermalUnits::RawCounts
        },
        ffc_hint,
        sequence: w.sequence,
        monotonic_ns: w.monotonic_ns,
        payload: w.payload,
    }
}

/// The inverse of [`raw_from_wire`] (for fakes).
pub fn wire_from_raw(r: &RawFrame) -> WireFrame {
    let mut flags = 0;
    if r.ffc_hint == FfcState::InProgress {
        flags |= simwire::FLAG_FFC_FROZEN;
    }
    if r.ffc_hint == FfcState::Imminent {
        flags |= simwire::FLAG_FFC_IMMINENT;
    }
    if r.telemetry_rows > 0 {
        flags |= simwire::FLAG_TELEMETRY;
    }
    if r.stream == StreamKind::Thermal && r.units == ThermalUnits::CentiKelvin {
        flags |= simwire::FLAG_TLINEAR;
    }
    WireFrame {
        stream: match r.stream {
            StreamKind::Thermal => StreamId::Thermal,
            StreamKind::Rgb => StreamId::Rgb,
        },
        flags,
        fourcc: r.fourcc,
        width: r.width,
        height: r.height,
        bytes_per_line: r.bytes_per_line,
        sequence: r.sequence,
        monotonic_ns: r.monotonic_ns,
        payload: r.payload.clone(),
    }
}

/// Frames of a simulated rig, read from its socket.
#[derive(Debug)]
pub struct SimSource {
    name: String,
    stream: BufReader<UnixStream>,
}

impl SimSource {
    /// Connects to the rig's socket.
    pub fn connect(socket: &Path) -> Result<Self, CaptureError> {
        let name = format!("sim:{}", socket.display());
        let s = UnixStream::connect(socket).map_err(|source| CaptureError::Device {
            path: socket.to_owned(),
            what: "connect to simulated rig",
            source,
        })?;
        Ok(Self {
            name,
            stream: BufReader::with_capacity(1 << 20, s),
        })
    }
}

impl FrameSource for SimSource {
    fn name(&self) -> &str {
        &self.name
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Option<RawFrame>, CaptureError> {
        // A read that times out mid-frame would lose framing: the timeout is treated as the
        // rig being gone (the caller reconnects), never as "no frame yet".
        let gone = |reason: String| CaptureError::DeviceUnavailable {
            device: self.name.clone(),
            reason,
        };
        self.stream
            .get_ref()
            .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))
            .map_err(|e| CaptureError::DeviceFailed {
                device: self.name.clone(),
                what: "set timeout".into(),
                source: e.into(),
            })?;
        match WireFrame::read_from(&mut self.stream, &self.name) {
            Ok(Some(w)) => Ok(Some(raw_from_wire(w))),
            Ok(None) => Err(gone("rig closed the socket".into())),
            Err(e) => Err(CaptureError::DeviceFailed {
                device: self.name.clone(),
                what: "read frame".into(),
                source: e.into(),
            }),
        }
    }
}

/// A simulated rig process this program started; stopped (SIGTERM, then SIGKILL) and reaped
/// on drop. Its stdin is a pipe held here, so the rig also stops if this process dies.
#[derive(Debug)]
pub struct SimRigProcess {
    child: Child,
    pub socket: PathBuf,
    /// `key: value` lines the rig announced on stdout (`fslp_pty`, `rig_pty`, …).
    announced: Arc<std::sync::Mutex<BTreeMap<String, String>>>,
}

impl SimRigProcess {
    /// A value the rig announced (e.g. `fslp_pty`, `rig_pty`).
    pub fn announced(&self, key: &str) -> Option<String> {
        self.announced.lock().ok().and_then(|m| m.get(key).cloned())
    }

    /// The announcements as they keep coming (e.g. a walk's `walk_done`), for a watcher thread.
    pub fn announcements(&self) -> Arc<std::sync::Mutex<BTreeMap<String, String>>> {
        self.announced.clone()
    }
}

impl Drop for SimRigProcess {
    fn drop(&mut self) {
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(2);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Makes sure a simulated rig answers on `socket`: returns `None` when one already does,
/// else starts `s3tir-firmware-sim` from the directory of the running executable and waits
/// (up to 10 s) for its socket.
pub fn ensure_sim_rig(
    spec: &SimSpec,
    rgb: bool,
    socket: &Path,
) -> Result<Option<SimRigProcess>, CaptureError> {
    if UnixStream::connect(socket).is_ok() {
        if spec.walk.is_some() {
            return Err(CaptureError::DeviceUnavailable {
                device: format!("sim:{}", spec.profile),
                reason: format!(
                    "a simulated rig already answers on {}: a walk needs a rig of its own (stop that one or pass another --sim-socket)",
                    socket.display()
                ),
            });
        }
        return Ok(None);
    }
    let exe_dir = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(Path::to_path_buf))
        .unwrap_or_default();
    let bin = exe_dir.join("s3tir-firmware-sim");
    let unavailable = |reason: String| CaptureError::DeviceUnavailable {
        device: format!("sim:{}", spec.profile),
        reason,
    };
    if !bin.is_file() {
        return Err(unavailable(format!(
            "no simulated rig on {} and {} is not installed",
            socket.display(),
            bin.display()
        )));
    }
    let _ = std::fs::remove_file(socket);
    let mut cmd = Command::new(&bin);
    cmd.arg("run").arg("--profile").arg(&spec.profile);
    if rgb {
        cmd.arg("--rgb");
    }
    if spec.profile == "lepton35" {
        // PureThermal's 160×122 mode: telemetry rows below the image.
        cmd.arg("--telemetry");
    }
    if let Some(w) = &spec.walk {
        cmd.arg("--walk")
            .arg(&w.kind)
            .arg("--duration")
            .arg(w.duration_s.to_string())
            .arg("--truth-dir")
            .arg(&w.truth_dir)
            .arg("--walk-tags")
            .arg(&w.tags);
        if w.board {
            cmd.arg("--walk-board");
        }
    }
    cmd.arg("--socket")
        .arg(socket)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped());
    let mut child = cmd.spawn().map_err(|e| CaptureError::DeviceFailed {
        device: format!("sim:{}", spec.profile),
        what: format!("cannot start {}", bin.display()),
        source: e.into(),
    })?;
    let announced: Arc<std::sync::Mutex<BTreeMap<String, String>>> = Arc::default();
    if let Some(out) = child.stdout.take() {
        let announced = announced.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if let Some((k, v)) = line.split_once(": ")
                    && let Ok(mut m) = announced.lock()
                {
                    m.insert(k.trim().to_owned(), v.trim().to_owned());
                }
            }
        });
    }
    let mut proc = SimRigProcess {
        child,
        socket: socket.to_owned(),
        announced,
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        // `ready` comes after the socket is bound and the ptys are announced. No probe
        // connection: the rig starts streaming to its first client, which must be ours.
        if proc.announced("ready").is_some() && socket.exists() {
            tracing::info!(socket = %socket.display(), "started simulated rig {}", bin.display());
            return Ok(Some(proc));
        }
        if let Ok(Some(status)) = proc.child.try_wait() {
            return Err(unavailable(format!(
                "{} exited with {status} before opening {}",
                bin.display(),
                socket.display()
            )));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Err(unavailable(format!(
        "{} did not open {} within 10 s",
        bin.display(),
        socket.display()
    )))
}

/// Configuration of a [`FakeRig`].
#[derive(Debug, Clone)]
pub struct FakeRigConfig {
    pub thermal: ThermalSynth,
    /// RGB MJPEG width, height, rate.
    pub rgb: Option<(u32, u32, f64)>,
    pub script: Script,
    /// Serve as fast as the reader takes them (timestamps still advance at the profile rate).
    pub unpaced: bool,
    /// Stop after this many produced buffers (drops included); `None` = forever.
    pub max_buffers: Option<u64>,
}

/// An in-process simulated rig serving synthetic frames on a Unix socket. Each connection
/// gets one continuous stream (sequence numbers continue across reconnects, like a rig that
/// kept running while the cable was out).
#[derive(Debug)]
pub struct FakeRig {
    pub socket: PathBuf,
    stop: Arc<AtomicBool>,
    vanish: Arc<AtomicBool>,
    /// Buffers written to clients.
    pub sent: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl FakeRig {
    /// Binds `socket` and serves in a background thread.
    pub fn start(socket: &Path, cfg: FakeRigConfig) -> Result<Self, CaptureError> {
        let _ = std::fs::remove_file(socket);
        let listener = UnixListener::bind(socket).map_err(|source| CaptureError::Device {
            path: socket.to_owned(),
            what: "bind fake rig socket",
            source,
        })?;
        listener
            .set_nonblocking(true)
            .map_err(|source| CaptureError::Device {
                path: socket.to_owned(),
                what: "set nonblocking",
                source,
            })?;
        let mut rig = SynthRig::new(cfg.thermal, cfg.rgb, cfg.script.clone(), monotonic_now_ns())?;
        let stop = Arc::new(AtomicBool::new(false));
        let vanish = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(AtomicU64::new(0));
        let (stop2, vanish2, sent2) = (stop.clone(), vanish.clone(), sent.clone());
        let name = socket.display().to_string();
        let thread = std::thread::spawn(move || {
            let mut produced = 0u64;
            // Wall/monotonic offset so buffers carry "now" when sent in real time.
            let t0 = rig.next_time_ns();
            let started = Instant::now();
            'serve: while !stop2.load(Ordering::Relaxed) {
                let Ok((mut conn, _)) = listener.accept() else {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                };
                let _ = conn.set_nonblocking(false);
                let _ = conn.set_write_timeout(Some(Duration::from_secs(2)));
                loop {
                    if stop2.load(Ordering::Relaxed) {
                        break 'serve;
                    }
                    if vanish2.load(Ordering::Relaxed) {
                        drop(conn);
                        while vanish2.load(Ordering::Relaxed) && !stop2.load(Ordering::Relaxed) {
                            // Refuse connections while "unplugged"; the core keeps running, so
                            // frames due meanwhile are lost (their sequence numbers consumed).
                            while let Ok((c, _)) = listener.accept() {
                                drop(c);
                            }
                            while Duration::from_nanos(rig.next_time_ns() - t0) <= started.elapsed()
                            {
                                produced += 1;
                                let _ = rig.next_buffer();
                            }
                            std::thread::sleep(Duration::from_millis(10));
                        }
                        continue 'serve;
                    }
                    if cfg.max_buffers.is_some_and(|m| produced >= m) {
                        std::thread::sleep(Duration::from_millis(10));
                        continue;
                    }
                    if !cfg.unpaced {
                        let due = Duration::from_nanos(rig.next_time_ns() - t0);
                        let el = started.elapsed();
                        if due > el {
                            std::thread::sleep((due - el).min(Duration::from_millis(20)));
                            continue;
                        }
                    }
                    produced += 1;
                    let Some(raw) = rig.next_buffer() else {
                        continue;
                    };
                    if wire_from_raw(&raw).write_to(&mut conn, &name).is_err() {
                        continue 'serve;
                    }
                    sent2.fetch_add(1, Ordering::Relaxed);
                }
            }
        });
        Ok(Self {
            socket: socket.to_owned(),
            stop,
            vanish,
            sent,
            thread: Some(thread),
        })
    }

    /// Simulates unplugging (`true`) and replugging (`false`) the rig.
    pub fn set_vanished(&self, vanished: bool) {
        self.vanish.store(vanished, Ordering::Relaxed);
    }
}

impl Drop for FakeRig {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.socket);
    }
}

#[cfg(test)]
mod tests {
    //! Proves: `--device sim` specs parse, wire flags map to frame state both ways, and a
    //! `SimSource` reads a fake rig's frames and reports its disappearance as an error; the
    //! fallback socket folder is private (created 0700; a symlink, a foreign or group/world-
    //! reachable folder refused).
    //! Does not run the `s3tir-firmware-sim` binary (tests/tests/capture_*.rs do, when built).
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_fallback_socket_folder_is_private() {
        use std::os::unix::fs::PermissionsExt;
        let tmp = tempfile::tempdir().unwrap();
        let uid = nix::unistd::getuid().as_raw();
        let dir = tmp.path().join("s3tir-1000");
        private_dir(&dir, uid).unwrap();
        let mode = std::fs::metadata(&dir).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o700, "created private");
        private_dir(&dir, uid).unwrap(); // our own private folder is accepted again
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
        let err = private_dir(&dir, uid).unwrap_err().to_string();
        assert!(err.contains("others can reach it"), "{err}");
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(&dir, &link).unwrap();
        let err = private_dir(&link, uid).unwrap_err().to_string();
        assert!(err.contains("not a directory"), "{err}");
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        let err = private_dir(&dir, uid.wrapping_add(1))
            .unwrap_err()
            .to_string();
        assert!(err.contains("belongs to uid"), "{err}");
    }

    #[test]
    fn specs_parse() {
        assert_eq!(SimSpec::parse("sim").unwrap().unwrap().profile, "boson640");
        assert_eq!(
            SimSpec::parse("sim:lepton35").unwrap().unwrap().profile,
            "lepton35"
        );
        assert!(SimSpec::parse("sim:nope").unwrap().is_err());
        assert!(SimSpec::parse("/dev/video0").is_none());
    }

    #[test]
    fn wire_round_trip_keeps_state() {
        let mut rig = SynthRig::new(
            ThermalSynth::lepton35(),
            None,
            Script {
                ffc_frames: vec![0],
                ..Script::default()
            },
            5,
        )
        .unwrap();
        let raw = rig.next_buffer().unwrap();
        assert_eq!(raw_from_wire(wire_from_raw(&raw)), raw);
    }

    #[test]
    fn source_reads_fake_rig_and_sees_it_vanish() {
        let dir = tempfile::tempdir().unwrap();
        let sock = dir.path().join("rig.sock");
        let rig = FakeRig::start(
            &sock,
            FakeRigConfig {
                thermal: ThermalSynth::lepton35(),
                rgb: None,
                script: Script::default(),
                unpaced: true,
                max_buffers: None,
            },
        )
        .unwrap();
        let mut src = SimSource::connect(&sock).unwrap();
        let a = src.next_frame(Duration::from_secs(2)).unwrap().unwrap();
        let b = src.next_frame(Duration::from_secs(2)).unwrap().unwrap();
        assert_eq!(b.sequence, a.sequence + 1);
        rig.set_vanished(true);
        let mut failed = false;
        for _ in 0..10_000 {
            if src.next_frame(Duration::from_millis(500)).is_err() {
                failed = true;
                break;
            }
        }
        assert!(failed, "reading from a vanished rig must fail");
        assert!(
            SimSource::connect(&sock)
                .and_then(|mut s| s.next_frame(Duration::from_millis(200)))
                .is_err()
        );
        rig.set_vanished(false);
        std::thread::sleep(Duration::from_millis(50));
        let mut src = SimSource::connect(&sock).unwrap();
        let c = src.next_frame(Duration::from_secs(2)).unwrap().unwrap();
        assert!(c.sequence > b.sequence, "sequence continues after return");
    }
}
