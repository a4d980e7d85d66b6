//! Structure from motion with COLMAP as an external process (Debian's `colmap` 3.8, CPU SIFT):
//! feature extraction with the calibrated camera fixed (one camera, the calibration's model in
//! COLMAP's words through [`crate::model::colmap::colmap_params`]), exhaustive or sequential matching,
//! the incremental mapper with focal length, principal point and distortion held fixed; the
//! largest reconstruction is kept. Each step's output goes to `colmap/STEP.log`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use super::frames::{FrameInfo, Stream};
use super::{Matcher, PosesError, PosesOptions, StageTimes};
use crate::model::camera::CameraModel;
use crate::model::colmap::{ColmapModel, colmap_params, read_model};
use crate::model::geometry::Rigid3;

fn run_step(
    program: &Path,
    workspace: &Path,
    step: &'static str,
    args: &[String],
) -> Result<(), PosesError> {
    let log = workspace.join(format!("{step}.log"));
    let file = std::fs::File::create(&log).map_err(|e| PosesError::Write {
        path: log.clone(),
        source: Box::new(e),
    })?;
    let err_file = file.try_clone().map_err(|e| PosesError::Write {
        path: log.clone(),
        source: Box::new(e),
    })?;
    tracing::info!(step, "colmap {}", args.join(" "));
    let status = Command::new(program)
        .arg(step)
        .args(args)
        // COLMAP links Qt; without a display it must not try to open one.
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .stdout(Stdio::from(file))
        .stderr(Stdio::from(err_file))
        .status()
        .map_err(|source| PosesError::ColmapMissing {
            program: program.to_path_buf(),
            source,
        })?;
    if status.success() {
        Ok(())
    } else {
        Err(PosesError::ColmapFailed {
            step,
            status: status.to_string(),
            log,
        })
    }
}

/// Checks that `program` runs at all (before anything long starts).
pub fn check_colmap(program: &Path) -> Result<(), PosesError> {
    let out = Command::new(program)
        .arg("help")
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null())
        .output()
        .map_err(|source| PosesError::ColmapMissing {
            program: program.to_path_buf(),
            source,
        })?;
    let text = String::from_utf8_lossy(&out.stdout);
    if text.contains("COLMAP") || text.to_lowercase().contains("colmap") {
        Ok(())
    } else {
        // Not an I/O failure of its own: the program ran but is not COLMAP.
        Err(PosesError::ColmapMissing {
            program: program.to_path_buf(),
            source: std::io::Error::other(format!(
                "`{} help` does not print COLMAP's usage ({})",
                program.display(),
                out.status
            )),
        })
    }
}

/// Runs COLMAP on `workspace/images` and returns the largest reconstruction.
pub fn run_colmap(
    workspace: &Path,
    camera: &CameraModel,
    keyframes: usize,
    opts: &PosesOptions,
    times: &mut StageTimes,
) -> Result<ColmapModel, PosesError> {
    let run = ColmapRun::new(workspace, opts)?;

    let t = Instant::now();
    run.extract_features(camera)?;
    times.colmap_features_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    run.match_features(keyframes, opts.matcher)?;
    times.colmap_matching_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let mapped = run.map();
    times.colmap_mapper_s = t.elapsed().as_secs_f64();
    if let Err(PosesError::ColmapFailed { log, .. }) = &mapped
        && std::fs::read_to_string(log).is_ok_and(|text| no_initial_pair(&text))
    {
        // Not a crash: no two keyframes share enough features to start a model (on the
        // simulated walk's thermal-only frames: 16–28 SIFT features each).
        return Err(too_few_registered(keyframes, workspace));
    }
    mapped?;

    largest_reconstruction(&run.sparse)?.ok_or_else(|| too_few_registered(keyframes, workspace))
}

/// Nothing registered: fewer than the 5 keyframes a model needs.
fn too_few_registered(keyframes: usize, workspace: &Path) -> PosesError {
    PosesError::TooFewRegistered {
        registered: 0,
        keyframes,
        needed: 5,
        workspace: workspace.to_path_buf(),
    }
}

/// One COLMAP run's program, workspace paths and thread count.
struct ColmapRun<'a> {
    program: &'a Path,
    workspace: &'a Path,
    db: PathBuf,
    images: PathBuf,
    sparse: PathBuf,
    threads: String,
}

impl<'a> ColmapRun<'a> {
    /// The run's paths in `workspace`, creating the mapper's output folder (`sparse`).
    fn new(workspace: &'a Path, opts: &'a PosesOptions) -> Result<Self, PosesError> {
        let db = workspace.join("database.db");
        let images = workspace.join("images");
        let sparse = workspace.join("sparse");
        std::fs::create_dir_all(&sparse).map_err(|e| PosesError::Write {
            path: sparse.clone(),
            source: Box::new(e),
        })?;
        Ok(Self {
            program: &opts.colmap,
            workspace,
            db,
            images,
            sparse,
            threads: opts.threads.max(1).to_string(),
        })
    }

    /// Runs one COLMAP step with `args` (output to `workspace/STEP.log`).
    fn step(&self, step: &'static str, args: &[String]) -> Result<(), PosesError> {
        run_step(self.program, self.workspace, step, args)
    }

    /// SIFT features of every image on the CPU, with one camera of the calibrated model.
    fn extract_features(&self, camera: &CameraModel) -> Result<(), PosesError> {
        let (model, params) = colmap_params(camera);
        let params = params
            .iter()
            .map(|p| format!("{p:?}"))
            .collect::<Vec<_>>()
            .join(",");
        self.step(
            "feature_extractor",
            &[
                "--database_path".into(),
                arg(&self.db),
                "--image_path".into(),
                arg(&self.images),
                "--ImageReader.single_camera".into(),
                "1".into(),
                "--ImageReader.camera_model".into(),
                model.into(),
                "--ImageReader.camera_params".into(),
                params,
                "--SiftExtraction.use_gpu".into(),
                "0".into(),
                // At most 1 024 features per keyframe (COLMAP's default is 8 192): matching
                // cost grows with their square; consecutive video keyframes need far fewer.
                "--SiftExtraction.max_num_features".into(),
                "1024".into(),
                "--SiftExtraction.num_threads".into(),
                self.threads.clone(),
            ],
        )
    }

    /// Feature matching: `matcher`, or by default exhaustive for up to 30 keyframes and
    /// sequential beyond.
    fn match_features(&self, keyframes: usize, matcher: Option<Matcher>) -> Result<(), PosesError> {
        // Exhaustive matching costs n² pairs (~0.03 s each on 2 cores at 1 024 features):
        // beyond 30 keyframes the video order is used (each keyframe with its 10 successors).
        let matcher = matcher.unwrap_or(if keyframes <= 30 {
            Matcher::Exhaustive
        } else {
            Matcher::Sequential { overlap: 10 }
        });
        let mut args = vec![
            "--database_path".into(),
            arg(&self.db),
            "--SiftMatching.use_gpu".into(),
            "0".into(),
            "--SiftMatching.num_threads".into(),
            self.threads.clone(),
        ];
        let step = match matcher {
            Matcher::Exhaustive => "exhaustive_matcher",
            Matcher::Sequential { overlap } => {
                args.extend([
                    "--SequentialMatching.overlap".into(),
                    overlap.to_string(),
                    "--SequentialMatching.loop_detection".into(),
                    "0".into(),
                ]);
                "sequential_matcher"
            }
        };
        self.step(step, &args)
    }

    /// The incremental mapper with focal length, principal point and distortion held fixed.
    fn map(&self) -> Result<(), PosesError> {
        self.step(
            "mapper",
            &[
                "--database_path".into(),
                arg(&self.db),
                "--image_path".into(),
                arg(&self.images),
                "--output_path".into(),
                arg(&self.sparse),
                "--Mapper.ba_refine_focal_length".into(),
                "0".into(),
                "--Mapper.ba_refine_principal_point".into(),
                "0".into(),
                "--Mapper.ba_refine_extra_params".into(),
                "0".into(),
                "--Mapper.num_threads".into(),
                self.threads.clone(),
            ],
        )
    }
}

/// A path as a command-line argument.
fn arg(p: &Path) -> String {
    p.display().to_string()
}

/// The reconstruction with the most images among the mapper's output folders (0, 1, …, the
/// first on ties); `None` when there is none.
fn largest_reconstruction(sparse: &Path) -> Result<Option<ColmapModel>, PosesError> {
    let mut best: Option<ColmapModel> = None;
    if let Ok(entries) = std::fs::read_dir(sparse) {
        let mut dirs: Vec<_> = entries.flatten().map(|e| e.path()).collect();
        dirs.sort();
        for dir in dirs.iter().filter(|d| d.is_dir()) {
            let m = read_model(dir).map_err(|source| PosesError::Model {
                path: dir.clone(),
                source,
            })?;
            if best
                .as_ref()
                .is_none_or(|b| m.images.len() > b.images.len())
            {
                best = Some(m);
            }
        }
    }
    Ok(best)
}

/// Whether a failed mapper's log says it found no pair of images to start from (COLMAP 3.8
/// exits with failure then, having registered nothing).
pub fn no_initial_pair(log: &str) -> bool {
    log.contains("No good initial image pair found") && !log.contains("Registering image")
}

/// The registered keyframes of `model` as `(monotonic_ns, world_from_cam)`: image names are
/// the stage's own (`rgb_SEQUENCE.jpg`, `thermal_SEQUENCE.png`), joined to the SfM stream's
/// frames by sequence. Images of other names are ignored.
pub fn registered_keyframes(model: &ColmapModel, frames: &[FrameInfo]) -> Vec<(u64, Rigid3)> {
    let by_seq: BTreeMap<u32, u64> = frames
        .iter()
        .map(|f| (f.sequence, f.monotonic_ns))
        .collect();
    let mut out: Vec<(u64, Rigid3)> = model
        .images
        .iter()
        .filter_map(|im| {
            let (_stream, seq): (Stream, u32) = Stream::parse_file_name(&im.name)?;
            let t = *by_seq.get(&seq)?;
            Some((t, im.cam_from_world.inverse()))
        })
        .collect();
    out.sort_by_key(|k| k.0);
    out
}

/// A registered keyframe is dropped when its pose is more than [`OUTLIER_DEG`] from the slerp
/// of its neighbours in time (each within [`super::fiducials::NEIGHBOUR_S`]) or its centre
/// farther from their interpolation than the larger of their distance apart and
/// [`OUTLIER_DEPTH`] × the scene depth (COLMAP's world has no unit: both are its own). A hand
/// turns well under a degree beyond a slerp in that time and the keyframes of a good model
/// agree to ~0.1°; a keyframe registered at a wrong place does not (one COLMAP run in six on
/// the simulated walk put one 14.6° and 1.2 m off, and every thermal pose interpolated from it
/// with it). Worst first ([`super::interp::drop_worst_jumps`]). Returns the capture times
/// dropped.
pub fn drop_jumps(registered: &mut Vec<(u64, Rigid3)>, points: &[[f64; 3]]) -> Vec<u64> {
    registered.sort_by_key(|k| k.0);
    let centres: Vec<glam::DVec3> = registered.iter().map(|k| k.1.translation_m).collect();
    let depth = super::select::scene_depth(&centres, points);
    super::interp::drop_worst_jumps(registered, super::fiducials::NEIGHBOUR_S, |j| {
        (j.turn_deg / OUTLIER_DEG).max(j.moved / j.span.max(OUTLIER_DEPTH * depth))
    })
}

/// [`drop_jumps`]: the largest turn, degrees, from the neighbours' slerp …
pub const OUTLIER_DEG: f64 = 2.0;
/// … and the centre's floor, as a fraction of the scene depth.
pub const OUTLIER_DEPTH: f64 = 0.05;
