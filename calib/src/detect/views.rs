//! Board detection over a whole board folder or recorded session: every image decoded and
//! searched (in parallel), the outcomes collected in listing order with a stated reason for
//! every image that gives no board, and the thermal corner order made to agree with RGB.
//! Single-image detection is [`crate::detect::frontend`]; the calibration pipeline solves from the
//! [`DetectedSet`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec2;

use rayon::prelude::*;
use s3tir_capture::Chain;

use crate::detect::board::ThermalPolarity;
use crate::detect::board::{BoardSpec, Camera, FileProblem, ViewFiles, list_views};
use crate::detect::frontend::{
    BoardDetection, BoardOrder, DetectFailure, detect_board, rotate_180,
};
use crate::detect::scalar::{ScalarImage, SourceKind, load_scalar};
use crate::detect::session::{SessionOptions, SessionViews};
use crate::error::CalibError;
use crate::progress::Progress;

/// One view's files and detections.
#[derive(Debug, Clone)]
pub struct DetectedView {
    pub key: String,
    pub files: [Option<PathBuf>; 2],
    pub detections: [Option<BoardDetection>; 2],
}

/// Everything detection produced for a folder.
#[derive(Debug, Clone)]
pub struct DetectedSet {
    pub dir: PathBuf,
    pub board: BoardSpec,
    pub views: Vec<DetectedView>,
    /// Image size per camera (`None`: no readable image).
    pub image_size: [Option<(u32, u32)>; 2],
    /// Image counts per camera (files listed).
    pub images: [usize; 2],
    pub problems: Vec<FileProblem>,
    /// How thermal ordering was fixed, in words.
    pub polarity_note: String,
    pub source_kinds: Vec<(Camera, SourceKind)>,
    pub detection_wall_s: f64,
    /// Input notes that become warnings (e.g. a truncated session).
    pub notes: Vec<String>,
}

fn problem(path: &Path, reason: impl Into<String>) -> FileProblem {
    FileProblem {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// True when `path` names a recorded session (`.mcap`).
pub fn is_session(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}

/// Loads `board.toml` and detects the board in every image of `dir`. A session path
/// (`.mcap`) is refused with [`CalibError::SessionNeedsBoard`]: use [`detect_session`].
/// `progress` hears one stage, one item per image.
pub fn detect_folder(dir: &Path, progress: &dyn Progress) -> Result<DetectedSet, CalibError> {
    if is_session(dir) {
        return Err(CalibError::SessionNeedsBoard {
            path: dir.to_path_buf(),
        });
    }
    let board = BoardSpec::load(&dir.join("board.toml"))?;
    let (files, mut problems) = list_views(dir)?;
    let thermal_palette = board.thermal_palette;
    detect_views(
        dir,
        board,
        files,
        &mut problems,
        progress,
        |path, camera| load_scalar(path, camera == Camera::Thermal, thermal_palette),
    )
}

/// Reads a recorded session (see [`crate::detect::session`]) and detects the board described by
/// `board_toml` in its views.
pub fn detect_session(
    session: &Path,
    board_toml: &Path,
    session_opts: &SessionOptions,
    progress: &dyn Progress,
) -> Result<DetectedSet, CalibError> {
    let board = BoardSpec::load(board_toml)?;
    let SessionViews {
        views,
        images,
        mut problems,
        notes,
    } = crate::detect::session::read_views(session, session_opts)?;
    let mut set = detect_views(
        session,
        board,
        views,
        &mut problems,
        progress,
        |name, camera| images.load(name, camera),
    )?;
    set.notes.extend(notes);
    Ok(set)
}

/// What detection made of one image.
enum ImageOutcome {
    Unreadable(String),
    Failed(String),
    Detected {
        size: (u32, u32),
        source: SourceKind,
        result: Result<BoardDetection, DetectFailure>,
    },
}

/// Detection over listed views; `load` decodes a listed image (a file, or a session frame).
///
/// Images are decoded and searched in parallel (rayon, one image per worker at a time, so
/// memory stays bounded by the worker count whatever the number of views); the outcomes are
/// then taken in listing order, so the problems, the image size of each camera (set by its
/// first readable image) and the views come out exactly as a sequential run gives them.
pub fn detect_views(
    dir: &Path,
    board: BoardSpec,
    files: Vec<ViewFiles>,
    problems: &mut Vec<FileProblem>,
    progress: &dyn Progress,
    load: impl Fn(&Path, Camera) -> Result<ScalarImage, CalibError> + Sync,
) -> Result<DetectedSet, CalibError> {
    let start = Instant::now();
    let jobs = image_jobs(&files);
    let outcomes = detect_images(&jobs, &board, progress, &load);
    let mut collected = Collected {
        image_size: [None, None],
        images: [0usize; 2],
        source_kinds: Vec::new(),
        views: files
            .into_iter()
            .map(|vf| DetectedView {
                key: vf.key,
                files: vf.files,
                detections: [None, None],
            })
            .collect(),
    };
    for ((v, camera, path), outcome) in jobs.iter().zip(outcomes) {
        collected.take(&board, *v, *camera, path, outcome, problems);
    }
    let Collected {
        image_size,
        images,
        source_kinds,
        mut views,
    } = collected;
    let polarity_note = resolve_thermal_order(&board, &mut views, problems);
    Ok(DetectedSet {
        dir: dir.to_path_buf(),
        board,
        views,
        image_size,
        images,
        problems: std::mem::take(problems),
        polarity_note,
        source_kinds,
        detection_wall_s: start.elapsed().as_secs_f64(),
        notes: Vec::new(),
    })
}

/// Every listed image as `(view index, camera, path)`, in listing order.
fn image_jobs(files: &[ViewFiles]) -> Vec<(usize, Camera, PathBuf)> {
    files
        .iter()
        .enumerate()
        .flat_map(|(v, vf)| {
            Camera::BOTH
                .into_iter()
                .filter_map(move |c| vf.files[c.index()].clone().map(|p| (v, c, p)))
        })
        .collect()
}

/// Decodes and searches every job's image in parallel, reporting progress; the outcomes in
/// job order.
fn detect_images(
    jobs: &[(usize, Camera, PathBuf)],
    board: &BoardSpec,
    progress: &dyn Progress,
    load: &(impl Fn(&Path, Camera) -> Result<ScalarImage, CalibError> + Sync),
) -> Vec<ImageOutcome> {
    // Images are detected in parallel by rayon: OpenCV's own worker threads would only
    // contend with them. Its thread count is restored afterwards.
    let cv_threads = opencv::core::get_num_threads().unwrap_or(-1);
    let _ = opencv::core::set_num_threads(1);
    progress.start("detecting images", Some(jobs.len() as u64));
    let outcomes: Vec<ImageOutcome> = jobs
        .par_iter()
        .map(|(_, camera, path)| {
            let (camera, path) = (*camera, path.as_path());
            let span = tracing::trace_span!("detect", file = %path.display());
            let _g = span.enter();
            let outcome = detect_image(path, camera, board, load);
            progress.item(
                &path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default(),
            );
            progress.advance(1);
            outcome
        })
        .collect();
    progress.finish();
    let _ = opencv::core::set_num_threads(cv_threads);
    outcomes
}

/// Decodes one image and searches it for the board.
fn detect_image(
    path: &Path,
    camera: Camera,
    board: &BoardSpec,
    load: &impl Fn(&Path, Camera) -> Result<ScalarImage, CalibError>,
) -> ImageOutcome {
    // A detector failure on one image (OpenCV, AprilTag) is that image's problem,
    // named by its file; the other images still calibrate.
    match load(path, camera) {
        Err(e) => ImageOutcome::Unreadable(Chain(&e).to_string()),
        Ok(img) => match detect_board(&img, board) {
            Ok(result) => ImageOutcome::Detected {
                size: (img.width_px, img.height_px),
                source: img.source,
                result,
            },
            Err(e) => ImageOutcome::Failed(Chain(&e).to_string()),
        },
    }
}

/// The outcomes taken so far, in listing order.
struct Collected {
    /// Per camera, the size of its first readable image.
    image_size: [Option<(u32, u32)>; 2],
    /// Images listed per camera.
    images: [usize; 2],
    source_kinds: Vec<(Camera, SourceKind)>,
    views: Vec<DetectedView>,
}

impl Collected {
    /// Takes the outcome of view `v`'s `camera` image: its detection, or the problem that
    /// keeps it out (unreadable, detection failed, wrong size, no board).
    fn take(
        &mut self,
        board: &BoardSpec,
        v: usize,
        camera: Camera,
        path: &Path,
        outcome: ImageOutcome,
        problems: &mut Vec<FileProblem>,
    ) {
        self.images[camera.index()] += 1;
        let (size, source, result) = match outcome {
            ImageOutcome::Unreadable(e) => {
                problems.push(problem(path, format!("unreadable: {e}")));
                return;
            }
            ImageOutcome::Failed(e) => {
                problems.push(problem(path, format!("detection failed: {e}")));
                return;
            }
            ImageOutcome::Detected {
                size,
                source,
                result,
            } => (size, source, result),
        };
        match self.image_size[camera.index()] {
            None => self.image_size[camera.index()] = Some(size),
            Some(s) if s != size => {
                problems.push(problem(
                    path,
                    format!(
                        "wrong size {}x{}: the {} camera's images are {}x{}",
                        size.0,
                        size.1,
                        camera.name(),
                        s.0,
                        s.1
                    ),
                ));
                return;
            }
            Some(_) => {}
        }
        if !self.source_kinds.contains(&(camera, source)) {
            self.source_kinds.push((camera, source));
        }
        match result {
            Ok(d) => self.views[v].detections[camera.index()] = Some(d),
            Err(why) => problems.push(problem(path, failure_reason(board, why))),
        }
    }
}

/// The problem report's wording of a detection failure.
fn failure_reason(board: &BoardSpec, why: DetectFailure) -> String {
    match why {
        DetectFailure::NotFound => format!(
            "no {}x{} board found (SB detector, classic detector on both polarities)",
            board.cols(),
            board.rows()
        ),
        DetectFailure::Ambiguous(why) => format!("ambiguous detection rejected: {why}"),
        DetectFailure::NoPartial(why) => format!(
            "no whole {}x{} board found (SB detector, classic detector on both polarities); {why}",
            board.cols(),
            board.rows()
        ),
    }
}

/// The image direction in which the board's corner index grows (least-squares slope of the
/// corners' image position against `c + r`, normalised): comparable between a whole and a
/// partial detection of one board.
fn direction(board: &BoardSpec, d: &BoardDetection) -> DVec2 {
    let cols = board.cols() as usize;
    let k: Vec<f64> = d
        .corner_ids
        .iter()
        .map(|&i| (i % cols + i / cols) as f64)
        .collect();
    let n = k.len().max(1) as f64;
    let k_mean = k.iter().sum::<f64>() / n;
    let p_mean = d.corners_px.iter().copied().sum::<DVec2>() / n;
    k.iter()
        .zip(&d.corners_px)
        .map(|(k, p)| (*p - p_mean) * (k - k_mean))
        .sum::<DVec2>()
        .normalize_or_zero()
}

/// Makes thermal corner order agree with RGB (see `frontend` docs): fixed polarity from
/// `board.toml`, or for `auto` a vote over pairs on whether the corner order runs the same
/// way in both images. Pairs that disagree with the majority are unpaired (reported).
/// Detections ordered by AprilTags are never turned. A colour-symmetric board with tags turns
/// each thermal detection that no tag ordered to agree with its tag-ordered RGB pair.
fn resolve_thermal_order(
    board: &BoardSpec,
    views: &mut Vec<DetectedView>,
    problems: &mut Vec<FileProblem>,
) -> String {
    let n = board.corner_count();
    let by_tags = |d: &BoardDetection| d.order == BoardOrder::Tags;
    if board.is_colour_symmetric() {
        if !board.has_tags() {
            return "board is colour-symmetric (cols + rows even): both cameras ordered with corner 0 nearest the image's top-left".into();
        }
        let mut turned = 0usize;
        for v in views.iter_mut() {
            if let [Some(t), Some(r)] = &mut v.detections
                && by_tags(r)
                && !by_tags(t)
                && direction(board, t).dot(direction(board, r)) < 0.0
            {
                rotate_180(t, n);
                turned += 1;
            }
        }
        return format!(
            "board is colour-symmetric (cols + rows even) with AprilTags: views ordered by their tags; thermal views without tags follow their RGB pair ({turned} turned), unpaired ones corner 0 nearest the image's top-left"
        );
    }
    let direction = |d: &BoardDetection| direction(board, d);
    let (rotate, note) = match board.thermal_polarity {
        ThermalPolarity::CoatedDark => (
            false,
            "thermal_polarity = coated_dark (board.toml)".to_string(),
        ),
        ThermalPolarity::CoatedBright => (
            true,
            "thermal_polarity = coated_bright (board.toml)".to_string(),
        ),
        ThermalPolarity::Auto => {
            let (mut dark, mut bright) = (0usize, 0usize);
            for v in views.iter() {
                if let [Some(t), Some(r)] = &v.detections {
                    if direction(t).dot(direction(r)) > 0.0 {
                        dark += 1;
                    } else {
                        bright += 1;
                    }
                }
            }
            if dark + bright == 0 {
                (false, "thermal_polarity = auto with no pairs: assumed coated_dark (ordering does not matter for one camera)".into())
            } else {
                (
                    bright > dark,
                    format!(
                        "thermal_polarity = auto: {} by vote over pairs ({dark} say coated_dark, {bright} coated_bright)",
                        if bright > dark {
                            "coated_bright"
                        } else {
                            "coated_dark"
                        }
                    ),
                )
            }
        }
    };
    let mut rgb_only = Vec::new();
    for v in views.iter_mut() {
        if rotate
            && let Some(t) = v.detections[0].as_mut()
            && !by_tags(t)
        {
            rotate_180(t, n);
        }
        if let [Some(t), Some(r)] = &v.detections
            && direction(t).dot(direction(r)) <= 0.0
        {
            if let Some(path) = &v.files[0] {
                problems.push(problem(
                    path,
                    "corner order disagrees with its RGB pair (polarity differs from the session's): not used as a pair; each image still calibrates its own camera",
                ));
            }
            // Two single-camera views under distinct keys.
            rgb_only.push(DetectedView {
                key: format!("{}#rgb-only", v.key),
                files: [None, v.files[1].take()],
                detections: [None, v.detections[1].take()],
            });
            v.key = format!("{}#thermal-only", v.key);
        }
    }
    views.extend(rgb_only);
    note
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::frontend::Refinement;

    /// A whole 9x5 board seen fronto-parallel, 10 px squares, corner 0 at `origin`, the corner
    /// index growing along `+x`/`+y` (`turned`: along `-x`/`-y`).
    fn seen(board: &BoardSpec, turned: bool, order: BoardOrder) -> BoardDetection {
        let cols = board.cols() as usize;
        let sign = if turned { -1.0 } else { 1.0 };
        let pts: Vec<DVec2> = (0..board.corner_count())
            .map(|i| {
                DVec2::new(200.0, 150.0)
                    + sign * 10.0 * DVec2::new((i % cols) as f64, (i / cols) as f64)
            })
            .collect();
        BoardDetection {
            corners_px: pts.clone(),
            corner_ids: (0..pts.len()).collect(),
            detector: "sb",
            inverted: false,
            sharpness_px: 1.0,
            contrast_z: 10.0,
            roughness_px: 0.0,
            planar_fit_px: 0.0,
            refinement: Refinement::CornerSubPix,
            variants: vec![(Refinement::CornerSubPix, pts)],
            order,
        }
    }

    #[test]
    fn colour_symmetric_thermal_follows_its_tag_ordered_rgb_pair() {
        let mut board = crate::synth::default_board();
        board.inner_corners = [9, 5];
        board.apriltag_ids = (0..30).collect();
        let view = |thermal_turned: bool| DetectedView {
            key: format!("turned-{thermal_turned}"),
            files: [None, None],
            detections: [
                Some(seen(&board, thermal_turned, BoardOrder::ImageOrientation)),
                Some(seen(&board, false, BoardOrder::Tags)),
            ],
        };
        let mut views = vec![view(true), view(false)];
        let mut problems = Vec::new();
        let note = resolve_thermal_order(&board, &mut views, &mut problems);
        assert!(note.contains("1 turned"), "{note}");
        for v in &views {
            let [Some(t), Some(r)] = &v.detections else {
                panic!("{}: both detections stay", v.key);
            };
            assert!(
                direction(&board, t).dot(direction(&board, r)) > 0.99,
                "{}: thermal order must follow RGB's",
                v.key
            );
        }
        assert!(problems.is_empty(), "{problems:?}");
    }
}
