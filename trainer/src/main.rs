//! `s3tir-train`: S³-TIR thermal splatting on the rig. This file holds the clap top level, the
//! logging set-up and the dispatch; each subcommand is a module of [`cli`].

mod cli;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};

use cli::ablation::AblationArgs;
use cli::bench::BenchArgs;
use cli::compare::CompareArgs;
use cli::devices::DevicesArgs;
use cli::eval::EvalArgs;
use cli::mesh::MeshArgs;
use cli::render::RenderArgs;
use cli::report::ReportArgs;
use cli::synth::SynthArgs;
use cli::train_args::TrainArgs;
use cli::view::ViewArgs;

/// S³-TIR thermal splatting: fit spatial-spectral primitives to posed thermal (and RGB) frames
/// with a Vulkan compute trainer that runs on the rig, and render novel views.
///
/// Train: `s3tir-train DATA --out RUN_DIR [--mode s3tir|3dgs|ges|gabor] [--iters N]
/// [--backend cpu|vulkan] [--budget N] [--seed S]` (or `s3tir-train train DATA …`). DATA is a
/// COLMAP dataset (`sparse/0/` + `images/`), e.g. the output of `s3tir-firmware-sim scene`.
/// Ctrl-C writes a checkpoint and exits; `--resume` continues from it.
///
/// Joint RGB + thermal (TGA-GS) on a rig's pair of cameras: a dataset holding both cameras'
/// images, each with its own camera (`s3tir-calib poses SESSION --with-rgb`, or
/// `s3tir-train SESSION.mcap --with-rgb`), trains one model with a thermal and a colour head:
/// `s3tir-train DATA --out RUN --rgb-pretrain 3000` — RGB pre-training, then every step trains
/// a view with the other camera's image of the same instant; L1-low for dark RGB
/// (`--rgb-loss auto`), the thermal gradient alignment loss (`--thermal-align`), the thermal
/// head rendered at the RGB resolution into `renders_sr/`. `ablation` measures the variants on
/// a simulated joint scene (`s3tir-firmware-sim scene --rgb-scale 4 --low-light`).
///
/// Every run ends with `RUN/report.html`: the held-out views recorded | rendered | error in
/// palettes with colour bars in kelvin and °C, the figures, error against time (`report RUN`
/// writes it again); `render RUN --path orbit --out DIR` flies around the model (frames and a
/// video).
///
/// `mesh RUN --out mesh.ply` fuses a run's rendered depth and temperature into a surface mesh
/// with a float `kelvin` per vertex (binary PLY) and an ironbow-coloured copy.
///
/// `devices` lists the Vulkan devices this computer offers and what the trainer needs of them
/// (storage-buffer range, shared memory, subgroups, float atomics).
#[derive(Debug, Parser)]
#[command(
    name = "s3tir-train",
    version,
    about,
    long_about,
    args_conflicts_with_subcommands = true,
    subcommand_negates_reqs = true
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// Not an `Option`: clap leaves an optional flattened struct `None` when its options sit
    /// in a nested flatten (the session's posing flags); without a subcommand DATA and --out
    /// are required, so a parsed `TrainArgs` with DATA is a training run.
    #[command(flatten)]
    train: TrainArgs,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List Vulkan devices: name, driver, API version, memory heaps, max storage-buffer range,
    /// shared memory, subgroup size and operations, float-atomic support. Exits non-zero with
    /// the reason when no Vulkan loader or driver is present.
    Devices(DevicesArgs),
    /// Train a model (same as `s3tir-train DATA --out RUN_DIR …`).
    Train(Box<TrainArgs>),
    /// Benchmark training steps/s: Vulkan backend vs CPU backend on the same scene and budget,
    /// full s3tir mode vs 3dgs mode, and the GPU time per kernel (timestamp queries).
    Bench(BenchArgs),
    /// Evaluate a run on its held-out views: PSNR, SSIM, LPIPS (when its weights are installed)
    /// and (radiometric data) kelvin MAE/RMSE, per view and mean.
    Eval(EvalArgs),
    /// An ablation by one command: several runs with the training options given, one part of
    /// the method taken away in each, into RUN_DIR/<variant>/, and the table in
    /// RUN_DIR/ablation.md and ablation.json. `--study tga` (default): the TGA-GS ablation on
    /// a dataset with truth (`s3tir-firmware-sim scene --rgb-scale K`) — thermal-only, joint,
    /// joint without the thermal gradient alignment loss, joint without RGB pre-training — each
    /// scored against DATA/truth (thermal at the input resolution and super-resolved at K×
    /// against bicubic upsampling and fused with the recorded image, RGB, depth) and, when the
    /// scene has a truth surface, meshed and the mesh scored (Chamfer, F-score, vertex kelvin).
    /// Two tables: every variant at --iters, then every variant at the joint run's training
    /// time (a joint step also trains the RGB partner, so equal iterations give the joint
    /// variants more work; runs more than 10 % off that time are trained again with it as their
    /// budget, into <variant>-equal-time/); with --time-budget, one table at that time.
    /// `--study spectral`: the S³-TIR paper's Table 2 on any thermal dataset — the full
    /// method, β fixed at 2, no spectral modulation (f = 0), no consistency term, no sparsity
    /// term, and 3DGS — scored on the held-out views (PSNR, SSIM, LPIPS, kelvin error); give
    /// `--time-budget` to compare at equal wall time.
    Ablation(Box<AblationArgs>),
    /// A surface mesh with a temperature per vertex: the run's training views rendered
    /// (expected depth, kelvin, colour), fused into a sparse truncated signed-distance volume
    /// and extracted by surface nets, trimmed to where the views saw it. Writes OUT (binary
    /// PLY: float `kelvin` per vertex, the run's RGB when it has colour) and OUT_thermal.ply
    /// (coloured by the ironbow palette for viewers that show only RGB); opens in MeshLab,
    /// Blender, CloudCompare. The voxel follows the scene's extent and --memory-budget-mib.
    Mesh(MeshArgs),
    /// Overlay the error-vs-time curves of several runs on one plot (e.g. s3tir vs 3dgs), or of
    /// groups of repeated runs (several seeds of one configuration: their mean, the range
    /// shaded), with a table of where the first leads each other after the warm-up.
    Compare(CompareArgs),
    /// Write a run's report again: RUN/report.html (one self-contained page, readable on a
    /// phone) and report.md — the run's settings and figures, each held-out view recorded |
    /// rendered | error in the ironbow and diverging palettes with colour bars in kelvin and °C,
    /// error against time, G-buffers, density and band rounds, the per-view response.
    /// Training writes it at the end of every run.
    Report(ReportArgs),
    /// Render a run along a camera path — the held-out views, an orbit around the scene, a
    /// spiral across the training cameras, or a JSON file of eye/target pairs — as palette
    /// frames with a colour bar in kelvin and °C, and a video (MP4 through ffmpeg when it is
    /// installed, otherwise an animated GIF), on either backend.
    Render(RenderArgs),
    /// Look at a run's thermal mesh in the browser: a local web viewer (http://127.0.0.1:8765/
    /// by default; the page and three.js come from this machine, nothing from the internet) to
    /// orbit the mesh, switch palette and range, and read the temperature of any surface point
    /// in K and °C by hovering or clicking. Meshes the run first when it has no mesh. Serves the
    /// run folder's files only, until Ctrl-C.
    View(ViewArgs),
    /// Write the built-in analytic test scene (a wall with a sharp emissivity step and a heated
    /// pipe) as a COLMAP dataset with 16-bit centikelvin images.
    Synth(SynthArgs),
}

/// Runs the command; an error is printed once, as one `error: …` line (the whole cause chain,
/// `s3tir_capture::Chain`), and exits 1.
fn main() -> std::process::ExitCode {
    s3tir_capture::error::exit_with(run())
}

fn run() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match (cli.command, cli.train) {
        (Some(Command::Devices(a)), _) => cli::devices::run(&a),
        (Some(Command::Train(a)), _) => cli::train::run(*a),
        (None, a) if a.data.is_some() => cli::train::run(a),
        (Some(Command::Bench(a)), _) => cli::bench::run(&a),
        (Some(Command::Eval(a)), _) => cli::eval::run(&a),
        (Some(Command::Ablation(a)), _) => cli::ablation::run(*a),
        (Some(Command::Mesh(a)), _) => cli::mesh::run(&a),
        (Some(Command::Compare(a)), _) => cli::compare::run(&a),
        (Some(Command::Report(a)), _) => cli::report::run(&a),
        (Some(Command::Render(a)), _) => cli::render::run(&a),
        (Some(Command::View(a)), _) => cli::view::run(&a),
        (Some(Command::Synth(a)), _) => cli::synth::run(&a),
        (None, _) => {
            bail!("nothing to do: give DATA --out RUN_DIR, or a subcommand (see --help)")
        }
    }
}

#[cfg(test)]
mod tests {
    /// clap checks a command's definition only when it is built: two options of one name
    /// (e.g. flattened from two option groups) would panic at every start. This builds it.
    #[test]
    fn the_command_line_is_well_formed() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
