//! The posed dataset the trainer reads (COLMAP layout, `trainer/src/dataset`):
//! `sparse/0/{cameras,images,points3D}.txt` through the workspace's COLMAP codec (one thermal
//! camera with the calibrated distortion), `images/thermal_SEQUENCE.png` (the recorded 16-bit
//! words untouched), `holdout.txt` (one held-out image name per line: the trainer tests on
//! these and never trains on them), `ffc.txt` (the views taken within
//! [`FRESH_AFTER_FFC_NS`] of the end of a flat-field correction, from the FFC telemetry: their
//! radiometric drift is zero, and the trainer's per-view response pins its offsets there) and
//! `poses.json` (the stage's report).

use std::collections::BTreeSet;
use std::path::Path;

use super::frames::{FrameInfo, Stream, for_thermal_frames};
use super::select::ThermalView;
use super::{PosesError, PosesReport};
use crate::camera::CameraModel;
use crate::colmap::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, colmap_params, write_text_model,
};

fn out_err(path: &Path, e: impl ToString) -> PosesError {
    PosesError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// A view this soon after the last frame an FFC froze counts as taken right after the
/// correction (`ffc.txt`): an uncooled core drifts ~0.002 K/s, so within a second its offset is
/// still the correction's.
pub const FRESH_AFTER_FFC_NS: u64 = 1_000_000_000;

/// The sequences of `views` taken within [`FRESH_AFTER_FFC_NS`] after the last FFC-frozen frame
/// of `frames` (the session's thermal frames in capture order) that precedes them.
pub fn fresh_after_ffc(frames: &[FrameInfo], views: &[ThermalView]) -> Vec<u32> {
    views
        .iter()
        .filter(|v| {
            frames
                .iter()
                .filter(|f| f.ffc_frozen && f.monotonic_ns <= v.monotonic_ns)
                .map(|f| f.monotonic_ns)
                .max()
                .is_some_and(|t| v.monotonic_ns - t <= FRESH_AFTER_FFC_NS)
        })
        .map(|v| v.sequence)
        .collect()
}

/// Writes the images, the model, `holdout.txt` and, when any view is `fresh` after a flat-field
/// correction, `ffc.txt` into `out`.
pub fn write(
    session: &Path,
    out: &Path,
    thermal: &CameraModel,
    views: &[ThermalView],
    points: &[ColmapPoint],
    fresh: &[u32],
) -> Result<(), PosesError> {
    let images = out.join("images");
    std::fs::create_dir_all(&images).map_err(|e| out_err(&images, e))?;
    let wanted: BTreeSet<u32> = views.iter().map(|v| v.sequence).collect();
    let mut written = BTreeSet::new();
    for_thermal_frames(session, &wanted, |seq, w, h, pixels| {
        let p = images.join(Stream::Thermal.file_name(seq));
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, pixels.to_vec())
            .ok_or_else(|| out_err(&p, "pixel count does not match size"))?;
        img.save(&p).map_err(|e| out_err(&p, e))?;
        written.insert(seq);
        Ok(())
    })?;
    if let Some(missing) = wanted.difference(&written).next() {
        return Err(PosesError::Session {
            path: session.to_path_buf(),
            reason: format!("thermal frame {missing} was scanned but could not be read again"),
        });
    }
    let model = ColmapModel {
        cameras: vec![ColmapCamera {
            id: 1,
            model_name: colmap_params(thermal).0.to_owned(),
            model: *thermal,
        }],
        images: views
            .iter()
            .enumerate()
            .map(|(i, v)| ColmapImage {
                id: i as u32 + 1,
                camera_id: 1,
                name: Stream::Thermal.file_name(v.sequence),
                cam_from_world: v.world_from_cam.inverse(),
            })
            .collect(),
        points: points.to_vec(),
    };
    let sparse = out.join("sparse").join("0");
    write_text_model(&sparse, &model).map_err(|e| out_err(&sparse, e))?;
    let holdout: String = views
        .iter()
        .filter(|v| v.held_out)
        .map(|v| Stream::Thermal.file_name(v.sequence) + "\n")
        .collect();
    let p = out.join("holdout.txt");
    std::fs::write(&p, holdout).map_err(|e| out_err(&p, e))?;
    if !fresh.is_empty() {
        let list: String = fresh
            .iter()
            .map(|&seq| Stream::Thermal.file_name(seq) + "\n")
            .collect();
        let p = out.join("ffc.txt");
        std::fs::write(&p, list).map_err(|e| out_err(&p, e))?;
    }
    Ok(())
}

/// Writes `poses.json`.
pub fn write_report(out: &Path, report: &PosesReport) -> Result<(), PosesError> {
    let p = out.join("poses.json");
    let text = serde_json::to_string_pretty(report).map_err(|e| out_err(&p, e))?;
    std::fs::write(&p, text).map_err(|e| out_err(&p, e))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::Rigid3;

    fn frame(sequence: u32, t_s: f64, ffc_frozen: bool) -> FrameInfo {
        FrameInfo {
            sequence,
            monotonic_ns: (t_s * 1e9) as u64,
            ffc_frozen,
            sharpness: 1.0,
        }
    }

    fn view(sequence: u32, t_s: f64) -> ThermalView {
        ThermalView {
            sequence,
            monotonic_ns: (t_s * 1e9) as u64,
            world_from_cam: Rigid3::IDENTITY,
            held_out: false,
        }
    }

    /// Views within a second after an FFC's frozen frames are fresh; views before any FFC or
    /// later after one are not.
    #[test]
    fn fresh_views_follow_the_frozen_frames_within_a_second() {
        let frames = [
            frame(1, 0.0, false),
            frame(2, 1.0, true),
            frame(3, 1.1, true),
            frame(4, 1.5, false),
            frame(5, 3.0, false),
            frame(6, 5.0, true),
            frame(7, 5.9, false),
        ];
        let views = [view(1, 0.0), view(4, 1.5), view(5, 3.0), view(7, 5.9)];
        assert_eq!(fresh_after_ffc(&frames, &views), vec![4, 7]);
    }
}
