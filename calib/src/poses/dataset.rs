//! The posed dataset the trainer reads (COLMAP layout, `trainer/src/dataset`):
//! `sparse/0/{cameras,images,points3D}.txt` through the workspace's COLMAP codec (one thermal
//! camera with the calibrated distortion), `images/thermal_SEQUENCE.png` (the recorded 16-bit
//! words untouched), `holdout.txt` (one held-out image name per line: the trainer tests on
//! these and never trains on them) and `poses.json` (the stage's report).

use std::collections::BTreeSet;
use std::path::Path;

use super::frames::{Stream, for_thermal_frames};
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

/// Writes the images, the model and `holdout.txt` into `out`.
pub fn write(
    session: &Path,
    out: &Path,
    thermal: &CameraModel,
    views: &[ThermalView],
    points: &[ColmapPoint],
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
    Ok(())
}

/// Writes `poses.json`.
pub fn write_report(out: &Path, report: &PosesReport) -> Result<(), PosesError> {
    let p = out.join("poses.json");
    let text = serde_json::to_string_pretty(report).map_err(|e| out_err(&p, e))?;
    std::fs::write(&p, text).map_err(|e| out_err(&p, e))
}
