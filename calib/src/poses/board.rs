//! The calibration board as a fiducial (`--board board.toml`): the board that calibrated the
//! rig, left standing in the scene, poses the keyframes that see it and gives COLMAP's world
//! its metric scale, like a tag map ([`super::fiducials`]) whose world is the board's frame.
//!
//! **Why a board works as a map.** Its inner corners are known in its own frame (corner (c, r)
//! at (c·square, r·square, 0), `board.toml`), so every square whose four corners are found is a
//! planar quad of known size and place, exactly what the tag machinery poses with: each such
//! square becomes one mapped "tag" ([`BoardFiducial::as_tag_map`], id = r·(cols − 1) + c), and
//! PnP, the neighbour check, the scale from triangulated corners and the agreement with
//! COLMAP run unchanged. A board is one plane: the pitch-against-height trade the tag module
//! describes applies, eased by its many corners (40 squares on the 9 × 6 board).
//!
//! **Both cameras.** An emissivity-coated board is seen by the thermal camera too (its coated
//! squares emit less), so a rig without RGB is posed wherever the board is in view. Finding
//! it needs the calibration front end (OpenCV's chessboard detectors and the sub-pixel
//! refinements of `s3tir-calib`): this module, OpenCV-free like the rest of the stage, takes
//! the finder as a function ([`BoardFinder`]); `s3tir-calib poses --board` passes the front
//! end's. Where the board is in view for only part of a walk, fewer keyframes are posed than
//! COLMAP would need (`min_registered`, `--min-registered`): the views between them are
//! still posed, the rest skipped with their reason.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::PosesError;
use super::fiducials::{SeenTags, TagMap};
use super::frames::{FrameInfo, Stream};
use crate::tags::TagDetection;

/// Finds the board in one keyframe image (`colmap/images/…`: RGB JPEG, thermal 8-bit PNG) of
/// the given stream: its inner corners found, as (row-major corner index, pixel with the
/// origin at the top-left pixel's centre); empty when the board is not found there. An error
/// is the finder's own (the image does not decode, the detector failed).
pub type BoardFinder = Arc<
    dyn Fn(&Path, Stream) -> Result<Vec<(usize, DVec2)>, Box<dyn std::error::Error + Send + Sync>>
        + Send
        + Sync,
>;

/// The board of `--board` (module docs).
#[derive(Clone)]
pub struct BoardFiducial {
    /// `board.toml`.
    pub path: PathBuf,
    /// Inner corners along a row and down a column.
    pub cols: u32,
    pub rows: u32,
    /// Side of one square, metres.
    pub square_m: f64,
    pub find: BoardFinder,
}

impl std::fmt::Debug for BoardFiducial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BoardFiducial")
            .field("path", &self.path)
            .field("cols", &self.cols)
            .field("rows", &self.rows)
            .field("square_m", &self.square_m)
            .finish_non_exhaustive()
    }
}

impl BoardFiducial {
    /// Row-major indices of square (c, r)'s four corners, in the order [`Self::as_tag_map`]
    /// gives their board points.
    fn square_corners(&self, c: u32, r: u32) -> [usize; 4] {
        let at = |c: u32, r: u32| (r * self.cols + c) as usize;
        [at(c, r + 1), at(c + 1, r + 1), at(c + 1, r), at(c, r)]
    }

    fn squares(&self) -> impl Iterator<Item = (u32, u32, u32)> + '_ {
        let w = self.cols.saturating_sub(1);
        (0..self.rows.saturating_sub(1)).flat_map(move |r| (0..w).map(move |c| (r * w + c, c, r)))
    }

    /// The board as a map of tags in its own frame, metres: one per square between four inner
    /// corners (module docs). `size_m` is the square's side.
    pub fn as_tag_map(&self) -> TagMap {
        let s = self.square_m;
        let point = |i: usize| {
            let (c, r) = (i as u32 % self.cols, i as u32 / self.cols);
            DVec3::new(f64::from(c) * s, f64::from(r) * s, 0.0)
        };
        TagMap {
            path: self.path.clone(),
            size_m: s,
            corners: self
                .squares()
                .map(|(id, c, r)| (id, self.square_corners(c, r).map(point)))
                .collect(),
        }
    }

    /// The squares of a found board whose four corners were found, as tag detections of
    /// [`Self::as_tag_map`].
    pub fn squares_seen(&self, corners: &[(usize, DVec2)]) -> Vec<TagDetection> {
        let found: BTreeMap<usize, DVec2> = corners.iter().copied().collect();
        self.squares()
            .filter_map(|(id, c, r)| {
                let quad = self.square_corners(c, r);
                let px: Vec<DVec2> = quad
                    .iter()
                    .map(|i| found.get(i).copied())
                    .collect::<Option<_>>()?;
                let centre = px.iter().copied().sum::<DVec2>() / 4.0;
                Some(TagDetection {
                    id,
                    hamming: 0,
                    decision_margin: 0.0,
                    centre_px: centre.to_array(),
                    corners_px: [px[0], px[1], px[2], px[3]].map(|p| p.to_array()),
                })
            })
            .collect()
    }

    /// The board in every keyframe (images in `dir`, named by the stage), in parallel.
    pub fn detect_in_keyframes(
        &self,
        dir: &Path,
        stream: Stream,
        keyframes: &[FrameInfo],
    ) -> Result<Vec<SeenTags>, PosesError> {
        keyframes
            .par_iter()
            .map(|k| {
                let path = dir.join(stream.file_name(k.sequence));
                let corners =
                    (self.find)(&path, stream).map_err(|source| PosesError::BoardFinder {
                        path: path.clone(),
                        board: self.path.clone(),
                        source,
                    })?;
                Ok(SeenTags {
                    sequence: k.sequence,
                    monotonic_ns: k.monotonic_ns,
                    tags: self.squares_seen(&corners),
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::model::camera::{BrownConrady, CameraModel, Intrinsics};
    use crate::model::geometry::Rigid3;
    use glam::DQuat;

    fn board() -> BoardFiducial {
        BoardFiducial {
            path: PathBuf::from("board.toml"),
            cols: 8,
            rows: 5,
            square_m: 0.06,
            find: Arc::new(|_, _| Ok(Vec::new())),
        }
    }

    fn camera() -> CameraModel {
        CameraModel {
            width_px: 160,
            height_px: 120,
            intrinsics: Intrinsics {
                fx: 147.0,
                fy: 147.0,
                cx: 79.5,
                cy: 59.5,
            },
            distortion: BrownConrady::default(),
        }
    }

    /// The board's inner corners as `camera` sees them from `cam_from_board`.
    fn project(
        b: &BoardFiducial,
        cam: &CameraModel,
        cam_from_board: &Rigid3,
    ) -> Vec<(usize, DVec2)> {
        (0..(b.cols * b.rows) as usize)
            .map(|i| {
                let p = DVec3::new(
                    f64::from(i as u32 % b.cols) * b.square_m,
                    f64::from(i as u32 / b.cols) * b.square_m,
                    0.0,
                );
                let c = cam_from_board.transform_point(p);
                (i, cam.project(c).expect("in front"))
            })
            .collect()
    }

    #[test]
    fn every_square_of_the_board_is_a_mapped_quad_of_its_size() {
        let b = board();
        let map = b.as_tag_map();
        assert_eq!(
            map.corners.len(),
            7 * 4,
            "one tag per square between inner corners"
        );
        for quad in map.corners.values() {
            for k in 0..4 {
                let side = (quad[(k + 1) % 4] - quad[k]).length();
                assert!((side - 0.06).abs() < 1e-12, "side {side}: {quad:?}");
            }
            assert!(
                quad.iter().all(|p| p.z == 0.0),
                "on the board's plane: {quad:?}"
            );
        }
    }

    #[test]
    fn a_board_in_view_poses_the_camera_in_the_boards_frame() {
        let b = board();
        let cam = camera();
        // 1.1 m in front of the board's centre, turned 25° about its vertical and 10° about
        // its horizontal axis: squares of ~7 px, as the simulated Lepton sees the walk board.
        let centre = DVec3::new(0.21, 0.12, 0.0);
        let rotation = DQuat::from_rotation_y(25f64.to_radians()) * DQuat::from_rotation_x(0.17);
        let cam_from_board = Rigid3::new(rotation, DVec3::new(0.0, 0.0, 1.1) - rotation * centre);
        let mut found = project(&b, &cam, &cam_from_board);
        // Half a pixel of alternating noise, and the last row not found (a partial board).
        for (i, p) in &mut found {
            p.x += if *i % 2 == 0 { 0.25 } else { -0.25 };
            p.y += if *i % 3 == 0 { 0.25 } else { -0.2 };
        }
        found.retain(|(i, _)| *i < 32);
        let squares = b.squares_seen(&found);
        assert_eq!(squares.len(), 7 * 3, "squares with all four corners found");
        let pose = super::super::fiducials::pnp(&b.as_tag_map(), &cam, &squares)
            .expect("a pose from the board's squares");
        let truth = cam_from_board.inverse();
        let rot_err = pose
            .world_from_cam
            .rotation
            .angle_between(truth.rotation)
            .to_degrees();
        let centre_err = (pose.world_from_cam.translation_m - truth.translation_m).length();
        assert!(
            rot_err < 0.5,
            "rotation {rot_err:.3}° off (< 0.5° at ±0.25 px)"
        );
        assert!(
            centre_err < 0.01,
            "centre {centre_err:.4} m off (< 1 cm at 1.1 m)"
        );
        assert!(pose.rms_px < 0.5, "corner rms {:.3} px", pose.rms_px);
    }

    #[test]
    fn a_board_not_found_sees_no_squares() {
        let b = board();
        assert!(b.squares_seen(&[]).is_empty());
        // Corners of one row only: no square has all four.
        let row: Vec<(usize, DVec2)> = (0..8).map(|i| (i, DVec2::new(i as f64, 0.0))).collect();
        assert!(b.squares_seen(&row).is_empty());
    }
}
