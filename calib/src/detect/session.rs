//! A recorded session (`.mcap`, written by `s3tir-capture`) as calibration input.
//!
//! The session is read with the capture crate's crash-tolerant reader
//! ([`s3tir_capture::session::read_session`]; a truncated file is used up to its last complete
//! chunk, with a warning). Views are the recorded thermal↔RGB pairs (`/pairs`):
//! - a pair whose thermal frame is an FFC-frozen copy (`ffc = in_progress`) is skipped and
//!   listed with the reason (a frozen frame repeats an older image, not the board's pose at
//!   the pair's time);
//! - a board waved at 8.7–60 Hz gives many near-identical pairs, which add detection time but
//!   no information: a pair is taken only when its thermal frame is at least
//!   `min_interval_s` after the previously taken one (default 0.5 s; 0 takes every pair);
//! - a session without pair records (one camera recorded) gives single-camera views from
//!   each stream's frames at the same interval;
//! - at most `max_views` views are kept (default 300), spread evenly over the session.
//!
//! Memory stays bounded however long the session: a first pass (`Chooser`) keeps only each
//! frame's stream, sequence, stamp and FFC state and decides the views; a second pass
//! (`load_chosen`) keeps the pixels of the chosen frames only (an hour of Boson is ~2 GB of
//! thermal frames; 300 views are ~200 MB with the RGB still compressed).
//!
//! The board geometry is not in a session: the caller passes `board.toml`.
//!
//! Each view is named after the session and the frame's session sequence
//! (`session.mcap#thermal/000123`: the recorded sequence, continued past a device reopen, see
//! [`SessionSequences`]), which is what the report's "files not used" list shows.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use s3tir_capture::CaptureError;
use s3tir_capture::frame::{CapturedFrame, RgbFrame, StreamKind, ThermalFrame};
use s3tir_capture::session::{
    FrameWindow, PairRecord, ReadOutcome, RecordedFrame, SessionItem, SessionSequences,
    parse_recorded, read_session,
};

use crate::detect::board::{Camera, FileProblem, ViewFiles};
use crate::detect::scalar::{ScalarImage, SourceKind, luminance};
use crate::error::CalibError;

/// How frames are taken from a session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionOptions {
    /// Smallest time between two views taken (thermal capture clock), seconds.
    pub min_interval_s: f64,
    /// Most views kept (spread evenly over the session); 0 keeps every one.
    pub max_views: usize,
}

impl Default for SessionOptions {
    fn default() -> Self {
        Self {
            min_interval_s: 0.5,
            max_views: DEFAULT_MAX_VIEWS,
        }
    }
}

/// Default [`SessionOptions::max_views`]: far more than a calibration needs (tens of board
/// poses), few enough to hold in memory.
pub const DEFAULT_MAX_VIEWS: usize = 300;

/// A frame as pass 1 remembers it, no pixels: stream (0 thermal, 1 RGB) and session
/// sequence (unique per stream; [`SessionSequences`]).
type FrameKey = (usize, u32);

enum Stored {
    Thermal(ThermalFrame),
    Rgb(RgbFrame),
}

/// The frames of a session chosen as views, kept in memory (RGB still compressed) and decoded
/// on demand.
pub struct SessionImages {
    path: PathBuf,
    frames: HashMap<PathBuf, Stored>,
}

impl std::fmt::Debug for SessionImages {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionImages")
            .field("path", &self.path)
            .field("frames", &self.frames.len())
            .finish()
    }
}

/// Views, images and problems found in a session.
#[derive(Debug)]
pub struct SessionViews {
    pub views: Vec<ViewFiles>,
    pub images: SessionImages,
    pub problems: Vec<FileProblem>,
    /// Notes for the warnings list (truncation, pairs thinned out).
    pub notes: Vec<String>,
}

fn frame_name(session: &Path, stream: StreamKind, sequence: u32) -> PathBuf {
    PathBuf::from(format!(
        "{}#{}/{sequence:06}",
        session.display(),
        stream.name()
    ))
}

/// At most `max` of `items` (0: all), spread evenly; a note says how many were left out.
fn spread<T>(items: Vec<T>, max: usize, notes: &mut Vec<String>) -> Vec<T> {
    let n = items.len();
    if max == 0 || n <= max {
        return items;
    }
    notes.push(format!(
        "session: {max} of {n} candidate views kept, spread evenly over the recording (--session-max-views)"
    ));
    let keep: std::collections::BTreeSet<usize> = (0..max).map(|i| i * n / max).collect();
    items
        .into_iter()
        .enumerate()
        .filter(|(i, _)| keep.contains(i))
        .map(|(_, x)| x)
        .collect()
}

/// Reads a session and chooses its views (module docs).
pub fn read_views(path: &Path, opts: &SessionOptions) -> Result<SessionViews, CalibError> {
    let min_interval_ns = (opts.min_interval_s.max(0.0) * 1e9) as u64;
    // Pass 1: which frames become views.
    let (chosen, outcome) = Chooser::read(path, min_interval_ns)?;
    let mut capped = Vec::new();
    let pairs = spread(chosen.pairs, opts.max_views, &mut capped);
    let singles = chosen
        .singles
        .map(|list| spread(list, opts.max_views, &mut capped));
    // Pass 2: the chosen frames' pixels.
    let (pairs, singles) = load_chosen(path, &pairs, &singles)?;
    let mut notes = Vec::new();
    if outcome.truncated {
        notes.push(format!(
            "session {} is truncated ({}): read up to its last complete chunk",
            path.display(),
            outcome
                .truncation_reason
                .as_deref()
                .unwrap_or("no reason given")
        ));
    }
    notes.extend(capped);
    if chosen.thinned > 0 {
        notes.push(format!(
            "session: {} of {} recorded pairs used, {} skipped as less than {:.2} s after the previous one (--session-interval-s)",
            pairs.len(),
            chosen.pair_records,
            chosen.thinned,
            opts.min_interval_s
        ));
    }
    let (views, frames) = if chosen.pair_records > 0 {
        pair_views(path, pairs)
    } else {
        notes.push(format!(
            "session {} has no thermal↔RGB pairs: each recorded stream calibrates its camera alone",
            path.display()
        ));
        single_views(path, singles)
    };
    Ok(SessionViews {
        views,
        images: SessionImages {
            path: path.to_path_buf(),
            frames,
        },
        problems: chosen.problems,
        notes,
    })
}

/// Pass 1 of [`read_views`]: the frames chosen as views, remembered without pixels.
struct Chooser<'a> {
    path: &'a Path,
    min_interval_ns: u64,
    /// Recent frames (pairs refer to frames a few back), keyed by arrival, not sequence:
    /// sequences restart when a device is reopened.
    recent: [FrameWindow<(FrameKey, bool)>; 2],
    /// Frames are named by their session sequence: a reopened device's restarted sequence
    /// numbers neither collide nor pick the wrong frame.
    ids: SessionSequences,
    /// Single-stream candidates, used when the session has no pairs.
    singles: [Vec<FrameKey>; 2],
    last_single_ns: [Option<u64>; 2],
    pairs: Vec<(FrameKey, FrameKey)>,
    problems: Vec<FileProblem>,
    /// Pair records read (taken or not).
    pair_records: usize,
    /// Pairs skipped as too soon after the previous one taken.
    thinned: usize,
    last_pair_ns: Option<u64>,
}

impl<'a> Chooser<'a> {
    /// Reads the session at `path` once and chooses its views: pairs at least
    /// `min_interval_ns` apart, else single-stream frames as far apart.
    fn read(path: &'a Path, min_interval_ns: u64) -> Result<(Self, ReadOutcome), CalibError> {
        let mut chooser = Self {
            path,
            min_interval_ns,
            recent: Default::default(),
            ids: SessionSequences::default(),
            singles: [Vec::new(), Vec::new()],
            last_single_ns: [None, None],
            pairs: Vec::new(),
            problems: Vec::new(),
            pair_records: 0,
            thinned: 0,
            last_pair_ns: None,
        };
        let outcome = read_session(path, |item| {
            match item {
                SessionItem::Frame(f) => chooser.frame(&f)?,
                SessionItem::Pair(p) => chooser.pair(&p),
                // Drops, status, rig trigger pulses and the rig clock fit do not change which
                // frames show the board.
                SessionItem::Drop(_)
                | SessionItem::Status(_)
                | SessionItem::Trigger(_)
                | SessionItem::Clock(_) => {}
            }
            Ok(())
        })
        .map_err(|source| CalibError::Session { source })?;
        Ok((chooser, outcome))
    }

    /// Whether a frame at `now_ns` is at least the minimum interval after `last_ns`.
    fn due(&self, last_ns: Option<u64>, now_ns: u64) -> bool {
        last_ns.is_none_or(|l| now_ns >= l + self.min_interval_ns)
    }

    /// Remembers a frame (stream, session sequence, FFC state) for the pairs to come, and
    /// takes it as a single-stream candidate while no pair has been seen.
    fn frame(&mut self, f: &RecordedFrame) -> Result<(), CaptureError> {
        let k = usize::from(f.raw.stream == StreamKind::Rgb);
        let key = (k, self.ids.next(f.raw.stream, f.raw.sequence));
        // Parsed for its FFC state (telemetry decides it); pixels dropped.
        let frame = parse_recorded(self.path, f)?;
        let frozen = matches!(&frame, CapturedFrame::Thermal(t) if t.is_ffc_frozen());
        // Single-stream views are only needed while no pair has been seen.
        let t_ns = f.raw.monotonic_ns;
        if self.pair_records == 0 && !frozen && self.due(self.last_single_ns[k], t_ns) {
            self.last_single_ns[k] = Some(t_ns);
            self.singles[k].push(key);
        }
        self.recent[k].push(f.raw.sequence, (key, frozen));
        Ok(())
    }

    /// Takes a pair, unless it refers to a frame not in the session or an FFC-frozen thermal
    /// frame (both listed as problems) or comes too soon after the previous one taken.
    fn pair(&mut self, p: &PairRecord) {
        self.pair_records += 1;
        self.singles = [Vec::new(), Vec::new()];
        let (Some(&(t, frozen)), Some(&(r, _))) = (
            self.recent[0].get(p.thermal_sequence),
            self.recent[1].get(p.rgb_sequence),
        ) else {
            self.problems.push(FileProblem {
                path: frame_name(self.path, StreamKind::Thermal, p.thermal_sequence),
                reason: format!(
                    "pair with RGB frame {} refers to a frame not in the session",
                    p.rgb_sequence
                ),
            });
            return;
        };
        if frozen {
            self.problems.push(FileProblem {
                path: frame_name(self.path, StreamKind::Thermal, p.thermal_sequence),
                reason:
                    "FFC-frozen thermal frame (flat-field correction in progress): pair skipped"
                        .into(),
            });
            return;
        }
        if !self.due(self.last_pair_ns, p.thermal_monotonic_ns) {
            self.thinned += 1;
            return;
        }
        self.last_pair_ns = Some(p.thermal_monotonic_ns);
        self.pairs.push((t, r));
    }
}

/// A chosen pair with its frames: (session sequence, frame) of each camera.
type LoadedPair = ((u32, ThermalFrame), (u32, RgbFrame));

/// The chosen frames of each camera used alone, as (session sequence, frame).
type LoadedSingles = [Vec<(u32, CapturedFrame)>; 2];

/// Pass 2 of [`read_views`]: reads the session again, keeping the chosen frames' pixels; the
/// pairs and single-stream frames as (session sequence, frame).
fn load_chosen(
    path: &Path,
    pairs: &[(FrameKey, FrameKey)],
    singles: &[Vec<FrameKey>; 2],
) -> Result<(Vec<LoadedPair>, LoadedSingles), CalibError> {
    let wanted: std::collections::HashSet<FrameKey> = pairs
        .iter()
        .flat_map(|(t, r)| [*t, *r])
        .chain(singles.iter().flatten().copied())
        .collect();
    let mut found: HashMap<FrameKey, CapturedFrame> = HashMap::with_capacity(wanted.len());
    let mut ids = SessionSequences::default();
    read_session(path, |item| {
        if let SessionItem::Frame(f) = item {
            let key = (
                usize::from(f.raw.stream == StreamKind::Rgb),
                ids.next(f.raw.stream, f.raw.sequence),
            );
            if wanted.contains(&key) {
                found.insert(key, parse_recorded(path, &f)?);
            }
        }
        Ok(())
    })
    .map_err(|source| CalibError::Session { source })?;
    let pairs: Vec<LoadedPair> = pairs
        .iter()
        .filter_map(|(t, r)| match (found.remove(t), found.remove(r)) {
            (Some(CapturedFrame::Thermal(tf)), Some(CapturedFrame::Rgb(rf))) => {
                Some(((t.1, tf), (r.1, rf)))
            }
            _ => None,
        })
        .collect();
    let singles: [Vec<(u32, CapturedFrame)>; 2] = singles.each_ref().map(|list| {
        list.iter()
            .filter_map(|k| found.remove(k).map(|f| (k.1, f)))
            .collect()
    });
    Ok((pairs, singles))
}

/// One two-camera view per pair, and the frames by name.
fn pair_views(path: &Path, pairs: Vec<LoadedPair>) -> (Vec<ViewFiles>, HashMap<PathBuf, Stored>) {
    let mut frames = HashMap::new();
    let mut views = Vec::new();
    for ((ts, t), (rs, r)) in pairs {
        let tn = frame_name(path, StreamKind::Thermal, ts);
        let rn = frame_name(path, StreamKind::Rgb, rs);
        views.push(ViewFiles {
            key: format!("{ts:06}"),
            files: [Some(tn.clone()), Some(rn.clone())],
        });
        frames.insert(tn, Stored::Thermal(t));
        frames.insert(rn, Stored::Rgb(r));
    }
    (views, frames)
}

/// One single-camera view per frame (thermal first, then RGB), and the frames by name.
fn single_views(
    path: &Path,
    singles: [Vec<(u32, CapturedFrame)>; 2],
) -> (Vec<ViewFiles>, HashMap<PathBuf, Stored>) {
    let mut frames = HashMap::new();
    let mut views = Vec::new();
    for (k, list) in singles.into_iter().enumerate() {
        for (sequence, frame) in list {
            let (stream, stored) = match frame {
                CapturedFrame::Thermal(t) => (StreamKind::Thermal, Stored::Thermal(t)),
                CapturedFrame::Rgb(r) => (StreamKind::Rgb, Stored::Rgb(r)),
            };
            let name = frame_name(path, stream, sequence);
            let mut files = [None, None];
            files[k] = Some(name.clone());
            views.push(ViewFiles {
                key: format!("{}-{sequence:06}", stream.name()),
                files,
            });
            frames.insert(name, stored);
        }
    }
    (views, frames)
}

impl SessionImages {
    /// Decodes a view's frame (`name` as listed in [`SessionViews::views`]).
    pub fn load(&self, name: &Path, camera: Camera) -> Result<ScalarImage, CalibError> {
        let bad = |reason: String| CalibError::Image {
            path: name.to_path_buf(),
            reason,
        };
        let img = match (self.frames.get(name), camera) {
            (Some(Stored::Thermal(t)), Camera::Thermal) => ScalarImage {
                width_px: t.width,
                height_px: t.height,
                values: t.pixels.iter().map(|&v| f32::from(v)).collect(),
                source: SourceKind::Grey16,
            },
            (Some(Stored::Rgb(r)), Camera::Rgb) => {
                let rgb = r
                    .to_rgb8(&self.path.display().to_string())
                    .map_err(|source| CalibError::Frame {
                        path: name.to_path_buf(),
                        source,
                    })?;
                let n = (r.width as usize) * (r.height as usize);
                if rgb.len() != 3 * n {
                    return Err(bad(format!(
                        "decoded {} bytes for a {}x{} RGB frame",
                        rgb.len(),
                        r.width,
                        r.height
                    )));
                }
                ScalarImage {
                    width_px: r.width,
                    height_px: r.height,
                    values: rgb
                        .chunks_exact(3)
                        .map(|p| luminance([p[0], p[1], p[2]]))
                        .collect(),
                    source: SourceKind::ColourLuminance,
                }
            }
            _ => return Err(bad("no such frame in the session".into())),
        };
        if img.width_px < 16
            || img.height_px < 16
            || img.values.len() != (img.width_px * img.height_px) as usize
        {
            return Err(bad(format!(
                "{}x{} frame with {} values is not usable for board detection",
                img.width_px,
                img.height_px,
                img.values.len()
            )));
        }
        Ok(img)
    }
}
