//! The TGA-GS ablation (paper Tables 3/4) on a dataset with truth: four runs of one base
//! configuration — thermal-only, joint, joint without the thermal gradient alignment loss,
//! joint without RGB pre-training — each scored by [`crate::truth::score`], as a table. When
//! the dataset holds a truth surface (`truth/surface.ply`), each model is also meshed
//! ([`crate::mesh`], default options) through the same cameras — every training camera of
//! both image sets, whatever the variant trained on, so the meshes differ only by their
//! geometry — and the mesh scored against it (Chamfer distance, F-score, vertex kelvin MAE).
//!
//! # Equal iterations and equal time
//! A joint step trains a thermal view *and* its RGB partner (16× the pixels at 4×), so at
//! equal iterations the joint variants have done more work and seen more supervision than
//! thermal-only. Users compare runs at equal wall time, so the table has both: with an
//! iteration count (no `time_budget_s`) every variant first runs that many iterations
//! ([`Equal::Iterations`]); then every variant is compared at the joint run's training time
//! ([`Equal::Time`]): a variant whose run took within [`SAME_TIME`] of it is that same run, any
//! other is trained again with that time as its budget (the schedule follows the time spent,
//! as in any budgeted run) into `<variant>-equal-time/`. With a time budget every run already
//! has the same time: one table, at equal time.
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::dataset::ThermalRange;
use crate::dataset::{Dataset, LoadOptions, Modality};
use crate::mesh::Mesh;
use crate::mesh::plyio::{Region, read_mesh_ply, read_region};
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

/// What a row's runs have in common: their iterations or their training time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Equal {
    Iterations,
    Time,
}

/// A run whose training time is within this fraction of the equal-time reference (the joint
/// run's) is at equal time already and is not trained again.
pub const SAME_TIME: f64 = 0.10;

/// Which run the ablation is training, for progress: the variant, what its table holds equal,
/// the time budget it runs to (`None`: the base configuration's iterations), and the run's
/// place among those planned so far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunLabel {
    pub variant: Variant,
    pub equal: Equal,
    pub budget_s: Option<f64>,
    pub index: usize,
    pub planned: usize,
}

/// One row of the table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationRow {
    pub variant: Variant,
    /// Which table the row belongs to.
    pub equal: Equal,
    pub run_dir: PathBuf,
    pub iterations: u64,
    pub train_seconds: f64,
    pub primitives: usize,
    pub score: TruthScore,
    /// The model's mesh against the truth surface (`None`: the dataset has none).
    #[serde(default)]
    pub mesh: Option<MeshScore>,
}

/// Trains and scores every variant of `base` (whose `data` holds truth) into `out/<slug>`, at
/// equal iterations and then at equal time (see the module docs); `backend` makes each run's
/// backend; `on_event` sees every run's events with its label.
pub fn run_ablation<B: Backend>(
    base: &TrainConfig,
    out: &Path,
    backend: &mut dyn FnMut() -> Result<B, TrainError>,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(&RunLabel, &Event),
) -> Result<Vec<AblationRow>, TrainError> {
    let mesh_truth = MeshTruth::load(base)?;
    let first = match base.time_budget_s {
        Some(_) => Equal::Time,
        None => Equal::Iterations,
    };
    let mut planned = Variant::ALL.len();
    let mut rows = Vec::new();
    for (index, v) in Variant::ALL.into_iter().enumerate() {
        let label = RunLabel {
            variant: v,
            equal: first,
            budget_s: base.time_budget_s,
            index,
            planned,
        };
        let row = run_variant(
            v.config(base),
            label,
            out.join(v.slug()),
            &mesh_truth,
            backend,
            stop,
            on_event,
        )?;
        rows.push(row);
    }
    if first == Equal::Time {
        return Ok(rows);
    }
    // Equal time: the joint run's training time is the reference.
    let reference = rows
        .iter()
        .find(|r| r.variant == Variant::Joint)
        .map_or(0.0, |r| r.train_seconds);
    let again: Vec<Variant> = rows
        .iter()
        .filter(|r| (r.train_seconds - reference).abs() > SAME_TIME * reference)
        .map(|r| r.variant)
        .collect();
    planned += again.len();
    let mut timed = Vec::new();
    let mut done_again = 0;
    for r in &rows {
        if !again.contains(&r.variant) {
            timed.push(AblationRow {
                equal: Equal::Time,
                ..r.clone()
            });
            continue;
        }
        let v = r.variant;
        let mut cfg = v.config(base);
        cfg.time_budget_s = Some(reference);
        let label = RunLabel {
            variant: v,
            equal: Equal::Time,
            budget_s: Some(reference),
            index: Variant::ALL.len() + done_again,
            planned,
        };
        let dir = out.join(format!("{}-equal-time", v.slug()));
        timed.push(run_variant(
            cfg,
            label,
            dir,
            &mesh_truth,
            backend,
            stop,
            on_event,
        )?);
        done_again += 1;
    }
    rows.extend(timed);
    Ok(rows)
}

/// What every variant's mesh is scored against: the truth surface and its region, the
/// cameras every variant is meshed through (every training camera of both image sets) and the
/// dataset's thermal range.
struct MeshTruth {
    surface: Mesh,
    region: Option<Region>,
    cameras: Vec<PinholeCamera>,
    range: ThermalRange,
}

impl MeshTruth {
    /// `base.data`'s truth surface; `None` when it has none (or no thermal range to mesh in).
    fn load(base: &TrainConfig) -> Result<Option<Self>, TrainError> {
        let path = base.data.join(TRUTH_SURFACE);
        if !path.is_file() {
            return Ok(None);
        }
        let bad = |e: crate::mesh::MeshError| TrainError::Stage {
            what: format!("the truth surface {}", path.display()),
            source: Box::new(e),
        };
        let surface = read_mesh_ply(&path).map_err(bad)?;
        let region = read_region(&path).map_err(bad)?;
        let all = Dataset::load(
            &base.data,
            &LoadOptions {
                modality: Modality::Both,
                ..base.load.clone()
            },
        )?;
        let cameras = all.train.iter().map(|&i| all.views[i].camera).collect();
        Ok(all.range.map(|range| Self {
            surface,
            region,
            cameras,
            range,
        }))
    }
}

/// Trains one run `cfg` into `dir`, scores it against the truth and meshes it when there is a
/// truth surface.
fn run_variant<B: Backend>(
    cfg: TrainConfig,
    label: RunLabel,
    dir: PathBuf,
    mesh_truth: &Option<MeshTruth>,
    backend: &mut dyn FnMut() -> Result<B, TrainError>,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(&RunLabel, &Event),
) -> Result<AblationRow, TrainError> {
    let data = cfg.data.clone();
    let start = Instant::now();
    let t = super::train_variant(cfg, dir.clone(), backend()?, stop, &mut |e| {
        on_event(&label, e)
    })?;
    tracing::info!(
        variant = label.variant.slug(),
        seconds = start.elapsed().as_secs_f64(),
        "trained"
    );
    let mut b = backend()?;
    let s = score(&data, &t.prims, t.rgb_background(), &mut b)?;
    let mesh = match mesh_truth {
        Some(m) => {
            let opts = MeshOptions::default();
            let (mesh, _) = mesh_views(
                &t.prims,
                &m.cameras,
                &m.range,
                &opts,
                &mut b,
                &mut |_, _, _| {},
            )
            .map_err(|e| TrainError::Stage {
                what: format!("run {}: meshing the model", dir.display()),
                source: Box::new(e),
            })?;
            Some(score_mesh(&mesh, &m.surface, opts.tau_m, m.region.as_ref()))
        }
        None => None,
    };
    Ok(AblationRow {
        variant: label.variant,
        equal: label.equal,
        run_dir: dir,
        iterations: t.iteration,
        train_seconds: t.train_seconds,
        primitives: t.prims.len(),
        score: s,
        mesh,
    })
}

/// The table as Markdown (paper Tables 3/4's layout, with our columns).
pub fn markdown(rows: &[AblationRow]) -> String {
    let mut s = String::new();
    for equal in [Equal::Iterations, Equal::Time] {
        let group: Vec<&AblationRow> = rows.iter().filter(|r| r.equal == equal).collect();
        if group.is_empty() {
            continue;
        }
        if !s.is_empty() {
            s.push('\n');
        }
        s.push_str(&match equal {
            Equal::Iterations => format!(
                "At equal iterations ({} each):\n\n",
                group.iter().map(|r| r.iterations).max().unwrap_or(0)
            ),
            Equal::Time => format!(
                "At equal training time ({:.0} s each, within {:.0} %):\n\n",
                group
                    .iter()
                    .find(|r| r.variant == Variant::Joint)
                    .map_or(0.0, |r| r.train_seconds),
                SAME_TIME * 100.0
            ),
        });
        s.push_str(&table(&group));
    }
    s
}

/// One table of rows that share their iterations or their time.
fn table(rows: &[&AblationRow]) -> String {
    let k = rows.first().map_or(0, |r| r.score.scale);
    let mut s = format!(
        "| run | thermal PSNR / SSIM / MAE (input) | thermal PSNR / SSIM / MAE ({k}×) | \
         bicubic {k}× PSNR / SSIM / MAE | bicubic {k}× back-projected PSNR / SSIM / MAE | \
         fused {k}× PSNR / SSIM / MAE | LPIPS input / {k}× / bicubic / fused | \
         RGB PSNR / SSIM | depth MAE ({k}×, coverage) | \
         mesh Chamfer / F-score / vertex MAE | iterations | seconds | primitives |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
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
            "| {} | {:.2} dB / {:.3} / {:.3} K | {:.2} dB / {:.3} / {:.3} K | {:.2} dB / {:.3} / {:.3} K | {} | {:.2} dB / {:.3} / {:.3} K | {} | {} | {:.1} mm ({:.0} %) | {} | {} | {:.0} | {} |\n",
            r.run_dir
                .file_name()
                .map_or_else(|| r.variant.slug().into(), |n| n.to_string_lossy()),
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
            r.train_seconds,
            r.primitives,
        ));
    }
    s
}
