//! Image-quality metrics on normalised planes (data range 1): PSNR, SSIM (the core's 11×11,
//! σ = 1.5 Gaussian SSIM, [`crate::loss::photometric::ssim`]), and temperature errors in kelvin
//! through the scene's [`ThermalRange`].

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

/// Metrics of one view.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ViewMetrics {
    pub name: String,
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
}

/// Per-view metrics and their means.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct EvalSummary {
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
    pub views: Vec<ViewMetrics>,
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
            views,
        }
    }
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
    ViewMetrics {
        name: name.to_owned(),
        psnr: psnr(pred, target),
        ssim: ssim(pred, target, width, height),
        kelvin_mae: k.map(|x| x.0),
        kelvin_rmse: k.map(|x| x.1),
    }
}
