//! `s3tir-calib`: calibration of thermal + RGB rigs with an emissivity-coated checkerboard.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use s3tir_calib::bench;
use s3tir_calib::detect::chessboard;
use s3tir_calib::detect::session::SessionOptions;
use s3tir_calib::progress::bars::ProgressBars;
use s3tir_calib::report::{document, export};
use s3tir_calib::solve::lm::SolveOptions;
use s3tir_calib::solve::pairs::PairThresholds;
use s3tir_calib::solve::pipeline::{self, PipelineOptions};
use s3tir_calib::tags::{self, TagConfig, TagDetector};

mod cli;

/// Calibrate a thermal + RGB camera rig with an emissivity-coated checkerboard.
///
/// `s3tir-calib BOARD_DIR` reads `BOARD_DIR/board.toml` (`[board] inner_corners = [cols, rows]`,
/// `square_mm`, optional `thermal_polarity` = auto | coated_dark | coated_bright and
/// `thermal_palette` = auto | ironbow | inferno | luminance, and for a board with tag36h11
/// AprilTags in its uncoated squares `apriltag_ids` (row by row) and `apriltag_ratio` (tag /
/// square side, default 0.7): the tags then fix each board's identity and corner order and let
/// a partly visible board give the corners around them) and the images in
/// `BOARD_DIR/thermal/` and `BOARD_DIR/rgb/` (16-bit PNG/TIFF, 8-bit grey, pseudo-colour,
/// RGB/RGBA). Images pair by equal file stem, or equal after dropping a leading `name_`
/// prefix (`thermal_0001.png` ↔ `rgb_0001.png`). It detects the board, initialises each
/// camera with OpenCV's calibrateCamera, then solves both cameras' intrinsics, the
/// thermal↔RGB extrinsic and all board poses in one robust Levenberg–Marquardt, and prints a
/// summary. Files that cannot be used are listed with the reason; the run fails only when
/// nothing is usable.
///
/// `s3tir-calib session.mcap --board board.toml` calibrates from a session recorded by
/// `s3tir-capture` instead: its thermal↔RGB pairs are the views (FFC-frozen thermal frames
/// skipped, at most one pair per --session-interval-s); the board geometry comes from the
/// given board.toml.
#[derive(Debug, Parser)]
#[command(
    name = "s3tir-calib",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    calibrate: CalibrateArgs,
}

#[derive(Debug, Args)]
struct CalibrateArgs {
    /// Board folder (board.toml, thermal/, rgb/), or a recorded session (.mcap; needs --board).
    board_dir: Option<PathBuf>,
    /// Board description for a recorded session (a folder uses its own board.toml).
    #[arg(long)]
    board: Option<PathBuf>,
    /// Session input: smallest time between two pairs used, seconds (0 = every pair).
    #[arg(long, default_value_t = 0.5)]
    session_interval_s: f64,
    /// Session input: most pairs used, spread evenly over the recording (0 = all). Keeps the
    /// memory of a long session bounded: only the chosen frames' pixels are held.
    #[arg(long, default_value_t = s3tir_calib::detect::session::DEFAULT_MAX_VIEWS)]
    session_max_views: usize,
    /// Where to write calibration.yaml; the exports (OpenCV, Kalibr, COLMAP, ROS) go beside it.
    #[arg(long, default_value = "calibration.yaml")]
    out: PathBuf,
    /// Write a markdown report with PNG plots into this folder.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Write the machine-readable summary (one JSON object) here.
    #[arg(long)]
    summary_json: Option<PathBuf>,
    /// Reject corners whose residual exceeds this many σ of their camera.
    #[arg(long, default_value_t = 4.0)]
    reject_sigma: f64,
    /// Huber threshold of the robust loss, pixels.
    #[arg(long, default_value_t = 1.0)]
    huber_px: f64,
    /// Pair consistency: a thermal/RGB pair is left out of the extrinsic when, with one
    /// board pose and the pairs' consensus extrinsic, an image's RMS exceeds this many times
    /// (and 0.5 px more than) what that image reaches with its own pose. Tested before the
    /// joint solve (the RGB pose carried into the thermal camera) and after it. Left-out
    /// pairs still calibrate their own cameras; the summary lists them with their figures.
    #[arg(long, default_value_t = 3.0)]
    pair_residual_ratio: f64,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Turn a recorded session into a posed thermal dataset for s3tir-train (COLMAP on the RGB
    /// keyframes, thermal poses interpolated and composed with the calibrated extrinsic).
    Poses(Box<cli::poses::PosesArgs>),
    /// Detect a chessboard in each image and print its corners (pixels, origin at the centre
    /// of the top-left pixel). Exits non-zero if any image has no board.
    Detect {
        /// Inner corners as COLSxROWS, e.g. 9x6.
        #[arg(long, value_parser = parse_corners)]
        inner_corners: (u32, u32),
        /// Image files (PNG, JPEG, TIFF; colour is converted to grey).
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
    /// Benchmark against OpenCV in the same process. With --real DIR: a real board folder
    /// (board.toml, thermal/, rgb/): per-image detection time and boards found, s3tir next to
    /// OpenCV's findChessboardCornersSB and its classic detector (one core each, decoded images
    /// in memory), s3tir's parallel detection as the calibrate command runs it, and the solve
    /// (everything after detection) next to OpenCV's calibrateCamera x2 + stereoCalibrate on the
    /// same corners. Without: a synthetic Lepton + 720p set, our detection + joint solve next to
    /// OpenCV's stereoCalibrate on the same detections, printed as a ratio.
    Bench {
        /// A folder of thermal images to pose (`poses DIR`'s defaults) instead: seconds per
        /// stage of the folder stage (reading, orientation, registration, bundle adjustment,
        /// writing), into a temporary dataset removed afterwards.
        #[arg(long, value_name = "DIR", conflicts_with = "real")]
        folder: Option<PathBuf>,
        /// A real board folder to benchmark on instead of the synthetic set.
        #[arg(long, value_name = "DIR")]
        real: Option<PathBuf>,
        /// Number of synthetic pairs.
        #[arg(long, default_value_t = 50)]
        pairs: usize,
        /// Seed of the synthetic set.
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Working folder for the generated images, kept after the run (default: a new folder
        /// under the temp dir, removed after the run).
        #[arg(long)]
        dir: Option<PathBuf>,
        /// Print AprilTags (tag36h11, one per uncoated square) on the synthetic board: times
        /// tag decoding and masking on the RGB images.
        #[arg(long)]
        apriltags: bool,
    },
    /// Detect AprilTags (tag36h11) in each image and print id, hamming, decision margin and the
    /// four corners (pixels, origin at the centre of the top-left pixel; order bottom-left,
    /// bottom-right, top-right, top-left of the upright tag). Colour images are converted with
    /// BT.601 luma. Exits non-zero if any image has no tag.
    Tags {
        /// Keep only these ids (comma-separated, e.g. 0,3,7); default: every id.
        #[arg(long, value_delimiter = ',')]
        ids: Vec<u32>,
        /// Decimate the image by this factor for quad detection (1 = full resolution).
        #[arg(long, default_value_t = 1.0)]
        quad_decimate: f32,
        /// Snap quad edges to nearby gradients (useful with --quad-decimate > 1; shifts exact
        /// corners by about -1/8 px).
        #[arg(long)]
        refine_edges: bool,
        /// Image files (PNG, JPEG, TIFF).
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
}

fn parse_corners(text: &str) -> Result<(u32, u32), String> {
    let (c, r) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{text:?}: expected COLSxROWS, e.g. 9x6"))?;
    let parse = |s: &str| {
        s.trim()
            .parse::<u32>()
            .map_err(|e| format!("{text:?}: {e}"))
    };
    Ok((parse(c)?, parse(r)?))
}

fn run_detect(cols: u32, rows: u32, images: &[PathBuf]) -> Result<()> {
    let mut missing = 0usize;
    for path in images {
        let grey = chessboard::read_grey(path)?;
        let mat = chessboard::mat_from_luma(&grey)?;
        match chessboard::find_chessboard(&mat, cols, rows)
            .with_context(|| format!("detecting the board in {}", path.display()))?
        {
            Some(d) => {
                println!(
                    "{}: {} corners ({:?})",
                    path.display(),
                    d.corners_px.len(),
                    d.detector
                );
                for c in &d.corners_px {
                    println!("  {:.3} {:.3}", c.x, c.y);
                }
            }
            None => {
                missing += 1;
                println!("{}: no {cols}x{rows} board found", path.display());
            }
        }
    }
    if missing > 0 {
        bail!(
            "{missing} of {} images had no {cols}x{rows} board",
            images.len()
        );
    }
    Ok(())
}

fn run_calibrate(args: &CalibrateArgs) -> Result<()> {
    let Some(dir) = &args.board_dir else {
        bail!("missing BOARD_DIR (see --help)");
    };
    let opts = PipelineOptions {
        solve: SolveOptions {
            huber_px: args.huber_px,
            reject_sigma: args.reject_sigma,
            ..SolveOptions::default()
        },
        pairs: PairThresholds {
            residual_ratio: args.pair_residual_ratio,
            ..PairThresholds::default()
        },
        progress: Some(std::sync::Arc::new(ProgressBars::new())),
    };
    let cal = if pipeline::is_session(dir) {
        let Some(board) = &args.board else {
            bail!(
                "{}: a recorded session (.mcap) does not carry the board geometry: pass --board board.toml",
                dir.display()
            );
        };
        let session_opts = SessionOptions {
            min_interval_s: args.session_interval_s,
            max_views: args.session_max_views,
        };
        pipeline::calibrate_session(dir, board, &session_opts, &opts)
    } else {
        if let Some(board) = &args.board {
            bail!(
                "--board {} is for .mcap sessions; the folder {} uses its own board.toml",
                board.display(),
                dir.display()
            );
        }
        pipeline::calibrate_folder(dir, &opts)
    }?; // no context added: the pipeline's errors name the file or session they are about
    let written = export::write_all(&cal, &args.out)?;
    if let Some(path) = &args.summary_json {
        export::write_summary(&cal, path)?;
    }
    if let Some(report_dir) = &args.report {
        document::write_report(&cal, report_dir)?;
        println!(
            "report: {} and {}",
            report_dir.join("report.md").display(),
            report_dir.join("report.html").display()
        );
    }
    for r in cal.cameras.iter().flatten() {
        let (i, s) = (r.model.intrinsics, r.sigma);
        println!(
            "{:7}: {} images, board in {}, used {}; RMS {:.3} px (alone: {:.3} px); fx {:.2}±{:.2} fy {:.2}±{:.2} cx {:.2}±{:.2} cy {:.2}±{:.2}",
            r.camera.name(),
            r.images,
            document::views_found(r),
            r.views_used,
            r.rms_px,
            r.mono_rms_px,
            i.fx,
            s.fx,
            i.fy,
            s.fy,
            i.cx,
            s.cx,
            i.cy,
            s.cy
        );
    }
    if let Some(t) = cal.rgb_from_thermal {
        let (_, angle) = t.rotation.to_axis_angle();
        println!(
            "rgb_from_thermal: {} pairs, rotation {:.3}°, translation ({:.4}, {:.4}, {:.4}) m; joint RMS {:.3} px",
            cal.pairs_used,
            angle.to_degrees(),
            t.translation_m.x,
            t.translation_m.y,
            t.translation_m.z,
            cal.joint_rms_px
        );
    }
    for p in &cal.pairs_inconsistent {
        println!("inconsistent pair: {}", p.describe());
    }
    for w in &cal.warnings {
        println!("warning: {w}");
    }
    for p in &cal.problems {
        println!("skipped: {}: {}", p.path.display(), p.reason);
    }
    if !cal.rejected.is_empty() {
        println!(
            "rejected {} outlier corners (see the report)",
            cal.rejected.len()
        );
    }
    println!(
        "wrote {}",
        written
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}

fn run_tags(config: TagConfig, images: &[PathBuf]) -> Result<()> {
    let mut detector = TagDetector::new(config)?;
    let mut missing = 0usize;
    for path in images {
        let decoded =
            image::open(path).with_context(|| format!("reading image {}", path.display()))?;
        let grey = match decoded {
            image::DynamicImage::ImageLuma8(g) => g,
            other => tags::luma_bt601(&other.to_rgb8()),
        };
        let found = detector.detect(&grey, path)?;
        println!("{}: {} tags", path.display(), found.len());
        if found.is_empty() {
            missing += 1;
        }
        for t in &found {
            let corners: Vec<String> = t
                .corners_px
                .iter()
                .map(|c| format!("({:.4} {:.4})", c[0], c[1]))
                .collect();
            println!(
                "  id {} hamming {} margin {:.1}: {}",
                t.id,
                t.hamming,
                t.decision_margin,
                corners.join(", ")
            );
        }
    }
    if missing > 0 {
        bail!("{missing} of {} images had no tag", images.len());
    }
    Ok(())
}

/// Runs the command; an error is printed once, as one `error: …` line (the whole cause chain,
/// `s3tir_capture::Chain`), and exits 1.
fn main() -> std::process::ExitCode {
    s3tir_capture::error::exit_with(run())
}

fn run() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Poses(a)) => cli::poses::run(&a),
        Some(Command::Detect {
            inner_corners: (cols, rows),
            images,
        }) => run_detect(cols, rows, &images),
        Some(Command::Bench {
            folder: Some(folder),
            ..
        }) => bench_folder(&folder),
        Some(Command::Bench {
            real: Some(real), ..
        }) => {
            let figures = bench::run_real(&real, &ProgressBars::new())?;
            println!("{figures}");
            Ok(())
        }
        Some(Command::Bench {
            pairs,
            seed,
            dir,
            apriltags,
            ..
        }) => {
            let keep = dir.is_some();
            let dir = dir.unwrap_or_else(|| {
                std::env::temp_dir().join(format!("s3tir-calib-bench-{}", std::process::id()))
            });
            let figures = bench::run(&dir, pairs, seed, apriltags, &ProgressBars::new());
            if !keep {
                let _ = std::fs::remove_dir_all(&dir);
            }
            println!("{}", figures?);
            Ok(())
        }
        Some(Command::Tags {
            ids,
            quad_decimate,
            refine_edges,
            images,
        }) => {
            let config = TagConfig {
                quad_decimate,
                refine_edges,
                ..TagConfig::default()
            }
            .with_board_ids(&ids);
            run_tags(config, &images)
        }
        None => run_calibrate(&cli.calibrate),
    }
}

/// `bench --folder DIR`: the folder stage's seconds per stage.
fn bench_folder(dir: &std::path::Path) -> Result<()> {
    use s3tir_calib::poses::folder::{FolderOptions, folder_to_dataset};
    let out = std::env::temp_dir().join(format!("s3tir-calib-bench-folder-{}", std::process::id()));
    let r = folder_to_dataset(dir, &out, &FolderOptions::default());
    let _ = std::fs::remove_dir_all(&out);
    let r = r?;
    let t = &r.times;
    println!(
        "{}: {} images {}×{}, {} posed ({:?})",
        dir.display(),
        r.images,
        r.camera.width_px,
        r.camera.height_px,
        r.views + r.held_out,
        r.method
    );
    println!("reading and converting  {:>7.2} s", t.scan_s);
    if let Some(p) = &r.plane {
        println!("orientation (warp, CLAHE) {:>5.2} s", p.turn_s);
        // The scales tried, then the one kept (listed again when the search ran).
        let tries = p.scale_px_per_m.len().saturating_sub(1).max(1);
        println!(
            "registration + in-plane {:>7.2} s ({} candidate pairs, {tries} scale(s) tried: {:.2} s each)",
            p.register_s,
            p.candidate_pairs,
            p.register_s / tries as f64
        );
        println!(
            "bundle adjustment       {:>7.2} s ({} iterations, {} points, {} observations)",
            p.bundle_s, p.bundle_iterations, p.points, p.observations
        );
    }
    println!("posing (all)            {:>7.2} s", t.pose_s);
    println!("writing the dataset     {:>7.2} s", t.write_s);
    println!("total                   {:>7.2} s", t.total_s);
    Ok(())
}

#[cfg(test)]
mod tests {
    /// clap checks a command's definition only when it is built: two options of one name
    /// (e.g. flattened from two option groups) would panic at every start. This builds it.
    #[test]
    fn the_command_line_is_well_formed() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
