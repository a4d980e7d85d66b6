//! `s3tir-firmware-sim scene`: a training dataset with its truth (thermal-only or joint).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use s3tir_firmware_sim::scene::joint::{JointOptions, write_joint_scene_set};
use s3tir_firmware_sim::scene::response::ResponseEffects;
use s3tir_firmware_sim::scene::truth::SURFACE_TRUTH_FILE;
use s3tir_firmware_sim::scene::{SceneConfig, SceneLayout, write_scene_set_with};
use serde::Serialize;

use super::{ImageSet, Written, progress_bar};

/// Options of `s3tir-firmware-sim scene`.
#[derive(Debug, Args)]
pub struct SceneArgs {
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Which scene.
    #[arg(long, value_enum, default_value = "objects")]
    pub layout: LayoutArg,
    /// Number of views (orbit or arc).
    #[arg(long, default_value_t = 24)]
    pub views: usize,
    /// Image width, pixels.
    #[arg(long, default_value_t = 160)]
    pub width: u32,
    /// Image height, pixels.
    #[arg(long, default_value_t = 120)]
    pub height: u32,
    /// Random seed (noise, surface points).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Export 8-bit grey images with per-frame automatic gain control (each frame stretched
    /// from its own coldest to warmest pixel), as camera apps export them, instead of
    /// 16-bit centikelvin. Truth in DIR/response.json.
    #[arg(long)]
    pub agc: bool,
    /// Offset drift of the radiometric stream between flat-field corrections: 1σ
    /// random-walk step per frame, kelvin (0: none). Truth in DIR/response.json.
    #[arg(long, default_value_t = 0.0)]
    pub drift_k: f64,
    /// A flat-field correction (drift reset) every this many frames (0: only before the
    /// first frame). The frames taken right after one are listed in DIR/ffc.txt.
    #[arg(long, default_value_t = 6)]
    pub ffc_every: usize,
    /// Joint RGB + thermal layout: an RGB camera of K times the thermal resolution per axis
    /// (K·width × K·height, same 57° field of view), mounted 3 cm beside the thermal
    /// camera. Writes DIR/images/thermal/ and DIR/images/rgb/ (COLMAP cameras 1 and 2,
    /// images 2k+1 and 2k+2 of instant k), DIR/holdout.txt (both images of every 8th
    /// instant) and DIR/truth/: apparent/thermal/ and apparent_sr/thermal/ (noise-free,
    /// blur-free apparent temperature at the thermal pose, W×H and K·W×K·H, centikelvin),
    /// depth/thermal/ and depth/rgb/ (mm), rgb/rgb/ (noise-free RGB) instead of DIR/images/,
    /// rgb/, depth/ and temperature/. 1 to 8; 0 (default): the thermal-only layout above.
    #[arg(long, default_value_t = 0, value_name = "K")]
    pub rgb_scale: u32,
    /// With --rgb-scale: the RGB camera in low light, exposed at 2 % instead of 100 % (shot
    /// and read noise dominate); its truth in DIR/truth/rgb/ has the same exposure without
    /// the noise.
    #[arg(long)]
    pub low_light: bool,
    /// Print one JSON object on stdout when done: what was written (paths, view counts,
    /// image sizes, files and bytes).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum LayoutArg {
    /// Heated pipe, box with an emissivity edge, radiator panel and a floor warmed by an
    /// underfloor pipe, seen from an orbit.
    Objects,
    /// Wall inspection: one wall filling every view, painted on one side of a vertical line and
    /// bare metal on the other (a sharp emissivity edge), warmed by an in-wall heating pipe (a
    /// smooth warm band); cameras on an arc in front of it.
    Wall,
    /// A brick facade with thermal texture finer than the primitives: warm mortar joints
    /// (~4 px at 640 px), bricks of slightly different temperatures, a surface-mounted hot pipe
    /// with sharp edges, a warm cabinet with printed foil labels; the wall's cameras. Meant for
    /// a real core's resolution: --width 640 --height 512.
    Facade,
}

/// `scene --json`: what the scene dataset holds.
#[derive(Debug, Serialize)]
struct SceneSummary {
    command: &'static str,
    out: PathBuf,
    layout: &'static str,
    views: usize,
    seed: u64,
    /// `{rgb_scale, low_light}` of the joint layout (`--rgb-scale K`), or null.
    joint: Option<JointSummary>,
    /// The thermal images (16-bit centikelvin, or 8-bit grey with `--agc`).
    thermal: ImageSet,
    rgb: ImageSet,
    colmap_model: PathBuf,
    colmap_images: usize,
    scene_json: PathBuf,
    truth_surface: PathBuf,
    /// `holdout.txt` (joint layout only).
    holdout: Option<PathBuf>,
    /// `response.json` (with `--agc` or `--drift-k`).
    response: Option<PathBuf>,
    #[serde(flatten)]
    written: Written,
    seconds: f64,
}

#[derive(Debug, Serialize)]
struct JointSummary {
    rgb_scale: u32,
    low_light: bool,
}

fn scene_summary(
    cfg: &SceneConfig,
    layout: SceneLayout,
    effects: ResponseEffects,
    joint: Option<JointOptions>,
    seconds: f64,
) -> Result<SceneSummary> {
    let out = &cfg.out_dir;
    let size = (cfg.width_px, cfg.height_px);
    let (thermal, rgb) = match &joint {
        None => (
            ImageSet::new(out.join("images"), cfg.views, size),
            ImageSet::new(out.join("rgb"), cfg.views, size),
        ),
        Some(j) => {
            let rgb = j.rgb_camera(cfg.width_px, cfg.height_px)?;
            (
                ImageSet::new(out.join("images/thermal"), cfg.views, size),
                ImageSet::new(
                    out.join("images/rgb"),
                    cfg.views,
                    (rgb.width_px, rgb.height_px),
                ),
            )
        }
    };
    Ok(SceneSummary {
        command: "scene",
        out: out.clone(),
        layout: layout.name(),
        views: cfg.views,
        seed: cfg.seed,
        joint: joint.map(|j| JointSummary {
            rgb_scale: j.rgb_scale,
            low_light: j.low_light,
        }),
        thermal,
        rgb,
        colmap_model: out.join("sparse/0"),
        colmap_images: if joint.is_some() {
            2 * cfg.views
        } else {
            cfg.views
        },
        scene_json: out.join("scene.json"),
        truth_surface: out.join(SURFACE_TRUTH_FILE),
        holdout: joint.map(|_| out.join("holdout.txt")),
        response: effects.any().then(|| out.join("response.json")),
        written: Written::of(out)?,
        seconds,
    })
}

/// Writes the scene dataset `a` asks for.
pub fn run(a: SceneArgs) -> Result<()> {
    let SceneArgs {
        out,
        layout,
        views,
        width,
        height,
        seed,
        agc,
        drift_k,
        ffc_every,
        rgb_scale,
        low_light,
        json,
    } = a;
    if !(drift_k >= 0.0 && drift_k.is_finite()) {
        anyhow::bail!("--drift-k must be a finite number ≥ 0, got {drift_k}");
    }
    let joint = JointOptions::from_flags(rgb_scale, low_light)
        .context("checking --rgb-scale and --low-light")?;
    let effects = ResponseEffects {
        agc,
        drift_step_k: drift_k,
        ffc_every,
    };
    let start = Instant::now();
    let cfg = SceneConfig {
        out_dir: out.clone(),
        views,
        width_px: width,
        height_px: height,
        seed,
    };
    let bar = progress_bar(views, "scene views");
    let layout = match layout {
        LayoutArg::Objects => SceneLayout::Objects,
        LayoutArg::Wall => SceneLayout::Wall,
        LayoutArg::Facade => SceneLayout::Facade,
    };
    let mut progress = |done: usize, _| bar.set_position(done as u64);
    match joint {
        None => write_scene_set_with(&cfg, layout, effects, &mut progress),
        Some(joint) => write_joint_scene_set(&cfg, layout, effects, &joint, &mut progress),
    }
    .with_context(|| format!("writing the scene set to {}", out.display()))?;
    bar.finish();
    let seconds = start.elapsed().as_secs_f64();
    tracing::info!(views, seconds, "scene set written to {}", out.display());
    if json {
        let summary = scene_summary(&cfg, layout, effects, joint, seconds)?;
        println!("{}", serde_json::to_string_pretty(&summary)?);
    }
    Ok(())
}
