//! `s3tir-firmware-sim`: the simulated s3tir rig.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use s3tir_firmware_sim::board::BoardSpec;
use s3tir_firmware_sim::dataset::{BoardSetConfig, Polarity, write_board_set};
use s3tir_firmware_sim::rig::Rig;
use s3tir_firmware_sim::scene::joint::{JointOptions, write_joint_scene_set};
use s3tir_firmware_sim::scene::response::ResponseEffects;
use s3tir_firmware_sim::scene::truth::SURFACE_TRUTH_FILE;
use s3tir_firmware_sim::scene::{SceneConfig, SceneLayout, write_scene_set_with};
use s3tir_firmware_sim::sensor::{RgbProfile, ThermalProfile};
use s3tir_firmware_sim::serve::{RgbFormat, ServeConfig, serve};
use s3tir_firmware_sim::walk::{TagInk, WalkKind, WalkRig, WalkRoom, WalkSpec, serve_walk};
use serde::Serialize;

/// The simulated s3tir rig: a thermal core, an RGB camera and the rig controller firmware,
/// producing physically plausible frames and ground truth when no hardware is attached.
///
/// Everything is seeded: the same command with the same seed writes the same bytes.
#[derive(Debug, Parser)]
#[command(name = "s3tir-firmware-sim", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum ProfileArg {
    /// FLIR Lepton 3.5: 160×120 Y16 at 8.7 Hz.
    Lepton35,
    /// FLIR Boson 640: 640×512 Y16 at 60 Hz.
    Boson640,
}

impl ProfileArg {
    fn profile(self) -> ThermalProfile {
        match self {
            ProfileArg::Lepton35 => ThermalProfile::lepton35(),
            ProfileArg::Boson640 => ThermalProfile::boson640(),
        }
    }
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum RgbFormatArg {
    /// Motion JPEG (V4L2 `MJPG`), quality 85.
    Mjpeg,
    /// Packed YUYV 4:2:2 (V4L2 `YUYV`).
    Yuyv,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum RgbSizeArg {
    /// 640×360 (the 1280×720 camera binned 2×2): a quarter of the per-frame work.
    #[value(name = "640x360")]
    Binned,
    /// 1280×720, the camera's full resolution (what `board` renders).
    #[value(name = "1280x720")]
    Full,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum PolarityArg {
    /// Board at 25 °C moved into −20 °C surroundings (TGA-GS): coated squares look colder.
    Cooled,
    /// Board at 25 °C moved into 70 °C surroundings: coated squares look warmer.
    Heated,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum LayoutArg {
    /// Heated pipe, box with an emissivity edge, radiator panel and a floor warmed by an
    /// underfloor pipe, seen from an orbit.
    Objects,
    /// Wall inspection: one wall filling every view, painted on one side of a vertical line and
    /// bare metal on the other (a sharp emissivity edge), warmed by an in-wall heating pipe (a
    /// smooth warm band); cameras on an arc in front of it.
    Wall,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Write a calibration set of the emissivity-coated board seen by the thermal and RGB
    /// cameras: DIR/board.toml, DIR/thermal/NNNN.png (16-bit TLinear centikelvin),
    /// DIR/rgb/NNNN.png (8-bit sRGB), DIR/truth.json (true cameras, extrinsic, board poses).
    Board {
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// Number of views.
        #[arg(long, default_value_t = 30)]
        views: usize,
        /// Thermal core.
        #[arg(long, value_enum, default_value = "lepton35")]
        profile: ProfileArg,
        /// Thermal-gradient induction of the board.
        #[arg(long, value_enum, default_value = "cooled")]
        polarity: PolarityArg,
        /// Random seed (poses, noise).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// RGB image size: the full 1280×720, or 640×360 (2×2 binned, what `run` serves by
        /// default: calibrate with this size to pose the live rig's sessions).
        #[arg(long, value_enum, default_value = "1280x720")]
        rgb_size: RgbSizeArg,
        /// Print one JSON object on stdout when done: what was written (paths, view counts,
        /// image sizes, files and bytes).
        #[arg(long)]
        json: bool,
    },
    /// Write a small thermal scene dataset for the trainer (--layout objects: heated pipe, box
    /// with an emissivity edge, radiator panel, ground plane, seen from an orbit; --layout wall:
    /// a wall with an emissivity edge and an in-wall heating pipe): COLMAP text model in
    /// DIR/sparse/0/, 16-bit TLinear PNGs in DIR/images/, RGB in DIR/rgb/, ground-truth depth
    /// and temperature in DIR/depth/ and DIR/temperature/, and the visible surface with its
    /// apparent temperature in DIR/truth/surface.ply (for scoring meshes).
    ///
    /// With --rgb-scale K: the joint RGB + thermal layout instead, a thermal camera
    /// (--width × --height) and an RGB camera of K times its resolution, rigidly 3 cm apart:
    /// DIR/images/thermal/NNNN.png and DIR/images/rgb/NNNN.png (both cameras in one COLMAP
    /// model in DIR/sparse/0/), DIR/holdout.txt, and truth in DIR/truth/ (noise-free apparent
    /// temperature at the thermal and at the RGB resolution, depth of both cameras, noise-free
    /// RGB, the visible surface DIR/truth/surface.ply). See firmware-sim/README.md, `scene`.
    Scene {
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// Which scene.
        #[arg(long, value_enum, default_value = "objects")]
        layout: LayoutArg,
        /// Number of views (orbit or arc).
        #[arg(long, default_value_t = 24)]
        views: usize,
        /// Image width, pixels.
        #[arg(long, default_value_t = 160)]
        width: u32,
        /// Image height, pixels.
        #[arg(long, default_value_t = 120)]
        height: u32,
        /// Random seed (noise, surface points).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Export 8-bit grey images with per-frame automatic gain control (each frame stretched
        /// from its own coldest to warmest pixel), as camera apps export them, instead of
        /// 16-bit centikelvin. Truth in DIR/response.json.
        #[arg(long)]
        agc: bool,
        /// Offset drift of the radiometric stream between flat-field corrections: 1σ
        /// random-walk step per frame, kelvin (0: none). Truth in DIR/response.json.
        #[arg(long, default_value_t = 0.0)]
        drift_k: f64,
        /// A flat-field correction (drift reset) every this many frames (0: only before the
        /// first frame). The frames taken right after one are listed in DIR/ffc.txt.
        #[arg(long, default_value_t = 6)]
        ffc_every: usize,
        /// Joint RGB + thermal layout: an RGB camera of K times the thermal resolution per axis
        /// (K·width × K·height, same 57° field of view), mounted 3 cm beside the thermal
        /// camera. Writes DIR/images/thermal/ and DIR/images/rgb/ (COLMAP cameras 1 and 2,
        /// images 2k+1 and 2k+2 of instant k), DIR/holdout.txt (both images of every 8th
        /// instant) and DIR/truth/: apparent/thermal/ and apparent_sr/thermal/ (noise-free,
        /// blur-free apparent temperature at the thermal pose, W×H and K·W×K·H, centikelvin),
        /// depth/thermal/ and depth/rgb/ (mm), rgb/rgb/ (noise-free RGB) instead of DIR/images/,
        /// rgb/, depth/ and temperature/. 1 to 8; 0 (default): the thermal-only layout above.
        #[arg(long, default_value_t = 0, value_name = "K")]
        rgb_scale: u32,
        /// With --rgb-scale: the RGB camera in low light, exposed at 2 % instead of 100 % (shot
        /// and read noise dominate); its truth in DIR/truth/rgb/ has the same exposure without
        /// the noise.
        #[arg(long)]
        low_light: bool,
        /// Print one JSON object on stdout when done: what was written (paths, view counts,
        /// image sizes, files and bytes).
        #[arg(long)]
        json: bool,
    },
    /// Run the simulated rig in real time: frames over a Unix socket (simwire), the Boson FSLP
    /// firmware and the rig controller on pseudo-terminals. Prints `key: value` lines
    /// (`socket`, `fslp_pty`, `rig_pty`, `thermal`, `rgb`, `ready`) on stdout, then serves until
    /// SIGINT/SIGTERM, stdin EOF (only when stdin is a pipe a parent holds) or the duration ends.
    Run {
        /// Thermal core.
        #[arg(long, value_enum, default_value = "lepton35")]
        profile: ProfileArg,
        /// Also serve the RGB camera (MJPEG at 30 Hz, --rgb-size) on the same socket.
        #[arg(long)]
        rgb: bool,
        /// RGB image size. 640×360 by default: the dev build keeps 30 Hz at that size on a
        /// loaded machine (see firmware-sim/README.md, `run`).
        #[arg(long, value_enum, default_value = "640x360")]
        rgb_size: RgbSizeArg,
        /// Unix socket path to listen on (replaced if it exists).
        #[arg(long)]
        socket: PathBuf,
        /// Stop after this many seconds (default: run until stopped).
        #[arg(long)]
        duration: Option<f64>,
        /// RGB camera in low light (2 % exposure: shot and read noise dominate).
        #[arg(long)]
        low_light: bool,
        /// RGB output format.
        #[arg(long, value_enum, default_value = "mjpeg")]
        rgb_format: RgbFormatArg,
        /// Append Lepton telemetry rows (160×122) to thermal frames.
        #[arg(long)]
        telemetry: bool,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Walk the rig through a textured scene instead of facing the board: `orbit` (a
        /// circle around it) or `handheld` (a person walking around it: drift, step bob, roll,
        /// tremor); or `board`: the rig still and the board waved through 1 s poses (a
        /// calibration session). Frames are rendered per pose (RGB at 10 Hz; slower than real time on a
        /// small machine, stamped on the walk's clock); --duration is the walk's length
        /// (default 20 s); no serial ptys. Prints `walk_done: thermal=N rgb=M` when every
        /// frame is sent. See firmware-sim/README.md, `run --walk`.
        #[arg(long, value_enum)]
        walk: Option<WalkArg>,
        /// With --walk: write the truth (cameras, extrinsic, every frame's pose) to
        /// DIR/truth.json when the walk ends.
        #[arg(long, requires = "walk")]
        truth_dir: Option<PathBuf>,
        /// With --walk: how the room's AprilTags are made. `printed`: paper, the RGB camera
        /// sees them; `heated`: aluminium foil over a heated black panel (310 K), which the
        /// thermal camera sees too (inverted) — fiducials for a rig without RGB.
        #[arg(long, value_enum, default_value = "printed", requires = "walk")]
        walk_tags: WalkTagsArg,
        /// With --walk orbit|handheld: the emissivity board (9 × 6 squares of 60 mm, warmed to
        /// 305 K) stands in the room, seen over about half a lap; its board.toml and pose go
        /// beside the truth (the poses stage's --board).
        #[arg(long, requires = "walk")]
        walk_board: bool,
    },
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum WalkTagsArg {
    Printed,
    Heated,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum WalkArg {
    Orbit,
    Handheld,
    /// The rig still, the emissivity board waved in front of it (a calibration session;
    /// board.toml beside the truth).
    Board,
}

/// `board --json`: what the board set holds.
#[derive(Debug, Serialize)]
struct BoardSummary {
    command: &'static str,
    out: PathBuf,
    views: usize,
    profile: &'static str,
    polarity: &'static str,
    seed: u64,
    thermal: ImageSet,
    rgb: ImageSet,
    board_toml: PathBuf,
    truth: PathBuf,
    #[serde(flatten)]
    written: Written,
    seconds: f64,
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

/// One folder of images: where, how many, their size.
#[derive(Debug, Serialize)]
struct ImageSet {
    dir: PathBuf,
    images: usize,
    width_px: u32,
    height_px: u32,
}

impl ImageSet {
    fn new(dir: PathBuf, images: usize, (width_px, height_px): (u32, u32)) -> Self {
        Self {
            dir,
            images,
            width_px,
            height_px,
        }
    }
}

/// Files and bytes under an output folder.
#[derive(Debug, Default, Serialize)]
struct Written {
    files: u64,
    bytes: u64,
}

impl Written {
    fn of(dir: &Path) -> Result<Self> {
        let mut w = Self::default();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for entry in
                std::fs::read_dir(&d).with_context(|| format!("listing {}", d.display()))?
            {
                let entry = entry.with_context(|| format!("listing {}", d.display()))?;
                let meta = entry
                    .metadata()
                    .with_context(|| format!("reading {}", entry.path().display()))?;
                if meta.is_dir() {
                    stack.push(entry.path());
                } else {
                    w.files += 1;
                    w.bytes += meta.len();
                }
            }
        }
        Ok(w)
    }
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
        layout: match layout {
            SceneLayout::Objects => "objects",
            SceneLayout::Wall => "wall",
        },
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

fn progress_bar(total: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(total as u64);
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}") {
        bar.set_style(style);
    }
    bar.set_message(what.to_owned());
    bar
}

/// A stop flag that SIGINT/SIGTERM set, so Ctrl-C stops the rig cleanly (socket removed).
/// Real handlers (`ctrlc`), not signals blocked in this thread and taken by a waiting one: a
/// process-directed signal goes to any thread that does not block it, and libraries start
/// threads before `main` runs (OpenBLAS, linked through OpenCV, starts its pool at load), so
/// a mask set here does not cover them and the signal killed the rig with its socket left.
fn stop_on_signals() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || {
        tracing::info!("SIGINT/SIGTERM: stopping");
        flag.store(true, Ordering::Relaxed);
    })
    .context("installing the SIGINT/SIGTERM handler")?;
    Ok(stop)
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Board {
            out,
            views,
            profile,
            polarity,
            seed,
            rgb_size,
            json,
        } => {
            let start = Instant::now();
            let rgb = match rgb_size {
                RgbSizeArg::Full => RgbProfile::hd720(),
                RgbSizeArg::Binned => RgbProfile::hd720().binned2(),
            };
            let cfg = BoardSetConfig {
                out_dir: out.clone(),
                views,
                rig: Rig::new(profile.profile(), rgb),
                board: BoardSpec::default(),
                polarity: match polarity {
                    PolarityArg::Cooled => Polarity::Cooled,
                    PolarityArg::Heated => Polarity::Heated,
                },
                seed,
                first_view_s: 60.0,
                view_interval_s: 8.0,
            };
            let bar = progress_bar(views, "board views");
            write_board_set(&cfg, &mut |done, _| bar.set_position(done as u64))
                .with_context(|| format!("writing the board set to {}", out.display()))?;
            bar.finish();
            let seconds = start.elapsed().as_secs_f64();
            tracing::info!(views, seconds, "board set written to {}", out.display());
            if json {
                let thermal = cfg.rig.thermal;
                let summary = BoardSummary {
                    command: "board",
                    out: out.clone(),
                    views,
                    profile: thermal.name,
                    polarity: match cfg.polarity {
                        Polarity::Cooled => "cooled",
                        Polarity::Heated => "heated",
                    },
                    seed,
                    thermal: ImageSet::new(
                        out.join("thermal"),
                        views,
                        (thermal.camera.width_px, thermal.camera.height_px),
                    ),
                    rgb: ImageSet::new(
                        out.join("rgb"),
                        views,
                        (cfg.rig.rgb.camera.width_px, cfg.rig.rgb.camera.height_px),
                    ),
                    board_toml: out.join("board.toml"),
                    truth: out.join("truth.json"),
                    written: Written::of(&out)?,
                    seconds,
                };
                println!("{}", serde_json::to_string_pretty(&summary)?);
            }
            Ok(())
        }
        Command::Scene {
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
        } => {
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
        Command::Run {
            profile,
            rgb,
            rgb_size,
            socket,
            duration,
            rgb_format,
            low_light,
            telemetry,
            seed,
            walk,
            truth_dir,
            walk_tags,
            walk_board,
        } => {
            let mut thermal = profile.profile();
            if telemetry {
                thermal.telemetry_rows = 2;
            }
            let cfg = ServeConfig {
                thermal,
                rgb: rgb.then(|| {
                    let full = if low_light {
                        RgbProfile::hd720_low_light()
                    } else {
                        RgbProfile::hd720()
                    };
                    match rgb_size {
                        RgbSizeArg::Full => full,
                        RgbSizeArg::Binned => full.binned2(),
                    }
                }),
                rgb_format: match rgb_format {
                    RgbFormatArg::Mjpeg => RgbFormat::Mjpeg,
                    RgbFormatArg::Yuyv => RgbFormat::Yuyv,
                },
                socket,
                duration_s: duration,
                seed,
                stop_on_stdin_eof: true,
                stop: stop_on_signals()?,
            };
            let mut announce = |key: &str, value: &str| {
                println!("{key}: {value}");
                // The parent reads these lines as they come.
                let _ = std::io::Write::flush(&mut std::io::stdout());
            };
            if let Some(kind) = walk {
                let stop = s3tir_firmware_sim::serve::watch_stop(&cfg);
                let rig = WalkRig {
                    thermal: cfg.thermal,
                    rgb: cfg.rgb,
                    seed,
                };
                let spec = WalkSpec {
                    kind: match kind {
                        WalkArg::Orbit => WalkKind::Orbit,
                        WalkArg::Handheld => WalkKind::Handheld,
                        WalkArg::Board => WalkKind::Board,
                    },
                    duration_s: cfg.duration_s.unwrap_or(20.0),
                    truth_dir,
                    room: WalkRoom {
                        tags: match walk_tags {
                            WalkTagsArg::Printed => TagInk::Printed,
                            WalkTagsArg::Heated => TagInk::Heated,
                        },
                        board: walk_board,
                    },
                };
                serve_walk(&cfg.socket, &rig, &spec, stop, &mut announce)
                    .context("running the simulated walk")?;
                return Ok(());
            }
            serve(cfg, &mut announce).context("running the simulated rig")?;
            Ok(())
        }
    }
}
