//! What the detection front end returns: a board in canonical corner order with its scores
//! and every sub-pixel refinement computed ([`BoardDetection`]), or why there is none
//! ([`DetectFailure`]), and the operations on a detection the pipeline needs (a 180° turn,
//! choosing a refinement).

use glam::DVec2;
use serde::Serialize;

/// A board found in one image, in canonical order (see the front end's overview), with its
/// scores.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BoardDetection {
    /// Inner corners, pixels (origin at the centre of the top-left pixel), in ascending
    /// [`Self::corner_ids`] order.
    #[serde(skip)]
    pub corners_px: Vec<DVec2>,
    /// The board's row-major corner index of each corner: `0..cols·rows` for a whole board,
    /// a subset for a partial one (AprilTag boards only). Every variant has these corners.
    #[serde(skip)]
    pub corner_ids: Vec<usize>,
    /// Which detector produced the kept result.
    pub detector: &'static str,
    /// True when found on the inverted image.
    pub inverted: bool,
    /// OpenCV's edge-rise sharpness in (original) pixels; lower is sharper.
    pub sharpness_px: f64,
    /// Square contrast: |mean(dark) − mean(bright)| / pooled std (dimensionless).
    pub contrast_z: f64,
    /// RMS second difference along rows/columns (px): grid roughness, lower is better.
    pub roughness_px: f64,
    /// RMS distance of the corners from the best homography of the board grid (px): how
    /// well they fit one plane seen through a pinhole (lens distortion adds to it equally
    /// for every refinement, so it ranks refinements of one image).
    pub planar_fit_px: f64,
    /// Which sub-pixel refinement `corners_px` holds (per image, the one with the smallest
    /// planar fit; the pipeline may choose another per camera, see [`Self::variants`]).
    pub refinement: Refinement,
    /// Every refinement computed for this image, in the same canonical order as `corners_px`.
    /// The planar fit cannot rank them when lens distortion dominates it (the simulated
    /// Lepton: 0.15–0.4 px for every refinement), so the pipeline ranks them per camera by
    /// the camera's own calibration RMS.
    #[serde(skip)]
    pub variants: Vec<(Refinement, Vec<DVec2>)>,
    /// What fixed the corner order.
    pub order: BoardOrder,
}

/// What fixed a detection's corner order (see the front end's overview, step 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BoardOrder {
    /// The coated square at corner 0 (boards with cols + rows odd).
    SquareColour,
    /// The board's AprilTags.
    Tags,
    /// Corner 0 nearest the image's top-left (colour-symmetric board, no tag seen).
    ImageOrientation,
}

/// Sub-pixel corner refinements, ranked per image by how well the corners fit a plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Refinement {
    /// The SB detector's own sub-pixel corners.
    Detector,
    /// `cornerSubPix` on the unquantised stretched image.
    CornerSubPix,
    /// The blurred-saddle model fit of [`crate::detect::saddle`].
    Saddle,
}

/// Why a detection was not found or rejected.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DetectFailure {
    NotFound,
    Ambiguous(String),
    /// No whole board; the board's AprilTags were looked for and gave no usable partial board
    /// (the reason says why).
    NoPartial(crate::detect::tagboard::TagRejection),
}

/// Rotates a canonical detection by 180° (corner i ↔ corner n−1−i, `n` the board's corner
/// count; partial detections keep their ascending id order). Used when the coated squares
/// turn out to be the bright ones in thermal images, or when the tags say so.
pub fn rotate_180(det: &mut BoardDetection, n: usize) {
    det.corners_px.reverse();
    for id in &mut det.corner_ids {
        *id = n.saturating_sub(1 + *id);
    }
    det.corner_ids.reverse();
    for (_, v) in &mut det.variants {
        v.reverse();
    }
}

impl BoardDetection {
    /// The corners of refinement `r`, or `corners_px` when `r` was not computed here (the
    /// classic detector has no sub-pixel corners of its own; the saddle fit runs on small
    /// squares only).
    pub fn corners_of(&self, r: Refinement) -> &[DVec2] {
        self.variants
            .iter()
            .find(|(v, _)| *v == r)
            .map_or(self.corners_px.as_slice(), |(_, c)| c.as_slice())
    }

    /// Makes refinement `r` the one in `corners_px` (no change when it was not computed).
    pub fn choose(&mut self, r: Refinement) {
        if let Some((_, c)) = self.variants.iter().find(|(v, _)| *v == r) {
            self.corners_px = c.clone();
            self.refinement = r;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_half_turn_maps_corner_ids_and_keeps_them_ascending() {
        let pts = vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.0, 1.0),
        ];
        let mut det = BoardDetection {
            corners_px: pts.clone(),
            corner_ids: vec![0, 1, 9],
            detector: "apriltag",
            inverted: false,
            sharpness_px: f64::NAN,
            contrast_z: f64::NAN,
            roughness_px: f64::NAN,
            planar_fit_px: 0.0,
            refinement: Refinement::CornerSubPix,
            variants: vec![(Refinement::CornerSubPix, pts)],
            order: BoardOrder::Tags,
        };
        // A 9x6 board: corner i becomes 53 - i.
        rotate_180(&mut det, 54);
        assert_eq!(det.corner_ids, vec![44, 52, 53]);
        assert_eq!(
            det.corners_px[0],
            DVec2::new(0.0, 1.0),
            "corner 9 became 44, listed first"
        );
        assert_eq!(
            det.variants[0].1, det.corners_px,
            "variants turn with the corners"
        );
    }
}
