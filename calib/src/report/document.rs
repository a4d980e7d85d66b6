//! `--report DIR`: `report.md` and `report.html` plus PNG plots (plotters): per-view RMS bars,
//! residual vectors over the image and a corner-coverage heat map per camera, and RMS against
//! solver iteration and wall time (`rms_vs_iteration.png`, `rms_vs_time.png`, also as
//! `iterations.csv`). `report.html` is self-contained: the plots are embedded as `data:` URIs
//! (and linked to the PNG files beside it), with tables of the result, the extrinsic, per-view
//! RMS, rejected corners, warnings and the files not used.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::report::plot::PngCanvas;

use crate::detect::board::Camera;
use crate::error::CalibError;
use crate::solve::pipeline::{Calibration, CameraResult};

/// The error of writing `path`, keeping its cause.
fn write_err<E: std::error::Error + Send + Sync + 'static>(
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

/// Writes the report into `dir`; returns the files written.
pub fn write_report(c: &Calibration, dir: &Path) -> Result<Vec<PathBuf>, CalibError> {
    std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    let mut files = Vec::new();
    let mut md = String::new();
    let _ = writeln!(md, "# s3tir-calib report\n");
    let _ = writeln!(
        md,
        "Board {}×{} inner corners, {} mm squares. Thermal ordering: {}.\n",
        c.board.cols(),
        c.board.rows(),
        c.board.square_mm,
        c.polarity_note
    );
    let _ = writeln!(
        md,
        "Detection {:.2} s, joint solve {:.3} s ({} iterations, converged: {}).\n",
        c.detection_wall_s,
        c.solve_wall_s,
        c.iterations.len().saturating_sub(1),
        c.converged
    );
    let _ = writeln!(
        md,
        "## Result\n\n| camera | images | views found | views used | RMS px | alone: RMS px (all corners) | corners | fx ± σ | fy ± σ | cx ± σ | cy ± σ |\n|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in c.cameras.iter().flatten() {
        let (i, s) = (r.model.intrinsics, r.sigma);
        let _ = writeln!(
            md,
            "| {} | {} | {}{} | {} | {:.4} | {:.4} ({:.4}) | {} | {:.3} ± {:.3} | {:.3} ± {:.3} | {:.3} ± {:.3} | {:.3} ± {:.3} |",
            r.camera.name(),
            r.images,
            r.views_found,
            if r.views_partial > 0 {
                format!(" ({} partial)", r.views_partial)
            } else {
                String::new()
            },
            r.views_used,
            r.rms_px,
            r.mono_rms_px,
            r.mono_rms_all_px,
            r.refinement.as_ref().map_or_else(
                || "-".to_string(),
                |f| {
                    let tried: Vec<String> = f
                        .mono_rms_all_px
                        .iter()
                        .map(|(r, rms)| format!("{r:?} {rms:.3}"))
                        .collect();
                    format!("{:?} (alone, all corners: {})", f.kept, tried.join(", "))
                }
            ),
            i.fx,
            s.fx,
            i.fy,
            s.fy,
            i.cx,
            s.cx,
            i.cy,
            s.cy
        );
    }
    let _ = writeln!(
        md,
        "\nJoint RMS {:.4} px over {} pairs (and unpaired views).\n",
        c.joint_rms_px, c.pairs_used
    );
    if let Some(t) = c.rgb_from_thermal {
        let (axis, angle) = t.rotation.to_axis_angle();
        let _ = writeln!(
            md,
            "`rgb_from_thermal`: rotation {:.4}° about ({:.3}, {:.3}, {:.3}), translation ({:.5}, {:.5}, {:.5}) m",
            angle.to_degrees(),
            axis.x,
            axis.y,
            axis.z,
            t.translation_m.x,
            t.translation_m.y,
            t.translation_m.z
        );
        if let Some(s) = c.extrinsic_sigma {
            let _ = writeln!(
                md,
                "(1σ: rotation ({:.4}, {:.4}, {:.4})°, translation ({:.5}, {:.5}, {:.5}) m).\n",
                s.rotation_deg[0],
                s.rotation_deg[1],
                s.rotation_deg[2],
                s.translation_m[0],
                s.translation_m[1],
                s.translation_m[2]
            );
        }
    }
    let _ = writeln!(
        md,
        "## Pair consistency\n\n{} pairs found, {} used for the extrinsic, {} left out (thresholds: {:?}; see `pairs` in the crate docs).\n",
        c.pairs_found,
        c.pairs_used,
        c.pairs_inconsistent.len(),
        c.pair_thresholds
    );
    for p in &c.pairs_inconsistent {
        let _ = writeln!(md, "- {}", p.describe());
    }
    let _ = writeln!(md, "\n## Warnings\n");
    if c.warnings.is_empty() {
        let _ = writeln!(md, "None.");
    }
    for w in &c.warnings {
        let _ = writeln!(md, "- {w}");
    }
    let _ = writeln!(md, "\n## Files not used\n");
    if c.problems.is_empty() {
        let _ = writeln!(md, "None.");
    }
    for p in &c.problems {
        let _ = writeln!(md, "- `{}`: {}", p.path.display(), p.reason);
    }
    let _ = writeln!(md, "\n## Rejected corners (k·σ test)\n");
    if c.rejected.is_empty() {
        let _ = writeln!(md, "None.");
    }
    for r in &c.rejected {
        let _ = writeln!(
            md,
            "- {} view `{}` corner {}: {:.3} px",
            r.camera.name(),
            c.view_keys.get(r.view).map_or("?", String::as_str),
            r.corner,
            r.residual_px
        );
    }
    let _ = writeln!(md, "\n## Plots\n");
    // (caption, file name) of every plot, for the HTML page.
    let mut plots: Vec<(String, String)> = Vec::new();
    for camera in Camera::BOTH {
        let Some(r) = &c.cameras[camera.index()] else {
            continue;
        };
        let name = camera.name();
        let p = dir.join(format!("per_view_rms_{name}.png"));
        per_view_bars(r, &p)?;
        files.push(p);
        let p = dir.join(format!("residuals_{name}.png"));
        let scale = residual_vectors(c, camera, r, &p)?;
        files.push(p);
        let p = dir.join(format!("coverage_{name}.png"));
        coverage(c, camera, r, &p)?;
        files.push(p);
        let _ = writeln!(
            md,
            "![{name} per-view RMS](per_view_rms_{name}.png)\n\n![{name} residuals ×{scale:.0}](residuals_{name}.png)\n\n![{name} coverage](coverage_{name}.png)\n"
        );
        plots.push((
            format!("{name}: RMS per view"),
            format!("per_view_rms_{name}.png"),
        ));
        plots.push((
            format!("{name}: residual vectors ×{scale:.0} (red: rejected)"),
            format!("residuals_{name}.png"),
        ));
        plots.push((
            format!("{name}: corner coverage"),
            format!("coverage_{name}.png"),
        ));
        let _ = writeln!(
            md,
            "| {name} view | RMS px | corners | tilt ° |\n|---|---|---|---|"
        );
        for v in &r.per_view {
            let _ = writeln!(
                md,
                "| {} | {:.4} | {} | {:.1} |",
                v.key, v.rms_px, v.corners_used, v.tilt_deg
            );
        }
        let _ = writeln!(md);
    }
    for (by_time, name) in [(false, "rms_vs_iteration.png"), (true, "rms_vs_time.png")] {
        let p = dir.join(name);
        rms_curve(c, by_time, &p)?;
        files.push(p);
        let _ = writeln!(md, "![{name}]({name})\n");
        plots.push((
            if by_time {
                "joint RMS vs solver wall time"
            } else {
                "joint RMS vs solver iteration"
            }
            .to_string(),
            name.to_string(),
        ));
    }
    let mut csv = String::from("iteration,wall_s,rms_px,lambda\n");
    for i in &c.iterations {
        let _ = writeln!(
            csv,
            "{},{:.6},{:.6},{:.3e}",
            i.iteration, i.wall_s, i.rms_px, i.lambda
        );
    }
    let p = dir.join("iterations.csv");
    std::fs::write(&p, csv).map_err(write_err(&p))?;
    files.push(p);
    let p = dir.join("report.md");
    std::fs::write(&p, md).map_err(write_err(&p))?;
    files.push(p);
    let p = dir.join("report.html");
    let html = html_report(c, dir, &plots)?;
    std::fs::write(&p, html).map_err(write_err(&p))?;
    files.push(p);
    Ok(files)
}

/// Escapes text for HTML element content and attribute values.
fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for ch in text.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Standard base64 (RFC 4648, with padding), for `data:` URIs.
fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(TABLE[((n >> (18 - 6 * k)) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// `report.html`: the same content as `report.md` as one self-contained page (plots embedded
/// as `data:` URIs, each also linked to its PNG beside the page).
fn html_report(
    c: &Calibration,
    dir: &Path,
    plots: &[(String, String)],
) -> Result<String, CalibError> {
    let mut h = String::new();
    let _ = writeln!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>s3tir-calib report</title>\n<style>\nbody {{ font-family: sans-serif; max-width: 1000px; margin: 2em auto; padding: 0 1em; }}\ntable {{ border-collapse: collapse; margin: 0.5em 0 1.5em; }}\nth, td {{ border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }}\nth {{ background: #eee; }}\ntd.l, th.l {{ text-align: left; }}\nfigure {{ margin: 1em 0; }}\nimg {{ max-width: 100%; border: 1px solid #ddd; }}\n.warn {{ color: #a40; }}\n</style>\n</head>\n<body>\n<h1>s3tir-calib report</h1>"
    );
    let _ = writeln!(
        h,
        "<p>Board {}×{} inner corners, {} mm squares. Thermal ordering: {}.</p>",
        c.board.cols(),
        c.board.rows(),
        c.board.square_mm,
        esc(&c.polarity_note)
    );
    let _ = writeln!(
        h,
        "<p>Detection {:.2} s, joint solve {:.3} s ({} iterations, converged: {}).</p>",
        c.detection_wall_s,
        c.solve_wall_s,
        c.iterations.len().saturating_sub(1),
        c.converged
    );
    let _ = writeln!(
        h,
        "<h2 id=\"result\">Result</h2>\n<table>\n<tr><th class=\"l\">camera</th><th>images</th><th>views found</th><th>views used</th><th>RMS px</th><th>OpenCV init RMS px</th><th>fx ± σ</th><th>fy ± σ</th><th>cx ± σ</th><th>cy ± σ</th><th class=\"l\">distortion k1 k2 p1 p2 k3</th></tr>"
    );
    for r in c.cameras.iter().flatten() {
        let (i, s, d) = (r.model.intrinsics, r.sigma, r.model.distortion);
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{:.3} ± {:.3}</td><td>{:.3} ± {:.3}</td><td>{:.3} ± {:.3}</td><td>{:.3} ± {:.3}</td><td class=\"l\">{:.5} {:.5} {:.6} {:.6} {:.5}</td></tr>",
            r.camera.name(),
            r.images,
            r.views_found,
            r.views_used,
            r.rms_px,
            r.init_rms_px,
            i.fx,
            s.fx,
            i.fy,
            s.fy,
            i.cx,
            s.cx,
            i.cy,
            s.cy,
            d.k1,
            d.k2,
            d.p1,
            d.p2,
            d.k3
        );
    }
    let _ = writeln!(
        h,
        "</table>\n<p>Joint RMS {:.4} px over {} pairs (and unpaired views).</p>",
        c.joint_rms_px, c.pairs_used
    );
    if let Some(t) = c.rgb_from_thermal {
        let (axis, angle) = t.rotation.to_axis_angle();
        let _ = writeln!(
            h,
            "<h2 id=\"extrinsic\">Extrinsic <code>rgb_from_thermal</code></h2>\n<table>\n<tr><th class=\"l\">quantity</th><th>value</th><th>1σ</th></tr>"
        );
        let sigma = c.extrinsic_sigma;
        let _ = writeln!(
            h,
            "<tr><td class=\"l\">rotation angle</td><td>{:.4}° about ({:.3}, {:.3}, {:.3})</td><td>{}</td></tr>",
            angle.to_degrees(),
            axis.x,
            axis.y,
            axis.z,
            sigma.map_or_else(
                || "–".to_string(),
                |s| format!(
                    "({:.4}, {:.4}, {:.4})°",
                    s.rotation_deg[0], s.rotation_deg[1], s.rotation_deg[2]
                )
            )
        );
        for (k, axis_name) in ["x", "y", "z"].iter().enumerate() {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\">translation {axis_name}</td><td>{:.5} m</td><td>{}</td></tr>",
                t.translation_m[k],
                sigma.map_or_else(
                    || "–".to_string(),
                    |s| format!("{:.5} m", s.translation_m[k])
                )
            );
        }
        let _ = writeln!(h, "</table>");
    }
    let _ = writeln!(h, "<h2 id=\"warnings\">Warnings</h2>");
    if c.warnings.is_empty() {
        let _ = writeln!(h, "<p>None.</p>");
    } else {
        let _ = writeln!(h, "<ul>");
        for w in &c.warnings {
            let _ = writeln!(h, "<li class=\"warn\">{}</li>", esc(w));
        }
        let _ = writeln!(h, "</ul>");
    }
    let _ = writeln!(h, "<h2 id=\"bad-input\">Files not used</h2>");
    if c.problems.is_empty() {
        let _ = writeln!(h, "<p>None.</p>");
    } else {
        let _ = writeln!(
            h,
            "<table>\n<tr><th class=\"l\">file</th><th class=\"l\">reason</th></tr>"
        );
        for p in &c.problems {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\"><code>{}</code></td><td class=\"l\">{}</td></tr>",
                esc(&p.path.display().to_string()),
                esc(&p.reason)
            );
        }
        let _ = writeln!(h, "</table>");
    }
    let _ = writeln!(h, "<h2 id=\"rejected\">Rejected corners (k·σ test)</h2>");
    if c.rejected.is_empty() {
        let _ = writeln!(h, "<p>None.</p>");
    } else {
        let _ = writeln!(
            h,
            "<table>\n<tr><th class=\"l\">camera</th><th class=\"l\">view</th><th>corner</th><th>residual px</th></tr>"
        );
        for r in &c.rejected {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{}</td><td>{:.3}</td></tr>",
                r.camera.name(),
                esc(c.view_keys.get(r.view).map_or("?", String::as_str)),
                r.corner,
                r.residual_px
            );
        }
        let _ = writeln!(h, "</table>");
    }
    for r in c.cameras.iter().flatten() {
        let name = r.camera.name();
        let _ = writeln!(
            h,
            "<h2 id=\"per-view-{name}\">{name}: RMS per view</h2>\n<table>\n<tr><th class=\"l\">view</th><th>RMS px</th><th>corners</th><th>tilt °</th></tr>"
        );
        for v in &r.per_view {
            let _ = writeln!(
                h,
                "<tr><td class=\"l\">{}</td><td>{:.4}</td><td>{}</td><td>{:.1}</td></tr>",
                esc(&v.key),
                v.rms_px,
                v.corners_used,
                v.tilt_deg
            );
        }
        let _ = writeln!(h, "</table>");
    }
    let _ = writeln!(h, "<h2 id=\"plots\">Plots</h2>");
    for (caption, file) in plots {
        let path = dir.join(file);
        let bytes = std::fs::read(&path).map_err(|x| CalibError::Output {
            path: path.clone(),
            reason: format!("reading the plot back for report.html: {x}"),
        })?;
        let _ = writeln!(
            h,
            "<figure><a href=\"{f}\"><img alt=\"{c}\" src=\"data:image/png;base64,{b}\"></a><figcaption>{c} (<a href=\"{f}\">{f}</a>)</figcaption></figure>",
            f = esc(file),
            c = esc(caption),
            b = base64(&bytes)
        );
    }
    let _ = writeln!(h, "</body>\n</html>");
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc_4648_vectors() {
        for (input, want) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(input.as_bytes()), want, "base64({input:?})");
        }
    }

    #[test]
    fn html_escaping_covers_markup_characters() {
        assert_eq!(
            esc(r#"<a href="x">'&'</a>"#),
            "&lt;a href=&quot;x&quot;&gt;&#39;&amp;&#39;&lt;/a&gt;"
        );
    }
}
