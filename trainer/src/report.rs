//! Run reports: `metrics.csv` (error against training wall time), its PNG plot, the `compare`
//! overlay of several runs or groups of repeated runs ([`Curve`]), G-buffer images (paper Fig. 4)
//! and the log-histogram of β (Fig. 6).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::series::DashedLineSeries;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use s3tir_calib::model::palette::Colormap;
use s3tir_calib::report::plot::PngCanvas;

use crate::look::image::{Scale, write_palette_png};
use crate::primitive::BETA_MAX;

#[derive(Debug, Error)]
pub enum ReportError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("writing image {path}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error(transparent)]
    Palette(Box<crate::look::image::ImageError>),
    #[error("plot {path}")]
    Plot {
        path: PathBuf,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Header of `metrics.csv`.
/// `psnr_aligned` and `kelvin_mae_aligned` are the held-out figures under each view's fitted
/// affine map / median offset ([`crate::metrics`]). A log whose first row has LPIPS ends with
/// one more column, [`LPIPS_COLUMN`]; without the LPIPS weights there is no such column.
pub const CSV_HEADER: &str = "iteration,seconds,loss,psnr,ssim,kelvin_mae,kelvin_rmse,primitives,memory_bytes,psnr_aligned,kelvin_mae_aligned";
/// The held-out mean LPIPS column of `metrics.csv` ([`crate::lpips`]).
pub const LPIPS_COLUMN: &str = "lpips";

/// One row of `metrics.csv`: held-out metrics at a training wall time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    pub iteration: u64,
    /// Training wall time (evaluation excluded), seconds.
    pub seconds: f64,
    /// Mean training loss since the previous row.
    pub loss: f64,
    pub psnr: f64,
    pub ssim: f64,
    pub kelvin_mae: Option<f64>,
    pub kelvin_rmse: Option<f64>,
    pub primitives: usize,
    /// Parameters and optimiser moments, bytes.
    pub memory_bytes: usize,
    /// Held-out PSNR under each view's fitted affine map (`None` in logs written before it).
    #[serde(default)]
    pub psnr_aligned: Option<f64>,
    /// Held-out kelvin MAE under each view's median offset.
    #[serde(default)]
    pub kelvin_mae_aligned: Option<f64>,
    /// Held-out mean LPIPS (`None`: no LPIPS weights installed, or images under 31 px).
    #[serde(default)]
    pub lpips: Option<f64>,
}

impl MetricsRow {
    /// The row under a header with (`with_lpips`) or without the LPIPS column.
    fn to_csv(&self, with_lpips: bool) -> String {
        let o = |x: Option<f64>| x.map_or_else(String::new, |v| format!("{v:.6}"));
        let lpips = if with_lpips {
            format!(",{}", o(self.lpips))
        } else {
            String::new()
        };
        format!(
            "{},{:.3},{:.6},{:.4},{:.5},{},{},{},{},{},{}{lpips}",
            self.iteration,
            self.seconds,
            self.loss,
            self.psnr,
            self.ssim,
            o(self.kelvin_mae),
            o(self.kelvin_rmse),
            self.primitives,
            self.memory_bytes,
            o(self.psnr_aligned),
            o(self.kelvin_mae_aligned)
        )
    }
}

/// Appends a row to `path`, writing the header first if the file is new.
pub fn append_row(path: &Path, row: &MetricsRow) -> Result<(), ReportError> {
    let io = |source| ReportError::Io {
        path: path.to_path_buf(),
        source,
    };
    // The log keeps the columns its header was written with: a run resumed after the LPIPS
    // weights were installed (or removed) leaves its column set as it began.
    let with_lpips = match fs::read_to_string(path) {
        Ok(text) => text
            .lines()
            .next()
            .is_some_and(|h| h.split(',').any(|c| c == LPIPS_COLUMN)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => row.lpips.is_some(),
        Err(e) => return Err(io(e)),
    };
    let new = !path.exists();
    let mut f = fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(io)?;
    if new {
        let extra = if with_lpips {
            format!(",{LPIPS_COLUMN}")
        } else {
            String::new()
        };
        writeln!(f, "{CSV_HEADER}{extra}").map_err(io)?;
    }
    writeln!(f, "{}", row.to_csv(with_lpips)).map_err(io)?;
    Ok(())
}

/// Reads `metrics.csv` (columns found by header name, so extra columns are fine).
pub fn read_rows(path: &Path) -> Result<Vec<MetricsRow>, ReportError> {
    let text = fs::read_to_string(path).map_err(|source| ReportError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |line: usize, reason: &str| ReportError::Format {
        path: path.to_path_buf(),
        reason: format!("line {line}: {reason}"),
    };
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or("").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let need = |name: &str| col(name).ok_or_else(|| bad(1, &format!("no column {name}")));
    let (ci, cs, cl, cp, css) = (
        need("iteration")?,
        need("seconds")?,
        need("loss")?,
        need("psnr")?,
        need("ssim")?,
    );
    let (ck, ckr, cn, cm) = (
        need("kelvin_mae")?,
        col("kelvin_rmse"),
        need("primitives")?,
        need("memory_bytes")?,
    );
    let (cpa, cka, clp) = (
        col("psnr_aligned"),
        col("kelvin_mae_aligned"),
        col(LPIPS_COLUMN),
    );
    let mut rows = Vec::new();
    for (n, l) in lines.enumerate() {
        if l.trim().is_empty() {
            continue;
        }
        let t: Vec<&str> = l.split(',').collect();
        let get = |c: usize| t.get(c).copied().unwrap_or("");
        let f = |c: usize| {
            get(c)
                .parse::<f64>()
                .map_err(|_| bad(n + 2, &format!("`{}` is not a number", get(c))))
        };
        let fo = |c: Option<usize>| c.and_then(|c| get(c).parse::<f64>().ok());
        rows.push(MetricsRow {
            iteration: f(ci)? as u64,
            seconds: f(cs)?,
            loss: f(cl)?,
            psnr: f(cp)?,
            ssim: f(css)?,
            kelvin_mae: fo(Some(ck)),
            kelvin_rmse: fo(ckr),
            primitives: f(cn)? as usize,
            memory_bytes: f(cm)? as usize,
            psnr_aligned: fo(cpa),
            kelvin_mae_aligned: fo(cka),
            lpips: fo(clp),
        });
    }
    Ok(rows)
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(220, 50, 32),
    RGBColor(0, 90, 181),
    RGBColor(0, 150, 80),
    RGBColor(160, 80, 200),
    RGBColor(230, 150, 0),
    RGBColor(90, 90, 90),
];

fn plot_err(path: &Path, e: impl std::error::Error + Send + Sync + 'static) -> ReportError {
    ReportError::Plot {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

/// Draws one plot on a canvas with the bundled font (no system fonts needed) and writes it to
/// `path` as PNG.
fn draw_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), ReportError>,
) -> Result<(), ReportError> {
    let mut canvas = PngCanvas::new(width, height).map_err(|e| plot_err(path, e))?;
    {
        let root = canvas.area();
        draw(&root)?;
        root.present().map_err(|e| plot_err(path, e))?;
    }
    canvas.save(path).map_err(|e| plot_err(path, e))
}

/// A held-out figure at one evaluation over one or more runs: their mean and range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    pub mean: f64,
    pub min: f64,
    pub max: f64,
}

impl Spread {
    /// One run's value.
    pub fn one(v: f64) -> Self {
        Self {
            mean: v,
            min: v,
            max: v,
        }
    }

    /// Mean and range of `values` (`None` when empty).
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        Some(Self {
            mean: values.iter().sum::<f64>() / values.len() as f64,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        })
    }
}

/// One evaluation of a [`Curve`]: training seconds (mean over the runs) and the held-out
/// figures (`None` where a run's log lacks them).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CurvePoint {
    pub seconds: f64,
    pub psnr: Spread,
    pub psnr_aligned: Option<Spread>,
    pub ssim: Spread,
    pub kelvin_mae: Option<Spread>,
    pub kelvin_mae_aligned: Option<Spread>,
    /// Held-out LPIPS (`None` where a run's log has no LPIPS column).
    pub lpips: Option<Spread>,
    /// Mean primitives.
    pub primitives: f64,
}

/// Error against training time of one run, or of repeated runs of one configuration (their
/// mean and range per evaluation; [`crate::compare`] builds those).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Curve {
    pub label: String,
    /// Runs behind each point.
    pub runs: usize,
    pub points: Vec<CurvePoint>,
}

impl Curve {
    /// One run's rows as a curve.
    pub fn of_run(label: &str, rows: &[MetricsRow]) -> Self {
        Self {
            label: label.to_owned(),
            runs: 1,
            points: rows
                .iter()
                .map(|r| CurvePoint {
                    seconds: r.seconds,
                    psnr: Spread::one(r.psnr),
                    psnr_aligned: r.psnr_aligned.map(Spread::one),
                    ssim: Spread::one(r.ssim),
                    kelvin_mae: r.kelvin_mae.map(Spread::one),
                    kelvin_mae_aligned: r.kelvin_mae_aligned.map(Spread::one),
                    lpips: r.lpips.map(Spread::one),
                    primitives: r.primitives as f64,
                })
                .collect(),
        }
    }
}

/// Plots held-out PSNR (left), kelvin MAE (SSIM when not radiometric) and, when the logs have it,
/// LPIPS (right) against training seconds, one line per run: `runs = [(label, rows)]`.
pub fn plot_runs(path: &Path, runs: &[(String, Vec<MetricsRow>)]) -> Result<(), ReportError> {
    let curves: Vec<Curve> = runs
        .iter()
        .map(|(label, rows)| Curve::of_run(label, rows))
        .collect();
    plot_curves(path, &curves)
}

/// A panel's figure of a point (`None`: not in the log).
type Getter = Box<dyn Fn(&CurvePoint) -> Option<Spread>>;

/// The panels of the error-vs-time plot as (title, raw figure, aligned figure); each draws the
/// raw figure (solid, its range shaded) and, when the log has it, the aligned one (dashed):
/// PSNR; kelvin MAE (SSIM when not radiometric); LPIPS when the logs have it.
fn panels(radiometric: bool, with_lpips: bool) -> Vec<(&'static str, Getter, Getter)> {
    let mut panels: Vec<(&'static str, Getter, Getter)> = vec![
        (
            "held-out PSNR (dB); dashed: affine-aligned",
            Box::new(|p| Some(p.psnr)),
            Box::new(|p| p.psnr_aligned),
        ),
        if radiometric {
            (
                "held-out MAE (K); dashed: offset-aligned",
                Box::new(|p| p.kelvin_mae),
                Box::new(|p| p.kelvin_mae_aligned),
            )
        } else {
            (
                "held-out SSIM",
                Box::new(|p| Some(p.ssim)),
                Box::new(|_| None),
            )
        },
    ];
    if with_lpips {
        panels.push((
            "held-out LPIPS (AlexNet; lower is better)",
            Box::new(|p| p.lpips),
            Box::new(|_| None),
        ));
    }
    panels
}

/// `[min, max]` of `vals` padded by 5 % (at least 1e-3); `(0, 1)` when there are none.
fn padded_range(vals: Vec<f64>) -> (f64, f64) {
    let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if lo.is_finite() && hi.is_finite() {
        let pad = ((hi - lo) * 0.05).max(1e-3);
        (lo - pad, hi + pad)
    } else {
        (0.0, 1.0)
    }
}

/// Plots held-out PSNR (left), kelvin MAE (SSIM when not radiometric) and, when the logs have it,
/// LPIPS (right; a third 550-px panel) against training seconds, one line per curve: the mean of
/// its runs, with the range of the raw figure shaded where a curve holds several runs, and the
/// aligned figure dashed where the logs have it.
pub fn plot_curves(path: &Path, curves: &[Curve]) -> Result<(), ReportError> {
    let all: Vec<&CurvePoint> = curves.iter().flat_map(|c| c.points.iter()).collect();
    let with_lpips = all.iter().any(|p| p.lpips.is_some());
    let width = if with_lpips { 1650 } else { 1100 };
    draw_png(path, (width, 450), |root| {
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let areas = root.split_evenly((1, if with_lpips { 3 } else { 2 }));
        let t_max = all.iter().map(|p| p.seconds).fold(1e-3, f64::max);
        let radiometric = all.iter().any(|p| p.kelvin_mae.is_some());
        let panels = panels(radiometric, with_lpips);
        for (area, (label, get, get_aligned)) in areas.iter().zip(panels.iter()) {
            let (lo, hi) = padded_range(
                all.iter()
                    .flat_map(|p| [get(p), get_aligned(p)])
                    .flatten()
                    .flat_map(|s| [s.min, s.max])
                    .collect(),
            );
            let mut chart = ChartBuilder::on(area)
                .caption(*label, ("sans-serif", 18))
                .margin(12)
                .x_label_area_size(35)
                .y_label_area_size(55)
                .build_cartesian_2d(0.0..t_max * 1.02, lo..hi)
                .map_err(|e| plot_err(path, e))?;
            chart
                .configure_mesh()
                .x_desc("training time (s)")
                .draw()
                .map_err(|e| plot_err(path, e))?;
            for (k, curve) in curves.iter().enumerate() {
                let colour = PALETTE[k % PALETTE.len()];
                let spreads: Vec<(f64, Spread)> = curve
                    .points
                    .iter()
                    .filter_map(|p| get(p).map(|s| (p.seconds, s)))
                    .collect();
                if curve.runs > 1 && spreads.len() > 1 {
                    let band: Vec<(f64, f64)> = spreads
                        .iter()
                        .map(|(t, s)| (*t, s.max))
                        .chain(spreads.iter().rev().map(|(t, s)| (*t, s.min)))
                        .collect();
                    chart
                        .draw_series(std::iter::once(Polygon::new(band, colour.mix(0.18))))
                        .map_err(|e| plot_err(path, e))?;
                }
                let pts: Vec<(f64, f64)> = spreads.iter().map(|(t, s)| (*t, s.mean)).collect();
                let name = if curve.runs > 1 {
                    format!("{} (mean of {} runs)", curve.label, curve.runs)
                } else {
                    curve.label.clone()
                };
                chart
                    .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                    .map_err(|e| plot_err(path, e))?
                    .label(name)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour));
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(|e| plot_err(path, e))?;
                let aligned: Vec<(f64, f64)> = curve
                    .points
                    .iter()
                    .filter_map(|p| get_aligned(p).map(|s| (p.seconds, s.mean)))
                    .collect();
                if !aligned.is_empty() {
                    chart
                        .draw_series(DashedLineSeries::new(aligned, 6, 4, colour.stroke_width(1)))
                        .map_err(|e| plot_err(path, e))?;
                }
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| plot_err(path, e))?;
        }
        Ok(())
    })
}

/// Writes a planar RGB render (`3·w·h` values in [0, 1], as datasets hold RGB) as an 8-bit
/// PNG.
pub fn write_rgb_png(
    path: &Path,
    planes: &[f32],
    width: usize,
    height: usize,
) -> Result<(), ReportError> {
    let n = width * height;
    if planes.len() != 3 * n {
        return Err(ReportError::Format {
            path: path.to_path_buf(),
            reason: format!(
                "RGB planes hold {} values, not 3×{width}×{height}",
                planes.len()
            ),
        });
    }
    let bytes: Vec<u8> = (0..n)
        .flat_map(|p| (0..3).map(move |c| (c, p)))
        .map(|(c, p)| (planes[c * n + p].clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let img = image::RgbImage::from_raw(width as u32, height as u32, bytes).ok_or_else(|| {
        ReportError::Format {
            path: path.to_path_buf(),
            reason: format!("not {width}×{height}"),
        }
    })?;
    img.save(path).map_err(|source| ReportError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a normalised thermal plane as a 16-bit PNG in the scene's raw units (centikelvin for
/// radiometric data), so renders compare with the inputs word for word.
pub fn write_thermal_png16(
    path: &Path,
    plane: &[f32],
    width: usize,
    height: usize,
    range: &crate::dataset::ThermalRange,
) -> Result<(), ReportError> {
    let words: Vec<u16> = plane
        .iter()
        .map(|&v| range.raw(f64::from(v)).round().clamp(0.0, 65535.0) as u16)
        .collect();
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
        width as u32,
        height as u32,
        words,
    )
    .ok_or_else(|| ReportError::Format {
        path: path.to_path_buf(),
        reason: format!("plane has {} values, not {width}×{height}", plane.len()),
    })?;
    img.save(path).map_err(|source| ReportError::Image {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a `height × width` f32 plane as a NumPy `.npy` file (format 1.0, little-endian `<f4`,
/// C order): `numpy.load` reads it, and so does [`read_npy_f32`].
pub fn write_npy_f32(
    path: &Path,
    plane: &[f32],
    width: usize,
    height: usize,
) -> Result<(), ReportError> {
    if plane.len() != width * height {
        return Err(ReportError::Format {
            path: path.to_path_buf(),
            reason: format!("plane has {} values, not {width}×{height}", plane.len()),
        });
    }
    let mut header =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    // Magic (6) + version (2) + header length (2) + header + '\n' is a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + 4 * plane.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in plane {
        out.extend_from_slice(&v.to_le_bytes());
    }
    fs::write(path, out).map_err(|source| ReportError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a 2-D little-endian f32 `.npy` file written by [`write_npy_f32`]: `(width, height,
/// values)`.
pub fn read_npy_f32(path: &Path) -> Result<(usize, usize, Vec<f32>), ReportError> {
    let bad = |reason: String| ReportError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let data = fs::read(path).map_err(|source| ReportError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if data.len() < 10 || &data[..8] != b"\x93NUMPY\x01\x00" {
        return Err(bad("not a version 1.0 .npy file".into()));
    }
    let hlen = usize::from(u16::from_le_bytes([data[8], data[9]]));
    let header = data
        .get(10..10 + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad("truncated header".into()))?;
    if !header.contains("'descr': '<f4'") || !header.contains("'fortran_order': False") {
        return Err(bad(format!(
            "unsupported header {header:?} (need <f4, C order)"
        )));
    }
    let shape: Vec<usize> = header
        .split("'shape': (")
        .nth(1)
        .and_then(|r| r.split(')').next())
        .ok_or_else(|| bad(format!("no shape in {header:?}")))?
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse::<usize>()
                .map_err(|e| bad(format!("shape {t:?}: {e}")))
        })
        .collect::<Result<_, _>>()?;
    let [height, width] = shape[..] else {
        return Err(bad(format!("shape {shape:?} is not 2-D")));
    };
    let body = &data[10 + hlen..];
    if body.len() != 4 * width * height {
        return Err(bad(format!(
            "{} data bytes for a {height}×{width} f32 array",
            body.len()
        )));
    }
    let values = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((width, height, values))
}

/// Writes the G-buffers of one view as palette PNGs `PREFIX_{psi_low,psi_high,psi_beta,depth}.png`
/// with their range in the file ([`crate::look::image`]): Ψ_low in ironbow over [0, max],
/// Ψ_high (signed) in the diverging palette over ±max |Ψ_high|, Ψ_β in inferno over
/// [2, max(3, max β)] (normalised by accumulated alpha, so a pixel covered by primitives of
/// β = 2 is the coldest colour), depth (expected, `depth/alpha`) in grey over its range; and
/// the exact values as f32 `.npy` arrays `PREFIX_{name}.npy` for the same four planes (same
/// normalisation; 0 where alpha ≤ 10⁻³) plus `PREFIX_alpha.npy` (accumulated alpha). Returns
/// the files written.
pub fn write_gbuffers(
    dir: &Path,
    prefix: &str,
    gb: &crate::render::GBuffers<f32>,
) -> Result<Vec<PathBuf>, ReportError> {
    let (w, h) = (gb.width, gb.height);
    let norm = |v: &[f32]| -> Vec<f32> {
        v.iter()
            .zip(&gb.alpha)
            .map(|(x, a)| if *a > 1e-3 { x / a } else { 0.0 })
            .collect()
    };
    let max = |v: &[f32]| -> f64 { f64::from(v.iter().copied().fold(0.0f32, f32::max)) };
    let beta = norm(&gb.psi_beta);
    let depth = norm(&gb.depth);
    let dmin = depth
        .iter()
        .zip(&gb.alpha)
        .filter(|(_, a)| **a > 1e-3)
        .map(|(d, _)| f64::from(*d))
        .fold(f64::INFINITY, f64::min);
    let mut out = Vec::new();
    let high = f64::from(gb.psi_high.iter().fold(0.0f32, |m, v| m.max(v.abs())));
    let planes: [(&str, Vec<f32>, Scale); 4] = [
        (
            "psi_low",
            gb.psi_low.clone(),
            Scale::new(Colormap::Ironbow, 0.0, max(&gb.psi_low), "normalised"),
        ),
        (
            "psi_high",
            gb.psi_high.clone(),
            Scale::new(Colormap::Diverging, -high, high, "normalised"),
        ),
        (
            "psi_beta",
            beta.clone(),
            Scale::new(
                Colormap::Inferno,
                2.0,
                max(&beta).clamp(3.0, BETA_MAX),
                "beta",
            ),
        ),
        (
            "depth",
            depth.clone(),
            Scale::new(
                Colormap::Grey,
                if dmin.is_finite() { dmin } else { 0.0 },
                max(&depth),
                "scene units",
            ),
        ),
    ];
    for (name, plane, scale) in &planes {
        let p = dir.join(format!("{prefix}_{name}.png"));
        write_palette_png(&p, plane, w, h, scale).map_err(|e| ReportError::Palette(Box::new(e)))?;
        out.push(p);
    }
    for (name, plane) in planes
        .iter()
        .map(|(n, p, _)| (*n, p))
        .chain([("alpha", &gb.alpha)])
    {
        let p = dir.join(format!("{prefix}_{name}.npy"));
        write_npy_f32(&p, plane, w, h)?;
        out.push(p);
    }
    Ok(out)
}

/// Log-histogram of β (paper Fig. 6): 24 log-spaced bins over [2, 64], bar height
/// `log10(1 + count)`.
pub fn plot_beta_histogram(path: &Path, betas: &[f64]) -> Result<(), ReportError> {
    const BINS: usize = 24;
    let (l0, l1) = (2f64.ln(), BETA_MAX.ln());
    let mut counts = [0usize; BINS];
    for &b in betas {
        let t = ((b.clamp(2.0, BETA_MAX).ln() - l0) / (l1 - l0) * BINS as f64).floor() as usize;
        counts[t.min(BINS - 1)] += 1;
    }
    let top = counts
        .iter()
        .map(|&c| (1.0 + c as f64).log10())
        .fold(0.5, f64::max);
    draw_png(path, (640, 400), |root| {
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("β of {} primitives", betas.len()),
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(35)
            .y_label_area_size(55)
            .build_cartesian_2d((2.0f64..BETA_MAX).log_scale(), 0.0..top * 1.05)
            .map_err(|e| plot_err(path, e))?;
        chart
            .configure_mesh()
            .x_desc("β (log scale)")
            .y_desc("log10(1 + count)")
            .draw()
            .map_err(|e| plot_err(path, e))?;
        let edge = |k: usize| (l0 + (l1 - l0) * k as f64 / BINS as f64).exp();
        chart
            .draw_series(counts.iter().enumerate().map(|(k, &c)| {
                Rectangle::new(
                    [(edge(k), 0.0), (edge(k + 1), (1.0 + c as f64).log10())],
                    PALETTE[1].filled(),
                )
            }))
            .map_err(|e| plot_err(path, e))?;
        Ok(())
    })
}
