//! The report's figures, drawn with plotters on the bundled-font canvas ([`super::plot`]):
//! per camera the RMS of every view (bars), the residual vectors over the image (scaled; red:
//! rejected) and a corner-coverage heat map; the joint RMS against solver iteration and wall
//! time (`rms_vs_iteration.png`, `rms_vs_time.png`).

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::detect::board::Camera;
use crate::error::CalibError;
use crate::report::page::Block;
use crate::report::plot::PngCanvas;
use crate::solve::pipeline::{Calibration, CameraResult};

/// Draws every figure into `dir`; returns the files written and their blocks for the page
/// (captions as the report shows them).
pub fn write_all(c: &Calibration, dir: &Path) -> Result<(Vec<PathBuf>, Vec<Block>), CalibError> {
    let mut files = Vec::new();
    let mut blocks = Vec::new();
    let mut figure = |file: String, caption: String| {
        files.push(dir.join(&file));
        blocks.push(Block::Figure { file, caption });
    };
    for camera in Camera::BOTH {
        let Some(r) = &c.cameras[camera.index()] else {
            continue;
        };
        let name = camera.name();
        let file = format!("per_view_rms_{name}.png");
        per_view_bars(r, &dir.join(&file))?;
        figure(file, format!("{name}: RMS per view"));
        let file = format!("residuals_{name}.png");
        let scale = residual_vectors(c, camera, r, &dir.join(&file))?;
        figure(
            file,
            format!("{name}: residual vectors ×{scale:.0} (red: rejected)"),
        );
        let file = format!("coverage_{name}.png");
        coverage(c, camera, r, &dir.join(&file))?;
        figure(file, format!("{name}: corner coverage"));
    }
    for (by_time, file, caption) in [
        (
            false,
            "rms_vs_iteration.png",
            "joint RMS vs solver iteration",
        ),
        (true, "rms_vs_time.png", "joint RMS vs solver wall time"),
    ] {
        rms_curve(c, by_time, &dir.join(file))?;
        figure(file.to_string(), caption.to_string());
    }
    Ok((files, blocks))
}

/// The error of writing `path`, keeping its cause.
pub(crate) fn write_err<E: std::error::Error + Send + Sync + 'static>(
    path: &Path,
) -> impl FnOnce(E) -> CalibError + '_ {
    move |source| CalibError::Write {
        path: path.to_path_buf(),
        source: Box::new(source),
    }
}

/// Draws one plot on a canvas with the bundled font and writes it to `path` as PNG.
fn draw_png<T>(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<T, CalibError>,
) -> Result<T, CalibError> {
    let mut canvas = PngCanvas::new(width, height).map_err(write_err(path))?;
    let out = {
        let root = canvas.area();
        let out = draw(&root)?;
        root.present().map_err(write_err(path))?;
        out
    };
    canvas.save(path).map_err(write_err(path))?;
    Ok(out)
}

fn per_view_bars(r: &CameraResult, path: &Path) -> Result<(), CalibError> {
    draw_png(path, (900, 420), |root| {
        root.fill(&WHITE).map_err(write_err(path))?;
        let n = r.per_view.len().max(1);
        let ymax = r
            .per_view
            .iter()
            .map(|v| v.rms_px)
            .fold(0.0, f64::max)
            .max(1e-3)
            * 1.15;
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("{}: RMS per view (px)", r.camera.name()),
                ("sans-serif", 20),
            )
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..n as f64, 0.0..ymax)
            .map_err(write_err(path))?;
        chart
            .configure_mesh()
            .x_desc("view")
            .y_desc("RMS px")
            .disable_x_mesh()
            .draw()
            .map_err(write_err(path))?;
        chart
            .draw_series(r.per_view.iter().enumerate().map(|(i, v)| {
                Rectangle::new(
                    [(i as f64 + 0.1, 0.0), (i as f64 + 0.9, v.rms_px)],
                    BLUE.mix(0.7).filled(),
                )
            }))
            .map_err(write_err(path))?;
        chart
            .draw_series(LineSeries::new(
                [(0.0, r.rms_px), (n as f64, r.rms_px)],
                RED.stroke_width(2),
            ))
            .map_err(write_err(path))?
            .label(format!("camera RMS {:.3} px", r.rms_px))
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.8))
            .draw()
            .map_err(write_err(path))?;
        Ok(())
    })
}

fn residual_vectors(
    c: &Calibration,
    camera: Camera,
    r: &CameraResult,
    path: &Path,
) -> Result<f64, CalibError> {
    let (w, h) = (f64::from(r.model.width_px), f64::from(r.model.height_px));
    let res = &c.residuals[camera.index()];
    let max = res
        .iter()
        .filter(|c| c.inlier)
        .map(|c| c.residual_px.length())
        .fold(0.0, f64::max)
        .max(1e-6);
    // Longest inlier arrow = 1/12 of the image width.
    let scale = w / 12.0 / max;
    let width = 900u32;
    let height = ((f64::from(width) * h / w) as u32).max(200);
    draw_png(path, (width, height + 40), |root| {
        root.fill(&WHITE).map_err(write_err(path))?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("{}: residuals ×{scale:.0} (red: rejected)", camera.name()),
                ("sans-serif", 18),
            )
            .margin(5)
            .build_cartesian_2d(-0.5..w - 0.5, h - 0.5..-0.5)
            .map_err(write_err(path))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .draw()
            .map_err(write_err(path))?;
        chart
            .draw_series(res.iter().map(|c| {
                let p = c.observed_px;
                let q = p + c.residual_px * scale;
                let colour = if c.inlier { BLUE } else { RED };
                PathElement::new([(p.x, p.y), (q.x, q.y)], colour.stroke_width(1))
            }))
            .map_err(write_err(path))?;
        Ok(scale)
    })
}

fn coverage(
    c: &Calibration,
    camera: Camera,
    r: &CameraResult,
    path: &Path,
) -> Result<(), CalibError> {
    let (w, h) = (f64::from(r.model.width_px), f64::from(r.model.height_px));
    let (gx, gy) = (16usize, 12usize);
    let mut counts = vec![0usize; gx * gy];
    for cr in &c.residuals[camera.index()] {
        let i = ((cr.observed_px.x + 0.5) / w * gx as f64)
            .floor()
            .clamp(0.0, gx as f64 - 1.0) as usize;
        let j = ((cr.observed_px.y + 0.5) / h * gy as f64)
            .floor()
            .clamp(0.0, gy as f64 - 1.0) as usize;
        counts[j * gx + i] += 1;
    }
    let max = counts.iter().copied().max().unwrap_or(1).max(1) as f64;
    draw_png(path, (800, 640), |root| {
        root.fill(&WHITE).map_err(write_err(path))?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("{}: corner coverage (white = never covered)", camera.name()),
                ("sans-serif", 18),
            )
            .margin(5)
            .build_cartesian_2d(0.0..w, h..0.0)
            .map_err(write_err(path))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .draw()
            .map_err(write_err(path))?;
        chart
            .draw_series(
                (0..gy)
                    .flat_map(|j| (0..gx).map(move |i| (i, j)))
                    .map(|(i, j)| {
                        let v = counts[j * gx + i] as f64 / max;
                        let colour = if counts[j * gx + i] == 0 {
                            WHITE.to_rgba()
                        } else {
                            HSLColor(0.66 - 0.66 * v, 0.9, 0.5).to_rgba()
                        };
                        let x0 = i as f64 * w / gx as f64;
                        let y0 = j as f64 * h / gy as f64;
                        Rectangle::new(
                            [(x0, y0), (x0 + w / gx as f64, y0 + h / gy as f64)],
                            colour.filled(),
                        )
                    }),
            )
            .map_err(write_err(path))?;
        Ok(())
    })
}

fn rms_curve(c: &Calibration, by_time: bool, path: &Path) -> Result<(), CalibError> {
    let pts: Vec<(f64, f64)> = c
        .iterations
        .iter()
        .map(|i| {
            (
                if by_time {
                    i.wall_s
                } else {
                    i.iteration as f64
                },
                i.rms_px,
            )
        })
        .collect();
    let xmax = pts.iter().map(|p| p.0).fold(0.0, f64::max).max(1e-6);
    let ymax = pts.iter().map(|p| p.1).fold(0.0, f64::max).max(1e-6) * 1.1;
    let ymin = pts
        .iter()
        .map(|p| p.1)
        .fold(f64::INFINITY, f64::min)
        .max(1e-6)
        * 0.9;
    draw_png(path, (800, 420), |root| {
        root.fill(&WHITE).map_err(write_err(path))?;
        let caption = if by_time {
            "joint RMS vs solver wall time"
        } else {
            "joint RMS vs solver iteration"
        };
        let mut chart = ChartBuilder::on(root)
            .caption(caption, ("sans-serif", 20))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..xmax, ymin..ymax)
            .map_err(write_err(path))?;
        chart
            .configure_mesh()
            .x_desc(if by_time { "seconds" } else { "iteration" })
            .y_desc("RMS px")
            .draw()
            .map_err(write_err(path))?;
        chart
            .draw_series(LineSeries::new(pts.clone(), BLUE.stroke_width(2)))
            .map_err(write_err(path))?;
        chart
            .draw_series(pts.iter().map(|p| Circle::new(*p, 3, BLUE.filled())))
            .map_err(write_err(path))?;
        Ok(())
    })
}
