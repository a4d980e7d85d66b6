//! `s3tir-capture radiometric FILE…`: what a FLIR `.fff` frame or radiometric JPEG holds — the
//! camera, its calibration and the conditions it stored, the temperatures under them or under
//! the conditions given — and, with `--out`, each frame as s3tir's 16-bit centikelvin PNG with
//! the parameters used recorded beside them.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use s3tir_capture::radiometric::{
    CameraInfo, Conditions, Radiometric, centikelvin_words, write_png16,
};
use serde::Serialize;

/// Options of `s3tir-capture radiometric`.
#[derive(Debug, Args)]
pub struct RadiometricArgs {
    /// FLIR `.fff` frames or radiometric JPEGs (FLIR hand-helds, DJI Zenmuse XT/XT2, Duo Pro R).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Write FILE_STEM.png (16-bit, 0.01 K per count) per file and radiometric.json (every
    /// file's camera, calibration and the conditions used) into this folder.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Object emissivity [default: the file's].
    #[arg(long)]
    emissivity: Option<f64>,
    /// Object distance, metres [default: the file's].
    #[arg(long = "distance-m")]
    distance_m: Option<f64>,
    /// Reflected apparent temperature, °C [default: the file's].
    #[arg(long = "reflected-c")]
    reflected_c: Option<f64>,
    /// Air temperature, °C [default: the file's].
    #[arg(long = "atmosphere-c")]
    atmosphere_c: Option<f64>,
    /// Relative humidity, per cent [default: the file's].
    #[arg(long = "humidity-percent")]
    humidity_percent: Option<f64>,
    /// IR window temperature, °C [default: the file's].
    #[arg(long = "window-c")]
    window_c: Option<f64>,
    /// IR window transmission (1: no window) [default: the file's].
    #[arg(long = "window-transmission")]
    window_transmission: Option<f64>,
    /// Print one JSON array (one object per file) instead of lines.
    #[arg(long)]
    json: bool,
}

/// One file's summary.
#[derive(Debug, Serialize)]
struct FileSummary {
    file: PathBuf,
    width: usize,
    height: usize,
    encoding: s3tir_capture::radiometric::fff::RawEncoding,
    camera: CameraInfo,
    /// The conditions the temperatures were computed under (the file's, overridden).
    conditions_used: Conditions,
    kelvin_min: f64,
    kelvin_median: f64,
    kelvin_max: f64,
    /// Pixels without a temperature (a word below what the surroundings alone give).
    invalid_pixels: usize,
    written: Option<PathBuf>,
}

impl RadiometricArgs {
    /// The file's conditions with the command line's overrides, checked.
    fn conditions(&self, file: &Conditions) -> Result<Conditions> {
        let c = Conditions {
            emissivity: self.emissivity.unwrap_or(file.emissivity),
            object_distance_m: self.distance_m.unwrap_or(file.object_distance_m),
            reflected_k: self.reflected_c.map_or(file.reflected_k, |c| c + 273.15),
            atmosphere_k: self.atmosphere_c.map_or(file.atmosphere_k, |c| c + 273.15),
            relative_humidity: self
                .humidity_percent
                .map_or(file.relative_humidity, |p| p / 100.0),
            window_k: self.window_c.map_or(file.window_k, |c| c + 273.15),
            window_transmission: self.window_transmission.unwrap_or(file.window_transmission),
        };
        let ok = c.emissivity > 0.0
            && c.emissivity <= 1.0
            && c.object_distance_m >= 0.0
            && (0.0..=1.0).contains(&c.relative_humidity)
            && c.window_transmission > 0.0
            && c.window_transmission <= 1.0
            && [c.reflected_k, c.atmosphere_k, c.window_k]
                .iter()
                .all(|k| k.is_finite() && *k > 0.0);
        if !ok {
            anyhow::bail!(
                "conditions out of range: emissivity {} (0–1], distance {} m (≥ 0), humidity \
                 {} (0–100 %), window transmission {} (0–1], temperatures above 0 K",
                c.emissivity,
                c.object_distance_m,
                c.relative_humidity * 100.0,
                c.window_transmission
            );
        }
        Ok(c)
    }
}

/// Runs `radiometric`.
pub fn run(a: &RadiometricArgs) -> Result<()> {
    if let Some(out) = &a.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    }
    let mut summaries = Vec::with_capacity(a.files.len());
    for file in &a.files {
        let r = Radiometric::read(file)?;
        let conditions = a
            .conditions(&r.camera.conditions)
            .with_context(|| file.display().to_string())?;
        let kelvin = r.kelvin(&conditions);
        let mut finite: Vec<f64> = kelvin.iter().copied().filter(|k| k.is_finite()).collect();
        finite.sort_by(f64::total_cmp);
        let written = match &a.out {
            Some(out) => {
                let stem = file.file_stem().unwrap_or_default().to_string_lossy();
                let path = out.join(format!("{stem}.png"));
                write_png16(
                    &path,
                    r.raw.width,
                    r.raw.height,
                    &centikelvin_words(&kelvin),
                )?;
                Some(path)
            }
            None => None,
        };
        summaries.push(FileSummary {
            file: file.clone(),
            width: r.raw.width,
            height: r.raw.height,
            encoding: r.raw.encoding,
            camera: r.camera,
            conditions_used: conditions,
            kelvin_min: finite.first().copied().unwrap_or(f64::NAN),
            kelvin_median: finite.get(finite.len() / 2).copied().unwrap_or(f64::NAN),
            kelvin_max: finite.last().copied().unwrap_or(f64::NAN),
            invalid_pixels: kelvin.len() - finite.len(),
            written,
        });
    }
    if let Some(out) = &a.out {
        let path = out.join("radiometric.json");
        let text = serde_json::to_string_pretty(&summaries)?;
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summaries)?);
        return Ok(());
    }
    for s in &summaries {
        let c = &s.conditions_used;
        let p = &s.camera.planck;
        println!("{}", s.file.display());
        println!(
            "  {} ({}), {}×{} ({})",
            s.camera.camera_model, s.camera.camera_serial_number, s.width, s.height, s.encoding
        );
        // the file stores single precision: shown as such
        let f32s = |v: f64| v as f32;
        println!(
            "  Planck R1 {} R2 {} B {} F {} O {}",
            f32s(p.r1),
            f32s(p.r2),
            f32s(p.b),
            f32s(p.f),
            p.o
        );
        println!(
            "  emissivity {:.3}, distance {:.2} m, reflected {:.2} °C, air {:.2} °C at {:.0} %, \
             window {:.2} °C × {:.2}",
            c.emissivity,
            c.object_distance_m,
            c.reflected_k - 273.15,
            c.atmosphere_k - 273.15,
            c.relative_humidity * 100.0,
            c.window_k - 273.15,
            c.window_transmission
        );
        println!(
            "  {:.2} K … {:.2} K … {:.2} K ({:.2} … {:.2} … {:.2} °C){}",
            s.kelvin_min,
            s.kelvin_median,
            s.kelvin_max,
            s.kelvin_min - 273.15,
            s.kelvin_median - 273.15,
            s.kelvin_max - 273.15,
            if s.invalid_pixels > 0 {
                format!(", {} pixels without a temperature", s.invalid_pixels)
            } else {
                String::new()
            }
        );
        if let Some(w) = &s.written {
            println!("  wrote {} (16-bit, 0.01 K per count)", w.display());
        }
    }
    Ok(())
}
