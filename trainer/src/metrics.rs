//! Image-quality metrics on normalised planes (data range 1): PSNR, SSIM (the core's 11×11,
//! σ = 1.5 Gaussian SSIM, [`crate::loss::photometric::ssim`]), LPIPS ([`crate::lpips`], filled
//! in by the evaluation that holds the network) and temperature errors in kelvin through the
//! scene's [`ThermalRange`].
//!
//! Each view is measured **raw** (the render as it is) and **aligned**: for PSNR and SSIM the
//! render under the affine map `a·x + c` fitted to the view's image in closed form (least
//! squares), for the kelvin MAE under the offset that minimises it (the median difference).
//! Held-out views have no learned response (`--response`), and a camera with automatic gain
//! or drift records each of them with its own; the aligned figures measure the scene without
//! that per-view response (NeRF-in-the-wild-style evaluations do the same), the raw ones
//! measure it with the mean camera's response.

use serde::{Deserialize, Serialize};

use crate::dataset::ThermalRange;

/// `10·log10(1/MSE)` for data in [0, 1]; capped at 100 dB for identical images.
pub fn psnr(pred: &[f32], target: &[f32]) -> f64 {
    let n = pred.len().min(target.len()).max(1);
    let mse = pred
        .iter()
        .zip(target)
        .map(|(a, b)| {
            let d = f64::from(*a) - f64::from(*b);
            d * d
        })
        .sum::<f64>()
        / n as f64;
    if mse <= 1e-10 {
        100.0
    } else {
        -10.0 * mse.log10()
    }
}

/// Mean SSIM (11×11 Gaussian window, σ = 1.5, C1 = 0.01², C2 = 0.03²).
pub fn ssim(pred: &[f32], target: &[f32], width: usize, height: usize) -> f64 {
    crate::loss::photometric::ssim(pred, target, width, height, None)
}

/// `(MAE, RMSE)` in kelvin of two normalised planes, when the range is radiometric.
pub fn kelvin_errors(pred: &[f32], target: &[f32], range: &ThermalRange) -> Option<(f64, f64)> {
    let k = range.kelvin_per_unit()?;
    let n = pred.len().min(target.len()).max(1) as f64;
    let (mut abs, mut sq) = (0.0, 0.0);
    for (a, b) in pred.iter().zip(target) {
        let d = (f64::from(*a) - f64::from(*b)) * k;
        abs += d.abs();
        sq += d * d;
    }
    Some((abs / n, (sq / n).sqrt()))
}

/// The least-squares affine map `(a, c)` with `a·pred + c ≈ target` (`a = 1` when `pred` is
/// flat).
pub fn affine_fit(pred: &[f32], target: &[f32]) -> (f64, f64) {
    let n = pred.len().min(target.len()).max(1) as f64;
    let mp = pred.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let mt = target.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
    let (mut cov, mut var) = (0.0, 0.0);
    for (a, b) in pred.iter().zip(target) {
        let (dp, dt) = (f64::from(*a) - mp, f64::from(*b) - mt);
        cov += dp * dt;
        var += dp * dp;
    }
    let a = if var > 1e-12 * n { cov / var } else { 1.0 };
    (a, mt - a * mp)
}

/// Kelvin MAE of `pred` against `target` after the offset that minimises it (the median of
/// the differences), with that offset in kelvin; `None` when not radiometric.
pub fn kelvin_mae_offset_aligned(
    pred: &[f32],
    target: &[f32],
    range: &ThermalRange,
) -> Option<(f64, f64)> {
    let k = range.kelvin_per_unit()?;
    let mut d: Vec<f64> = pred
        .iter()
        .zip(target)
        .map(|(a, b)| (f64::from(*b) - f64::from(*a)) * k)
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    let offset = d[d.len() / 2];
    let mae = d.iter().map(|x| (x - offset).abs()).sum::<f64>() / d.len() as f64;
    Some((mae, offset))
}

/// Metrics of one view: raw, and aligned (see the module docs).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
    /// PSNR and SSIM of the render under the affine map fitted to this view (`align_gain`,
    /// `align_offset`, normalised units). `None` in files written before they existed.
    #[serde(default)]
    pub psnr_aligned: Option<f64>,
    #[serde(default)]
    pub ssim_aligned: Option<f64>,
    #[serde(default)]
    pub align_gain: Option<f64>,
    #[serde(default)]
    pub align_offset: Option<f64>,
    /// Kelvin MAE after the offset that minimises it (`align_offset_kelvin`).
    #[serde(default)]
    pub kelvin_mae_aligned: Option<f64>,
    #[serde(default)]
    pub align_offset_kelvin: Option<f64>,
    /// LPIPS (AlexNet, v0.1) of the raw render against the frame, both over the dataset's
    /// normalised range; absent without the weights or under 31 px ([`crate::lpips`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
}

/// Per-view metrics and their means.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct EvalSummary {
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
    /// Means of the views' aligned figures ([`ViewMetrics`]).
    #[serde(default)]
    pub psnr_aligned: Option<f64>,
    #[serde(default)]
    pub ssim_aligned: Option<f64>,
    #[serde(default)]
    pub kelvin_mae_aligned: Option<f64>,
    /// Mean LPIPS of the views (absent when any view lacks it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
    pub views: Vec<ViewMetrics>,
    /// Means over the held-out RGB views of a run with colour (PSNR over the three planes,
    /// SSIM the planes' mean); `None` without RGB views.
    #[serde(default)]
    pub rgb_psnr: Option<f64>,
    #[serde(default)]
    pub rgb_ssim: Option<f64>,
    /// Joint runs' super-resolved thermal scored against the recorded held-out frames it
    /// cannot be compared with directly: the K× render averaged over K×K blocks back to the
    /// recorded resolution (downsampled consistency; `None`: no SR renders). Filled at the
    /// run's end ([`crate::train::Trainer::write_outputs`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sr_consistency: Option<SrConsistency>,
}

/// [`EvalSummary::sr_consistency`]: means over the held-out thermal views.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SrConsistency {
    pub scale: usize,
    pub psnr: f64,
    pub ssim: f64,
}

impl EvalSummary {
    /// Means over `views` (`NaN` PSNR/SSIM for an empty list).
    pub fn from_views(views: Vec<ViewMetrics>) -> Self {
        let n = views.len() as f64;
        let mean = |f: &dyn Fn(&ViewMetrics) -> f64| views.iter().map(f).sum::<f64>() / n;
        let opt_mean = |f: &dyn Fn(&ViewMetrics) -> Option<f64>| {
            let v: Option<Vec<f64>> = views.iter().map(f).collect();
            v.filter(|v| !v.is_empty())
                .map(|v| v.iter().sum::<f64>() / v.len() as f64)
        };
        Self {
            psnr: mean(&|v| v.psnr),
            ssim: mean(&|v| v.ssim),
            kelvin_mae: opt_mean(&|v| v.kelvin_mae),
            kelvin_rmse: opt_mean(&|v| v.kelvin_rmse),
            psnr_aligned: opt_mean(&|v| v.psnr_aligned),
            ssim_aligned: opt_mean(&|v| v.ssim_aligned),
            kelvin_mae_aligned: opt_mean(&|v| v.kelvin_mae_aligned),
            lpips: opt_mean(&|v| v.lpips),
            views,
            rgb_psnr: None,
            rgb_ssim: None,
            sr_consistency: None,
        }
    }
}

/// PSNR over the three planes and the planes' mean SSIM of a planar RGB render (`3·w·h`).
pub fn rgb_metrics(pred: &[f32], target: &[f32], width: usize, height: usize) -> (f64, f64) {
    let n = width * height;
    let s = (0..3)
        .map(|c| {
            ssim(
                &pred[c * n..(c + 1) * n],
                &target[c * n..(c + 1) * n],
                width,
                height,
            )
        })
        .sum::<f64>()
        / 3.0;
    (psnr(pred, target), s)
}

/// Metrics of one rendered thermal plane against its target.
pub fn view_metrics(
    name: &str,
    pred: &[f32],
    target: &[f32],
    width: usize,
    height: usize,
    range: Option<&ThermalRange>,
) -> ViewMetrics {
    let k = range.and_then(|r| kelvin_errors(pred, target, r));
    let (a, c) = affine_fit(pred, target);
    let aligned: Vec<f32> = pred
        .iter()
        .map(|&v| (a * f64::from(v) + c) as f32)
        .collect();
    let ka = range.and_then(|r| kelvin_mae_offset_aligned(pred, target, r));
    ViewMetrics {
        name: name.to_owned(),
        psnr: psnr(pred, target),
        ssim: ssim(pred, target, width, height),
        kelvin_mae: k.map(|x| x.0),
        kelvin_rmse: k.map(|x| x.1),
        psnr_aligned: Some(psnr(&aligned, target)),
        ssim_aligned: Some(ssim(&aligned, target, width, height)),
        align_gain: Some(a),
        align_offset: Some(c),
        kelvin_mae_aligned: ka.map(|x| x.0),
        align_offset_kelvin: ka.map(|x| x.1),
        lpips: None,
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::dataset::images::ImageKind;

    /// A render that differs from its image by an affine map scores perfectly aligned, and
    /// worse raw; the kelvin MAE aligned by the median offset is the spread about it.
    #[test]
    fn aligned_metrics_remove_a_per_view_affine_response() {
        let (w, h) = (16, 12);
        let pred: Vec<f32> = (0..w * h)
            .map(|p| 0.3 + 0.4 * ((p % w) as f32 / w as f32))
            .collect();
        let target: Vec<f32> = pred.iter().map(|v| 0.6 * v + 0.25).collect();
        let range = ThermalRange {
            kind: ImageKind::Thermal16,
            units: Some(crate::dataset::ThermalUnits::CentiKelvin),
            min_raw: 27_000.0,
            max_raw: 32_000.0,
        };
        let m = view_metrics("v", &pred, &target, w, h, Some(&range));
        let (a, c) = (m.align_gain.unwrap(), m.align_offset.unwrap());
        assert!(
            (a - 0.6).abs() < 1e-5 && (c - 0.25).abs() < 1e-5,
            "fit ({a}, {c}), expected (0.6, 0.25)"
        );
        assert!(
            m.psnr_aligned.unwrap() > 90.0,
            "aligned PSNR {:?}",
            m.psnr_aligned
        );
        assert!(
            m.psnr < 25.0,
            "raw PSNR {} should show the response",
            m.psnr
        );
        // An offset only: aligned MAE ~0, raw MAE = the offset (0.02 × 50 K = 1 K).
        let shifted: Vec<f32> = pred.iter().map(|v| v + 0.02).collect();
        let m = view_metrics("v", &pred, &shifted, w, h, Some(&range));
        assert!(
            (m.kelvin_mae.unwrap() - 1.0).abs() < 1e-3,
            "raw MAE {:?}",
            m.kelvin_mae
        );
        assert!(
            m.kelvin_mae_aligned.unwrap() < 1e-3,
            "aligned MAE {:?}",
            m.kelvin_mae_aligned
        );
        assert!((m.align_offset_kelvin.unwrap() - 1.0).abs() < 1e-3);
    }
}
