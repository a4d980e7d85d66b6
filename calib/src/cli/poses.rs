//! `s3tir-calib poses`: part of the `s3tir-calib` binary (not of the library).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;
use clap::{Args, ValueEnum};
use s3tir_calib::detect::board::BoardSpec;
use s3tir_calib::detect::frontend::detect_board;
use s3tir_calib::detect::scalar::load_scalar;
use s3tir_calib::model::calfile::CalibrationFile;
use s3tir_calib::poses::board::BoardFiducial;
use s3tir_calib::poses::frames::Stream;
use s3tir_calib::poses::{self, Matcher, PosesOptions};
use s3tir_calib::progress::Progress;
use s3tir_calib::progress::bars::ProgressBars;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum MatcherArg {
    /// Exhaustive up to 30 keyframes, sequential (overlap 10) above.
    Auto,
    Exhaustive,
    Sequential,
}

/// Turn a recorded session into a posed thermal dataset (COLMAP layout) for `s3tir-train`.
///
/// Structure from motion (COLMAP, CPU) runs on the RGB keyframes with the calibrated RGB
/// camera fixed; each usable thermal frame gets the RGB pose interpolated to its capture time,
/// composed with the calibrated rgb_from_thermal. A session without RGB runs COLMAP on the
/// thermal frames. With an AprilTag map (--tags) or the calibration board standing in the
/// scene (--board) the scale is metric, and keyframes that see them are posed without COLMAP. FFC-frozen and motion-blurred frames are skipped, near-duplicates thinned,
/// every --holdout-every-th view held out (holdout.txt). The dataset: sparse/0/ (the thermal
/// camera with its calibrated distortion; the trainer undistorts at load), images/ (16-bit
/// words untouched), holdout.txt, poses.json (what was kept and why), colmap/ (COLMAP's
/// workspace and logs); with --with-rgb also the posed RGB keyframes (joint training). The
/// output folder must not exist or be empty.
#[derive(Debug, Args)]
pub struct PosesArgs {
    /// Recorded session (.mcap, from s3tir-capture).
    session: PathBuf,
    /// The rig's calibration.yaml (from s3tir-calib); default: the one attached to the session.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// Dataset folder to write (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    /// COLMAP program.
    #[arg(long, env = "S3TIR_COLMAP", default_value = "colmap")]
    colmap: PathBuf,
    /// Use this COLMAP model (text or binary) of the keyframes instead of running COLMAP; its
    /// image names must be the stage's own (rgb_SEQUENCE.jpg / thermal_SEQUENCE.png, as in a
    /// previous run's colmap/images/).
    #[arg(long)]
    poses: Option<PathBuf>,
    /// Keyframes per second for structure from motion, at least: a thermal-only session takes
    /// the sharpest thermal frame of each slot; with RGB the keyframes are the RGB frames
    /// around the thermal candidates, and a slot without any (an FFC, dropped thermal frames)
    /// gets its sharpest RGB frame so that the chain of overlapping keyframes stays unbroken
    #[arg(long, default_value_t = 2.0)]
    keyframe_hz: f64,
    /// At most this many keyframes (two per thermal candidate with RGB; candidates are
    /// thinned to fit). Structure-from-motion time grows with it.
    #[arg(long, default_value_t = 240)]
    max_keyframes: usize,
    /// COLMAP matcher.
    #[arg(long, value_enum, default_value = "auto")]
    matcher: MatcherArg,
    /// A frame is motion-blurred below this fraction of its neighbours' median sharpness.
    #[arg(long, default_value_t = 0.6)]
    blur_ratio: f64,
    /// Thermal candidates per second (the sharpest of each slot), before thinning.
    #[arg(long, default_value_t = 2.0)]
    thermal_hz: f64,
    /// Thinning: keep a view that moved this fraction of the median scene depth …
    #[arg(long, default_value_t = 0.01)]
    min_baseline: f64,
    /// … or turned this many degrees since the last kept view.
    #[arg(long, default_value_t = 2.0)]
    min_rotation_deg: f64,
    /// At most this many thermal views.
    #[arg(long, default_value_t = 300)]
    max_views: usize,
    /// Hold out every k-th view for testing (0: none).
    #[arg(long, default_value_t = 8)]
    holdout_every: usize,
    /// Interpolate poses only between registered keyframes at most this far apart, seconds
    /// (with RGB also at most one bracket of keyframes, 2 × 0.12 s).
    #[arg(long, default_value_t = 1.5)]
    max_gap_s: f64,
    /// Metres per COLMAP world unit, when known: applies the calibrated lever arm between the
    /// cameras at the right scale (without it the thermal centre is taken at the RGB centre).
    #[arg(long)]
    metres_per_unit: Option<f64>,
    /// AprilTag map (TOML: family = "tag36h11", size_m, and optionally [[tag]] id + corners_m,
    /// four world corners in metres: bottom-left, bottom-right, top-right, top-left as
    /// printed). The size gives COLMAP's world its metric scale (tag corners triangulated);
    /// with corners, keyframes that see two mapped tags are posed by PnP, and COLMAP does not
    /// run when enough are; when it does run, its keyframe rotations are checked against the
    /// tags' PnP poses (a warning if the model disagrees, e.g. hinged in parts).
    /// s3tir-firmware-sim writes one beside a walk's truth (tags.toml).
    #[arg(long)]
    tags: Option<PathBuf>,
    /// The calibration board (its board.toml) standing still in the scene: keyframes that see
    /// it, RGB or thermal (an emissivity board shows in both), are posed by PnP on its corners
    /// in the board's frame (metres), and COLMAP does not run when enough are; otherwise it
    /// gives COLMAP's world its metric scale and checks its rotations, as --tags does. Not
    /// with --tags.
    #[arg(long, conflicts_with = "tags")]
    board: Option<PathBuf>,
    /// With a tag layout or --board, run COLMAP anyway (the fiducials then give the scale and
    /// the check).
    #[arg(long)]
    no_tag_poses: bool,
    /// At least this fraction of the keyframes (and at least 5) must be posed. Lower it when
    /// the board or the tags are in view for only part of the walk: views between posed
    /// keyframes are still posed, the rest skipped with their reason.
    #[arg(long, default_value_t = 0.5, value_parser = fraction)]
    min_registered: f64,
    /// Also write every posed RGB keyframe (images/rgb_SEQUENCE.png as recorded, 8-bit RGB;
    /// the calibrated RGB camera as camera 2; its pose in the thermal views' world; those
    /// around held-out thermal views held out too), for joint RGB + thermal training. An error
    /// on a session without RGB.
    #[arg(long)]
    with_rgb: bool,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

fn fraction(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 1.0 => Ok(v),
        _ => Err(format!("{s}: a fraction in (0, 1] is expected")),
    }
}

/// `--board`: the board file, and the calibration front end as its finder.
fn board_fiducial(path: &std::path::Path) -> Result<BoardFiducial> {
    let spec = BoardSpec::load(path)?;
    let (cols, rows, square_m) = (spec.cols(), spec.rows(), spec.square_m());
    type FindError = Box<dyn std::error::Error + Send + Sync>;
    let find = std::sync::Arc::new(move |image: &std::path::Path, stream: Stream| {
        let thermal = stream == Stream::Thermal;
        let scalar = load_scalar(image, thermal, spec.thermal_palette).map_err(FindError::from)?;
        Ok(
            match detect_board(&scalar, &spec).map_err(FindError::from)? {
                Ok(found) => found.corner_ids.into_iter().zip(found.corners_px).collect(),
                Err(_) => Vec::new(),
            },
        )
    });
    Ok(BoardFiducial {
        path: path.to_path_buf(),
        cols,
        rows,
        square_m,
        find,
    })
}

pub fn run(a: &PosesArgs) -> Result<()> {
    let cal = match &a.calibration {
        Some(p) => Some(CalibrationFile::read(p)?),
        None => None,
    };
    let board = a.board.as_deref().map(board_fiducial).transpose()?;
    let opts = PosesOptions {
        colmap: a.colmap.clone(),
        user_model: a.poses.clone(),
        keyframe_hz: a.keyframe_hz,
        max_keyframes: a.max_keyframes,
        matcher: match a.matcher {
            MatcherArg::Auto => None,
            MatcherArg::Exhaustive => Some(Matcher::Exhaustive),
            MatcherArg::Sequential => Some(Matcher::Sequential { overlap: 10 }),
        },
        blur_ratio: a.blur_ratio,
        thermal_hz: a.thermal_hz,
        min_baseline: a.min_baseline,
        min_rotation_deg: a.min_rotation_deg,
        max_views: a.max_views,
        holdout_every: a.holdout_every,
        max_gap_s: a.max_gap_s,
        metres_per_unit: a.metres_per_unit,
        tags: a.tags.clone(),
        board,
        tag_poses: !a.no_tag_poses,
        min_registered: a.min_registered,
        progress: (!a.json).then(|| Arc::new(ProgressBars::new()) as Arc<dyn Progress>),
        with_rgb: a.with_rgb,
        ..PosesOptions::default()
    };
    // No context added: the stage's errors name the session or file they are about.
    let report = poses::session_to_dataset(&a.session, cal.as_ref(), &a.out, &opts)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", poses::summary(&report));
    }
    Ok(())
}
