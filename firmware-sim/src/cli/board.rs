//! `s3tir-firmware-sim board`: the emissivity board's calibration set with its truth.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use s3tir_firmware_sim::board::BoardSpec;
use s3tir_firmware_sim::dataset::{BoardSetConfig, Polarity, write_board_set};
use s3tir_firmware_sim::rig::Rig;
use s3tir_firmware_sim::sensor::RgbProfile;
use serde::Serialize;

use super::{ImageSet, ProfileArg, RgbSizeArg, Written, progress_bar};

/// Options of `s3tir-firmware-sim board`.
#[derive(Debug, Args)]
pub struct BoardArgs {
    /// Output directory (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Number of views.
    #[arg(long, default_value_t = 30)]
    pub views: usize,
    /// Thermal core.
    #[arg(long, value_enum, default_value = "lepton35")]
    pub profile: ProfileArg,
    /// Thermal-gradient induction of the board.
    #[arg(long, value_enum, default_value = "cooled")]
    pub polarity: PolarityArg,
    /// Random seed (poses, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// RGB image size: the full 1280×720, or 640×360 (2×2 binned, what `run` serves by
    /// default: calibrate with this size to pose the live rig's sessions).
    #[arg(long, value_enum, default_value = "1280x720")]
    pub rgb_size: RgbSizeArg,
    /// Print one JSON object on stdout when done: what was written (paths, view counts,
    /// image sizes, files and bytes).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum PolarityArg {
    /// Board at 25 °C moved into −20 °C surroundings (TGA-GS): coated squares look colder.
    Cooled,
    /// Board at 25 °C moved into 70 °C surroundings: coated squares look warmer.
    Heated,
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

/// Writes the board set `a` asks for.
pub fn run(a: BoardArgs) -> Result<()> {
    let BoardArgs {
        out,
        views,
        profile,
        polarity,
        seed,
        rgb_size,
        json,
    } = a;
    let start = Instant::now();
    let rgb = rgb_size.apply(RgbProfile::hd720());
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
