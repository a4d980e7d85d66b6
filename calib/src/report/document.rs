//! `--report DIR`: `report.md` and `report.html` (one [`Page`], two renderings: the same
//! sections in both) plus the PNG figures of [`super::figures`] and `iterations.csv`.
//! `report.html` is self-contained: the figures are embedded as `data:` URIs (and linked to the
//! PNG files beside it). Sections: the board and timings, the result per camera, the extrinsic
//! with its 1σ, pair consistency, warnings, files not used, rejected corners, RMS per view, the
//! figures.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::CalibError;
use crate::report::figures::{self, write_err};
use crate::report::page::{Block, Cell, Column, Page};
use crate::solve::pipeline::{Calibration, CameraResult};

/// Writes the report into `dir` (created if missing); returns every file written.
pub fn write_report(c: &Calibration, dir: &Path) -> Result<Vec<PathBuf>, CalibError> {
    std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    let (mut files, figures) = figures::write_all(c, dir)?;
    let mut page = Page::new("s3tir-calib report");
    summary(&mut page, c);
    result_table(&mut page, c);
    extrinsic(&mut page, c);
    pair_consistency(&mut page, c);
    left_out(&mut page, c);
    per_view(&mut page, c);
    page.push(Block::heading("Plots", "plots"));
    page.blocks.extend(figures);

    let html_path = dir.join("report.html");
    let html = page.html(dir).map_err(write_err(&html_path))?;
    for (name, text) in [
        ("iterations.csv", iterations_csv(c)),
        ("report.md", page.markdown()),
        ("report.html", html),
    ] {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(write_err(&p))?;
        files.push(p);
    }
    Ok(files)
}

/// "12" or "12 (3 partial, by AprilTags)": the views in which the board was found.
pub fn views_found(r: &CameraResult) -> String {
    if r.views_partial > 0 {
        format!(
            "{} ({} partial, by AprilTags)",
            r.views_found, r.views_partial
        )
    } else {
        r.views_found.to_string()
    }
}

/// The board, the thermal ordering and the timings.
fn summary(page: &mut Page, c: &Calibration) {
    page.push(Block::paragraph(format!(
        "Board {}×{} inner corners, {} mm squares. Thermal ordering: {}.",
        c.board.cols(),
        c.board.rows(),
        c.board.square_mm,
        c.polarity_note
    )));
    page.push(Block::paragraph(format!(
        "Detection {:.2} s, joint solve {:.3} s ({} iterations, converged: {}).",
        c.detection_wall_s,
        c.solve_wall_s,
        c.iterations.len().saturating_sub(1),
        c.converged
    )));
}

/// One row per camera: views, RMS (joint, alone, OpenCV's start), the corner refinement kept,
/// intrinsics with 1σ, distortion.
fn result_table(page: &mut Page, c: &Calibration) {
    let columns = [
        Column::text("camera"),
        Column::number("images"),
        Column::number("views found"),
        Column::number("views used"),
        Column::number("RMS px"),
        Column::number("alone: RMS px (all corners)"),
        Column::number("OpenCV init RMS px"),
        Column::text("corners"),
        Column::number("fx ± σ"),
        Column::number("fy ± σ"),
        Column::number("cx ± σ"),
        Column::number("cy ± σ"),
        Column::text("distortion k1 k2 p1 p2 k3"),
    ];
    let rows = c
        .cameras
        .iter()
        .flatten()
        .map(|r| {
            let (i, s, d) = (r.model.intrinsics, r.sigma, r.model.distortion);
            let refinement = r.refinement.as_ref().map_or_else(
                || "-".to_string(),
                |f| {
                    let tried: Vec<String> = f
                        .mono_rms_all_px
                        .iter()
                        .map(|(r, rms)| format!("{r:?} {rms:.3}"))
                        .collect();
                    format!("{:?} (alone, all corners: {})", f.kept, tried.join(", "))
                },
            );
            let pm = |v: f64, s: f64| Cell::from(format!("{v:.3} ± {s:.3}"));
            vec![
                r.camera.name().into(),
                r.images.to_string().into(),
                views_found(r).into(),
                r.views_used.to_string().into(),
                format!("{:.4}", r.rms_px).into(),
                format!("{:.4} ({:.4})", r.mono_rms_px, r.mono_rms_all_px).into(),
                format!("{:.4}", r.init_rms_px).into(),
                refinement.into(),
                pm(i.fx, s.fx),
                pm(i.fy, s.fy),
                pm(i.cx, s.cx),
                pm(i.cy, s.cy),
                format!(
                    "{:.5} {:.5} {:.6} {:.6} {:.5}",
                    d.k1, d.k2, d.p1, d.p2, d.k3
                )
                .into(),
            ]
        })
        .collect();
    page.push(Block::heading("Result", "result"));
    page.push(Block::Table {
        columns: columns.to_vec(),
        rows,
    });
    page.push(Block::paragraph(format!(
        "Joint RMS {:.4} px over {} pairs (and unpaired views).",
        c.joint_rms_px, c.pairs_used
    )));
}

/// `rgb_from_thermal` as angle–axis and translation, with its 1σ where the solve gave one.
fn extrinsic(page: &mut Page, c: &Calibration) {
    let Some(t) = c.rgb_from_thermal else {
        return;
    };
    let (axis, angle) = t.rotation.to_axis_angle();
    let sigma = c.extrinsic_sigma;
    let mut rows = vec![vec![
        "rotation angle".into(),
        format!(
            "{:.4}° about ({:.3}, {:.3}, {:.3})",
            angle.to_degrees(),
            axis.x,
            axis.y,
            axis.z
        )
        .into(),
        sigma
            .map_or_else(
                || "–".to_string(),
                |s| {
                    format!(
                        "({:.4}, {:.4}, {:.4})°",
                        s.rotation_deg[0], s.rotation_deg[1], s.rotation_deg[2]
                    )
                },
            )
            .into(),
    ]];
    for (k, axis_name) in ["x", "y", "z"].iter().enumerate() {
        rows.push(vec![
            format!("translation {axis_name}").into(),
            format!("{:.5} m", t.translation_m[k]).into(),
            sigma
                .map_or_else(
                    || "–".to_string(),
                    |s| format!("{:.5} m", s.translation_m[k]),
                )
                .into(),
        ]);
    }
    page.push(Block::heading("Extrinsic rgb_from_thermal", "extrinsic"));
    page.push(Block::Table {
        columns: vec![
            Column::text("quantity"),
            Column::number("value"),
            Column::number("1σ"),
        ],
        rows,
    });
}

/// How many thermal–RGB pairs the extrinsic used, and why the others were left out.
fn pair_consistency(page: &mut Page, c: &Calibration) {
    page.push(Block::heading("Pair consistency", "pairs"));
    page.push(Block::paragraph(format!(
        "{} pairs found, {} used for the extrinsic, {} left out (thresholds: {:?}; see `pairs` in the crate docs).",
        c.pairs_found,
        c.pairs_used,
        c.pairs_inconsistent.len(),
        c.pair_thresholds
    )));
    if !c.pairs_inconsistent.is_empty() {
        page.push(Block::List {
            items: c.pairs_inconsistent.iter().map(|p| p.describe()).collect(),
            warn: false,
        });
    }
}

/// Warnings, files not used and rejected corners: what the result did not take in.
fn left_out(page: &mut Page, c: &Calibration) {
    page.push(Block::heading("Warnings", "warnings"));
    page.push(Block::List {
        items: c.warnings.clone(),
        warn: true,
    });
    page.push(Block::heading("Files not used", "bad-input"));
    page.push(Block::Table {
        columns: vec![Column::text("file"), Column::text("reason")],
        rows: c
            .problems
            .iter()
            .map(|p| {
                vec![
                    Cell::code(p.path.display().to_string()),
                    p.reason.clone().into(),
                ]
            })
            .collect(),
    });
    page.push(Block::heading("Rejected corners (k·σ test)", "rejected"));
    page.push(Block::Table {
        columns: vec![
            Column::text("camera"),
            Column::text("view"),
            Column::number("corner"),
            Column::number("residual px"),
        ],
        rows: c
            .rejected
            .iter()
            .map(|r| {
                vec![
                    r.camera.name().into(),
                    Cell::code(c.view_keys.get(r.view).map_or("?", String::as_str)),
                    r.corner.to_string().into(),
                    format!("{:.3}", r.residual_px).into(),
                ]
            })
            .collect(),
    });
}

/// Per camera, the RMS, corners and board tilt of every view used.
fn per_view(page: &mut Page, c: &Calibration) {
    for r in c.cameras.iter().flatten() {
        let name = r.camera.name();
        page.push(Block::heading(
            format!("{name}: RMS per view"),
            format!("per-view-{name}"),
        ));
        page.push(Block::Table {
            columns: vec![
                Column::text("view"),
                Column::number("RMS px"),
                Column::number("corners"),
                Column::number("tilt °"),
            ],
            rows: r
                .per_view
                .iter()
                .map(|v| {
                    vec![
                        Cell::code(v.key.as_str()),
                        format!("{:.4}", v.rms_px).into(),
                        v.corners_used.to_string().into(),
                        format!("{:.1}", v.tilt_deg).into(),
                    ]
                })
                .collect(),
        });
    }
}

/// The solver's iterations: `iteration,wall_s,rms_px,lambda`.
fn iterations_csv(c: &Calibration) -> String {
    let mut csv = String::from("iteration,wall_s,rms_px,lambda\n");
    for i in &c.iterations {
        let _ = writeln!(
            csv,
            "{},{:.6},{:.6},{:.3e}",
            i.iteration, i.wall_s, i.rms_px, i.lambda
        );
    }
    csv
}
