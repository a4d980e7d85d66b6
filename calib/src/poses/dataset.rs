//! The posed dataset the trainer reads (COLMAP layout, `trainer/src/dataset`):
//! `sparse/0/{cameras,images,points3D}.txt` through the workspace's COLMAP codec (camera 1: the
//! thermal camera with the calibrated distortion), `images/thermal_SEQUENCE.png` (the recorded
//! 16-bit words untouched), `holdout.txt` (one held-out image name per line: the trainer tests on
//! these and never trains on them), `ffc.txt` (the views taken within
//! [`FRESH_AFTER_FFC_NS`] of the end of a flat-field correction, from the FFC telemetry: their
//! radiometric drift is zero, and the trainer's per-view response pins its offsets there) and
//! `poses.json` (the stage's report).
//!
//! ## With the RGB keyframes (`--with-rgb`, [`super::PosesOptions::with_rgb`])
//! For joint RGB + thermal training (one model, each image through its own camera) the dataset
//! also holds every **posed RGB keyframe** ([`super::select::rgb_views`]): the keyframes
//! COLMAP registered (or the user's model holds) or the fiducial fast path posed by PnP, less
//! those whose pose jumps from their neighbours' (not used for the thermal poses either).
//! - `images/rgb_SEQUENCE.png`: the recorded frame decoded to 8-bit RGB, lossless and **not
//!   undistorted** (the trainer undistorts at load, as it does the thermal images);
//! - camera 2 in `cameras.txt`: the calibrated RGB camera, its model and distortion written by
//!   the same codec ([`colmap_params`]) as the thermal camera's;
//! - one `images.txt` entry per RGB view with camera 2. Its pose is the keyframe's pose itself,
//!   the very pose the thermal views are interpolated from (`world_from_thermal =
//!   world_from_rgb(t) ∘ rgb_from_thermal`, the lever arm in world units), so both sets share
//!   one world: COLMAP's (with its scale, when known, only in the lever arm) or the tag map's
//!   or the board's on the fast path. At a keyframe's own time the two poses differ by exactly
//!   the (scaled) extrinsic.
//! - `holdout.txt` also names the RGB views within `max_sync_s` (0.12 s: the RGB keyframes
//!   bracketing a thermal view are chosen within it) of each held-out thermal view, and the
//!   one nearest to it in any case, so a held-out instant is held out in both modalities;
//! - `poses.json`: `rgb_views` (RGB views written, held-out ones included) and `rgb_held_out`.
//!
//! A session without RGB frames cannot give any: `--with-rgb` on it is an error naming the
//! session, raised before anything is written (a joint dataset was asked for; a thermal-only
//! one under that name would only fail later, in the trainer's joint mode).

use std::collections::BTreeSet;
use std::path::Path;

use super::frames::{FrameInfo, Pixels, Stream, for_frames};
use super::select::{RgbView, ThermalView};
use super::{PosesError, PosesReport};
use crate::model::camera::CameraModel;
use crate::model::colmap::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, colmap_params, write_text_model,
};

/// The RGB half of a joint dataset (`--with-rgb`): the calibrated RGB camera and its views.
#[derive(Debug, Clone, Copy)]
pub struct RgbViews<'a> {
    pub camera: &'a CameraModel,
    pub views: &'a [RgbView],
}

/// COLMAP camera id of the thermal camera; the RGB camera's is [`RGB_CAMERA_ID`].
pub const THERMAL_CAMERA_ID: u32 = 1;
pub const RGB_CAMERA_ID: u32 = 2;

/// An output that failed to encode or write, with its cause.
fn out_err(path: &Path, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> PosesError {
    PosesError::Write {
        path: path.to_path_buf(),
        source: e.into(),
    }
}

/// An output that cannot be written as asked (no underlying error).
fn invalid(path: &Path, reason: impl Into<String>) -> PosesError {
    PosesError::Output {
        path: path.to_path_buf(),
        reason: reason.into(),
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
/// correction, `ffc.txt` into `out`; with `rgb`, the RGB views too (module docs).
pub fn write(
    session: &Path,
    out: &Path,
    thermal: &CameraModel,
    views: &[ThermalView],
    rgb: Option<RgbViews<'_>>,
    points: &[ColmapPoint],
    fresh: &[u32],
) -> Result<(), PosesError> {
    let images = out.join("images");
    std::fs::create_dir_all(&images).map_err(|e| out_err(&images, e))?;
    write_images(session, &images, views, rgb)?;
    let (model, holdout) = dataset_model(thermal, views, rgb, points);
    let sparse = out.join("sparse").join("0");
    write_text_model(&sparse, &model).map_err(|e| out_err(&sparse, e))?;
    write_lists(out, holdout, fresh)
}

/// Reads the chosen frames from the session again and writes them into `images` (thermal
/// 16-bit words as recorded, RGB 8-bit); a frame scanned but not read again is an error.
fn write_images(
    session: &Path,
    images: &Path,
    views: &[ThermalView],
    rgb: Option<RgbViews<'_>>,
) -> Result<(), PosesError> {
    let wanted: BTreeSet<u32> = views.iter().map(|v| v.sequence).collect();
    let wanted_rgb: BTreeSet<u32> = rgb
        .iter()
        .flat_map(|r| r.views.iter().map(|v| v.sequence))
        .collect();
    let (mut written, mut written_rgb) = (BTreeSet::new(), BTreeSet::new());
    let mut grey_rgb = 0usize;
    for_frames(session, &wanted, &wanted_rgb, |seq, w, h, pixels| {
        match pixels {
            Pixels::Thermal(words) => {
                let p = images.join(Stream::Thermal.dataset_file_name(seq));
                let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, words.to_vec())
                    .ok_or_else(|| invalid(&p, "pixel count does not match size"))?;
                img.save(&p).map_err(|e| out_err(&p, e))?;
                written.insert(seq);
            }
            Pixels::Rgb8(px) => {
                let p = images.join(Stream::Rgb.dataset_file_name(seq));
                if let Some(cam) = rgb.map(|r| r.camera)
                    && (w, h) != (cam.width_px, cam.height_px)
                {
                    return Err(invalid(
                        &p,
                        format!(
                            "RGB frame {seq} is {w}×{h} px, the calibrated RGB camera {}×{} px",
                            cam.width_px, cam.height_px
                        ),
                    ));
                }
                if px.chunks_exact(3).all(|p| p[0] == p[1] && p[1] == p[2]) {
                    grey_rgb += 1;
                }
                let img = image::RgbImage::from_raw(w, h, px.to_vec())
                    .ok_or_else(|| invalid(&p, "pixel count does not match size"))?;
                img.save(&p).map_err(|e| out_err(&p, e))?;
                written_rgb.insert(seq);
            }
        }
        Ok(())
    })?;
    for (stream, wanted, written) in [
        ("thermal", &wanted, &written),
        ("RGB", &wanted_rgb, &written_rgb),
    ] {
        if let Some(missing) = wanted.difference(written).next() {
            return Err(PosesError::Session {
                path: session.to_path_buf(),
                reason: format!("{stream} frame {missing} was scanned but could not be read again"),
            });
        }
    }
    if grey_rgb > 0 {
        // The trainer tells RGB from thermal images by their pixels, and reads an 8-bit
        // colour image without any colour as a grey (thermal) one.
        tracing::warn!(
            frames = grey_rgb,
            "RGB frames without any colour (R = G = B everywhere, a monochrome camera or a neutral scene): the trainer may read them as grey thermal images"
        );
    }
    Ok(())
}

/// The COLMAP model of the dataset (the thermal camera, with `rgb` the RGB camera as the
/// second; images in `views` order, then the RGB views) and the held-out image names.
fn dataset_model(
    thermal: &CameraModel,
    views: &[ThermalView],
    rgb: Option<RgbViews<'_>>,
    points: &[ColmapPoint],
) -> (ColmapModel, Vec<String>) {
    let camera = |id: u32, model: &CameraModel| ColmapCamera {
        id,
        model_name: colmap_params(model).0.to_owned(),
        model: *model,
    };
    let mut cameras = vec![camera(THERMAL_CAMERA_ID, thermal)];
    let mut entries: Vec<(u32, String, crate::model::geometry::Rigid3)> = views
        .iter()
        .map(|v| {
            (
                THERMAL_CAMERA_ID,
                Stream::Thermal.dataset_file_name(v.sequence),
                v.world_from_cam,
            )
        })
        .collect();
    let mut holdout: Vec<String> = views
        .iter()
        .filter(|v| v.held_out)
        .map(|v| Stream::Thermal.dataset_file_name(v.sequence))
        .collect();
    if let Some(r) = rgb {
        cameras.push(camera(RGB_CAMERA_ID, r.camera));
        entries.extend(r.views.iter().map(|v| {
            (
                RGB_CAMERA_ID,
                Stream::Rgb.dataset_file_name(v.sequence),
                v.world_from_cam,
            )
        }));
        holdout.extend(
            r.views
                .iter()
                .filter(|v| v.held_out)
                .map(|v| Stream::Rgb.dataset_file_name(v.sequence)),
        );
    }
    let model = ColmapModel {
        cameras,
        images: entries
            .into_iter()
            .enumerate()
            .map(|(i, (camera_id, name, world_from_cam))| ColmapImage {
                id: i as u32 + 1,
                camera_id,
                name,
                cam_from_world: world_from_cam.inverse(),
            })
            .collect(),
        points: points.to_vec(),
    };
    (model, holdout)
}

/// `holdout.txt`, and `ffc.txt` when any view is fresh after a flat-field correction.
fn write_lists(out: &Path, holdout: Vec<String>, fresh: &[u32]) -> Result<(), PosesError> {
    let holdout: String = holdout.into_iter().map(|n| n + "\n").collect();
    let p = out.join("holdout.txt");
    std::fs::write(&p, holdout).map_err(|e| out_err(&p, e))?;
    if !fresh.is_empty() {
        let list: String = fresh
            .iter()
            .map(|&seq| Stream::Thermal.dataset_file_name(seq) + "\n")
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
