//! The `s3tir-firmware-sim` subcommands, one module each (`board`, `scene`, `run`), and what
//! they share: the thermal-core and RGB-size options, the `--json` summaries' parts, progress.

pub mod board;
pub mod run;
pub mod scene;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};
use s3tir_firmware_sim::sensor::{RgbProfile, ThermalProfile};
use serde::Serialize;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum ProfileArg {
    /// FLIR Lepton 3.5: 160×120 Y16 at 8.7 Hz.
    Lepton35,
    /// FLIR Boson 640: 640×512 Y16 at 60 Hz.
    Boson640,
}

impl ProfileArg {
    pub(crate) fn profile(self) -> ThermalProfile {
        match self {
            ProfileArg::Lepton35 => ThermalProfile::lepton35(),
            ProfileArg::Boson640 => ThermalProfile::boson640(),
        }
    }
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub(crate) enum RgbSizeArg {
    /// 640×360 (the 1280×720 camera binned 2×2): a quarter of the per-frame work.
    #[value(name = "640x360")]
    Binned,
    /// 1280×720, the camera's full resolution (what `board` renders).
    #[value(name = "1280x720")]
    Full,
}

impl RgbSizeArg {
    /// `full` at this size.
    pub(crate) fn apply(self, full: RgbProfile) -> RgbProfile {
        match self {
            RgbSizeArg::Full => full,
            RgbSizeArg::Binned => full.binned2(),
        }
    }
}

/// One folder of images: where, how many, their size.
#[derive(Debug, Serialize)]
pub(crate) struct ImageSet {
    dir: PathBuf,
    images: usize,
    width_px: u32,
    height_px: u32,
}

impl ImageSet {
    pub(crate) fn new(dir: PathBuf, images: usize, (width_px, height_px): (u32, u32)) -> Self {
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
pub(crate) struct Written {
    files: u64,
    bytes: u64,
}

impl Written {
    pub(crate) fn of(dir: &Path) -> Result<Self> {
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

pub(crate) fn progress_bar(total: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(total as u64);
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}") {
        bar.set_style(style);
    }
    bar.set_message(what.to_owned());
    bar
}
