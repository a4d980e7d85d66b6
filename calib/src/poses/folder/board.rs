//! The board method: every shot sees the calibration board (a hand-held survey of a heated
//! board, sun-board's 47 views), so each is posed on its own by PnP on the board's squares in
//! the board's frame (metres; the board plane is z = 0, its z pointing away from the cameras),
//! with the calibrated thermal camera (`--calibration`: the board's corners are only as good as
//! the distortion model they are undistorted with). The board machinery is the session stage's
//! ([`crate::poses::board`]: the board as a map of square "tags", the finder passed in by
//! `s3tir-calib`, whose OpenCV front end finds chessboards).
//!
//! **The 180° ambiguity.** In a thermal image the coated and bare squares' polarity is not
//! known, so a found corner grid can be the board turned half a turn. Both orders are posed;
//! the one with the camera on the board's front side (z < 0) wins, and between two such, the
//! one whose camera is nearest the previous shot's (shots sorted by name follow the hand).
//!
//! A shot where the board is not found, or whose PnP reprojects above
//! [`crate::poses::fiducials::pnp::MAX_PNP_RMS_PX`], is left out with that reason. Seed points:
//! the board's plane seen through each posed view.

use glam::{DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use super::super::PosesError;
use super::super::board::BoardFiducial;
use super::super::fiducials::{MAX_PNP_RMS_PX, TagPose, pnp};
use super::super::frames::Stream;
use super::super::stats::{median, percentile};
use super::Posing;
use super::scan::Folder;
use crate::model::camera::CameraModel;
use crate::progress::Progress;

/// What the board method measured (in `poses.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct BoardFigures {
    pub board_found: usize,
    pub posed: usize,
    pub pnp_rms_px_median: f64,
    pub pnp_rms_px_max: f64,
    /// Camera height above the board, metres: min and max.
    pub height_m: [f64; 2],
}

/// The shot's two PnP candidates (the grid as found and turned half a turn).
fn candidates(
    board: &BoardFiducial,
    cam: &CameraModel,
    corners: &[(usize, DVec2)],
) -> Vec<TagPose> {
    let n = (board.cols * board.rows) as usize;
    let map = board.as_tag_map();
    let turned: Vec<(usize, DVec2)> = corners.iter().map(|&(i, p)| (n - 1 - i, p)).collect();
    [corners.to_vec(), turned]
        .iter()
        .filter_map(|c| pnp(&map, cam, &board.squares_seen(c)))
        .collect()
}

/// Of a shot's PnP candidates, the one with its camera in front of the board (z < 0) and, among
/// those, nearest `near` (module docs).
fn choose(cands: Vec<TagPose>, near: Option<DVec3>) -> Option<TagPose> {
    cands.into_iter().min_by(|a, b| {
        let key = |p: &TagPose| {
            let c = p.world_from_cam.translation_m;
            (u8::from(c.z >= 0.0), near.map_or(0.0, |q| (c - q).length()))
        };
        let (ka, kb) = (key(a), key(b));
        ka.0.cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
    })
}

/// The RGB partners of posed thermal shots, posed by PnP on the board in their own image with
/// the calibrated RGB camera (`--with-rgb`): of the two orders, the one in front of the board
/// nearest the partner thermal camera (the two lenses are centimetres apart). `None` where the
/// board is not found in the partner or PnP fails the stage's bound (the caller then composes
/// the calibrated extrinsic, or leaves the view out).
pub fn pose_partners(
    folder: &Folder,
    rgb_cam: &CameraModel,
    board: &BoardFiducial,
    thermal: &[(usize, crate::model::geometry::Rigid3)],
    progress: &dyn Progress,
) -> Result<Vec<Option<TagPose>>, PosesError> {
    progress.start(
        "finding the board in the RGB partners",
        Some(thermal.len() as u64),
    );
    let found: Result<Vec<Option<TagPose>>, PosesError> = thermal
        .par_iter()
        .map(|(i, world_from_thermal)| {
            let r = match &folder.shots[*i].rgb {
                None => Ok(None),
                Some(path) => (board.find)(path, Stream::Rgb)
                    .map_err(|source| PosesError::BoardFinder {
                        path: path.clone(),
                        board: board.path.clone(),
                        source,
                    })
                    .map(|corners| {
                        (corners.len() >= 4)
                            .then(|| {
                                choose(
                                    candidates(board, rgb_cam, &corners),
                                    Some(world_from_thermal.translation_m),
                                )
                            })
                            .flatten()
                            .filter(|p| p.world_from_cam.translation_m.z < 0.0)
                    }),
            };
            progress.advance(1);
            r
        })
        .collect();
    progress.finish();
    found
}

/// Poses every shot on the board (module docs).
pub fn pose(
    folder: &Folder,
    cam: &CameraModel,
    board: &BoardFiducial,
    progress: &dyn Progress,
) -> Result<(Posing, BoardFigures), PosesError> {
    progress.start("finding the board", Some(folder.shots.len() as u64));
    let found: Vec<Result<Vec<(usize, DVec2)>, PosesError>> = folder
        .shots
        .par_iter()
        .map(|s| {
            let r =
                (board.find)(&s.path, Stream::Thermal).map_err(|source| PosesError::BoardFinder {
                    path: s.path.clone(),
                    board: board.path.clone(),
                    source,
                });
            progress.advance(1);
            r
        })
        .collect();
    progress.finish();
    let mut figures = BoardFigures::default();
    let mut posed = Vec::new();
    let mut left_out = Vec::new();
    let mut rms = Vec::new();
    let mut prev: Option<DVec3> = None;
    for (i, f) in found.into_iter().enumerate() {
        let corners = f?;
        if corners.len() < 4 {
            left_out.push((i, "the board is not found".to_owned()));
            continue;
        }
        figures.board_found += 1;
        match choose(candidates(board, cam, &corners), prev) {
            Some(p) if p.world_from_cam.translation_m.z < 0.0 => {
                prev = Some(p.world_from_cam.translation_m);
                rms.push(p.rms_px);
                posed.push((i, p.world_from_cam));
            }
            Some(_) => left_out.push((i, "the camera would be behind the board".to_owned())),
            None => left_out.push((
                i,
                format!("PnP on the board reprojects above {} px", MAX_PNP_RMS_PX),
            )),
        }
    }
    if posed.len() < 3 {
        return Err(PosesError::Folder {
            path: folder.dir.clone(),
            reason: format!(
                "the board ({}) was found in {} and posed in {} of {} images (at least 3 needed): check its inner-corner count and that the views see it whole",
                board.path.display(),
                figures.board_found,
                posed.len(),
                folder.shots.len()
            ),
        });
    }
    figures.posed = posed.len();
    figures.pnp_rms_px_median = median(&rms);
    figures.pnp_rms_px_max = percentile(&rms, 1.0);
    let heights: Vec<f64> = posed.iter().map(|p| -p.1.translation_m.z).collect();
    figures.height_m = [
        heights.iter().copied().fold(f64::INFINITY, f64::min),
        heights.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    ];
    let points = super::plane_seeds(folder, cam, &posed, DVec3::Z, 0.0);
    Ok((Posing::thermal(posed, left_out, points), figures))
}
