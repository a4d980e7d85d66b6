//! `s3tir-train mesh`: a run fused into a surface mesh with a temperature per vertex.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

#[cfg(not(feature = "vulkan"))]
use anyhow::bail;
use anyhow::{Context, Result};
use clap::Args;
use s3tir_trainer::train::{BackendKind, CpuBackend};

/// Options of `s3tir-train mesh`.
#[derive(Debug, Args)]
pub struct MeshArgs {
    /// Run folder written by training (any backend's).
    run_dir: PathBuf,
    /// Output mesh (binary PLY); the colour-mapped copy goes beside it as OUT_thermal.ply.
    #[arg(long, default_value = "mesh.ply")]
    out: PathBuf,
    /// Voxel edge in metres [default: the scene's extent / --resolution, grown until the
    /// volume fits --memory-budget-mib].
    #[arg(long = "voxel-size-m")]
    voxel_size_m: Option<f64>,
    /// Voxels along the scene's longest side when the voxel is automatic.
    #[arg(long, default_value_t = 512)]
    resolution: usize,
    /// Truncation distance of the signed-distance volume, in voxels.
    #[arg(long, default_value_t = 3.0)]
    trunc_voxels: f64,
    /// Memory the volume may use, MiB (the renders kept for fusion come on top: ~3.6 MB per
    /// 640×512 view with colour).
    #[arg(long, default_value_t = 1024)]
    memory_budget_mib: u64,
    /// Rendered alpha from which a pixel is surface.
    #[arg(long, default_value_t = 0.5)]
    min_alpha: f32,
    /// Observation weight a voxel needs to take part in the surface, in head-on-equivalent
    /// views: each view counts |cos θ| of the angle between its ray and the surface (a grazing
    /// view measures distance badly), so 1 is one head-on view or two at 60°.
    #[arg(long, default_value_t = 1.0)]
    min_weight: f32,
    /// Score the mesh against the dataset's truth surface (DATA/truth/surface.ply, written by
    /// `s3tir-firmware-sim scene`): Chamfer distance, F-score at --tau-m, kelvin MAE.
    #[arg(long)]
    truth: bool,
    /// Distance threshold of the F-score and of the vertices whose kelvin is scored, metres.
    #[arg(long, default_value_t = 0.02)]
    tau_m: f64,
    /// Backend that renders the views.
    #[arg(long, value_enum, default_value_t = BackendKind::Cpu)]
    backend: BackendKind,
    /// Vulkan device index (see `devices`; default: the best device).
    #[arg(long)]
    device_index: Option<usize>,
    /// Print one JSON object (files, voxel, blocks, vertices, triangles, seconds per stage,
    /// peak memory, the truth score).
    #[arg(long)]
    json: bool,
}

/// `mesh`: progress bars per stage, the summary as text or JSON.
pub fn run(a: &MeshArgs) -> Result<()> {
    use s3tir_trainer::mesh::run::{MeshOptions, MeshStage, mesh_run};
    let opts = MeshOptions {
        voxel_m: a.voxel_size_m,
        resolution: a.resolution,
        trunc_voxels: a.trunc_voxels,
        memory_budget_bytes: a.memory_budget_mib.saturating_mul(1 << 20),
        min_alpha: a.min_alpha,
        min_weight: a.min_weight,
        tau_m: a.tau_m,
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>8} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut progress = |stage: MeshStage, done: usize, total: usize| {
        bar.set_message(match stage {
            MeshStage::Render => "render",
            MeshStage::Fuse => "fuse",
            MeshStage::Extract => "extract",
        });
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let what = || format!("meshing {} into {}", a.run_dir.display(), a.out.display());
    let s = match a.backend {
        #[cfg(feature = "vulkan")]
        BackendKind::Vulkan => {
            let b = s3tir_trainer::gpu::backend::VulkanBackend::new(
                &super::vulkan_options(a.device_index, false),
                s3tir_trainer::render::RenderSettings::default(),
            )
            .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
            mesh_run(&a.run_dir, &a.out, &opts, a.truth, b, &mut progress).with_context(what)?
        }
        #[cfg(not(feature = "vulkan"))]
        BackendKind::Vulkan => {
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        BackendKind::Cpu => mesh_run(
            &a.run_dir,
            &a.out,
            &opts,
            a.truth,
            CpuBackend::default(),
            &mut progress,
        )
        .with_context(what)?,
    };
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    let st = &s.stats;
    println!(
        "{} vertices, {} triangles from {} of {} views; voxel {:.2} mm, truncation {:.2} mm, {} blocks ({:.1} MiB)",
        st.vertices,
        st.triangles,
        st.views,
        st.views_rendered,
        st.voxel_m * 1e3,
        st.trunc_m * 1e3,
        st.blocks,
        st.volume_bytes as f64 / f64::from(1 << 20)
    );
    println!(
        "render {:.1} s, fuse {:.1} s, extract {:.1} s; peak memory {}",
        st.render_s,
        st.fuse_s,
        st.extract_s,
        s.peak_rss_bytes.map_or_else(
            || "unknown".to_owned(),
            |b| format!("{:.0} MiB", b as f64 / f64::from(1 << 20))
        )
    );
    if let Some(t) = &s.truth {
        println!(
            "against truth: Chamfer {:.2} mm (accuracy {:.2}, completeness {:.2}), F-score {:.3} at {:.0} mm (precision {:.3}, recall {:.3}), vertex temperature MAE {:.3} K",
            t.chamfer_m * 1e3,
            t.accuracy_m * 1e3,
            t.completeness_m * 1e3,
            t.f_score,
            t.tau_m * 1e3,
            t.precision,
            t.recall,
            t.kelvin_mae
        );
    }
    println!(
        "wrote {} (kelvin{}) and {} (ironbow {:.2}–{:.2} {})",
        s.out.display(),
        if s.colour { " and RGB" } else { "" },
        s.thermal_out.display(),
        s.kelvin_lo,
        s.kelvin_hi,
        if s.radiometric {
            "K"
        } else {
            "normalised: the data is not radiometric"
        }
    );
    Ok(())
}

/// `mesh RUN --out OUT --backend B` with every other option at its default (what `view` runs
/// for a run that has no mesh yet), through the same clap definitions as the command line.
pub fn mesh_with_defaults(run_dir: &Path, out: &Path, backend: BackendKind) -> Result<()> {
    #[derive(clap::Parser)]
    struct Defaults {
        #[command(flatten)]
        args: MeshArgs,
    }
    let args = <Defaults as clap::Parser>::try_parse_from([
        OsStr::new("mesh"),
        run_dir.as_os_str(),
        OsStr::new("--out"),
        out.as_os_str(),
        OsStr::new("--backend"),
        OsStr::new(backend.as_str()),
    ])
    .context("the mesh command's defaults")?;
    run(&args.args)
}
