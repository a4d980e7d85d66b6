//! The capture daemon: device reader threads → one bounded queue → pipeline → session writer,
//! on a tokio runtime that also keeps the recording duration and the chunk-flush ticks. It
//! draws nothing and installs no signal handler: the caller stops it through the `stop` flag
//! and is told what happens through [`DaemonEvent`]s (the `s3tir-capture` binary turns them
//! into its status line and sets the flag on SIGINT/SIGTERM).
//!
//! - Backpressure: readers `try_send` into a bounded queue of [`DaemonConfig::queue_frames`]
//!   buffers. When the writer falls behind (slow disk) frames are dropped and counted per
//!   stream (`queue_drops_*` in the session's status records), never buffered without bound.
//! - Reconnect: a reader whose device fails (unplugged camera, simulated rig gone) reopens it
//!   every 200 ms until it returns; each return is counted in `reconnects`.
//! - Stall watchdog: a device that stays open but delivers nothing for
//!   [`DaemonConfig::stall_timeout`] (UVC bridges such as the PureThermal are known to stall
//!   this way; V4L2 only times out) is closed and reopened, counted in `stalls`. Frames lost
//!   across a reopen are counted as drops by time ([`crate::session::pairing::SeqTracker`]): a
//!   reopened V4L2 device restarts its sequence numbers.
//! - Shutdown: the caller's `stop` flag or the end of [`DaemonConfig::duration`] stop the
//!   readers, drain the queue, decide pending pairs, and finish the file (summary + footer).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use crate::backend::FrameSource;
use crate::backend::stamp::wall_now_ns;
use crate::error::CaptureError;
use crate::error::Chain;
use crate::frame::{FfcState, RawFrame, StreamKind};
use crate::session::clock_sync::ClockMap;
use crate::session::pairing::PairingMode;
use crate::session::pipeline::{Pipeline, StreamCounts};
use crate::session::{SessionInfo, SessionRecord, SessionWriter, StatusRecord, TriggerRecord};
use crate::wire::rig_protocol::{MAX_TRIGGER_EVENTS, TriggerEvent};

/// Opens (and reopens) a device.
pub type SourceFactory =
    Box<dyn Fn() -> Result<Box<dyn FrameSource>, CaptureError> + Send + Sync + 'static>;

/// A device the daemon reads, by name.
pub struct SourceSpec {
    pub name: String,
    pub open: SourceFactory,
}

impl std::fmt::Debug for SourceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SourceSpec")
            .field("name", &self.name)
            .finish()
    }
}

/// What the daemon records.
pub struct DaemonConfig {
    pub sources: Vec<SourceSpec>,
    pub out: PathBuf,
    pub info: SessionInfo,
    pub pairing: PairingMode,
    /// Stop after this long (`None`: until the caller sets `stop`).
    pub duration: Option<Duration>,
    /// Capacity of the reader → writer queue, in buffers.
    pub queue_frames: usize,
    /// Calibration file attached to the session: (name with the file's extension, bytes);
    /// the media type follows the extension.
    pub calibration: Option<(String, Vec<u8>)>,
    /// Extra per-buffer write delay (tests: simulates a slow disk).
    pub slow_disk: Option<Duration>,
    /// A device that delivers no buffer for this long is reopened (the stall watchdog).
    pub stall_timeout: Duration,
    /// Polls the thermal core's FFC state (Boson over FSLP), every 100 ms in its own thread.
    /// Thermal frames whose device says nothing about FFC (V4L2 Y16 from a Boson carries no
    /// telemetry) take the last polled state, so frozen frames are flagged.
    pub ffc_poll: Option<FfcPoller>,
    /// Polls the rig controller for trigger pulses after the given count (every 100 ms, in
    /// its own thread); with `rough_clock`, frames are paired by pulse
    /// ([`crate::session::clock_sync`]).
    pub trigger_poll: Option<TriggerPoller>,
    /// Controller → camera clock map from a status exchange before the trigger started, and
    /// the controller's pulse count then.
    pub rough_clock: Option<(ClockMap, u32)>,
}

/// See [`DaemonConfig::trigger_poll`]: `since_count` → pulses after it (at most 32 a call).
pub type TriggerPoller =
    Box<dyn FnMut(u32) -> Result<Vec<TriggerEvent>, CaptureError> + Send + 'static>;

impl std::fmt::Debug for DaemonConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DaemonConfig")
            .field("sources", &self.sources)
            .field("out", &self.out)
            .field("pairing", &self.pairing)
            .field("duration", &self.duration)
            .field("queue_frames", &self.queue_frames)
            .field("ffc_poll", &self.ffc_poll.is_some())
            .field("trigger_poll", &self.trigger_poll.is_some())
            .field("rough_clock", &self.rough_clock)
            .finish_non_exhaustive()
    }
}

/// See [`DaemonConfig::ffc_poll`].
pub type FfcPoller = Box<dyn FnMut() -> Result<FfcState, CaptureError> + Send + 'static>;

const FFC_NONE: u8 = 255;

fn ffc_to_u8(s: FfcState) -> u8 {
    match s {
        FfcState::Idle => 0,
        FfcState::Imminent => 1,
        FfcState::InProgress => 2,
        FfcState::Unknown => FFC_NONE,
    }
}

fn ffc_from_u8(v: u8) -> FfcState {
    match v {
        0 => FfcState::Idle,
        1 => FfcState::Imminent,
        2 => FfcState::InProgress,
        _ => FfcState::Unknown,
    }
}

/// Gives a thermal buffer the polled FFC state when its device reported none.
pub fn apply_polled_ffc(raw: &mut RawFrame, polled: FfcState) {
    if raw.stream == StreamKind::Thermal && raw.ffc_hint == FfcState::Unknown {
        raw.ffc_hint = polled;
    }
}

/// Live counters, shared with the caller.
#[derive(Debug, Default)]
pub struct Counters {
    pub frames: [AtomicU64; 2],
    pub rejected: [AtomicU64; 2],
    pub queue_drops: [AtomicU64; 2],
    pub reconnects: AtomicU64,
    pub stalls: AtomicU64,
    pub serial_errors: AtomicU64,
    pub bytes: AtomicU64,
}

/// Default of [`DaemonConfig::stall_timeout`]: the slowest core (Lepton, 8.7 Hz) delivers ~26
/// frames in this time, and a Boson FFC freezes the image, not the stream.
pub const DEFAULT_STALL_TIMEOUT: Duration = Duration::from_secs(3);

impl Counters {
    fn status(&self) -> StatusRecord {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        StatusRecord {
            wall_unix_ns: wall_now_ns(),
            rejected_thermal: l(&self.rejected[0]),
            rejected_rgb: l(&self.rejected[1]),
            queue_drops_thermal: l(&self.queue_drops[0]),
            queue_drops_rgb: l(&self.queue_drops[1]),
            reconnects: l(&self.reconnects),
            serial_errors: l(&self.serial_errors),
            stalls: l(&self.stalls),
        }
    }
}

/// What a finished recording did (`s3tir-capture --json` prints it).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DaemonReport {
    pub thermal: StreamCounts,
    pub rgb: StreamCounts,
    pub pairs: u64,
    pub status: StatusRecord,
    pub bytes_written: u64,
    pub elapsed_s: f64,
    /// The last controller → camera clock map (when triggering).
    pub clock: Option<ClockMap>,
}

/// What a running recording tells its caller ([`run_with_events`]).
#[derive(Debug, Clone, PartialEq)]
pub enum DaemonEvent {
    /// Once a second: frame rates over the last second and the live counters.
    Status {
        /// Since the recording started.
        elapsed: Duration,
        /// Thermal frames recorded per second over the last second.
        thermal_hz: f64,
        /// RGB frames recorded per second over the last second.
        rgb_hz: f64,
        /// The counters as the session's status records carry them.
        status: StatusRecord,
        /// Bytes written to the session so far.
        bytes_written: u64,
    },
    /// The recording is ending: the queue is drained and the file finished next.
    Stopping { why: StopReason },
}

/// Why a recording ends ([`DaemonEvent::Stopping`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// The caller set the `stop` flag (a signal, the end of a simulated walk).
    Requested,
    /// [`DaemonConfig::duration`] has passed.
    Duration,
    /// The session writer stopped (disk full, I/O error); [`run`] returns its error.
    WriterStopped,
}

enum Msg {
    Frame {
        device: Arc<str>,
        raw: RawFrame,
        wall_unix_ns: u64,
    },
    Triggers(Vec<TriggerEvent>),
    Tick,
}

fn idx(s: StreamKind) -> usize {
    match s {
        StreamKind::Thermal => 0,
        StreamKind::Rgb => 1,
    }
}

/// Records until the duration ends or `stop` is set. Blocks the calling thread (it builds its
/// own tokio runtime). The same as [`run_with_events`] with the events ignored.
pub fn run(
    cfg: DaemonConfig,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
) -> Result<DaemonReport, CaptureError> {
    run_with_events(cfg, stop, counters, |_| {})
}

/// Records until the duration ends or `stop` is set, calling `on_event` on the calling thread
/// with the recording's status once a second and when it is stopping. Blocks the calling
/// thread (it builds its own tokio runtime).
pub fn run_with_events(
    cfg: DaemonConfig,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    on_event: impl FnMut(DaemonEvent),
) -> Result<DaemonReport, CaptureError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|source| CaptureError::SessionIo {
            path: cfg.out.clone(),
            what: "start runtime",
            source,
        })?;
    rt.block_on(run_async(cfg, stop, counters, on_event))
}

/// The recording: the session file opened (the calibration attached), a blocking reader per
/// source and per serial poller, the writer thread, and the control loop until a stop; then
/// every task joined and the report made.
async fn run_async(
    cfg: DaemonConfig,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    mut on_event: impl FnMut(DaemonEvent),
) -> Result<DaemonReport, CaptureError> {
    let started = Instant::now();
    let mut writer = SessionWriter::create(&cfg.out, &cfg.info)?;
    if let Some((name, data)) = &cfg.calibration {
        writer.attach(name, attachment_media_type(name), data)?;
    }
    let (tx, rx) = mpsc::channel::<Msg>(cfg.queue_frames.max(2));
    let ffc = Arc::new(AtomicU8::new(FFC_NONE));
    let mut readers = Vec::new();
    if let Some(poll) = cfg.ffc_poll {
        readers.push(spawn_ffc_poller(
            poll,
            ffc.clone(),
            stop.clone(),
            counters.clone(),
        ));
    }
    if let Some(poll) = cfg.trigger_poll {
        let since = cfg.rough_clock.map_or(0, |(_, c)| c);
        readers.push(spawn_trigger_poller(
            poll,
            since,
            tx.clone(),
            stop.clone(),
            counters.clone(),
        ));
    }
    // Readers: one blocking thread per device.
    let stall_timeout = cfg.stall_timeout;
    for spec in cfg.sources {
        let tx = tx.clone();
        let stop = stop.clone();
        let counters = counters.clone();
        let ffc = ffc.clone();
        readers.push(tokio::task::spawn_blocking(move || {
            read_loop(spec, tx, stop, counters, ffc, stall_timeout);
        }));
    }
    // Writer: the pipeline and the file, on a blocking thread.
    let wcounters = counters.clone();
    let (pairing, slow, rough_clock) = (cfg.pairing, cfg.slow_disk, cfg.rough_clock);
    let writer_task = tokio::task::spawn_blocking(move || {
        write_loop(writer, rx, pairing, slow, rough_clock, &wcounters)
    });
    let control = Control {
        started,
        duration: cfg.duration,
        stop: &stop,
        counters: &counters,
    };
    let why = control.run(&tx, &mut on_event).await;
    on_event(DaemonEvent::Stopping { why });
    stop.store(true, Ordering::Relaxed);
    for r in readers {
        let _ = r.await;
    }
    drop(tx);
    let (pipe, bytes_written) = writer_task.await.map_err(|e| CaptureError::SessionIo {
        path: cfg.out.clone(),
        what: "writer task",
        source: std::io::Error::other(e),
    })??;
    Ok(DaemonReport {
        clock: pipe.clock(),
        thermal: pipe.thermal,
        rgb: pipe.rgb,
        pairs: pipe.pairs,
        status: counters.status(),
        bytes_written,
        elapsed_s: started.elapsed().as_secs_f64(),
    })
}

/// The media type of an attachment, by its file name's extension.
fn attachment_media_type(name: &str) -> &'static str {
    match name.rsplit('.').next() {
        Some("yaml" | "yml") => "application/yaml",
        Some("toml") => "application/toml",
        Some("json") => "application/json",
        _ => "application/octet-stream",
    }
}

/// The FFC-state poller (serial control), every 100 ms until the stop: a failed poll is
/// counted, warned about, and leaves the state unknown.
fn spawn_ffc_poller(
    mut poll: FfcPoller,
    ffc: Arc<AtomicU8>,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
) -> tokio::task::JoinHandle<()> {
    tokio::task::spawn_blocking(move || {
        while !stop.load(Ordering::Relaxed) {
            match poll() {
                Ok(s) => ffc.store(ffc_to_u8(s), Ordering::Relaxed),
                Err(e) => {
                    counters.serial_errors.fetch_add(1, Ordering::Relaxed);
                    ffc.store(FFC_NONE, Ordering::Relaxed);
                    tracing::warn!("FFC state poll failed: {}", Chain(&e));
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

/// Trigger pulses (rig controller) from count `since` on, every 100 ms (at once again while a
/// poll comes back full). Pulses are never dropped: the poller waits for room in the queue
/// (they are few and pairing needs every one).
fn spawn_trigger_poller(
    mut poll: TriggerPoller,
    since: u32,
    tx: mpsc::Sender<Msg>,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
) -> tokio::task::JoinHandle<()> {
    tokio::task::spawn_blocking(move || {
        let mut since = since;
        while !stop.load(Ordering::Relaxed) {
            match poll(since) {
                Ok(events) => {
                    let full = events.len() >= MAX_TRIGGER_EVENTS;
                    if let Some(last) = events.last() {
                        since = last.count;
                        if tx.blocking_send(Msg::Triggers(events)).is_err() {
                            return;
                        }
                    }
                    if full {
                        continue;
                    }
                }
                Err(e) => {
                    counters.serial_errors.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!("trigger poll failed: {}", Chain(&e));
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

/// The writer thread: every message through the pipeline into the session file, a status
/// record each second, the pipeline's last records at the end; returns the pipeline (its
/// figures) and the bytes written.
fn write_loop(
    mut writer: SessionWriter,
    mut rx: mpsc::Receiver<Msg>,
    pairing: PairingMode,
    slow: Option<Duration>,
    rough_clock: Option<(ClockMap, u32)>,
    wcounters: &Counters,
) -> Result<(Pipeline, u64), CaptureError> {
    let mut pipe = Pipeline::new(pairing);
    if let Some((rough, _)) = rough_clock {
        for r in pipe.set_rough_clock(rough) {
            writer.write(&r)?;
        }
    }
    let mut last_status = Instant::now();
    let mut warned = 0u32;
    while let Some(msg) = rx.blocking_recv() {
        match msg {
            Msg::Frame {
                device,
                raw,
                wall_unix_ns,
            } => {
                let k = idx(raw.stream);
                match pipe.push(&device, &raw, wall_unix_ns) {
                    Ok(recs) => {
                        for r in &recs {
                            writer.write(r)?;
                        }
                        wcounters.frames[k].fetch_add(1, Ordering::Relaxed);
                        wcounters
                            .bytes
                            .store(writer.bytes_written(), Ordering::Relaxed);
                    }
                    Err(e) => {
                        wcounters.rejected[k].fetch_add(1, Ordering::Relaxed);
                        if warned < 20 {
                            warned += 1;
                            tracing::warn!("rejected buffer: {}", Chain(&e));
                        }
                    }
                }
                if let Some(d) = slow {
                    std::thread::sleep(d);
                }
            }
            Msg::Triggers(events) => {
                for e in events {
                    let t = TriggerRecord {
                        count: e.count,
                        controller_ns: e.time_ns,
                    };
                    for r in pipe.push_trigger(t) {
                        writer.write(&r)?;
                    }
                }
            }
            Msg::Tick => writer.tick()?,
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            writer.write(&SessionRecord::Status(wcounters.status()))?;
        }
    }
    for r in pipe.finish() {
        writer.write(&r)?;
    }
    writer.write(&SessionRecord::Status(wcounters.status()))?;
    let bytes = writer.bytes_written();
    writer.finish()?;
    Ok((pipe, bytes))
}

/// The control loop's view of the recording.
struct Control<'a> {
    started: Instant,
    duration: Option<Duration>,
    stop: &'a AtomicBool,
    counters: &'a Counters,
}

impl Control<'_> {
    /// Every 100 ms: a tick to the writer, a status event each second; ends on the stop flag,
    /// the duration, or a writer that stopped (its error is the report's).
    async fn run(
        &self,
        tx: &mpsc::Sender<Msg>,
        on_event: &mut impl FnMut(DaemonEvent),
    ) -> StopReason {
        let (started, stop, counters) = (self.started, self.stop, self.counters);
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        let mut last_frames = [0u64; 2];
        let mut last_status = Instant::now();
        loop {
            tick.tick().await;
            if stop.load(Ordering::Relaxed) {
                break StopReason::Requested;
            }
            if self.duration.is_some_and(|d| started.elapsed() >= d) {
                break StopReason::Duration;
            }
            // A full queue delays the tick, never drops it. A closed queue means the writer
            // stopped (disk full, I/O error): stop and report its error.
            if tx.send(Msg::Tick).await.is_err() {
                tracing::error!("the session writer stopped; ending the recording");
                break StopReason::WriterStopped;
            }
            if last_status.elapsed() >= Duration::from_secs(1) {
                let dt = last_status.elapsed().as_secs_f64();
                last_status = Instant::now();
                let f = [
                    counters.frames[0].load(Ordering::Relaxed),
                    counters.frames[1].load(Ordering::Relaxed),
                ];
                let hz = |k: usize| (f[k] - last_frames[k]) as f64 / dt;
                let (thermal_hz, rgb_hz) = (hz(0), hz(1));
                last_frames = f;
                on_event(DaemonEvent::Status {
                    elapsed: started.elapsed(),
                    thermal_hz,
                    rgb_hz,
                    status: counters.status(),
                    bytes_written: counters.bytes.load(Ordering::Relaxed),
                });
            }
        }
    }
}

fn read_loop(
    spec: SourceSpec,
    tx: mpsc::Sender<Msg>,
    stop: Arc<AtomicBool>,
    counters: Arc<Counters>,
    ffc: Arc<AtomicU8>,
    stall_timeout: Duration,
) {
    let name: Arc<str> = Arc::from(spec.name.as_str());
    let mut source: Option<Box<dyn FrameSource>> = None;
    let mut ever_opened = false;
    let mut warned_open = false;
    // When the open device last delivered a buffer (or was opened).
    let mut last_buffer = Instant::now();
    // Wait at most this long per call, so a stall is noticed on time.
    let wait = stall_timeout.min(Duration::from_millis(1000));
    while !stop.load(Ordering::Relaxed) {
        let Some(src) = source.as_mut() else {
            match (spec.open)() {
                Ok(s) => {
                    if ever_opened {
                        counters.reconnects.fetch_add(1, Ordering::Relaxed);
                        tracing::info!(device = %name, "device is back: reconnected");
                    }
                    ever_opened = true;
                    warned_open = false;
                    last_buffer = Instant::now();
                    source = Some(s);
                }
                Err(e) => {
                    if !warned_open {
                        tracing::warn!(device = %name, "cannot open ({}); retrying every 200 ms", Chain(&e));
                        warned_open = true;
                    }
                    std::thread::sleep(Duration::from_millis(200));
                }
            }
            continue;
        };
        match src.next_frame(wait) {
            Ok(Some(mut raw)) => {
                last_buffer = Instant::now();
                apply_polled_ffc(&mut raw, ffc_from_u8(ffc.load(Ordering::Relaxed)));
                let k = idx(raw.stream);
                let msg = Msg::Frame {
                    device: name.clone(),
                    raw,
                    wall_unix_ns: wall_now_ns(),
                };
                match tx.try_send(msg) {
                    Ok(()) => {}
                    Err(mpsc::error::TrySendError::Full(_)) => {
                        counters.queue_drops[k].fetch_add(1, Ordering::Relaxed);
                    }
                    Err(mpsc::error::TrySendError::Closed(_)) => return,
                }
            }
            Ok(None) => {
                if last_buffer.elapsed() >= stall_timeout && !stop.load(Ordering::Relaxed) {
                    counters.stalls.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        device = %name,
                        "no buffer for {:.1} s: the device stalled; reopening it",
                        last_buffer.elapsed().as_secs_f64()
                    );
                    source = None;
                }
            }
            // Stopped while waiting (e.g. a simulated walk that has sent its last frame): the
            // source did not fail, the recording ended.
            Err(_) if stop.load(Ordering::Relaxed) => break,
            Err(e) => {
                tracing::warn!(device = %name, "device failed ({}); reconnecting", Chain(&e));
                source = None;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: the polled FFC state is applied only to thermal buffers whose device said
    //! nothing (V4L2), never overriding a device's own report; the state encoding round-trips.
    use super::*;
    use crate::device::FourCc;
    use crate::frame::ThermalUnits;

    #[test]
    fn polled_ffc_fills_only_unknown_thermal_state() {
        let mut raw = RawFrame {
            stream: StreamKind::Thermal,
            fourcc: FourCc::Y16,
            width: 1,
            height: 1,
            bytes_per_line: 2,
            telemetry_rows: 0,
            units: ThermalUnits::RawCounts,
            ffc_hint: FfcState::Unknown,
            sequence: 0,
            monotonic_ns: 0,
            payload: vec![0, 0],
        };
        apply_polled_ffc(&mut raw, FfcState::InProgress);
        assert_eq!(raw.ffc_hint, FfcState::InProgress);
        raw.ffc_hint = FfcState::Idle;
        apply_polled_ffc(&mut raw, FfcState::InProgress);
        assert_eq!(raw.ffc_hint, FfcState::Idle, "device report wins");
        raw.stream = StreamKind::Rgb;
        raw.ffc_hint = FfcState::Unknown;
        apply_polled_ffc(&mut raw, FfcState::InProgress);
        assert_eq!(raw.ffc_hint, FfcState::Unknown, "RGB untouched");
        for s in [
            FfcState::Idle,
            FfcState::Imminent,
            FfcState::InProgress,
            FfcState::Unknown,
        ] {
            assert_eq!(ffc_from_u8(ffc_to_u8(s)), s);
        }
    }
}
