//! Posed image datasets for training: COLMAP sparse models (text or binary) plus an images
//! folder — the layout `s3tir-firmware-sim scene --out DIR` writes (`DIR/sparse/0/`,
//! `DIR/images/`).
//!
//! At load:
//! - distorted cameras (`SIMPLE_RADIAL`, `RADIAL`, `OPENCV`) are **undistorted once** to a
//!   pinhole camera with the same `K` (bilinear resampling through `s3tir_calib`'s Brown–Conrady
//!   model; output pixels whose source falls outside the image take the nearest edge value —
//!   a known limitation: there is no validity mask);
//! - an image is RGB when it is 8-bit colour, or 8-bit grey and named as the RGB camera's
//!   ([`named_rgb`]: `rgb/…` or `rgb_…`, the joint layouts the simulator and the poses stage
//!   write); the model may hold both image sets, each with its own camera (joint training);
//! - thermal values (16-bit words, 8-bit grey, pseudo-colour palette index) are normalised to
//!   [0, 1] with **one range per scene** ([`ThermalRange`]), kept so renders and errors convert
//!   back to kelvin when the words are centikelvin; RGB is divided by 255;
//! - views are sorted by image name; the held-out test views are those `DATA/holdout.txt` names
//!   (one image name per line, as the poses stage writes it), else every `holdout_every`-th one
//!   (index 0, k, 2k, …; default 8, as 3DGS's LLFF hold-out; 0: no test views);
//! - `DATA/ffc.txt` (optional, same format) names the views taken right after a flat-field
//!   correction, whose radiometric drift is zero: the per-view response pins their offsets
//!   there ([`Dataset::fresh_after_ffc`], `train::response`);
//! - initial points come from `points3D` or, when there are none, uniformly from the scene
//!   bounds ([`Dataset::bounds_m`]).
//!
//! [`Dataset::load`] reads as those steps; each is a function of `load.rs`.

pub mod images;
mod load;
/// The COLMAP codec lives in calib's OpenCV-free layer (one codec for every stage).
pub use s3tir_calib::model::colmap;
pub mod synth;

use std::path::{Path, PathBuf};

use glam::DVec2;
use s3tir_calib::CameraModel;
pub use s3tir_capture::frame::ThermalUnits;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::camera::PinholeCamera;
use images::{ColourMode, ImageKind, RawImage};
use load::{load_view_image, normalised_view, open_model, scene_range, split_views};

/// Errors of dataset loading.
#[derive(Debug, Error)]
pub enum DatasetError {
    #[error("{what} not found: {path}")]
    MissingFile { path: PathBuf, what: &'static str },
    #[error("cannot read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The COLMAP model could not be read (file and line in the error).
    #[error(transparent)]
    Colmap(#[from] s3tir_calib::model::colmap::ColmapError),
    /// The image could not be decoded or encoded.
    #[error("image {path}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    /// The image decodes but is not one the trainer takes.
    #[error("image {path}: {reason}")]
    UnsupportedImage { path: PathBuf, reason: String },
    #[error("image {image} refers to camera {camera_id}, which {model_dir} does not define")]
    UnknownCamera {
        model_dir: PathBuf,
        image: String,
        camera_id: u32,
    },
    #[error(
        "image {path} is {actual_w}×{actual_h} but its camera {camera_id} is {expected_w}×{expected_h}"
    )]
    SizeMismatch {
        path: PathBuf,
        camera_id: u32,
        expected_w: usize,
        expected_h: usize,
        actual_w: usize,
        actual_h: usize,
    },
    #[error("dataset {root} is empty: {reason}")]
    Empty { root: PathBuf, reason: String },
    #[error("dataset {root}: thermal images mix kinds ({first:?} and {other:?} in {path})")]
    MixedKinds {
        root: PathBuf,
        path: PathBuf,
        first: ImageKind,
        other: ImageKind,
    },
}

/// The file that names a dataset's held-out views (module docs).
pub const HOLDOUT_FILE: &str = "holdout.txt";
/// Views taken right after a flat-field correction, one image name per line.
pub const FFC_FILE: &str = "ffc.txt";

/// Which of a dataset's image sets a run trains on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Modality {
    /// Every image: a joint RGB + thermal run when the model holds both.
    #[default]
    Both,
    /// Thermal images only (RGB images are dropped at load).
    Thermal,
    /// RGB images only.
    Rgb,
}

impl std::fmt::Display for Modality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Modality::Both => "both",
            Modality::Thermal => "thermal",
            Modality::Rgb => "rgb",
        })
    }
}

impl std::str::FromStr for Modality {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "both" => Ok(Modality::Both),
            "thermal" => Ok(Modality::Thermal),
            "rgb" => Ok(Modality::Rgb),
            other => Err(format!(
                "unknown image set `{other}` (expected both, thermal or rgb)"
            )),
        }
    }
}

/// Options of [`Dataset::load`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoadOptions {
    /// Every k-th view (by name) is a test view; 0: none.
    pub holdout_every: usize,
    /// What the 16-bit words are (TLinear centikelvin by default).
    pub thermal_units: ThermalUnits,
    /// How 8-bit colour images are read.
    pub colour: ColourMode,
    /// Integer box-filter downscale (1: full resolution).
    pub downscale: usize,
    /// Images folder (default `DATA/images`).
    pub images_dir: Option<PathBuf>,
    /// Which image sets to keep (options written before it read as both).
    #[serde(default)]
    pub modality: Modality,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            holdout_every: 8,
            thermal_units: ThermalUnits::CentiKelvin,
            colour: ColourMode::Rgb,
            downscale: 1,
            images_dir: None,
            modality: Modality::Both,
        }
    }
}

/// The per-scene range of the thermal values, in the file's units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThermalRange {
    pub kind: ImageKind,
    /// Meaning of 16-bit words (`None` for 8-bit kinds).
    pub units: Option<ThermalUnits>,
    pub min_raw: f64,
    pub max_raw: f64,
}

impl ThermalRange {
    /// Whether values convert to kelvin (16-bit centikelvin).
    pub fn radiometric(&self) -> bool {
        self.kind == ImageKind::Thermal16 && self.units == Some(ThermalUnits::CentiKelvin)
    }
    /// Raw value of a normalised value.
    pub fn raw(&self, normalised: f64) -> f64 {
        self.min_raw + normalised * (self.max_raw - self.min_raw)
    }
    /// Kelvin of a normalised value, when radiometric.
    pub fn kelvin(&self, normalised: f64) -> Option<f64> {
        self.radiometric().then(|| self.raw(normalised) / 100.0)
    }
    /// Kelvin per normalised unit, when radiometric (to convert errors).
    pub fn kelvin_per_unit(&self) -> Option<f64> {
        self.radiometric()
            .then(|| (self.max_raw - self.min_raw) / 100.0)
    }
    /// Normalised value of a raw value (the inverse of [`Self::raw`]).
    pub fn normalise(&self, raw: f64) -> f32 {
        ((raw - self.min_raw) / (self.max_raw - self.min_raw)) as f32
    }
}

/// One posed view.
#[derive(Debug, Clone)]
pub struct View {
    /// Image file name (relative to the images folder).
    pub name: String,
    /// Undistorted pinhole camera.
    pub camera: PinholeCamera,
    /// Normalised thermal plane (`width·height`), if this is a thermal image.
    pub thermal: Option<Vec<f32>>,
    /// Three planes in [0, 1], if this is an RGB image.
    pub rgb: Option<Vec<f32>>,
}

/// A loaded dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    pub root: PathBuf,
    pub views: Vec<View>,
    pub train: Vec<usize>,
    pub test: Vec<usize>,
    /// Thermal range (`None` when there are no thermal images).
    pub range: Option<ThermalRange>,
    /// Sparse points (world metres) and their colours.
    pub points_m: Vec<[f64; 3]>,
    pub point_rgb: Vec<[u8; 3]>,
    /// COLMAP model names of the cameras that were undistorted at load.
    pub undistorted_models: Vec<String>,
    /// Views taken right after a flat-field correction (`DATA/ffc.txt`; `None`: the dataset
    /// does not say).
    pub fresh_after_ffc: Option<Vec<usize>>,
}

/// Whether an image name says it is the RGB camera's: in an `rgb/` folder (the simulator's
/// joint scenes) or named `rgb_…` (the poses stage's `--with-rgb` datasets).
pub fn named_rgb(name: &str) -> bool {
    let p = Path::new(name);
    p.components()
        .next()
        .is_some_and(|c| c.as_os_str() == "rgb" && p.components().count() > 1)
        || p.file_name()
            .is_some_and(|f| f.to_string_lossy().starts_with("rgb_"))
}

impl Dataset {
    /// Loads `root` (see the module docs for the layout): the COLMAP model, every image it
    /// registers (undistorted, downscaled), one thermal range for the scene, then the views
    /// split into training and held-out sets.
    pub fn load(root: &Path, opts: &LoadOptions) -> Result<Self, DatasetError> {
        let (model_dir, model) = open_model(root)?;
        let images_dir = opts
            .images_dir
            .clone()
            .unwrap_or_else(|| root.join("images"));
        let mut ordered = model.images.clone();
        ordered.sort_by(|a, b| a.name.cmp(&b.name));
        let mut raws: Vec<(String, PinholeCamera, RawImage)> = Vec::new();
        let mut undistorted_models = Vec::new();
        for im in &ordered {
            let cam = model
                .cameras
                .iter()
                .find(|c| c.id == im.camera_id)
                .ok_or_else(|| DatasetError::UnknownCamera {
                    model_dir: model_dir.clone(),
                    image: im.name.clone(),
                    camera_id: im.camera_id,
                })?;
            let (pin, raw) = load_view_image(im, cam, &images_dir, opts, &mut undistorted_models)?;
            raws.push((im.name.clone(), pin, raw));
        }
        let range = scene_range(&raws, root, &images_dir, opts)?;
        let views: Vec<View> = raws
            .into_iter()
            .map(|(name, camera, raw)| normalised_view(name, camera, &raw, range))
            .collect();
        let split = split_views(root, views, opts)?;
        Ok(Self {
            root: root.to_path_buf(),
            views: split.views,
            train: split.train,
            test: split.test,
            range,
            points_m: model.points.iter().map(|p| p.position_m).collect(),
            point_rgb: model.points.iter().map(|p| p.rgb).collect(),
            undistorted_models,
            fresh_after_ffc: split.fresh_after_ffc,
        })
    }

    /// Whether any view carries RGB.
    pub fn has_rgb(&self) -> bool {
        self.views.iter().any(|v| v.rgb.is_some())
    }

    /// Whether any view carries thermal data.
    pub fn has_thermal(&self) -> bool {
        self.views.iter().any(|v| v.thermal.is_some())
    }

    /// Axis-aligned scene bounds `(min, max)`: the sparse points' box, or (with no points) a box
    /// centred on the least-squares meeting point of the optical axes with half-size half the
    /// mean camera distance to it.
    pub fn bounds_m(&self) -> ([f64; 3], [f64; 3]) {
        if !self.points_m.is_empty() {
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for p in &self.points_m {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            return (lo, hi);
        }
        use glam::{DMat3, DVec3};
        let mut a = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        let mut centres = Vec::new();
        for v in &self.views {
            let w = v.camera.cam_from_world.inverse();
            let c = w.translation_m;
            let d = w.transform_vector(DVec3::Z).normalize_or(DVec3::Z);
            let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
            a += p;
            b += p * c;
            centres.push(c);
        }
        let centre = if a.determinant().abs() > 1e-9 {
            a.inverse() * b
        } else {
            // Parallel axes: one unit in front of the mean camera.
            let mean = centres.iter().copied().sum::<DVec3>() / centres.len().max(1) as f64;
            mean + DVec3::Z
        };
        let dist =
            centres.iter().map(|c| c.distance(centre)).sum::<f64>() / centres.len().max(1) as f64;
        let h = (0.5 * dist).max(1e-3);
        (
            (centre - DVec3::splat(h)).to_array(),
            (centre + DVec3::splat(h)).to_array(),
        )
    }

    /// Mean normalised thermal value at the projections of `p` into the training views that see
    /// it (`None` if none does) — used to initialise ω_low.
    pub fn thermal_at(&self, p_world: [f64; 3]) -> Option<f32> {
        let mut sum = 0.0f64;
        let mut n = 0usize;
        for &i in &self.train {
            let v = &self.views[i];
            let Some(t) = &v.thermal else { continue };
            let pc = v.camera.to_cam(p_world);
            if pc[2] <= 1e-6 {
                continue;
            }
            let [u, vv] = v.camera.project_cam(pc);
            let (x, y) = (u.round(), vv.round());
            if x >= 0.0
                && y >= 0.0
                && (x as usize) < v.camera.width
                && (y as usize) < v.camera.height
            {
                sum += f64::from(t[y as usize * v.camera.width + x as usize]);
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f64) as f32)
    }

    /// Mean RGB (in [0, 1]) at the projections of `p` into the RGB training views that see it
    /// (`None` if none does) — used to initialise the SH colour from the images, as ω_low is
    /// from the thermal ones (a point's stored colour need not match the images' exposure: a
    /// low-light camera records the scene far darker, and a colour too bright at the start
    /// is first corrected through opacity, which the thermal head shares).
    pub fn rgb_at(&self, p_world: [f64; 3]) -> Option<[f64; 3]> {
        let mut sum = [0.0f64; 3];
        let mut n = 0usize;
        for &i in &self.train {
            let v = &self.views[i];
            let Some(rgb) = &v.rgb else { continue };
            let pc = v.camera.to_cam(p_world);
            if pc[2] <= 1e-6 {
                continue;
            }
            let [u, vv] = v.camera.project_cam(pc);
            let (x, y) = (u.round(), vv.round());
            let (w, h) = (v.camera.width, v.camera.height);
            if x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h {
                let p = y as usize * w + x as usize;
                for (c, s) in sum.iter_mut().enumerate() {
                    *s += f64::from(rgb[c * w * h + p]);
                }
                n += 1;
            }
        }
        (n > 0).then(|| sum.map(|s| s / n as f64))
    }
}

/// Bilinear sample of plane `c` of `img` at pixel `(u, v)`, clamped to the edge.
fn bilinear(img: &RawImage, plane: usize, u: f64, v: f64) -> f64 {
    let (w, h) = (img.width, img.height);
    let u = u.clamp(0.0, (w - 1) as f64);
    let v = v.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (u.floor() as usize, v.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (u - x0 as f64, v - y0 as f64);
    let base = plane * w * h;
    let at = |x: usize, y: usize| img.values[base + y * w + x];
    (1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x1, y0))
        + fy * ((1.0 - fx) * at(x0, y1) + fx * at(x1, y1))
}

/// Resamples a distorted image to the pinhole camera with the same intrinsics.
pub fn undistort(img: &RawImage, model: &CameraModel) -> RawImage {
    let i = &model.intrinsics;
    let planes = img.values.len() / (img.width * img.height).max(1);
    let n = img.width * img.height;
    let mut out = vec![0.0; img.values.len()];
    for y in 0..img.height {
        for x in 0..img.width {
            let p = DVec2::new((x as f64 - i.cx) / i.fx, (y as f64 - i.cy) / i.fy);
            let d = model.distortion.distort(p);
            let (u, v) = (d.x * i.fx + i.cx, d.y * i.fy + i.cy);
            for c in 0..planes {
                out[c * n + y * img.width + x] = bilinear(img, c, u, v);
            }
        }
    }
    RawImage {
        values: out,
        ..img.clone()
    }
}

/// Box-filter downscale by an integer factor (the last partial rows/columns are dropped).
fn downsample(img: &RawImage, s: usize) -> RawImage {
    if s <= 1 {
        return img.clone();
    }
    let (w, h) = ((img.width / s).max(1), (img.height / s).max(1));
    let planes = img.values.len() / (img.width * img.height).max(1);
    let mut out = vec![0.0; planes * w * h];
    for c in 0..planes {
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0;
                let mut cnt = 0.0;
                for dy in 0..s {
                    for dx in 0..s {
                        let (sx, sy) = (x * s + dx, y * s + dy);
                        if sx < img.width && sy < img.height {
                            acc += img.values[c * img.width * img.height + sy * img.width + sx];
                            cnt += 1.0;
                        }
                    }
                }
                out[c * w * h + y * w + x] = acc / cnt;
            }
        }
    }
    RawImage {
        width: w,
        height: h,
        kind: img.kind,
        values: out,
    }
}

#[cfg(test)]
mod tests {
    use super::named_rgb;

    /// The joint layouts' RGB names (the simulator's `rgb/NNNN.png`, the poses stage's
    /// `rgb_SEQ.png`) are RGB by name; thermal names and a file merely called `rgb` are not.
    #[test]
    fn rgb_camera_images_are_known_by_name() {
        for name in ["rgb/0008.png", "rgb_000123.png", "walk/rgb_1.png"] {
            assert!(named_rgb(name), "{name} should read as the RGB camera's");
        }
        for name in [
            "thermal/0008.png",
            "thermal_000123.png",
            "rgb.png",
            "0008.png",
            "rgb",
        ] {
            assert!(
                !named_rgb(name),
                "{name} should not read as the RGB camera's"
            );
        }
    }
}
