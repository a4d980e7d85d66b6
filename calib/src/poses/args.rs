//! The posing options as command-line flags, declared once: `s3tir-calib poses` and
//! `s3tir-train SESSION.mcap` flatten [`PosingArgs`] into their own commands (the doc comments
//! below are their `--help`), and every default is read from [`PosesOptions::default`], the one
//! place it is declared. Left to each command: the session and output paths, the hold-out
//! (the trainer's `--holdout` serves both), `--board` (its finder is OpenCV's, which only
//! `s3tir-calib` links) and the progress display.

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use crate::poses::{Matcher, PosesOptions};

/// COLMAP's matcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MatcherArg {
    /// Exhaustive up to 30 keyframes, sequential (overlap 10) above.
    Auto,
    Exhaustive,
    Sequential,
}

/// How a recorded session is posed (see `s3tir-calib poses --help` for the stage).
#[derive(Debug, Clone, Args)]
pub struct PosingArgs {
    /// The rig's calibration.yaml (from s3tir-calib) [default: the one attached to the session].
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// COLMAP program.
    #[arg(long, env = "S3TIR_COLMAP", default_value_os_t = PosesOptions::default().colmap)]
    pub colmap: PathBuf,
    /// Use this COLMAP model (text or binary) of the keyframes instead of running COLMAP; its
    /// image names must be the stage's own (rgb_SEQUENCE.jpg / thermal_SEQUENCE.png, as in a
    /// previous run's colmap/images/).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Keyframes per second for structure from motion, at least: a thermal-only session takes
    /// the sharpest thermal frame of each slot; with RGB the keyframes are the RGB frames
    /// around the thermal candidates, and a slot without any (an FFC, dropped thermal frames)
    /// gets its sharpest RGB frame so that the chain of overlapping keyframes stays unbroken
    #[arg(long, default_value_t = PosesOptions::default().keyframe_hz)]
    pub keyframe_hz: f64,
    /// At most this many keyframes (two per thermal candidate with RGB; candidates are
    /// thinned to fit). Structure-from-motion time grows with it.
    #[arg(long, default_value_t = PosesOptions::default().max_keyframes)]
    pub max_keyframes: usize,
    /// COLMAP matcher.
    #[arg(long, value_enum, default_value = "auto")]
    pub matcher: MatcherArg,
    /// A frame is motion-blurred below this fraction of its neighbours' median sharpness.
    #[arg(long, default_value_t = PosesOptions::default().blur_ratio)]
    pub blur_ratio: f64,
    /// Thermal candidates per second (the sharpest of each slot), before thinning.
    #[arg(long, default_value_t = PosesOptions::default().thermal_hz)]
    pub thermal_hz: f64,
    /// Thinning: keep a view that moved this fraction of the median scene depth …
    #[arg(long, default_value_t = PosesOptions::default().min_baseline)]
    pub min_baseline: f64,
    /// … or turned this many degrees since the last kept view.
    #[arg(long, default_value_t = PosesOptions::default().min_rotation_deg)]
    pub min_rotation_deg: f64,
    /// At most this many thermal views.
    #[arg(long, default_value_t = PosesOptions::default().max_views)]
    pub max_views: usize,
    /// Interpolate poses only between registered keyframes at most this far apart, seconds
    /// (with RGB also at most one bracket of keyframes, 2 × 0.12 s).
    #[arg(long, default_value_t = PosesOptions::default().max_gap_s)]
    pub max_gap_s: f64,
    /// Metres per COLMAP world unit, when known: applies the calibrated lever arm between the
    /// cameras at the right scale (without it the thermal centre is taken at the RGB centre).
    #[arg(long)]
    pub metres_per_unit: Option<f64>,
    /// AprilTag map (TOML: family = "tag36h11", size_m, and optionally [[tag]] id + corners_m,
    /// four world corners in metres: bottom-left, bottom-right, top-right, top-left as
    /// printed). The size gives COLMAP's world its metric scale (tag corners triangulated);
    /// with corners, keyframes that see two mapped tags are posed by PnP, and COLMAP does not
    /// run when enough are; when it does run, its keyframe rotations are checked against the
    /// tags' PnP poses (a warning if the model disagrees, e.g. hinged in parts).
    /// s3tir-firmware-sim writes one beside a walk's truth (tags.toml).
    #[arg(long)]
    pub tags: Option<PathBuf>,
    /// With a tag layout or a board, run COLMAP anyway (the fiducials then give the scale and
    /// the check).
    #[arg(long)]
    pub no_tag_poses: bool,
    /// At least this fraction of the keyframes (and at least 5) must be posed. Lower it when
    /// the board or the tags are in view for only part of the walk: views between posed
    /// keyframes are still posed, the rest skipped with their reason.
    #[arg(long, default_value_t = PosesOptions::default().min_registered, value_parser = fraction)]
    pub min_registered: f64,
    /// Also write every posed RGB keyframe (images/rgb_SEQUENCE.png as recorded, 8-bit RGB;
    /// the calibrated RGB camera as camera 2; its pose in the thermal views' world; those
    /// around held-out thermal views held out too), for joint RGB + thermal training. An error
    /// on a session without RGB. A folder of images: the posed shots' RGB partners
    /// (images/rgb_STEM.png; posed by PnP on the board with --board, else by the calibration's
    /// extrinsic; needs --calibration with the RGB camera).
    #[arg(long)]
    pub with_rgb: bool,
}

/// `--min-registered`: a fraction in (0, 1].
fn fraction(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 1.0 => Ok(v),
        _ => Err(format!("{s}: a fraction in (0, 1] is expected")),
    }
}

impl PosingArgs {
    /// The stage's options these flags give (board, progress and hold-out left at their
    /// defaults for the caller to set).
    pub fn options(&self) -> PosesOptions {
        PosesOptions {
            colmap: self.colmap.clone(),
            user_model: self.poses.clone(),
            keyframe_hz: self.keyframe_hz,
            max_keyframes: self.max_keyframes,
            matcher: match self.matcher {
                MatcherArg::Auto => None,
                MatcherArg::Exhaustive => Some(Matcher::Exhaustive),
                MatcherArg::Sequential => Some(Matcher::Sequential { overlap: 10 }),
            },
            blur_ratio: self.blur_ratio,
            thermal_hz: self.thermal_hz,
            min_baseline: self.min_baseline,
            min_rotation_deg: self.min_rotation_deg,
            max_views: self.max_views,
            max_gap_s: self.max_gap_s,
            metres_per_unit: self.metres_per_unit,
            tags: self.tags.clone(),
            tag_poses: !self.no_tag_poses,
            min_registered: self.min_registered,
            with_rgb: self.with_rgb,
            ..PosesOptions::default()
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use clap::Parser;

    use super::*;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        posing: PosingArgs,
    }

    /// No flags give the stage's declared defaults (the `--help` shows the same numbers).
    #[test]
    fn no_flags_give_the_stage_defaults() {
        let got = Cli::try_parse_from(["x"]).unwrap().posing.options();
        let want = PosesOptions::default();
        assert_eq!(got.keyframe_hz, want.keyframe_hz);
        assert_eq!(got.max_keyframes, want.max_keyframes);
        assert_eq!(got.blur_ratio, want.blur_ratio);
        assert_eq!(got.thermal_hz, want.thermal_hz);
        assert_eq!(got.min_baseline, want.min_baseline);
        assert_eq!(got.min_rotation_deg, want.min_rotation_deg);
        assert_eq!(got.max_views, want.max_views);
        assert_eq!(got.max_gap_s, want.max_gap_s);
        assert_eq!(got.min_registered, want.min_registered);
        assert_eq!(got.tag_poses, want.tag_poses);
        assert_eq!(got.matcher, want.matcher);
        assert_eq!(got.with_rgb, want.with_rgb);
    }

    #[test]
    fn a_fraction_outside_0_1_is_refused() {
        for bad in ["0", "1.5", "-0.2", "x"] {
            assert!(
                Cli::try_parse_from(["x", "--min-registered", bad]).is_err(),
                "--min-registered {bad} should be refused"
            );
        }
        let ok = Cli::try_parse_from(["x", "--min-registered", "0.25"]).unwrap();
        assert_eq!(ok.posing.options().min_registered, 0.25);
    }
}
