//! The TGA-GS ablation (paper Tables 3/4) on a dataset with truth: four runs of one base
//! configuration — thermal-only, joint, joint without the thermal gradient alignment loss,
//! joint without RGB pre-training — each scored by [`crate::truth::score`], as a table. When
//! the dataset holds a truth surface (`truth/surface.ply`), each model is also meshed
//! ([`crate::mesh`], default options) through the same cameras — every training camera of
//! both image sets, whatever the variant trained on, so the meshes differ only by their
//! geometry — and the mesh scored against it (Chamfer distance, F-score, vertex kelvin MAE).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::dataset::{Dataset, LoadOptions, Modality};
use crate::mesh::run::{MeshOptions, TRUTH_SURFACE, mesh_views};
use crate::mesh::score::{MeshScore, score as score_mesh};
use crate::train::{Backend, Event, TrainConfig, TrainError};
use crate::truth::{TruthScore, score};

/// One configuration of the ablation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    ThermalOnly,
    Joint,
    JointNoAlign,
    JointNoPretrain,
}

impl Variant {
    pub const ALL: [Variant; 4] = [
        Variant::ThermalOnly,
        Variant::Joint,
        Variant::JointNoAlign,
        Variant::JointNoPretrain,
    ];

    /// Folder name of the variant's run.
    pub fn slug(self) -> &'static str {
        match self {
            Variant::ThermalOnly => "thermal-only",
            Variant::Joint => "joint",
            Variant::JointNoAlign => "joint-no-align",
            Variant::JointNoPretrain => "joint-no-pretrain",
        }
    }

    /// The variant's configuration derived from the joint base `base`.
    pub fn config(self, base: &TrainConfig) -> TrainConfig {
        let mut c = base.clone();
        match self {
            Variant::ThermalOnly => {
                c.load.modality = Modality::Thermal;
                c.joint.rgb_pretrain = 0;
                c.joint.thermal_align = None;
            }
            Variant::Joint => {}
            Variant::JointNoAlign => c.joint.thermal_align = Some(0.0),
            Variant::JointNoPretrain => c.joint.rgb_pretrain = 0,
        }
        c
    }
}

/// One row of the table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationRow {
    pub variant: Variant,
    pub run_dir: PathBuf,
    pub iterations: u64,
    pub train_seconds: f64,
    pub primitives: usize,
    pub score: TruthScore,
    /// The model's mesh against the truth surface (`None`: the dataset has none).
    #[serde(default)]
    pub mesh: Option<MeshScore>,
}

/// Trains and scores every variant of `base` (whose `data` holds truth) into `out/<slug>`;
/// `backend` makes each run's backend; `on_event` sees every run's events with its variant.
pub fn run_ablation<B: Backend>(
    base: &TrainConfig,
    out: &Path,
    backend: &mut dyn FnMut() -> Result<B, TrainError>,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(Variant, &Event),
) -> Result<Vec<AblationRow>, TrainError> {
    let mut rows = Vec::new();
    let truth_surface = base.data.join(TRUTH_SURFACE);
    let mesh_truth = if truth_surface.is_file() {
        let bad = |e: crate::mesh::MeshError| TrainError::Stage {
            what: format!("the truth surface {}", truth_surface.display()),
            source: Box::new(e),
        };
        let truth = crate::mesh::plyio::read_mesh_ply(&truth_surface).map_err(bad)?;
        let region = crate::mesh::plyio::read_region(&truth_surface).map_err(bad)?;
        let all = Dataset::load(
            &base.data,
            &LoadOptions {
                modality: Modality::Both,
                ..base.load.clone()
            },
        )?;
        let cams: Vec<_> = all.train.iter().map(|&i| all.views[i].camera).collect();
        Some((truth, region, cams, all.range))
    } else {
        None
    };
    for v in Variant::ALL {
        let dir = out.join(v.slug());
        let start = Instant::now();
        let t = super::train_variant(v.config(base), dir.clone(), backend()?, stop, &mut |e| {
            on_event(v, e)
        })?;
        tracing::info!(
            variant = v.slug(),
            seconds = start.elapsed().as_secs_f64(),
            "trained"
        );
        let mut b = backend()?;
        let s = score(&base.data, &t.prims, t.rgb_background(), &mut b)?;
        let mesh = match (&mesh_truth, &mesh_truth.as_ref().and_then(|m| m.3)) {
            (Some((truth, region, cams, _)), Some(range)) => {
                let opts = MeshOptions::default();
                let (m, _) = mesh_views(&t.prims, cams, range, &opts, &mut b, &mut |_, _, _| {})
                    .map_err(|e| TrainError::Stage {
                        what: format!("run {}: meshing the model", dir.display()),
                        source: Box::new(e),
                    })?;
                Some(score_mesh(&m, truth, opts.tau_m, region.as_ref()))
            }
            _ => None,
        };
        rows.push(AblationRow {
            variant: v,
            run_dir: dir,
            iterations: t.iteration,
            train_seconds: t.train_seconds,
            primitives: t.prims.len(),
            score: s,
            mesh,
        });
    }
    Ok(rows)
}

/// The table as Markdown (paper Tables 3/4's layout, with our columns).
pub fn markdown(rows: &[AblationRow]) -> String {
    let k = rows.first().map_or(0, |r| r.score.scale);
    let mut s = format!(
        "| run | thermal PSNR / SSIM / MAE (input) | thermal PSNR / SSIM / MAE ({k}×) | \
         bicubic {k}× PSNR / SSIM / MAE | bicubic {k}× back-projected PSNR / SSIM / MAE | \
         fused {k}× PSNR / SSIM / MAE | LPIPS input / {k}× / bicubic / fused | \
         RGB PSNR / SSIM | depth MAE ({k}×, coverage) | \
         mesh Chamfer / F-score / vertex MAE | iterations | primitives |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        let t = &r.score;
        let rgb = match (t.rgb_psnr, t.rgb_ssim) {
            (Some(p), Some(q)) => format!("{p:.2} dB / {q:.3}"),
            _ => "—".into(),
        };
        let mesh = r.mesh.map_or_else(
            || "—".to_owned(),
            |m| {
                format!(
                    "{:.1} mm / {:.3} at {:.0} mm / {:.3} K",
                    m.chamfer_m * 1e3,
                    m.f_score,
                    m.tau_m * 1e3,
                    m.kelvin_mae
                )
            },
        );
        // LPIPS: "—" where it is not defined (no weights installed, or under 31 px).
        let lp = |x: Option<f64>| x.map_or_else(|| "—".to_owned(), |v| format!("{v:.3}"));
        let lpips = format!(
            "{} / {} / {} / {}",
            lp(t.thermal.lpips),
            lp(t.thermal_sr.lpips),
            lp(t.bicubic_sr.lpips),
            lp(t.fused_sr.lpips)
        );
        let bicubic_bp = t.bicubic_bp_sr.map_or_else(
            || "—".to_owned(),
            |b| format!("{:.2} dB / {:.3} / {:.3} K", b.psnr, b.ssim, b.kelvin_mae),
        );
        s.push_str(&format!(
            "| {} | {:.2} dB / {:.3} / {:.3} K | {:.2} dB / {:.3} / {:.3} K | {:.2} dB / {:.3} / {:.3} K | {} | {:.2} dB / {:.3} / {:.3} K | {} | {} | {:.1} mm ({:.0} %) | {} | {} | {} |\n",
            r.variant.slug(),
            t.thermal.psnr,
            t.thermal.ssim,
            t.thermal.kelvin_mae,
            t.thermal_sr.psnr,
            t.thermal_sr.ssim,
            t.thermal_sr.kelvin_mae,
            t.bicubic_sr.psnr,
            t.bicubic_sr.ssim,
            t.bicubic_sr.kelvin_mae,
            bicubic_bp,
            t.fused_sr.psnr,
            t.fused_sr.ssim,
            t.fused_sr.kelvin_mae,
            lpips,
            rgb,
            t.depth_rgb.mae_m * 1000.0,
            t.depth_rgb.coverage * 100.0,
            mesh,
            r.iterations,
            r.primitives,
        ));
    }
    s
}
