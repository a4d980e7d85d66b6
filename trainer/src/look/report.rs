//! The run report: `RUN/report.html` (one self-contained page, figures embedded, readable on a
//! phone) and `RUN/report.md`, with the figures in `RUN/report/`. Written at the end of every
//! training run and again by `s3tir-train report RUN`; drawn only from the run folder's files
//! and the dataset's recorded frames, so an older run gets one too.
//!
//! Sections: the run (data, mode, backend, budget, seed, primitives); the held-out figures
//! (PSNR, SSIM, LPIPS where its weights are installed, kelvin error, raw and aligned); each
//! held-out view as recorded | rendered | error (ironbow over the recorded frame's 1st–99th
//! percentile, the error in the diverging palette symmetric about 0; colour bars in kelvin and
//! °C for radiometric data, in the dataset's normalised unit otherwise, said so); super-resolved
//! views next to bicubic (joint runs); error against training time; the G-buffers of the first
//! views (Ψ_low, Ψ_high, β, depth, each with its bar); β's histogram; density and band rounds;
//! the per-view response; the run's notes.

use std::path::{Path, PathBuf};

use s3tir_calib::model::palette::Colormap;
use s3tir_calib::report::page::{Block, Cell, Column, Page};
use serde::de::DeserializeOwned;

use super::LookError;
use super::figure::{Panel, draw_row};
use super::image::{DisplayUnits, Scale};
use crate::dataset::Dataset;
use crate::metrics::EvalSummary;
use crate::report::read_npy_f32;
use crate::train::{CapacityReport, TrainConfig, files, load_config, output_stem};

/// Held-out views drawn in full (the table lists every view).
pub const MAX_VIEWS: usize = 24;
/// Views whose G-buffers are drawn.
pub const GBUFFER_VIEWS: usize = 2;
/// The quantile cut at each end of a temperature scale (robust to a few hot pixels).
const SCALE_Q: f64 = 0.01;

/// What [`write_run_report`] wrote.
#[derive(Debug, Clone)]
pub struct ReportWritten {
    pub html: PathBuf,
    pub markdown: PathBuf,
    /// Held-out views drawn recorded | rendered | error.
    pub views_drawn: usize,
    /// What the report could not show, and why (also on the page).
    pub missing: Vec<String>,
}

/// Writes `RUN/report.html`, `RUN/report.md` and `RUN/report/*.png` for the run folder
/// `run_dir` (its `config.json`, `eval.json`, renders and G-buffers, and its dataset's recorded
/// frames); `on_view(done, total)` after each held-out view is drawn.
pub fn write_run_report(
    run_dir: &Path,
    on_view: &mut dyn FnMut(usize, usize),
) -> Result<ReportWritten, LookError> {
    let cfg = load_config(run_dir)?;
    let data = Dataset::load(&cfg.data, &cfg.load).map_err(|e| {
        format!(
            "recorded frames not shown: the dataset {} does not load ({e})",
            cfg.data.display()
        )
    });
    write_report_for(run_dir, &cfg, data.as_ref().map_err(Clone::clone), on_view)
}

/// [`write_run_report`] with the run's configuration and dataset at hand (the end of a
/// training run); `data` is the dataset, or why it is not there (the page says so).
pub fn write_report_for(
    run_dir: &Path,
    cfg: &TrainConfig,
    data: Result<&Dataset, String>,
    on_view: &mut dyn FnMut(usize, usize),
) -> Result<ReportWritten, LookError> {
    let eval: EvalSummary = read_json(&run_dir.join(files::EVAL))?;
    let capacity: Option<CapacityReport> = read_json(&run_dir.join(files::CAPACITY)).ok();
    let fig_dir = run_dir.join(files::REPORT_DIR);
    std::fs::create_dir_all(&fig_dir).map_err(|source| LookError::Io {
        path: fig_dir.clone(),
        source,
    })?;
    let mut missing = Vec::new();
    let data = match data {
        Ok(d) => Some(d),
        Err(why) => {
            missing.push(why);
            None
        }
    };
    let units = DisplayUnits {
        range: data.and_then(|d| d.range),
    };
    let run_name = run_dir
        .canonicalize()
        .unwrap_or_else(|_| run_dir.to_path_buf())
        .file_name()
        .map_or_else(|| "run".to_string(), |n| n.to_string_lossy().into_owned());
    let mut page = Page::new(&format!("s3tir run report: {run_name}"));

    page.push(Block::heading("Run", "run"));
    page.push(settings_table(cfg, capacity.as_ref(), data));

    page.push(Block::heading("Held-out figures", "figures"));
    page.push(Block::paragraph(format!(
        "Mean over {} held-out views. Raw: the render as it is; aligned: under each view's \
         fitted affine map (PSNR) or median offset (kelvin MAE), which forgives a camera's \
         per-frame gain and offset. LPIPS: AlexNet v0.1 over the dataset's normalised range{}.",
        eval.views.len(),
        if eval.lpips.is_some() {
            ""
        } else {
            " (not measured: the LPIPS weights are not installed, scripts/install-deps.sh)"
        }
    )));
    page.push(figures_table(&eval));

    page.push(Block::heading("Held-out views", "views"));
    page.push(Block::paragraph(if units.radiometric() {
        "Recorded | rendered in the ironbow palette over the recorded frame's 1st–99th \
         percentile, colour bars in kelvin and °C; error = rendered − recorded in the diverging \
         palette (blue: rendered too cold, red: too warm), symmetric about 0 K."
            .to_string()
    } else {
        "Recorded | rendered in the ironbow palette over the recorded frame's 1st–99th \
         percentile; error = rendered − recorded in the diverging palette (blue: too cold, red: \
         too warm). The dataset is not radiometric: values are in its normalised unit (0 and 1 \
         are the coldest and hottest raw values of the dataset), not kelvin."
            .to_string()
    }));
    let mut drawn = 0;
    if let Some(data) = data {
        let thermal: Vec<usize> = data
            .test
            .iter()
            .copied()
            .filter(|&i| data.views[i].thermal.is_some())
            .collect();
        if thermal.len() > MAX_VIEWS {
            missing.push(format!(
                "{} of {} held-out views drawn (the table lists all)",
                MAX_VIEWS,
                thermal.len()
            ));
        }
        let total = thermal.len().min(MAX_VIEWS);
        for &i in thermal.iter().take(MAX_VIEWS) {
            let v = &data.views[i];
            let stem = output_stem(&v.name, i);
            let render_path = run_dir.join(files::RENDERS).join(format!("{stem}.png"));
            let Some(recorded) = &v.thermal else {
                continue;
            };
            let (rw, rh, rendered) = match read_render(&render_path, &units) {
                Ok(r) => r,
                Err(e) => {
                    missing.push(format!("{}: render not shown ({e})", v.name));
                    continue;
                }
            };
            let (w, h) = (v.camera.width, v.camera.height);
            if (rw, rh) != (w, h) {
                missing.push(format!(
                    "{}: render is {rw}×{rh}, the view {w}×{h} (from another dataset?)",
                    render_path.display()
                ));
                continue;
            }
            let rec: Vec<f32> = recorded.iter().map(|&x| units.value(x)).collect();
            let err: Vec<f32> = rendered.iter().zip(&rec).map(|(&r, &x)| r - x).collect();
            let scale = Scale::robust(Colormap::Ironbow, &rec, SCALE_Q, units.unit());
            let panels = [
                panel("recorded", rec, w, h, scale.clone()),
                panel("rendered", rendered, w, h, scale),
                panel(
                    "rendered − recorded",
                    err.clone(),
                    w,
                    h,
                    Scale::symmetric(Colormap::Diverging, &err, SCALE_Q, units.error_unit()),
                ),
            ];
            let file = format!("{}/view_{stem}.png", files::REPORT_DIR);
            draw_row(&run_dir.join(&file), &panels)?;
            page.push(Block::Figure {
                file,
                caption: view_caption(&v.name, &eval),
            });
            sr_figure(run_dir, &stem, recorded, w, h, &units, &mut page)?;
            drawn += 1;
            on_view(drawn, total);
        }
    }
    if drawn == 0 {
        page.push(Block::paragraph(
            "No held-out thermal view drawn (see below).",
        ));
    }

    page.push(Block::heading("Error against training time", "time"));
    push_existing_figure(
        &mut page,
        run_dir,
        files::METRICS_PNG,
        "held-out error at each evaluation against training wall time (metrics.csv)",
        &mut missing,
    );

    page.push(Block::heading("G-buffers", "gbuffers"));
    page.push(Block::paragraph(
        "What the primitives carry, per pixel: Ψ_low (the Gaussian part of the temperature), \
         Ψ_high (the spectral bands' part, signed), β (the primitives' shape exponent, 2 = \
         Gaussian; normalised by coverage) and depth (expected, scene units). Black: no \
         coverage.",
    ));
    if let Some(data) = data {
        for &i in data.test.iter().take(GBUFFER_VIEWS) {
            let stem = output_stem(&data.views[i].name, i);
            match gbuffer_panels(run_dir, &stem, &units) {
                Ok(panels) => {
                    let file = format!("{}/gbuffers_{stem}.png", files::REPORT_DIR);
                    draw_row(&run_dir.join(&file), &panels)?;
                    page.push(Block::Figure {
                        file,
                        caption: format!("G-buffers of {}", data.views[i].name),
                    });
                }
                Err(e) => missing.push(format!("G-buffers of {stem} not shown ({e})")),
            }
        }
    }
    push_existing_figure(
        &mut page,
        run_dir,
        files::BETA_HIST,
        "β of every primitive (log scale; β = 2 is the Gaussian)",
        &mut missing,
    );

    if let Some(cap) = &capacity {
        capacity_sections(&mut page, cap);
    }
    page.push(Block::heading("Not shown", "missing"));
    page.push(Block::List {
        items: missing.clone(),
        warn: true,
    });

    let md_path = run_dir.join(files::REPORT_MD);
    let html_path = run_dir.join(files::REPORT_HTML);
    let html = page.html(run_dir).map_err(|e| LookError::Io {
        path: e.path,
        source: e.source,
    })?;
    write_text(&md_path, &page.markdown())?;
    write_text(&html_path, &html)?;
    Ok(ReportWritten {
        html: html_path,
        markdown: md_path,
        views_drawn: drawn,
        missing,
    })
}

fn panel(title: &str, plane: Vec<f32>, width: usize, height: usize, scale: Scale) -> Panel {
    Panel {
        title: title.to_string(),
        plane,
        width,
        height,
        scale,
    }
}

fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, LookError> {
    let text = std::fs::read_to_string(path).map_err(|source| LookError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| LookError::Format {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

fn write_text(path: &Path, text: &str) -> Result<(), LookError> {
    std::fs::write(path, text).map_err(|source| LookError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// A 16-bit render in the shown unit: (width, height, values).
fn read_render(path: &Path, units: &DisplayUnits) -> Result<(usize, usize, Vec<f32>), LookError> {
    let img = ::image::open(path)
        .map_err(|e| LookError::Format {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?
        .into_luma16();
    let values = img
        .as_raw()
        .iter()
        .map(|&w| units.value_of_raw(w))
        .collect();
    Ok((img.width() as usize, img.height() as usize, values))
}

fn settings_table(
    cfg: &TrainConfig,
    cap: Option<&CapacityReport>,
    data: Option<&Dataset>,
) -> Block {
    let mut rows: Vec<Vec<Cell>> = vec![
        vec!["data".into(), Cell::code(cfg.data.display().to_string())],
        vec!["mode".into(), Cell::code(cfg.mode.to_string())],
        vec!["backend".into(), Cell::code(cfg.backend.as_str())],
        vec![
            "budget".into(),
            match cfg.time_budget_s {
                Some(s) => format!("{s:.0} s of training time").into(),
                None => format!("{} iterations", cfg.iters).into(),
            },
        ],
        vec!["seed".into(), cfg.seed.to_string().into()],
    ];
    if let Some(d) = data {
        rows.push(vec![
            "views".into(),
            format!("{} training, {} held out", d.train.len(), d.test.len()).into(),
        ]);
        rows.push(vec![
            "thermal values".into(),
            match &d.range {
                Some(r) if r.radiometric() => format!(
                    "radiometric: {:.2}–{:.2} K over the dataset",
                    r.min_raw / 100.0,
                    r.max_raw / 100.0
                )
                .into(),
                Some(_) => "not radiometric (normalised units)".into(),
                None => "no thermal images".into(),
            },
        ]);
    }
    if let Some(c) = cap {
        rows.push(vec!["primitives".into(), c.primitives.to_string().into()]);
        rows.push(vec![
            "bands".into(),
            format!(
                "{} → {} per primitive, {} primitives hold bands, {} on the Gaussian path",
                c.bands_initial, c.bands_now, c.band_holders, c.gaussian_path_primitives
            )
            .into(),
        ]);
    }
    Block::Table {
        columns: vec![Column::text("setting"), Column::text("value")],
        rows,
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "—".to_string(), |x| format!("{x:.digits$}"))
}

fn figures_table(eval: &EvalSummary) -> Block {
    let columns = vec![
        Column::text("view"),
        Column::number("PSNR dB"),
        Column::number("aligned dB"),
        Column::number("SSIM"),
        Column::number("LPIPS"),
        Column::number("MAE K"),
        Column::number("aligned MAE K"),
    ];
    let mut rows = vec![vec![
        "mean".into(),
        format!("{:.2}", eval.psnr).into(),
        opt(eval.psnr_aligned, 2).into(),
        format!("{:.4}", eval.ssim).into(),
        opt(eval.lpips, 4).into(),
        opt(eval.kelvin_mae, 3).into(),
        opt(eval.kelvin_mae_aligned, 3).into(),
    ]];
    for v in &eval.views {
        rows.push(vec![
            Cell::code(v.name.clone()),
            format!("{:.2}", v.psnr).into(),
            opt(v.psnr_aligned, 2).into(),
            format!("{:.4}", v.ssim).into(),
            opt(v.lpips, 4).into(),
            opt(v.kelvin_mae, 3).into(),
            opt(v.kelvin_mae_aligned, 3).into(),
        ]);
    }
    Block::Table { columns, rows }
}

fn view_caption(name: &str, eval: &EvalSummary) -> String {
    match eval.views.iter().find(|v| v.name == name) {
        Some(v) => {
            let mut s = format!("{name}: PSNR {:.2} dB, SSIM {:.3}", v.psnr, v.ssim);
            if let Some(l) = v.lpips {
                s += &format!(", LPIPS {l:.3}");
            }
            if let Some(k) = v.kelvin_mae {
                s += &format!(", MAE {k:.2} K");
            }
            s
        }
        None => name.to_string(),
    }
}

/// Adds `file` (relative to the run) as a figure when it exists, else says it is missing.
fn push_existing_figure(
    page: &mut Page,
    run_dir: &Path,
    file: &str,
    caption: &str,
    missing: &mut Vec<String>,
) {
    if run_dir.join(file).is_file() {
        page.push(Block::Figure {
            file: file.to_string(),
            caption: caption.to_string(),
        });
    } else {
        missing.push(format!("{file} not found in the run folder"));
    }
}

/// Ψ_low, Ψ_high, β and depth of one view from its `.npy` G-buffers (no coverage: NaN, drawn
/// in the coldest colour).
fn gbuffer_panels(
    run_dir: &Path,
    stem: &str,
    units: &DisplayUnits,
) -> Result<Vec<Panel>, LookError> {
    let dir = run_dir.join(files::GBUFFERS);
    let read = |name: &str| read_npy_f32(&dir.join(format!("{stem}_{name}.npy")));
    let (w, h, alpha) = read("alpha")?;
    let covered = |plane: Vec<f32>, f: &dyn Fn(f32) -> f32| -> Vec<f32> {
        plane
            .into_iter()
            .zip(&alpha)
            .map(|(v, &a)| if a > 1e-3 { f(v) } else { f32::NAN })
            .collect()
    };
    let low = covered(read("psi_low")?.2, &|v| units.value(v));
    let high = covered(read("psi_high")?.2, &|v| units.difference(v));
    let beta = covered(read("psi_beta")?.2, &|v| v);
    let depth = covered(read("depth")?.2, &|v| v);
    let beta_hi = super::image::quantile(&beta, 1.0 - SCALE_Q)
        .unwrap_or(3.0)
        .max(3.0);
    Ok(vec![
        panel(
            "Ψ_low",
            low.clone(),
            w,
            h,
            Scale::robust(Colormap::Ironbow, &low, SCALE_Q, units.unit()),
        ),
        panel(
            "Ψ_high",
            high.clone(),
            w,
            h,
            Scale::symmetric(Colormap::Diverging, &high, SCALE_Q, units.error_unit()),
        ),
        panel(
            "β",
            beta,
            w,
            h,
            Scale::new(Colormap::Inferno, 2.0, beta_hi, "β"),
        ),
        panel(
            "depth",
            depth.clone(),
            w,
            h,
            Scale::robust(Colormap::Grey, &depth, SCALE_Q, "scene units"),
        ),
    ])
}

/// Joint runs with `--sr-scale`: the recorded frame upsampled bicubically | the super-resolved
/// render | the render fused with the recorded frame, all at the SR size in one scale.
fn sr_figure(
    run_dir: &Path,
    stem: &str,
    recorded: &[f32],
    w: usize,
    h: usize,
    units: &DisplayUnits,
    page: &mut Page,
) -> Result<(), LookError> {
    let sr_path = run_dir.join(files::RENDERS_SR).join(format!("{stem}.png"));
    if !sr_path.is_file() {
        return Ok(());
    }
    let (sw, sh, sr) = read_render(&sr_path, units)?;
    let rec: Vec<f32> = recorded.iter().map(|&x| units.value(x)).collect();
    let buf = ::image::ImageBuffer::<::image::Luma<f32>, Vec<f32>>::from_raw(
        w as u32,
        h as u32,
        rec.clone(),
    )
    .ok_or_else(|| LookError::Format {
        path: sr_path.clone(),
        reason: format!("recorded frame is not {w}×{h}"),
    })?;
    let bicubic = ::image::imageops::resize(
        &buf,
        sw as u32,
        sh as u32,
        ::image::imageops::FilterType::CatmullRom,
    )
    .into_raw();
    let scale = Scale::robust(Colormap::Ironbow, &rec, SCALE_Q, units.unit());
    let mut panels = vec![
        panel("recorded, bicubic", bicubic, sw, sh, scale.clone()),
        panel("super-resolved render", sr, sw, sh, scale.clone()),
    ];
    let fused_path = run_dir
        .join(files::RENDERS_SR_FUSED)
        .join(format!("{stem}.png"));
    if fused_path.is_file() {
        panels.push(panel(
            "fused with the recorded frame",
            read_render(&fused_path, units)?.2,
            sw,
            sh,
            scale,
        ));
    }
    let file = format!("{}/sr_{stem}.png", files::REPORT_DIR);
    draw_row(&run_dir.join(&file), &panels)?;
    page.push(Block::Figure {
        file,
        caption: format!("{stem} super-resolved {}×{sh} from {w}×{h}", sw),
    });
    Ok(())
}

fn capacity_sections(page: &mut Page, cap: &CapacityReport) {
    page.push(Block::heading("Density control", "density"));
    page.push(Block::Table {
        columns: vec![
            Column::number("iteration"),
            Column::number("seconds"),
            Column::number("before"),
            Column::number("after"),
            Column::number("cloned"),
            Column::number("split"),
            Column::number("pruned"),
            Column::number("left out (budget)"),
        ],
        rows: cap
            .densify_rounds
            .iter()
            .map(|r| {
                vec![
                    r.iteration.to_string().into(),
                    format!("{:.0}", r.seconds).into(),
                    r.before.to_string().into(),
                    r.after.to_string().into(),
                    r.cloned.to_string().into(),
                    r.split.to_string().into(),
                    r.pruned.to_string().into(),
                    r.over_budget.to_string().into(),
                ]
            })
            .collect(),
    });
    page.push(Block::heading("Bands", "bands"));
    page.push(Block::paragraph(format!(
        "{} primitives hold bands at the end ({} per primitive, {} at the start); consistency: {}.",
        cap.band_holders, cap.bands_now, cap.bands_initial, cap.consistency_reason
    )));
    page.push(Block::Table {
        columns: vec![
            Column::text("round"),
            Column::number("iteration"),
            Column::number("holders before"),
            Column::number("after"),
            Column::number("over λ"),
            Column::number("bands dropped"),
        ],
        rows: cap
            .band_rounds
            .iter()
            .map(|r| {
                vec![
                    format!("{:?}", r.kind).to_lowercase().into(),
                    r.iteration.to_string().into(),
                    r.holders_before.to_string().into(),
                    r.holders_after.to_string().into(),
                    r.over_threshold.to_string().into(),
                    r.bands_dropped.to_string().into(),
                ]
            })
            .collect(),
    });
    if let Some(resp) = &cap.response {
        page.push(Block::heading("Per-view response", "response"));
        page.push(Block::paragraph(format!("{}: {}", resp.kind, resp.reason)));
        page.push(Block::Table {
            columns: vec![
                Column::text("view"),
                Column::number("gain"),
                Column::number("offset"),
                Column::number("offset K"),
            ],
            rows: resp
                .views
                .iter()
                .map(|v| {
                    vec![
                        Cell::code(v.name.clone()),
                        format!("{:.4}", v.gain).into(),
                        format!("{:+.4}", v.offset).into(),
                        opt(v.offset_kelvin, 3).into(),
                    ]
                })
                .collect(),
        });
    }
    page.push(Block::heading("Notes", "notes"));
    page.push(Block::List {
        items: cap.notes.clone(),
        warn: false,
    });
}
