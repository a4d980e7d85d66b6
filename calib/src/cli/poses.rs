//! `s3tir-calib poses`: part of the `s3tir-calib` binary (not of the library).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Result;
use clap::Args;
use s3tir_calib::detect::board::BoardSpec;
use s3tir_calib::detect::frontend::detect_board;
use s3tir_calib::detect::scalar::load_scalar;
use s3tir_calib::model::calfile::CalibrationFile;
use s3tir_calib::poses::args::PosingArgs;
use s3tir_calib::poses::board::BoardFiducial;
use s3tir_calib::poses::folder::args::FolderArgs;
use s3tir_calib::poses::folder::intrinsics::IntrinsicsArgs;
use s3tir_calib::poses::folder::{self, FolderOptions};
use s3tir_calib::poses::frames::Stream;
use s3tir_calib::poses::{self, PosesOptions};
use s3tir_calib::progress::Progress;
use s3tir_calib::progress::bars::ProgressBars;

/// Turn a recorded session, or a folder of thermal images, into a posed thermal dataset
/// (COLMAP layout) for `s3tir-train`.
///
/// A folder (radiometric FLIR/DJI JPEGs, 16-bit TIFF/PNG with --units, or 8-bit pictures;
/// thermal/ and rgb/ subfolders or DJI's _T/_W names pair RGB partners): every image read to
/// temperatures, the camera from --calibration, --hfov-deg/--focal-px, EXIF or a known camera,
/// and the shots posed by the method the metadata allows: the planar method (a facade or nadir
/// survey with GPS and gimbal angles: images turned into one orientation, patches matched
/// between neighbours around the shift GPS predicts, a bundle adjustment with the points near
/// one plane and GPS/altitude/gimbal priors). It writes images/ (16-bit centikelvin, counts,
/// or 8-bit grey, not undistorted), sparse/0/, holdout.txt and poses.json (every file's
/// decision, the camera's source, the figures). With --board and --calibration each shot is
/// posed by PnP on the calibration board instead (the board method). Other folders — free-hand
/// views, no metadata — are posed by structure from motion (COLMAP; on the RGB partners when
/// --calibration has their camera and the extrinsic), GPS positions, when the files have them,
/// making the world east-north-up metres. --with-rgb adds the RGB partners for joint
/// training.
///
/// A session:
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
    /// Recorded session (.mcap, from s3tir-capture), or a folder of thermal images.
    session: PathBuf,
    /// Dataset folder to write (must not exist or be empty).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    posing: PosingArgs,
    /// Hold out every k-th view for testing (0: none).
    #[arg(long, default_value_t = PosesOptions::default().holdout_every)]
    holdout_every: usize,
    /// The calibration board (its board.toml) standing still in the scene: keyframes that see
    /// it, RGB or thermal (an emissivity board shows in both), are posed by PnP on its corners
    /// in the board's frame (metres), and COLMAP does not run when enough are; otherwise it
    /// gives COLMAP's world its metric scale and checks its rotations, as --tags does. Not
    /// with --tags. A folder of images: every shot is posed by PnP on the board (the board
    /// method; needs --calibration).
    #[arg(long, conflicts_with = "tags")]
    board: Option<PathBuf>,
    #[command(flatten)]
    folder: FolderArgs,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
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
    let cal = match &a.posing.calibration {
        Some(p) => Some(CalibrationFile::read(p)?),
        None => None,
    };
    if a.session.is_dir() {
        let calibration = a.posing.calibration.clone().zip(cal);
        let opts = FolderOptions {
            board: a.board.as_deref().map(board_fiducial).transpose()?,
            holdout_every: a.holdout_every,
            progress: (!a.json).then(|| Arc::new(ProgressBars::new()) as Arc<dyn Progress>),
            ..a.folder.options(
                IntrinsicsArgs {
                    calibration,
                    ..IntrinsicsArgs::default()
                },
                &a.posing.options(),
            )
        };
        let report = folder::folder_to_dataset(&a.session, &a.out, &opts)?;
        if a.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{}", folder::summary(&report));
        }
        return Ok(());
    }
    let opts = PosesOptions {
        board: a.board.as_deref().map(board_fiducial).transpose()?,
        holdout_every: a.holdout_every,
        progress: (!a.json).then(|| Arc::new(ProgressBars::new()) as Arc<dyn Progress>),
        ..a.posing.options()
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
