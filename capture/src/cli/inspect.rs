//! `s3tir-capture inspect FILE…`: what a thermal image file from another camera holds — its
//! metadata (camera, capture time, GPS, altitudes, gimbal and flight angles); for FLIR `.fff`
//! frames and radiometric JPEGs, the camera's calibration, the conditions it stored and the
//! temperatures under them or under the conditions given; for 16-bit or float grey PNG/TIFF,
//! the temperatures in the stated `--units`; for 8-bit pictures, that they hold none — and, with
//! `--out`, each frame with temperatures as s3tir's 16-bit centikelvin PNG with the parameters
//! used beside them.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use s3tir_capture::image_meta::{GeoPosition, ImageMeta};
use s3tir_capture::radiometric::fff::RawEncoding;
use s3tir_capture::radiometric::{
    CameraInfo, ConditionOverrides, Conditions, Radiometric, ThermalFile, Units, centikelvin_words,
};
use serde::Serialize;

/// Options of `s3tir-capture inspect`.
#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Image files: FLIR `.fff` frames, radiometric JPEGs (FLIR hand-helds, DJI Zenmuse
    /// XT/XT2, Duo Pro R), or any JPEG/TIFF/PNG for its metadata.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Write each radiometric file as FILE_STEM.png (16-bit, 0.01 K per count) and
    /// inspect.json (every file's metadata, camera, calibration and the conditions used) into
    /// this folder.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    conditions: ConditionOverrides,
    /// What the values of 16-bit or float grey PNG/TIFF files are (the files do not say):
    /// kelvin, decikelvin, centikelvin, millikelvin, celsius, decicelsius, centicelsius,
    /// millicelsius, or raw (counts, no temperature).
    #[arg(long)]
    units: Option<Units>,
    /// Print one JSON array (one object per file) instead of lines.
    #[arg(long)]
    json: bool,
}

/// One file's summary.
#[derive(Debug, Serialize)]
struct FileSummary {
    file: PathBuf,
    metadata: ImageMeta,
    /// A FLIR radiometric file's content.
    radiometric: Option<RadiometricSummary>,
    /// A 16-bit or float grey image's temperatures in the stated `--units`.
    scaled: Option<ScaledSummary>,
    /// Neither: an 8-bit picture (no temperature), width × height.
    picture8: Option<(usize, usize)>,
}

#[derive(Debug, Serialize)]
struct ScaledSummary {
    width: usize,
    height: usize,
    units: Units,
    /// `None` for raw counts.
    kelvin_min: Option<f64>,
    kelvin_median: Option<f64>,
    kelvin_max: Option<f64>,
    written: Option<PathBuf>,
}

#[derive(Debug, Serialize)]
struct RadiometricSummary {
    width: usize,
    height: usize,
    encoding: RawEncoding,
    camera: CameraInfo,
    /// The conditions the temperatures were computed under (the file's, overridden).
    conditions_used: Conditions,
    kelvin_min: f64,
    kelvin_median: f64,
    kelvin_max: f64,
    /// Pixels without a temperature (a word below what the surroundings alone give).
    invalid_pixels: usize,
    /// The FFF's own GPS record.
    gps: Option<GeoPosition>,
    written: Option<PathBuf>,
}

impl InspectArgs {
    fn radiometric(&self, file: &std::path::Path, r: Radiometric) -> Result<RadiometricSummary> {
        let conditions = self
            .conditions
            .apply(&r.camera.conditions)
            .with_context(|| file.display().to_string())?;
        let kelvin = r.kelvin(&conditions);
        let spread = Spread::of(&kelvin);
        let written = self.write_kelvin(file, r.raw.width, r.raw.height, &kelvin)?;
        Ok(RadiometricSummary {
            width: r.raw.width,
            height: r.raw.height,
            encoding: r.raw.encoding,
            camera: r.camera,
            conditions_used: conditions,
            kelvin_min: spread.min.unwrap_or(f64::NAN),
            kelvin_median: spread.median.unwrap_or(f64::NAN),
            kelvin_max: spread.max.unwrap_or(f64::NAN),
            invalid_pixels: kelvin.len() - spread.finite,
            gps: r.gps,
            written,
        })
    }
}

impl InspectArgs {
    fn scaled(&self, file: &std::path::Path, f: &ThermalFile) -> Result<ScaledSummary> {
        let ThermalFile::Scaled {
            width,
            height,
            units,
            ..
        } = *f
        else {
            anyhow::bail!("{}: not a scaled image", file.display());
        };
        let kelvin = f.kelvin();
        let spread = kelvin.as_deref().map(Spread::of).unwrap_or_default();
        let written = match &kelvin {
            Some(k) => self.write_kelvin(file, width, height, k)?,
            None => None,
        };
        Ok(ScaledSummary {
            width,
            height,
            units,
            kelvin_min: spread.min,
            kelvin_median: spread.median,
            kelvin_max: spread.max,
            written,
        })
    }
}

impl InspectArgs {
    /// With `--out`, `kelvin` as a 16-bit centikelvin PNG at [`output_path`] (written through
    /// `image`, as `export` writes thermal frames); the path written.
    fn write_kelvin(
        &self,
        file: &std::path::Path,
        width: usize,
        height: usize,
        kelvin: &[f64],
    ) -> Result<Option<PathBuf>> {
        let Some(out) = &self.out else {
            return Ok(None);
        };
        let path = output_path(out, file);
        let size = |n: usize| u32::try_from(n).context("image too large");
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
            size(width)?,
            size(height)?,
            centikelvin_words(kelvin),
        )
        .context("pixel count does not match the size")?;
        img.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(Some(path))
    }
}

/// Smallest, median and largest finite value, and how many are finite.
#[derive(Debug, Default)]
struct Spread {
    min: Option<f64>,
    median: Option<f64>,
    max: Option<f64>,
    finite: usize,
}

impl Spread {
    fn of(values: &[f64]) -> Self {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        Self {
            min: v.first().copied(),
            median: v.get(v.len() / 2).copied(),
            max: v.last().copied(),
            finite: v.len(),
        }
    }
}

/// Where `--out` writes `file`'s temperatures: `OUT/STEM.png`.
fn output_path(out: &std::path::Path, file: &std::path::Path) -> PathBuf {
    let stem = file.file_stem().unwrap_or_default().to_string_lossy();
    out.join(format!("{stem}.png"))
}

/// Runs `inspect`.
pub fn run(a: &InspectArgs) -> Result<()> {
    if let Some(out) = &a.out {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    }
    let mut summaries = Vec::with_capacity(a.files.len());
    // Every output name, checked before anything is written: two inputs with one stem, or an
    // output that is an input (`--out` the input folder), would lose data.
    if let Some(out) = &a.out {
        let mut planned = std::collections::HashMap::new();
        for file in &a.files {
            let target = output_path(out, file);
            if let Some(other) = planned.insert(target.clone(), file) {
                anyhow::bail!(
                    "{} and {} would both be written as {}: inspect them into separate --out \
                     folders",
                    other.display(),
                    file.display(),
                    target.display()
                );
            }
            if let (Ok(a), Ok(b)) = (target.canonicalize(), file.canonicalize())
                && a == b
            {
                anyhow::bail!(
                    "--out would overwrite the input {}: write into another folder",
                    file.display()
                );
            }
        }
    }
    for file in &a.files {
        let metadata = ImageMeta::read(file)?;
        let mut summary = FileSummary {
            file: file.clone(),
            metadata,
            radiometric: None,
            scaled: None,
            picture8: None,
        };
        match ThermalFile::read(file, a.units)? {
            ThermalFile::Radiometric(r) => summary.radiometric = Some(a.radiometric(file, *r)?),
            f @ ThermalFile::Scaled { .. } => summary.scaled = Some(a.scaled(file, &f)?),
            ThermalFile::Picture8 { width, height } => summary.picture8 = Some((width, height)),
        }
        summaries.push(summary);
    }
    if let Some(out) = &a.out {
        let path = out.join("inspect.json");
        let text = serde_json::to_string_pretty(&summaries)?;
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summaries)?);
        return Ok(());
    }
    for s in &summaries {
        println!("{}", s.file.display());
        print_metadata(&s.metadata, s.radiometric.as_ref().and_then(|r| r.gps));
        if let Some(r) = &s.radiometric {
            print_radiometric(r);
        }
        if let Some(sc) = &s.scaled {
            println!(
                "  {}×{} grey in {:?}{}",
                sc.width,
                sc.height,
                sc.units,
                match (sc.kelvin_min, sc.kelvin_median, sc.kelvin_max) {
                    (Some(lo), Some(mid), Some(hi)) => format!(
                        ": {lo:.2} K … {mid:.2} K … {hi:.2} K ({:.2} … {:.2} … {:.2} °C)",
                        lo - 273.15,
                        mid - 273.15,
                        hi - 273.15
                    ),
                    _ => ": counts, no temperature".to_string(),
                }
            );
            if let Some(w) = &sc.written {
                println!("  wrote {} (16-bit, 0.01 K per count)", w.display());
            }
        }
        if let Some((w, h)) = s.picture8 {
            println!(
                "  {w}×{h} 8-bit picture: no temperatures (its grey levels follow the camera's \
                 gain)"
            );
        }
    }
    Ok(())
}

/// `fff_gps`: the radiometric file's own GPS record, shown where the metadata has no position.
fn print_metadata(m: &ImageMeta, fff_gps: Option<GeoPosition>) {
    let camera = [m.make.as_deref(), m.model.as_deref()]
        .into_iter()
        .flatten()
        .collect::<Vec<_>>()
        .join(" ");
    if !camera.is_empty() || m.capture_time.is_some() {
        println!(
            "  {}{}",
            if camera.is_empty() {
                "camera unknown"
            } else {
                &camera
            },
            m.capture_time
                .as_deref()
                .map_or(String::new(), |t| format!(", taken {t}"))
        );
    }
    let source = if m.gps_xmp.is_some() {
        "DJI XMP"
    } else if m.gps_exif.is_some() {
        "EXIF"
    } else {
        "FLIR GPS record"
    };
    match m.position().or(fff_gps) {
        Some(p) => println!(
            "  GPS {:.7}°, {:.7}°{}{} ({source})",
            p.latitude_deg,
            p.longitude_deg,
            p.altitude_m
                .map_or(String::new(), |a| format!(", {a:.2} m")),
            m.relative_altitude_m
                .map_or(String::new(), |a| format!(", {a:.2} m above take-off")),
        ),
        None => println!("  no GPS position"),
    }
    if let Some(g) = m.gimbal {
        println!(
            "  gimbal yaw {:.2}°, pitch {:.2}°, roll {:.2}°",
            g.yaw_deg, g.pitch_deg, g.roll_deg
        );
    }
    if let Some(f) = m.focal_length_mm {
        println!("  focal length {f} mm");
    }
}

fn print_radiometric(s: &RadiometricSummary) {
    let c = &s.conditions_used;
    let p = &s.camera.planck;
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
