//! Writing the files of a scene dataset: PNG images (16-bit, 8-bit grey, sRGB), the truth's
//! depth and temperature words, JSON documents, the response effects' files and the COLMAP text
//! model (through the workspace's codec, [`s3tir_calib::model::colmap`]).

use std::fs;
use std::path::Path;

use glam::DVec3;
use s3tir_calib::model::colmap::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, colmap_params, write_text_model,
};
use s3tir_calib::{CameraModel, Rigid3};
use serde::Serialize;

use super::response::{ExportedFrame, ResponseEffects, ResponseSimulator};
use crate::error::SimError;

/// The error of a failed file operation `what` on `path`.
pub(crate) fn io(path: &Path, what: &'static str) -> impl FnOnce(std::io::Error) -> SimError {
    let path = path.to_path_buf();
    move |source| SimError::Io { path, what, source }
}

/// Creates the folders `dirs` (relative to `out`) and their parents.
pub(crate) fn create_dirs(out: &Path, dirs: &[&str]) -> Result<(), SimError> {
    for d in dirs {
        let p = out.join(d);
        fs::create_dir_all(&p).map_err(io(&p, "create directory"))?;
    }
    Ok(())
}

/// Writes a `w × h` PNG of pixel type `P` from its samples (`what` names it in errors).
fn save_png<P>(
    path: &Path,
    w: u32,
    h: u32,
    samples: Vec<P::Subpixel>,
    what: &'static str,
) -> Result<(), SimError>
where
    P: image::Pixel + image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
{
    image::ImageBuffer::<P, Vec<P::Subpixel>>::from_raw(w, h, samples)
        .ok_or(SimError::InvalidParameter {
            parameter: "image buffer",
            value: path.display().to_string(),
            why: "size does not match",
        })?
        .save(path)
        .map_err(|source| SimError::Image {
            path: path.to_path_buf(),
            what,
            source: Box::new(source),
        })
}

/// Writes a `w × h` 16-bit grey PNG.
pub(crate) fn save_u16(path: &Path, w: u32, h: u32, data: Vec<u16>) -> Result<(), SimError> {
    save_png::<image::Luma<u16>>(path, w, h, data, "16-bit PNG")
}

/// Writes a `w × h` 8-bit sRGB PNG of packed RGB bytes.
pub(crate) fn save_rgb8(path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<(), SimError> {
    save_png::<image::Rgb<u8>>(path, w, h, rgb, "RGB PNG")
}

/// Writes a thermal frame as the response simulator exported it (16-bit centikelvin or 8-bit
/// grey after AGC).
pub(crate) fn save_exported(
    path: &Path,
    w: u32,
    h: u32,
    frame: ExportedFrame,
) -> Result<(), SimError> {
    match frame {
        ExportedFrame::CentiKelvin(words) => save_u16(path, w, h, words),
        ExportedFrame::Grey8(grey) => save_png::<image::Luma<u8>>(path, w, h, grey, "8-bit PNG"),
    }
}

/// Depths in metres → the 16-bit millimetre words of the depth truth (0 stays 0: no surface).
pub(crate) fn depth_mm_words(depth_m: &[f64]) -> Vec<u16> {
    depth_m
        .iter()
        .map(|d| (d * 1000.0).round().clamp(0.0, 65535.0) as u16)
        .collect()
}

/// Temperatures in kelvin → centikelvin words.
pub(crate) fn centikelvin_words(temp_k: &[f64]) -> Vec<u16> {
    temp_k
        .iter()
        .map(|t| (t * 100.0).round().clamp(0.0, 65535.0) as u16)
        .collect()
}

/// Writes `ffc.txt` (with drift, without AGC: the frames right after a flat-field correction)
/// and `response.json` (with any effect) into `out`.
pub(crate) fn write_response_files(
    out: &Path,
    effects: ResponseEffects,
    response: &ResponseSimulator,
) -> Result<(), SimError> {
    if effects.drift_step_k > 0.0 && !effects.agc {
        // What a capture session's FFC telemetry says: the frames right after a correction.
        let fresh: String = response
            .truth()
            .frames
            .iter()
            .filter(|f| f.ffc_before)
            .map(|f| f.image.clone() + "\n")
            .collect();
        let p = out.join("ffc.txt");
        fs::write(&p, fresh).map_err(io(&p, "write"))?;
    }
    if effects.any() {
        write_json(
            &out.join("response.json"),
            &response.truth(),
            "response.json",
        )?;
    }
    Ok(())
}

/// Writes `value` as pretty JSON followed by a newline.
pub(crate) fn write_json(
    path: &Path,
    value: &impl Serialize,
    what: &'static str,
) -> Result<(), SimError> {
    let text =
        serde_json::to_string_pretty(value).map_err(|source| SimError::Json { what, source })?;
    fs::write(path, text + "\n").map_err(io(path, "write"))
}

/// One image of a dataset's COLMAP model: image `id` taken by camera `camera_id` at
/// `cam_from_world`, its quaternion kept with w ≥ 0 (COLMAP's habit; the same rotation).
pub(crate) fn colmap_image(
    id: usize,
    camera_id: u32,
    name: String,
    cam_from_world: &Rigid3,
) -> Result<ColmapImage, SimError> {
    let id = u32::try_from(id).map_err(|_| SimError::InvalidParameter {
        parameter: "COLMAP image id",
        value: id.to_string(),
        why: "COLMAP image ids are 32-bit",
    })?;
    let mut cam_from_world = *cam_from_world;
    if cam_from_world.rotation.w < 0.0 {
        cam_from_world.rotation = -cam_from_world.rotation;
    }
    Ok(ColmapImage {
        id,
        camera_id,
        name,
        cam_from_world,
    })
}

/// Writes the COLMAP text model (`cameras.txt`, `images.txt`, `points3D.txt`) into
/// `sparse_dir` through [`write_text_model`]: the `cameras` as [`colmap_params`] names them
/// (PINHOLE for the scene cameras; `cx, cy` moved by +½ px to COLMAP's pixel convention there
/// and only there), `images` with empty 2-D feature lines, `points` numbered from 1 with their
/// colour, error 0 and empty tracks.
pub(crate) fn write_colmap_text(
    sparse_dir: &Path,
    cameras: &[(u32, CameraModel)],
    images: Vec<ColmapImage>,
    points: &[(DVec3, [u8; 3])],
) -> Result<(), SimError> {
    let model = ColmapModel {
        cameras: cameras
            .iter()
            .map(|&(id, model)| ColmapCamera {
                id,
                model_name: colmap_params(&model).0.to_owned(),
                model,
            })
            .collect(),
        images,
        points: points
            .iter()
            .zip(1u64..)
            .map(|(&(p, rgb), id)| ColmapPoint {
                id,
                position_m: p.to_array(),
                rgb,
            })
            .collect(),
    };
    write_text_model(sparse_dir, &model).map_err(|source| SimError::Colmap {
        source: Box::new(source),
    })
}
