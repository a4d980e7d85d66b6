//! Scoring a run against a simulated scene's truth (`s3tir-firmware-sim scene --rgb-scale K`
//! writes it under `DATA/truth/`, mirroring the image names): the thermal head at the input
//! resolution and super-resolved at K× (the render alone, and fused with the recorded image:
//! [`crate::superres`]) against bicubic upsampling of the recorded thermal image and against
//! the fusion's own control (back-projection started from bicubic: what the recorded image
//! alone gives), the colour head, and the geometry (expected depth) against the true depth.
//!
//! Truth files (`DATA/truth/…/<image name>`): `apparent/` noise-free apparent temperature at
//! the thermal camera (16-bit centikelvin), `apparent_sr/` the same at K× through the same
//! pose, `depth/` camera z in millimetres (0: no surface) for thermal and RGB images,
//! `rgb/` the noise-free RGB at the input's exposure (8-bit sRGB).
//!
//! Thermal figures are in the dataset's normalised units (PSNR, SSIM: the range the run
//! trains in) and kelvin (MAE). Depth: the rendered expected depth (`depth / alpha`) where
//! `alpha ≥ 0.5` and the truth sees a surface; coverage is the fraction of those truth pixels
//! the render covers.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::dataset::{Dataset, DatasetError, Modality, ThermalRange};
use crate::metrics::{rgb_metrics, view_metrics};
use crate::primitive::Primitives;
use crate::superres::{back_project, bicubic_upsample};
use crate::train::{Backend, TrainError, composite_background};

/// The truth folder of a dataset.
pub const TRUTH_DIR: &str = "truth";
/// Alpha above which a rendered pixel counts as surface for the depth error.
pub const DEPTH_MIN_ALPHA: f32 = 0.5;

/// Thermal figures against truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThermalScore {
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: f64,
    /// LPIPS over the scene's normalised range ([`crate::lpips`]); `None` without the weights or
    /// under 31 px (a table's input-resolution column of a tiny scene).
    #[serde(default)]
    pub lpips: Option<f64>,
}

/// Depth figures against truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthScore {
    /// Mean absolute error of the expected depth, metres.
    pub mae_m: f64,
    /// Fraction of the truth's surface pixels the render covers (alpha ≥ 0.5).
    pub coverage: f64,
}

/// A run scored against its dataset's truth, means over the held-out instants.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthScore {
    /// Held-out thermal views scored.
    pub views: usize,
    /// Super-resolution factor K (RGB width / thermal width).
    pub scale: usize,
    /// The thermal head at the input resolution.
    pub thermal: ThermalScore,
    /// The thermal head rendered at K× through the thermal camera.
    pub thermal_sr: ThermalScore,
    /// Bicubic (Catmull-Rom) K× upsampling of the recorded held-out thermal image.
    pub bicubic_sr: ThermalScore,
    /// The K× render fused with the recorded held-out thermal image by back-projection
    /// ([`crate::superres`]): what `renders_sr_fused/` holds.
    pub fused_sr: ThermalScore,
    /// The control of `fused_sr`: the same back-projection started from bicubic instead of the
    /// render — what the recorded image alone gives through the fusion, so `fused_sr` against
    /// it is the model's own contribution (`None` in scores written before it existed).
    #[serde(default)]
    pub bicubic_bp_sr: Option<ThermalScore>,
    /// The colour head on the held-out RGB views (`None`: the run has no colour).
    pub rgb_psnr: Option<f64>,
    pub rgb_ssim: Option<f64>,
    /// Expected depth at the held-out RGB cameras (K× resolution).
    pub depth_rgb: DepthScore,
    /// Expected depth at the held-out thermal cameras (input resolution).
    pub depth_thermal: DepthScore,
}

fn truth_err(path: &Path, reason: impl Into<String>) -> TrainError {
    TrainError::Config {
        reason: format!("truth {}: {}", path.display(), reason.into()),
    }
}

fn read_png16(path: &Path, w: usize, h: usize) -> Result<Vec<u16>, TrainError> {
    let img = image::open(path)
        .map_err(|source| DatasetError::Image {
            path: path.to_path_buf(),
            source,
        })?
        .into_luma16();
    if img.width() as usize != w || img.height() as usize != h {
        return Err(truth_err(
            path,
            format!("is {}×{}, expected {w}×{h}", img.width(), img.height()),
        ));
    }
    Ok(img.into_raw())
}

fn read_rgb(path: &Path, w: usize, h: usize) -> Result<Vec<f32>, TrainError> {
    let img = image::open(path)
        .map_err(|source| DatasetError::Image {
            path: path.to_path_buf(),
            source,
        })?
        .into_rgb8();
    if img.width() as usize != w || img.height() as usize != h {
        return Err(truth_err(
            path,
            format!("is {}×{}, expected {w}×{h}", img.width(), img.height()),
        ));
    }
    // Planar R, G, B in [0, 1], as datasets hold RGB.
    let n = w * h;
    let mut out = vec![0.0; 3 * n];
    for (p, px) in img.pixels().enumerate() {
        for c in 0..3 {
            out[c * n + p] = f32::from(px.0[c]) / 255.0;
        }
    }
    Ok(out)
}

/// Normalised thermal values of centikelvin truth words in the dataset's range.
fn normalise(words: &[u16], range: &ThermalRange) -> Vec<f32> {
    words
        .iter()
        .map(|&w| ((f64::from(w) - range.min_raw) / (range.max_raw - range.min_raw)) as f32)
        .collect()
}

fn thermal_score(
    pred: &[f32],
    truth: &[f32],
    w: usize,
    h: usize,
    range: &ThermalRange,
) -> ThermalScore {
    let m = view_metrics("", pred, truth, w, h, Some(range));
    ThermalScore {
        psnr: m.psnr,
        ssim: m.ssim,
        kelvin_mae: m.kelvin_mae.unwrap_or(f64::NAN),
        lpips: crate::lpips::installed().and_then(|l| l.plane_distance(pred, truth, w, h)),
    }
}

/// Depth error sums of one rendered view against truth millimetres.
fn depth_sums(depth: &[f32], alpha: &[f32], truth_mm: &[u16]) -> (f64, usize, usize) {
    let (mut err, mut covered, mut surface) = (0.0, 0, 0);
    for ((&d, &a), &t) in depth.iter().zip(alpha).zip(truth_mm) {
        if t == 0 {
            continue;
        }
        surface += 1;
        if a >= DEPTH_MIN_ALPHA {
            covered += 1;
            err += (f64::from(d / a) - f64::from(t) / 1000.0).abs();
        }
    }
    (err, covered, surface)
}

fn mean_score(s: &[ThermalScore]) -> ThermalScore {
    let n = s.len().max(1) as f64;
    ThermalScore {
        psnr: s.iter().map(|x| x.psnr).sum::<f64>() / n,
        ssim: s.iter().map(|x| x.ssim).sum::<f64>() / n,
        kelvin_mae: s.iter().map(|x| x.kelvin_mae).sum::<f64>() / n,
        lpips: s
            .iter()
            .map(|x| x.lpips)
            .sum::<Option<f64>>()
            .map(|t| t / n),
    }
}

/// The image of the other modality taken at the same instant: the same file name in a
/// sibling folder (`thermal/0008.png` ↔ `rgb/0008.png`).
fn partner<'a>(data: &'a Dataset, name: &str) -> Option<&'a crate::dataset::View> {
    let file = Path::new(name).file_name()?;
    data.views
        .iter()
        .find(|v| v.name != name && v.rgb.is_some() && Path::new(&v.name).file_name() == Some(file))
}

/// Scores `prims` against the truth of the dataset at `data_root` (loaded whole: both image
/// sets, whatever the run trained on) on its held-out instants.
pub fn score<B: Backend>(
    data_root: &Path,
    prims: &Primitives<f32>,
    rgb_background: [f32; 3],
    backend: &mut B,
) -> Result<TruthScore, TrainError> {
    let truth = data_root.join(TRUTH_DIR);
    if !truth.is_dir() {
        return Err(truth_err(
            &truth,
            "no truth folder (written by `s3tir-firmware-sim scene --rgb-scale K`)",
        ));
    }
    let data = Dataset::load(
        data_root,
        &crate::dataset::LoadOptions {
            modality: Modality::Both,
            ..Default::default()
        },
    )?;
    let range = data
        .range
        .filter(ThermalRange::radiometric)
        .ok_or_else(|| truth_err(&truth, "the dataset's thermal images are not centikelvin"))?;
    let has_colour = !prims.sh.is_empty();
    let (mut th, mut sr, mut bi, mut fu) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut bb = Vec::new();
    let (mut rgb_p, mut rgb_s) = (Vec::new(), Vec::new());
    let mut d_rgb = (0.0, 0, 0);
    let mut d_th = (0.0, 0, 0);
    let mut scale = 0;
    let add = |acc: &mut (f64, usize, usize), s: (f64, usize, usize)| {
        acc.0 += s.0;
        acc.1 += s.1;
        acc.2 += s.2;
    };
    for &i in &data.test {
        let v = &data.views[i];
        let Some(input) = &v.thermal else { continue };
        let rgb_view = partner(&data, &v.name).ok_or_else(|| {
            truth_err(
                &truth,
                format!("no RGB image beside the held-out {}", v.name),
            )
        })?;
        let cam: PinholeCamera = v.camera;
        let (w, h) = (cam.width, cam.height);
        if rgb_view.camera.width % w != 0 || rgb_view.camera.width / w == 0 {
            return Err(truth_err(
                &truth,
                format!(
                    "the RGB width {} is not a multiple of the thermal width {w}",
                    rgb_view.camera.width
                ),
            ));
        }
        let k = rgb_view.camera.width / w;
        scale = k;
        let truth_of = |kind: &str, name: &str| truth.join(kind).join(name);
        // Input resolution.
        let gb = backend.render(prims, &cam)?;
        let t_in = normalise(&read_png16(&truth_of("apparent", &v.name), w, h)?, &range);
        th.push(thermal_score(&gb.thermal, &t_in, w, h, &range));
        let d_mm = read_png16(&truth_of("depth", &v.name), w, h)?;
        add(&mut d_th, depth_sums(&gb.depth, &gb.alpha, &d_mm));
        // Super-resolved, and bicubic from the recorded image.
        let cam_k = cam.scaled(k);
        let gb_k = backend.render(prims, &cam_k)?;
        let t_sr = normalise(
            &read_png16(&truth_of("apparent_sr", &v.name), w * k, h * k)?,
            &range,
        );
        sr.push(thermal_score(&gb_k.thermal, &t_sr, w * k, h * k, &range));
        let up = bicubic_upsample(input, w, h, k);
        bi.push(thermal_score(&up, &t_sr, w * k, h * k, &range));
        let fused = back_project(&gb_k.thermal, input, w, h, k);
        fu.push(thermal_score(&fused, &t_sr, w * k, h * k, &range));
        let bicubic_bp = back_project(&up, input, w, h, k);
        bb.push(thermal_score(&bicubic_bp, &t_sr, w * k, h * k, &range));
        // Geometry and colour at the RGB camera.
        let rc = rgb_view.camera;
        let gb_r = backend.render(prims, &rc)?;
        let d_mm = read_png16(&truth_of("depth", &rgb_view.name), rc.width, rc.height)?;
        add(&mut d_rgb, depth_sums(&gb_r.depth, &gb_r.alpha, &d_mm));
        if has_colour && !gb_r.rgb.is_empty() {
            let t = read_rgb(&truth_of("rgb", &rgb_view.name), rc.width, rc.height)?;
            let shown = composite_background(&gb_r.rgb, &gb_r.alpha, rgb_background);
            let (p, q) = rgb_metrics(&shown, &t, rc.width, rc.height);
            rgb_p.push(p);
            rgb_s.push(q);
        }
    }
    if th.is_empty() {
        return Err(truth_err(&truth, "the dataset holds out no thermal view"));
    }
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let depth = |s: (f64, usize, usize)| DepthScore {
        mae_m: if s.1 > 0 { s.0 / s.1 as f64 } else { f64::NAN },
        coverage: s.1 as f64 / s.2.max(1) as f64,
    };
    Ok(TruthScore {
        views: th.len(),
        scale,
        thermal: mean_score(&th),
        thermal_sr: mean_score(&sr),
        bicubic_sr: mean_score(&bi),
        fused_sr: mean_score(&fu),
        bicubic_bp_sr: Some(mean_score(&bb)),
        rgb_psnr: mean(&rgb_p),
        rgb_ssim: mean(&rgb_s),
        depth_rgb: depth(d_rgb),
        depth_thermal: depth(d_th),
    })
}

/// Scores a finished run (its PLY) against its dataset's truth.
pub fn score_run<B: Backend>(run_dir: &Path, mut backend: B) -> Result<TruthScore, TrainError> {
    let cfg = crate::train::load_config(run_dir)?;
    if cfg.load.downscale != 1 {
        return Err(truth_err(
            &cfg.data.join(TRUTH_DIR),
            format!(
                "the run was trained at --downscale {}: truth is at full resolution",
                cfg.load.downscale
            ),
        ));
    }
    let ply: PathBuf = run_dir.join(crate::train::files::PLY);
    let prims = crate::ply::read_ply(&ply)?;
    let bg = crate::train::read_background(run_dir)?;
    score(&cfg.data, &prims, bg, &mut backend)
}
