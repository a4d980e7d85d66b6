//! Evaluation rows, the run's outputs (PLY, renders — 16-bit, each with its readable ironbow
//! copy `{stem}_ironbow.png` —, G-buffers, plots, eval and capacity JSON) and the evaluation of
//! a finished run.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::joint::composite_background;
use super::{Backend, TrainConfig, TrainError, Trainer, files, io_err};
use crate::checkpoint;
use crate::dataset::Dataset;
use crate::look::image::DisplayUnits;
use crate::metrics::{EvalSummary, rgb_metrics, view_metrics};
use crate::primitive::beta_of_raw;
use crate::report::{self, MetricsRow};

impl<B: Backend> Trainer<B> {
    /// Renders the held-out views (all training views if there are none) and measures them.
    pub fn evaluate(&mut self) -> Result<EvalSummary, TrainError> {
        self.evaluate_with(&mut |_, _| {})
    }

    /// [`Trainer::evaluate`], reporting `(views done, views to do)` after each view (the
    /// binaries draw it).
    pub fn evaluate_with(
        &mut self,
        on_view: &mut dyn FnMut(usize, usize),
    ) -> Result<EvalSummary, TrainError> {
        self.sync_host()?;
        let ids = if self.data.test.is_empty() {
            self.data.train.clone()
        } else {
            self.data.test.clone()
        };
        let total = ids.len();
        let mut out = Vec::new();
        let mut rgb = Vec::new();
        for (done, i) in ids.into_iter().enumerate() {
            on_view(done, total);
            let v = &self.data.views[i];
            match (&v.thermal, &v.rgb) {
                (Some(target), _) => {
                    let gb = self.backend.render(&self.prims, &v.camera)?;
                    let mut m = view_metrics(
                        &v.name,
                        &gb.thermal,
                        target,
                        gb.width,
                        gb.height,
                        self.data.range.as_ref(),
                    );
                    m.lpips = crate::lpips::installed().and_then(|l| {
                        self.frame_features.plane_lpips(
                            l,
                            i,
                            &gb.thermal,
                            target,
                            (gb.width, gb.height),
                        )
                    });
                    out.push(m);
                }
                (None, Some(target)) if !self.prims.sh.is_empty() => {
                    let gb = self.backend.render(&self.prims, &v.camera)?;
                    let shown = composite_background(&gb.rgb, &gb.alpha, self.rgb_background());
                    rgb.push(rgb_metrics(&shown, target, gb.width, gb.height));
                }
                (None, _) => {}
            }
        }
        on_view(total, total);
        let mut e = EvalSummary::from_views(out);
        if !rgb.is_empty() {
            let n = rgb.len() as f64;
            e.rgb_psnr = Some(rgb.iter().map(|r| r.0).sum::<f64>() / n);
            e.rgb_ssim = Some(rgb.iter().map(|r| r.1).sum::<f64>() / n);
        }
        Ok(e)
    }

    pub(super) fn eval_row(&mut self) -> Result<MetricsRow, TrainError> {
        let e = self.evaluate()?;
        let loss = if self.state.loss_count > 0 {
            self.state.loss_sum / self.state.loss_count as f64
        } else {
            f64::NAN
        };
        self.state.loss_sum = 0.0;
        self.state.loss_count = 0;
        let row = MetricsRow {
            iteration: self.iteration,
            seconds: self.train_seconds,
            loss,
            psnr: e.psnr,
            ssim: e.ssim,
            kelvin_mae: e.kelvin_mae,
            kelvin_rmse: e.kelvin_rmse,
            primitives: self.prims.len(),
            memory_bytes: self.memory_bytes(),
            psnr_aligned: e.psnr_aligned,
            kelvin_mae_aligned: e.kelvin_mae_aligned,
            lpips: e.lpips,
        };
        report::append_row(&self.run_dir.join(files::METRICS_CSV), &row)?;
        self.state.last_eval_s = self.train_seconds;
        Ok(row)
    }

    /// PLY, renders and G-buffers of the test views, β histogram, plots, eval and capacity JSON.
    pub fn write_outputs(&mut self) -> Result<(), TrainError> {
        self.sync_host()?;
        let dir = self.run_dir.clone();
        crate::ply::write_ply(&dir.join(files::PLY), &self.prims)?;
        let renders = dir.join(files::RENDERS);
        let gbuf = dir.join(files::GBUFFERS);
        std::fs::create_dir_all(&renders).map_err(io_err(&renders))?;
        std::fs::create_dir_all(&gbuf).map_err(io_err(&gbuf))?;
        let sr = self.sr_scale();
        let renders_sr = dir.join(files::RENDERS_SR);
        let renders_fused = dir.join(files::RENDERS_SR_FUSED);
        if sr.is_some() {
            std::fs::create_dir_all(&renders_sr).map_err(io_err(&renders_sr))?;
            std::fs::create_dir_all(&renders_fused).map_err(io_err(&renders_fused))?;
        }
        let mut sr_scores = Vec::new();
        for &i in &self.data.test {
            let v = &self.data.views[i];
            let gb = self.backend.render(&self.prims, &v.camera)?;
            let stem = output_stem(&v.name, i);
            match (&v.rgb, &self.data.range) {
                (Some(_), _) if !gb.rgb.is_empty() => report::write_rgb_png(
                    &renders.join(format!("{stem}.png")),
                    &composite_background(&gb.rgb, &gb.alpha, self.rgb_background()),
                    gb.width,
                    gb.height,
                )?,
                (None, Some(range)) => {
                    let shown = DisplayUnits {
                        range: Some(*range),
                    };
                    report::write_thermal_png16(
                        &renders.join(format!("{stem}.png")),
                        &gb.thermal,
                        gb.width,
                        gb.height,
                        range,
                    )?;
                    shown
                        .write_ironbow_copy(
                            &renders,
                            &stem,
                            &gb.thermal,
                            (gb.width, gb.height),
                            v.thermal.as_deref(),
                        )
                        .map_err(look_err)?;
                    if let Some(k) = sr {
                        let gk = self.backend.render(&self.prims, &v.camera.scaled(k))?;
                        if let Some(recorded) = &v.thermal {
                            let down = crate::superres::box_downsample(
                                &gk.thermal,
                                gb.width,
                                gb.height,
                                k,
                            );
                            sr_scores.push((
                                crate::metrics::psnr(&down, recorded),
                                crate::metrics::ssim(&down, recorded, gb.width, gb.height),
                            ));
                        }
                        report::write_thermal_png16(
                            &renders_sr.join(format!("{stem}.png")),
                            &gk.thermal,
                            gk.width,
                            gk.height,
                            range,
                        )?;
                        shown
                            .write_ironbow_copy(
                                &renders_sr,
                                &stem,
                                &gk.thermal,
                                (gk.width, gk.height),
                                v.thermal.as_deref(),
                            )
                            .map_err(look_err)?;
                        if let Some(recorded) = &v.thermal {
                            let fused = crate::superres::back_project(
                                &gk.thermal,
                                recorded,
                                gb.width,
                                gb.height,
                                k,
                            );
                            report::write_thermal_png16(
                                &renders_fused.join(format!("{stem}.png")),
                                &fused,
                                gk.width,
                                gk.height,
                                range,
                            )?;
                            shown
                                .write_ironbow_copy(
                                    &renders_fused,
                                    &stem,
                                    &fused,
                                    (gk.width, gk.height),
                                    Some(recorded.as_slice()),
                                )
                                .map_err(look_err)?;
                        }
                    }
                }
                _ => {}
            }
            report::write_gbuffers(&gbuf, &stem, &gb)?;
        }
        let betas: Vec<f64> = self
            .prims
            .beta_raw
            .iter()
            .map(|&r| beta_of_raw(f64::from(r)).0)
            .collect();
        report::plot_beta_histogram(&dir.join(files::BETA_HIST), &betas)?;
        let rows = report::read_rows(&dir.join(files::METRICS_CSV))?;
        report::plot_runs(
            &dir.join(files::METRICS_PNG),
            &[(self.cfg.mode.to_string(), rows)],
        )?;
        let mut eval = self.evaluate()?;
        if let (Some(scale), false) = (sr, sr_scores.is_empty()) {
            let n = sr_scores.len() as f64;
            eval.sr_consistency = Some(crate::metrics::SrConsistency {
                scale,
                psnr: sr_scores.iter().map(|s| s.0).sum::<f64>() / n,
                ssim: sr_scores.iter().map(|s| s.1).sum::<f64>() / n,
            });
        }
        write_json(&dir.join(files::EVAL), &eval)?;
        if let Some(bg) = &self.state.background {
            write_json(
                &dir.join(files::BACKGROUND),
                &BackgroundFile {
                    rgb_background: bg.colour,
                },
            )?;
        }
        let mut cap = self.capacity_report();
        if self.cfg.cpu_timing
            && let Some((with, general)) = self.cpu_shortcut_timing()?
        {
            cap.cpu_step_ms_with_shortcuts = Some(with);
            cap.cpu_step_ms_general_path = Some(general);
        }
        write_json(&dir.join(files::CAPACITY), &cap)?;
        Ok(())
    }
}

/// A palette copy that could not be written (as the G-buffers' palette PNGs report it).
fn look_err(e: crate::look::image::ImageError) -> TrainError {
    TrainError::from(report::ReportError::Palette(Box::new(e)))
}

/// The file stem of a view's outputs: its image name without the extension, folders joined
/// by `_` (a joint dataset's `thermal/0008.png` and `rgb/0008.png` must not collide).
pub fn output_stem(name: &str, index: usize) -> String {
    let p = Path::new(name);
    let stem = p.with_extension("");
    let s = stem
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("_");
    if s.is_empty() {
        format!("view{index}")
    } else {
        s
    }
}

pub(super) fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<(), TrainError> {
    let s = serde_json::to_string_pretty(v).map_err(|source| TrainError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    std::fs::write(path, s).map_err(io_err(path))
}

/// `RUN_DIR/rgb_background.json`: the background colour the RGB views are composited over
/// (runs with RGB views).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BackgroundFile {
    /// Per channel, in the images' units ([0, 1]).
    pub rgb_background: [f64; 3],
}

/// The RGB background colour a finished run wrote (black when it wrote none).
pub fn read_background(run_dir: &Path) -> Result<[f32; 3], TrainError> {
    let path = run_dir.join(files::BACKGROUND);
    if !path.exists() {
        return Ok([0.0; 3]);
    }
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let f: BackgroundFile = serde_json::from_str(&text).map_err(|source| TrainError::Json {
        path: path.clone(),
        source,
    })?;
    Ok(f.rgb_background.map(|c| c as f32))
}

/// Held-out evaluation of a finished (or checkpointed) run, as `s3tir-train eval` prints it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunEval {
    pub run_dir: PathBuf,
    pub mode: String,
    pub primitives: usize,
    /// The metrics, raw and aligned, per view and mean (flattened into the JSON: `psnr`,
    /// `kelvin_mae` (`null` when the data are not radiometric), `psnr_aligned`, `views`, …).
    #[serde(flatten)]
    pub eval: EvalSummary,
}

/// Reads `RUN_DIR/config.json`.
pub fn load_config(run_dir: &Path) -> Result<TrainConfig, TrainError> {
    let path = run_dir.join(files::CONFIG);
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    serde_json::from_str(&text).map_err(|source| TrainError::Json { path, source })
}

/// Evaluates the run's primitives (its PLY, or its checkpoint when there is no PLY yet) on the
/// held-out views of its dataset.
pub fn evaluate_run<B: Backend>(run_dir: &Path, backend: B) -> Result<RunEval, TrainError> {
    evaluate_run_with(run_dir, backend, &mut |_, _| {})
}

/// [`evaluate_run`], reporting `(views done, views to do)` as it goes.
pub fn evaluate_run_with<B: Backend>(
    run_dir: &Path,
    backend: B,
    on_view: &mut dyn FnMut(usize, usize),
) -> Result<RunEval, TrainError> {
    let cfg = load_config(run_dir)?;
    let data = Dataset::load(&cfg.data, &cfg.load)?;
    let ply = run_dir.join(files::PLY);
    let prims = if ply.exists() {
        crate::ply::read_ply(&ply)?
    } else {
        checkpoint::load(&run_dir.join(files::CHECKPOINT))?.primitives
    };
    let mode = cfg.mode.to_string();
    let mut t = Trainer::bare(cfg, data, backend, run_dir);
    t.prims = prims;
    let bg = read_background(run_dir)?;
    t.state.background = Some(super::joint::Background::fixed(bg.map(f64::from)));
    let e = t.evaluate_with(on_view)?;
    Ok(RunEval {
        run_dir: run_dir.to_path_buf(),
        mode,
        primitives: t.prims.len(),
        eval: e,
    })
}
