//! The steps of [`super::Dataset::load`], in order: the model ([`open_model`]), each image
//! ([`load_view_image`]), the scene's thermal range ([`scene_range`]), the views in training
//! units ([`normalised_view`]) and the training / held-out split ([`split_views`], over the name
//! lists of [`read_name_list`]).

use std::path::{Path, PathBuf};

use super::images::{ImageKind, RawImage, load_image};
use super::{
    DatasetError, FFC_FILE, HOLDOUT_FILE, LoadOptions, Modality, ThermalRange, View, colmap,
    downsample, named_rgb, undistort,
};
use crate::camera::PinholeCamera;

/// The image names a list file (`holdout.txt`, `ffc.txt`) gives, one per line (`#` comments),
/// each checked against the registered `views`; `None` when the file does not exist.
pub(super) fn read_name_list(
    root: &Path,
    file: &str,
    views: &[View],
) -> Result<Option<std::collections::BTreeSet<String>>, DatasetError> {
    let path = root.join(file);
    if !path.is_file() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|source| DatasetError::Io {
        path: path.clone(),
        source,
    })?;
    let names: std::collections::BTreeSet<String> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(str::to_owned)
        .collect();
    if let Some(unknown) = names.iter().find(|n| !views.iter().any(|v| &v.name == *n)) {
        return Err(DatasetError::Empty {
            root: root.to_path_buf(),
            reason: format!(
                "{} names {unknown}, which the model does not register",
                path.display()
            ),
        });
    }
    Ok(Some(names))
}

pub(super) fn find_model_dir(root: &Path) -> Option<PathBuf> {
    let has = |d: &Path| d.join("cameras.txt").exists() || d.join("cameras.bin").exists();
    [
        root.join("sparse").join("0"),
        root.join("sparse"),
        root.to_path_buf(),
    ]
    .into_iter()
    .find(|d| has(d))
}

/// The dataset's COLMAP model (its folder and contents); a model with no images is an error.
pub(super) fn open_model(root: &Path) -> Result<(PathBuf, colmap::ColmapModel), DatasetError> {
    if !root.is_dir() {
        return Err(DatasetError::MissingFile {
            path: root.to_path_buf(),
            what: "dataset folder",
        });
    }
    let model_dir = find_model_dir(root).ok_or_else(|| DatasetError::MissingFile {
        path: root.join("sparse").join("0").join("cameras.txt"),
        what: "COLMAP sparse model (cameras.txt or cameras.bin)",
    })?;
    let model = colmap::read_model(&model_dir)?;
    if model.images.is_empty() {
        return Err(DatasetError::Empty {
            root: root.to_path_buf(),
            reason: format!("{} registers no images", model_dir.display()),
        });
    }
    Ok((model_dir, model))
}

/// One registered image read, checked against its camera's size, undistorted when the camera
/// has distortion (its model name noted in `undistorted_models`) and downscaled, with its
/// pinhole camera at the loaded size.
pub(super) fn load_view_image(
    im: &colmap::ColmapImage,
    cam: &colmap::ColmapCamera,
    images_dir: &Path,
    opts: &LoadOptions,
    undistorted_models: &mut Vec<String>,
) -> Result<(PinholeCamera, RawImage), DatasetError> {
    let path = images_dir.join(&im.name);
    let raw = load_image(&path, opts.colour)?;
    // An 8-bit image that is grey by its pixels but named as the RGB camera's (a
    // neutral scene, a monochrome RGB sensor) stays RGB: a joint dataset's modality
    // is the camera's, not the content's.
    let raw = if raw.kind == ImageKind::Grey8 && named_rgb(&im.name) {
        let n = raw.values.len();
        RawImage {
            kind: ImageKind::Rgb8,
            values: raw.values.iter().copied().cycle().take(3 * n).collect(),
            ..raw
        }
    } else {
        raw
    };
    let (ew, eh) = (cam.model.width_px as usize, cam.model.height_px as usize);
    if raw.width != ew || raw.height != eh {
        return Err(DatasetError::SizeMismatch {
            path,
            camera_id: cam.id,
            expected_w: ew,
            expected_h: eh,
            actual_w: raw.width,
            actual_h: raw.height,
        });
    }
    let distorted = cam.model.distortion != s3tir_calib::BrownConrady::default();
    let raw = if distorted {
        if !undistorted_models.contains(&cam.model_name) {
            undistorted_models.push(cam.model_name.clone());
        }
        undistort(&raw, &cam.model)
    } else {
        raw
    };
    let scale = opts.downscale.max(1);
    let raw = downsample(&raw, scale);
    let i = &cam.model.intrinsics;
    let s = scale as f64;
    let pin = PinholeCamera {
        fx_px: i.fx / s,
        fy_px: i.fy / s,
        cx_px: (i.cx + 0.5) / s - 0.5,
        cy_px: (i.cy + 0.5) / s - 0.5,
        width: raw.width,
        height: raw.height,
        cam_from_world: im.cam_from_world,
    };
    Ok((pin, raw))
}

/// One thermal kind per scene, one range per scene: the raw minimum and maximum over every
/// thermal image (`None` when the scene has none); a flat scene gets a unit span.
pub(super) fn scene_range(
    raws: &[(String, PinholeCamera, RawImage)],
    root: &Path,
    images_dir: &Path,
    opts: &LoadOptions,
) -> Result<Option<ThermalRange>, DatasetError> {
    let mut range: Option<ThermalRange> = None;
    for (name, _, raw) in raws {
        if raw.kind == ImageKind::Rgb8 {
            continue;
        }
        let (lo, hi) = raw
            .values
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        match &mut range {
            None => {
                range = Some(ThermalRange {
                    kind: raw.kind,
                    units: (raw.kind == ImageKind::Thermal16).then_some(opts.thermal_units),
                    min_raw: lo,
                    max_raw: hi,
                });
            }
            Some(r) => {
                if r.kind != raw.kind {
                    return Err(DatasetError::MixedKinds {
                        root: root.to_path_buf(),
                        path: images_dir.join(name),
                        first: r.kind,
                        other: raw.kind,
                    });
                }
                r.min_raw = r.min_raw.min(lo);
                r.max_raw = r.max_raw.max(hi);
            }
        }
    }
    // A flat scene (or NaN-free degenerate range) gets a unit span.
    if let Some(r) = &mut range
        && r.max_raw <= r.min_raw
    {
        r.max_raw = r.min_raw + 1.0;
    }
    Ok(range)
}

/// A view with its image in training units: thermal through the scene's range, RGB in [0, 1].
pub(super) fn normalised_view(
    name: String,
    camera: PinholeCamera,
    raw: &RawImage,
    range: Option<ThermalRange>,
) -> View {
    let (thermal, rgb) = if raw.kind == ImageKind::Rgb8 {
        (
            None,
            Some(raw.values.iter().map(|v| (v / 255.0) as f32).collect()),
        )
    } else {
        let r = range.unwrap_or(ThermalRange {
            kind: raw.kind,
            units: None,
            min_raw: 0.0,
            max_raw: 1.0,
        });
        (
            Some(raw.values.iter().map(|&v| r.normalise(v)).collect()),
            None,
        )
    };
    View {
        name,
        camera,
        thermal,
        rgb,
    }
}

/// The views kept for the modality trained, and which train, which are held out, which follow
/// a flat-field correction.
pub(super) struct Split {
    pub views: Vec<View>,
    pub train: Vec<usize>,
    pub test: Vec<usize>,
    pub fresh_after_ffc: Option<Vec<usize>>,
}

/// Splits the views by `holdout.txt` (else every `holdout_every`-th) after checking the name
/// lists against the whole model, keeping the modality trained; no training view is an error.
pub(super) fn split_views(
    root: &Path,
    views: Vec<View>,
    opts: &LoadOptions,
) -> Result<Split, DatasetError> {
    let k = opts.holdout_every;
    let held_out = read_name_list(root, HOLDOUT_FILE, &views)?;
    let fresh = read_name_list(root, FFC_FILE, &views)?;
    // The image sets not trained on are dropped after the name lists are checked against
    // the whole model (a joint holdout.txt names both sets).
    let views: Vec<View> = views
        .into_iter()
        .filter(|v| match opts.modality {
            Modality::Both => true,
            Modality::Thermal => v.thermal.is_some(),
            Modality::Rgb => v.rgb.is_some(),
        })
        .collect();
    if views.is_empty() {
        return Err(DatasetError::Empty {
            root: root.to_path_buf(),
            reason: format!("no {} images in the model", opts.modality),
        });
    }
    let (test, train): (Vec<usize>, Vec<usize>) = match held_out {
        Some(names) => (0..views.len()).partition(|&i| names.contains(&views[i].name)),
        None => (0..views.len()).partition(|&i| k > 0 && i % k == 0),
    };
    let fresh_after_ffc = fresh.map(|names| {
        (0..views.len())
            .filter(|&i| names.contains(&views[i].name))
            .collect()
    });
    if train.is_empty() {
        return Err(DatasetError::Empty {
            root: root.to_path_buf(),
            reason: format!(
                "no training views left: {} views, {} held out",
                views.len(),
                test.len()
            ),
        });
    }
    Ok(Split {
        views,
        train,
        test,
        fresh_after_ffc,
    })
}
