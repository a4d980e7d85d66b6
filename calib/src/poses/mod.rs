//! Poses from a recorded session: a session (`.mcap`) and its rig's calibration become a posed
//! thermal dataset in COLMAP layout, the trainer's input (feature `poses`, no OpenCV).
//!
//! Why here: poses are camera geometry over time. calib already owns the camera model, the
//! rigid transforms, the calibration file, the COLMAP codec and reading sessions; the trainer
//! (which depends on calib's OpenCV-free layer) calls this stage in-process for
//! `s3tir-train SESSION.mcap`, `s3tir-calib poses` runs it alone, and `s3tir-capture export
//! --dataset` (capture sits below calib) runs `s3tir-calib poses` as a process.
//!
//! ## The stage, in order
//! 1. **Scan** ([`frames`]): one read of the session collects every frame's stream, sequence,
//!    capture time (`monotonic_ns`, the common clock of both cameras), FFC state and a sharpness
//!    score (variance of the Laplacian over the image's own contrast). Nothing is kept in
//!    memory but these numbers; a truncated session is read up to its last complete chunk and
//!    the report says how much was readable.
//! 2. **Keyframes** ([`select`]): frames whose sharpness falls below `blur_ratio` × the median
//!    of their neighbours are motion-blurred and skipped, FFC-frozen thermal frames are
//!    skipped; the thermal candidates are the sharpest thermal frame of each `1 / thermal_hz`
//!    slot. Structure from motion runs on the RGB stream: its keyframes are the RGB frames just
//!    before and after each thermal candidate (within `max_sync_s`), so every thermal pose is
//!    interpolated over one RGB period, never across a hand's jitter (on the simulated
//!    hand-held walk, keyframes nearest the thermal frames but interpolated over up to 0.3 s
//!    left errors up to 0.7° from its 1.1 Hz, ±2° roll). Where the thermal stream has no
//!    candidates (an FFC, drops) the gap is bridged: each `1 / keyframe_hz` slot without a
//!    keyframe gets its sharpest RGB frame, so the chain of overlapping keyframes that structure
//!    from motion needs is never broken (an FFC's 3 s hole let COLMAP hinge the walk by
//!    degrees in one run of three). A thermal-only session runs it on the thermal stream, the
//!    sharpest frame of each `1 / keyframe_hz` slot.
//! 3. **Poses of the keyframes.** *Fast path* ([`fiducials`]): with a tag map that places
//!    AprilTags in the world (`--tags FILE`), every keyframe that sees two mapped tags is posed
//!    by PnP on their corners; when enough keyframes are posed so (`min_registered`), COLMAP
//!    does not run and the world is the map's, in metres. The calibration board standing in
//!    the scene (`--board`, [`board`]) is such a map too, in the board's frame, and is found in
//!    thermal keyframes as well (a rig without RGB). Otherwise, **structure from
//!    motion** ([`sfm`]): Debian's `colmap` (3.8) runs as an external process
//!    on the keyframes, CPU SIFT, with the calibrated intrinsics and distortion **fixed** (the
//!    calibration's model, written in COLMAP's words by the workspace's one COLMAP codec), or a
//!    user's model (`--poses DIR`) is read instead. The largest reconstruction is kept, and
//!    a registered keyframe whose pose jumps from its neighbours' in time is not used
//!    ([`sfm::drop_jumps`]; the fast path's PnP poses are judged the same way). With a tag
//!    map, the keyframes that see its tags are also posed by PnP and the model's rotations
//!    are checked against theirs ([`agreement`]: one rotation between the two worlds, or a
//!    warning that the model disagrees, e.g. hinged in parts).
//! 4. **Thermal poses** ([`interp`]): every usable thermal frame (not FFC-frozen, not blurred)
//!    gets the SfM camera's pose interpolated to its capture time (slerp of the rotation, linear
//!    centre) between the two registered keyframes around it (at most `max_gap_s` apart),
//!    composed with the calibrated `rgb_from_thermal`: `world_from_thermal = world_from_rgb(t)
//!    ∘ rgb_from_thermal`. The extrinsic is metric and COLMAP's world is not: its translation is
//!    applied in world units through `metres_per_unit` when the scale is known
//!    (`--metres-per-unit`). Without it the thermal camera centre is taken at the RGB camera's
//!    (the rotation is applied, the few-centimetre lever arm is not): a bounded error of the
//!    lever arm's length, where a guessed scale could be wrong by any factor. The report says
//!    which. With a tag map (`--tags FILE`, [`fiducials`]) the scale is measured: tag corners
//!    triangulated in COLMAP's world against the tags' printed size.
//! 5. **Views** ([`select`]): near-duplicates are thinned (a view is kept when it moved at least
//!    `min_baseline` × the median scene depth or turned `min_rotation_deg` since the last kept
//!    one), every `holdout_every`-th kept view is held out (`holdout.txt`: the trainer never
//!    trains on them; their poses come from interpolation like every thermal view's, no SfM
//!    step saw their pixels).
//! 6. **Dataset** ([`dataset`]): `sparse/0/` (one thermal camera with the calibrated
//!    distortion, `images.txt`, the SfM points in `points3D.txt` — none on the AprilTag fast
//!    path, where the trainer initialises in the scene's bounds), `images/` (the radiometric
//!    16-bit words untouched, PNG), `holdout.txt`, and `poses.json` (every frame's decision and
//!    why, the SfM figures and the timings). Distortion: images stay untouched on disk; the
//!    trainer undistorts them once at load (`OPENCV`/`FULL_OPENCV` camera, bilinear, same K),
//!    so the rasterisers stay pinhole and the dataset stays radiometric. With `--with-rgb`
//!    ([`PosesOptions::with_rgb`]) the posed RGB keyframes join it for joint training: their
//!    frames as 8-bit RGB PNG, the calibrated RGB camera as camera 2, their poses the very
//!    keyframe poses the thermal views were interpolated from (one world), held out around
//!    the held-out thermal views ([`dataset`] module docs).
//!
//! Nothing already written is lost: the output folder must not exist (or be empty), the stage
//! builds in `OUT.partial` (COLMAP's logs stay there when it fails; the next run clears it) and
//! renames it to `OUT` when everything is written, and the session is only read.
//!
//! Around the steps: `rig` takes the calibration (given or attached to the session) and checks
//! it against the session's frames, `output` keeps the output folder safe as above, `report`
//! holds what the stage did ([`PosesReport`]) and the lines the CLIs print ([`summary`]);
//! `stages` has one function per step above, each taking what the earlier ones returned
//! (checked inputs, keyframes, fiducials, registration, track, scale, views, the dataset);
//! [`session_to_dataset`] runs them in order and builds the report.

pub mod agreement;
pub mod args;
pub mod board;
pub mod dataset;
pub mod fiducials;
pub mod folder;
pub mod frames;
pub mod interp;
mod output;
mod report;
mod rig;
pub mod select;
pub mod sfm;
mod stages;
pub mod stats;
#[cfg(test)]
mod tests;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Serialize;
use thiserror::Error;

use crate::model::calfile::CalibrationFile;
use crate::progress::Progress;
use output::{finish_output, start_output};
pub use report::{PosesReport, StageTimes, summary};
pub use rig::{RigModels, attached_calibration, rig_models};

/// Errors of the poses stage; each says what to install, record or pass.
#[derive(Debug, Error)]
pub enum PosesError {
    /// The session reads, but not as the stage needs (a validation).
    #[error("session {path}: {reason}")]
    Session { path: PathBuf, reason: String },
    /// The session could not be read (capture's error names the session, so this level adds
    /// nothing to its message).
    #[error(transparent)]
    SessionRead { source: s3tir_capture::CaptureError },
    #[error(
        "the calibration has no {what}: {why} (calibrate the rig with s3tir-calib BOARD --out calibration.yaml, from a board set or a session recorded with the board in view)"
    )]
    MissingCalibration { what: &'static str, why: String },
    #[error(
        "calibration of another rig: the {camera} camera is calibrated at {calibrated_w}×{calibrated_h} px but session {session} records {session_w}×{session_h} px"
    )]
    CalibrationMismatch {
        camera: &'static str,
        session: PathBuf,
        calibrated_w: u32,
        calibrated_h: u32,
        session_w: u32,
        session_h: u32,
    },
    #[error(
        "`{program}` (COLMAP) cannot be run (install Debian's colmap package, as scripts/install-deps.sh does, pass --colmap PATH, or give a COLMAP model of the keyframes with --poses DIR)"
    )]
    ColmapMissing {
        program: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("COLMAP {step} failed ({status}); its log: {log}")]
    ColmapFailed {
        step: &'static str,
        status: String,
        log: PathBuf,
    },
    #[error(
        "structure from motion registered {registered} of {keyframes} keyframes (at least {needed} needed): the walk may be too fast or blurred, the scene too bland, or the frames too few; record slower, with more texture in view, or lower --blur-ratio; a rig without RGB in a scene of little thermal texture needs thermal fiducials (heated AprilTags with --tags, or the emissivity board with --board). COLMAP's workspace: {workspace}"
    )]
    TooFewRegistered {
        registered: usize,
        keyframes: usize,
        needed: usize,
        workspace: PathBuf,
    },
    /// An output that cannot be written as asked (a validation: never overwrite, sizes).
    #[error("{path}: {reason}")]
    Output { path: PathBuf, reason: String },
    /// An output file could not be encoded or written (an I/O, image, JSON or COLMAP error).
    #[error("{path}")]
    Write {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("the COLMAP model {path}")]
    Model {
        path: PathBuf,
        #[source]
        source: crate::model::colmap::ColmapError,
    },
    #[error("session {path}: {reason}")]
    Nothing { path: PathBuf, reason: String },
    /// An AprilTag map or fiducial option that cannot be used (a validation).
    #[error("AprilTag map or detection {path}: {reason}")]
    Tags { path: PathBuf, reason: String },
    /// The calibration board (`--board`) could not be looked for in a keyframe.
    #[error("AprilTag map or detection {path}: finding the board of {board}")]
    BoardFinder {
        path: PathBuf,
        board: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A folder of images that cannot be posed as it is (a validation: no images, mixed
    /// sizes or kinds, too few views registered).
    #[error("{path}: {reason}")]
    Folder { path: PathBuf, reason: String },
    /// An image of a folder could not be read or decoded (its error says how).
    #[error("{path}")]
    ImageRead {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// An AprilTag map or keyframe could not be read, or the tag detector failed.
    #[error("AprilTag map or detection {path}")]
    TagsRead {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Which COLMAP matcher pairs the keyframes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Matcher {
    /// Every keyframe with every other one (best for ≤ ~60 keyframes and loops).
    Exhaustive,
    /// Each keyframe with its `overlap` successors (video; scales linearly).
    Sequential { overlap: usize },
}

/// Options of the stage (defaults: [`PosesOptions::default`]).
#[derive(Debug, Clone, Serialize)]
pub struct PosesOptions {
    /// The COLMAP program.
    pub colmap: PathBuf,
    /// A COLMAP model (text or binary) of the keyframes to use instead of running COLMAP;
    /// image names as this stage writes them (`rgb_SEQUENCE.jpg`, `thermal_SEQUENCE.png`).
    pub user_model: Option<PathBuf>,
    /// Keyframes per second, at least. Thermal-only sessions: the sharpest thermal frame of
    /// each slot. With RGB the keyframes are the RGB frames around the thermal candidates
    /// (`thermal_hz`), and a slot without any gets its sharpest RGB frame (gaps bridged).
    pub keyframe_hz: f64,
    /// With RGB: a thermal candidate's keyframes are the RGB frames just before and after it,
    /// each at most this far in time.
    pub max_sync_s: f64,
    /// At most this many keyframes (with RGB: two per thermal candidate, candidates thinned
    /// evenly to fit; thermal-only: the slots widen to fit). Matching and mapping time grow
    /// with it (module docs of `sfm`).
    pub max_keyframes: usize,
    /// `None`: exhaustive up to 30 keyframes, sequential (overlap 10) above.
    pub matcher: Option<Matcher>,
    /// A frame is motion-blurred when its sharpness is below this fraction of the median of
    /// its ±`blur_window` neighbours.
    pub blur_ratio: f64,
    pub blur_window: usize,
    /// Thermal views: at most this many per second before thinning.
    pub thermal_hz: f64,
    /// Thinning: a view is kept when it moved this fraction of the median scene depth …
    pub min_baseline: f64,
    /// … or turned this many degrees since the last kept view.
    pub min_rotation_deg: f64,
    /// At most this many thermal views.
    pub max_views: usize,
    /// Every k-th kept view is held out (0: none).
    pub holdout_every: usize,
    /// Interpolate only between registered keyframes at most this far apart in time (with RGB,
    /// also at most one bracket: `2 × max_sync_s`).
    pub max_gap_s: f64,
    /// At least this fraction of the keyframes (and at least 5) must register.
    pub min_registered: f64,
    /// Metres per SfM world unit, when known (module docs, step 4); wins over the tags' scale.
    pub metres_per_unit: Option<f64>,
    /// An AprilTag map (`fiducials` module docs): metric scale for COLMAP's world, and with a
    /// layout, poses without COLMAP.
    pub tags: Option<PathBuf>,
    /// The calibration board standing in the scene ([`board`]): its frame is the world of the
    /// fast path, its squares give COLMAP's world its scale; used like a tag map (not with
    /// `tags`).
    #[serde(skip)]
    pub board: Option<board::BoardFiducial>,
    /// With a tag layout or a board: pose keyframes by PnP and skip COLMAP when enough are
    /// posed (`false`: COLMAP always runs; the fiducials still give the scale).
    pub tag_poses: bool,
    /// CPU threads COLMAP may use.
    pub threads: usize,
    /// Receives the stage's progress (`None`: nobody watches); a binary passes
    /// [`crate::progress::bars::ProgressBars`] to draw bars.
    #[serde(skip)]
    pub progress: Option<Arc<dyn Progress>>,
    /// Also write the posed RGB keyframes (`images/rgb_SEQUENCE.png`, a second camera) for
    /// joint RGB + thermal training ([`dataset`] module docs); an error on a session without
    /// RGB frames.
    pub with_rgb: bool,
}

impl Default for PosesOptions {
    fn default() -> Self {
        Self {
            colmap: PathBuf::from("colmap"),
            user_model: None,
            keyframe_hz: 2.0,
            max_sync_s: 0.12,
            max_keyframes: 240,
            matcher: None,
            blur_ratio: 0.6,
            blur_window: 6,
            thermal_hz: 2.0,
            min_baseline: 0.01,
            min_rotation_deg: 2.0,
            max_views: 300,
            holdout_every: 8,
            max_gap_s: 1.5,
            min_registered: 0.5,
            metres_per_unit: None,
            tags: None,
            board: None,
            tag_poses: true,
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
            progress: None,
            with_rgb: false,
        }
    }
}

/// Runs the whole stage: `session` + `cal` → a posed thermal dataset in `out` (module docs).
///
/// `cal`: the rig's calibration; `None` takes the one attached to the session
/// (`s3tir-capture --calibration FILE`), and fails when there is none.
pub fn session_to_dataset(
    session: &Path,
    cal: Option<&CalibrationFile>,
    out: &Path,
    opts: &PosesOptions,
) -> Result<PosesReport, PosesError> {
    let t_all = std::time::Instant::now();
    let mut times = StageTimes::default();
    let inputs = stages::check_inputs(session, cal, opts, &mut times)?;
    // Only now (inputs checked) is anything created: in OUT.partial, renamed to OUT at the end,
    // so a failed run leaves its COLMAP logs there and never a half dataset under OUT.
    let final_out = out;
    let out = &start_output(final_out)?;
    let keys = stages::choose_keyframes(&inputs, out, opts, &mut times)?;
    let seen = stages::find_fiducials(&inputs, &keys, opts, &mut times)?;
    let reg = stages::register_keyframes(&inputs, &keys, &seen, opts, &mut times)?;
    let t = std::time::Instant::now();
    let track = stages::track(&keys, &reg, opts);
    times.interpolate_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let scale = stages::scale(&inputs, &keys, &seen, &reg, opts);
    times.scale_s = t.elapsed().as_secs_f64();
    let views = stages::select_views(&inputs, &keys, &seen, &reg, &track, &scale, opts)?;
    let t = std::time::Instant::now();
    stages::write_dataset(out, &inputs, &views, &reg)?;
    times.write_s = t.elapsed().as_secs_f64();
    times.total_s = t_all.elapsed().as_secs_f64();

    let report = PosesReport {
        session: session.to_path_buf(),
        dataset: final_out.to_path_buf(),
        sfm_stream: keys.sfm_stream.name(),
        pose_source: reg.pose_source,
        session_truncated: inputs.scan.truncated,
        session_note: inputs.scan.note.clone(),
        thermal_frames: inputs.scan.thermal.len(),
        rgb_frames: inputs.scan.rgb.len(),
        dropped_frames: inputs.scan.dropped,
        keyframes: keys.keyframes.len(),
        registered: reg.registered.len(),
        outlier_keyframes: if seen.fast_path {
            seen.jumps.len()
        } else {
            reg.sfm_jumps.len()
        },
        sfm_points: reg.sfm_points.len(),
        metres_per_unit: scale.metres_per_unit,
        scale_source: scale.scale_source,
        board: opts.board.is_some(),
        tag_keyframes: inputs
            .tag_map
            .as_ref()
            .map(|_| seen.tags.iter().filter(|s| !s.tags.is_empty()).count()),
        tag_scale: scale.tag_scale,
        tag_agreement: scale.tag_agreement,
        views: views.thermal.iter().filter(|v| !v.held_out).count(),
        held_out: views.thermal.iter().filter(|v| v.held_out).count(),
        rgb_views: views.rgb.len(),
        rgb_held_out: views.rgb.iter().filter(|v| v.held_out).count(),
        skipped: views.skipped,
        times,
        frames: views.decisions,
    };
    dataset::write_report(out, &report)?;
    finish_output(out, final_out)?;
    Ok(report)
}
