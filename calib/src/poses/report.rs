//! What the stage did: the report (also `poses.json` in the dataset), the time per step, and
//! the few human lines the CLIs print from it.

use std::path::PathBuf;

use serde::Serialize;

use super::{agreement, fiducials, select};

/// Seconds spent per stage.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StageTimes {
    pub scan_s: f64,
    pub keyframes_s: f64,
    /// AprilTag detection in the keyframes and PnP.
    pub tags_s: f64,
    pub colmap_features_s: f64,
    pub colmap_matching_s: f64,
    pub colmap_mapper_s: f64,
    pub interpolate_s: f64,
    pub scale_s: f64,
    pub write_s: f64,
    pub total_s: f64,
}

/// What the stage did (also `poses.json` in the dataset).
#[derive(Debug, Clone, Serialize)]
pub struct PosesReport {
    pub session: PathBuf,
    pub dataset: PathBuf,
    /// "rgb" or "thermal": the stream the keyframes come from.
    pub sfm_stream: &'static str,
    /// What posed the keyframes: "colmap", "apriltags" or "board" (fast paths) or "user model".
    pub pose_source: &'static str,
    pub session_truncated: bool,
    pub session_note: Option<String>,
    pub thermal_frames: usize,
    pub rgb_frames: usize,
    pub dropped_frames: u64,
    pub keyframes: usize,
    /// Keyframes posed (by structure from motion, a user's model or AprilTags) and used.
    pub registered: usize,
    /// Posed keyframes not used: their poses jump from their neighbours' in time
    /// (`sfm::drop_jumps`, `fiducials::drop_jumps`).
    pub outlier_keyframes: usize,
    pub sfm_points: usize,
    /// Metres per world unit, when known.
    pub metres_per_unit: Option<f64>,
    pub scale_source: String,
    /// The fiducials are the calibration board (`--board`), not AprilTags.
    pub board: bool,
    /// Keyframes in which at least one tag of the map was decoded (with `--tags`), or one
    /// square of the board found (with `--board`).
    pub tag_keyframes: Option<usize>,
    /// The scale measured from the tags on COLMAP's world (with `--tags`, COLMAP path).
    pub tag_scale: Option<fiducials::TagScale>,
    /// The model's keyframe rotations against the tags' PnP poses (with `--tags`, COLMAP or
    /// user model; [`agreement`]).
    pub tag_agreement: Option<agreement::TagAgreement>,
    /// Thermal views trained on, and held out.
    pub views: usize,
    pub held_out: usize,
    /// RGB views written (`--with-rgb`; held-out ones included; 0 without it).
    #[serde(default)]
    pub rgb_views: usize,
    /// Of them, in `holdout.txt`.
    #[serde(default)]
    pub rgb_held_out: usize,
    /// Count of thermal frames per reason they were not used.
    pub skipped: std::collections::BTreeMap<String, usize>,
    pub times: StageTimes,
    /// One entry per thermal frame and keyframe: what happened to it.
    pub frames: Vec<select::FrameDecision>,
}

/// A few human lines about a report (what the CLIs print).
pub fn summary(r: &PosesReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    if let Some(note) = &r.session_note {
        let _ = writeln!(s, "warning: {note}");
    }
    let _ = writeln!(
        s,
        "session {}: {} thermal, {} RGB frames, {} dropped",
        r.session.display(),
        r.thermal_frames,
        r.rgb_frames,
        r.dropped_frames
    );
    match r.pose_source {
        "apriltags" | "board" => {
            let _ = writeln!(
                s,
                "{} poses on {}: {} of {} keyframes posed by PnP (COLMAP not run)",
                if r.pose_source == "board" {
                    "board"
                } else {
                    "AprilTag"
                },
                r.sfm_stream,
                r.registered,
                r.keyframes
            );
        }
        source => {
            let _ = writeln!(
                s,
                "structure from motion ({source}) on {}: {} of {} keyframes registered, {} points",
                r.sfm_stream, r.registered, r.keyframes, r.sfm_points
            );
        }
    }
    if r.outlier_keyframes > 0 {
        let _ = writeln!(
            s,
            "warning: {} posed keyframes not used, their poses jump from their neighbours' in time (poses.json says which)",
            r.outlier_keyframes
        );
    }
    if let Some(n) = r.tag_keyframes {
        let _ = writeln!(
            s,
            "{} in {n} of {} keyframes",
            if r.board {
                "the board found"
            } else {
                "AprilTags decoded"
            },
            r.keyframes
        );
    }
    if let Some(a) = &r.tag_agreement {
        let _ = writeln!(
            s,
            "{}{} model vs {} poses on {} keyframes: median {:.2}°, max {:.2}°, {} over {:.0}°{}",
            if a.agrees { "" } else { "warning: " },
            r.pose_source,
            if r.board { "board" } else { "AprilTag" },
            a.keyframes,
            a.median_deg,
            a.max_deg,
            a.disagreeing,
            agreement::DISAGREE_DEG,
            if a.agrees {
                ""
            } else {
                " — the model disagrees with the fiducials (hinged in parts?); check poses.json, or run again"
            }
        );
    }
    let _ = writeln!(s, "scale: {}", r.scale_source);
    let _ = writeln!(
        s,
        "dataset {}: {} training views, {} held out",
        r.dataset.display(),
        r.views,
        r.held_out
    );
    if r.rgb_views > 0 {
        let _ = writeln!(
            s,
            "  with RGB: {} posed RGB keyframes, {} of them held out (camera 2)",
            r.rgb_views, r.rgb_held_out
        );
    }
    for (why, n) in &r.skipped {
        let _ = writeln!(s, "  skipped {n}: {why}");
    }
    let t = &r.times;
    let _ = writeln!(
        s,
        "time {:.1} s: scan {:.1}, tags {:.1}, features {:.1}, matching {:.1}, mapper {:.1}, write {:.1}",
        t.total_s,
        t.scan_s,
        t.tags_s,
        t.colmap_features_s,
        t.colmap_matching_s,
        t.colmap_mapper_s,
        t.write_s
    );
    s
}
