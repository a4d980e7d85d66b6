//! The folder's images: which are thermal, which are their RGB partners, what each says
//! (metadata) and holds (temperatures, counts or an 8-bit picture).
//!
//! ## Layouts
//! - `DIR/thermal/` (and optionally `DIR/rgb/`): the thermal images and their partners, paired
//!   by file stem (`thermal/Img05.jpg` ↔ `rgb/Img05.jpg`);
//! - `DIR/` with DJI's suffixes: `…_T.JPG` thermal, `…_W.JPG`/`…_V.JPG` (wide/visible) the
//!   partner with the same prefix (M30T, M3T, H20T, XT2);
//! - `DIR/` with images of two sizes (a dual camera writing both, e.g. Mavic 2 Enterprise Dual):
//!   the smaller ones are thermal, the larger their partners, paired by capture time (EXIF
//!   `DateTimeOriginal` within [`PAIR_WITHIN_S`]);
//! - otherwise every image in `DIR` is thermal.
//!
//! ## What a thermal image becomes
//! Through capture's one reader ([`ThermalFile`]): a FLIR radiometric JPEG/FFF becomes kelvin
//! under its own conditions with the command line's overrides ([`ConditionOverrides`]), a 16-bit
//! or float grey TIFF/PNG kelvin through its stated unit (`--image-units`), or counts (`--units raw`),
//! an 8-bit picture its grey values (colour pictures — palette renders — by luma, said in the
//! report). All of a folder must be one kind and one size; anything else is an error naming
//! the files.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use s3tir_capture::image_meta::ImageMeta;
use s3tir_capture::radiometric::{
    ConditionOverrides, Conditions, ThermalFile, Units, centikelvin_words,
};
use serde::Serialize;

use super::super::PosesError;
use crate::progress::Progress;

/// RGB partners found by capture time must be this close (seconds).
pub const PAIR_WITHIN_S: f64 = 1.0;

/// Extensions read as images (case-insensitive).
const IMAGE_EXTENSIONS: &[&str] = &["jpg", "jpeg", "tif", "tiff", "png", "fff"];

/// What a folder's thermal pixels are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelKind {
    /// 16-bit words, 0.01 K per count (radiometric files, or grey images in a temperature unit).
    CentiKelvin,
    /// 16-bit sensor counts (`--units raw`): monotone in radiance, no temperature.
    Counts,
    /// 8-bit grey pictures (automatic gain per frame: the trainer's per-view response fits it).
    Grey8,
}

/// One thermal image's pixels, as the dataset will store them.
#[derive(Debug, Clone)]
pub enum Pixels {
    Words(Vec<u16>),
    Grey8(Vec<u8>),
}

/// One thermal shot of the folder.
#[derive(Debug, Clone)]
pub struct Shot {
    pub path: PathBuf,
    /// File name (unique in the folder).
    pub name: String,
    pub width: usize,
    pub height: usize,
    pub pixels: Pixels,
    pub meta: ImageMeta,
    /// The conditions a radiometric file was converted under.
    pub conditions: Option<Conditions>,
    /// Its RGB partner, when the folder has them.
    pub rgb: Option<PathBuf>,
}

/// The scanned folder.
#[derive(Debug, Clone)]
pub struct Folder {
    pub dir: PathBuf,
    pub kind: PixelKind,
    /// Shots sorted by file name.
    pub shots: Vec<Shot>,
    /// How thermal images and partners were told apart and paired (for the report).
    pub layout: String,
    /// Colour thermal pictures read by their luma (palette renders), if any.
    pub colour_pictures: usize,
    /// RGB images left without a thermal partner.
    pub unpaired_rgb: Vec<String>,
}

impl Folder {
    /// The shots' grey values for image matching, scaled to 0–255 (16-bit words over the
    /// folder's 1st–99th percentile, so every shot has the same scale).
    pub fn grey_for_matching(&self) -> Vec<Vec<f32>> {
        match self.kind {
            PixelKind::Grey8 => self
                .shots
                .iter()
                .map(|s| match &s.pixels {
                    Pixels::Grey8(v) => v.iter().map(|&g| f32::from(g)).collect(),
                    Pixels::Words(w) => w.iter().map(|&g| f32::from(g)).collect(),
                })
                .collect(),
            PixelKind::CentiKelvin | PixelKind::Counts => {
                let mut sample: Vec<u16> = self
                    .shots
                    .iter()
                    .flat_map(|s| match &s.pixels {
                        Pixels::Words(w) => w.iter().step_by(17).copied().collect::<Vec<_>>(),
                        Pixels::Grey8(_) => Vec::new(),
                    })
                    .filter(|&w| w > 0)
                    .collect();
                sample.sort_unstable();
                let at = |q: f64| {
                    sample
                        .get(((sample.len().saturating_sub(1)) as f64 * q) as usize)
                        .map_or(0.0, |&w| f32::from(w))
                };
                let (lo, hi) = (at(0.01), at(0.99));
                let span = (hi - lo).max(1.0);
                self.shots
                    .iter()
                    .map(|s| match &s.pixels {
                        Pixels::Words(w) => w
                            .iter()
                            .map(|&g| ((f32::from(g) - lo) / span * 255.0).clamp(0.0, 255.0))
                            .collect(),
                        Pixels::Grey8(v) => v.iter().map(|&g| f32::from(g)).collect(),
                    })
                    .collect()
            }
        }
    }
}

/// A folder problem (a validation).
fn folder_err(path: &Path, reason: impl Into<String>) -> PosesError {
    PosesError::Folder {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn is_image(p: &Path) -> bool {
    p.is_file()
        && p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Image files directly in `dir`, sorted by name.
fn images_in(dir: &Path) -> Result<Vec<PathBuf>, PosesError> {
    let rd = std::fs::read_dir(dir).map_err(|e| PosesError::ImageRead {
        path: dir.to_path_buf(),
        source: Box::new(e),
    })?;
    let mut v: Vec<PathBuf> = rd
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_image(p))
        .collect();
    v.sort();
    Ok(v)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Thermal paths with their partners (module docs, "Layouts").
struct Layout {
    thermal: Vec<PathBuf>,
    partners: Vec<Option<PathBuf>>,
    unpaired_rgb: Vec<String>,
    words: String,
}

/// Width and height of an image: from its header (JPEG, PNG, TIFF) without decoding it, else
/// (a FLIR `.fff`) through the thermal reader.
fn image_size(p: &Path) -> Result<(u32, u32), PosesError> {
    if let Ok(wh) = image::image_dimensions(p) {
        return Ok(wh);
    }
    let (w, h) = ThermalFile::read(p, Some(Units::Raw))
        .map_err(|e| PosesError::ImageRead {
            path: p.to_path_buf(),
            source: Box::new(e),
        })?
        .size();
    Ok((w as u32, h as u32))
}

fn find_layout(dir: &Path) -> Result<Layout, PosesError> {
    let thermal_dir = dir.join("thermal");
    if thermal_dir.is_dir() {
        let thermal = images_in(&thermal_dir)?;
        let rgb_dir = ["rgb", "visible", "RGB"]
            .iter()
            .map(|n| dir.join(n))
            .find(|d| d.is_dir());
        let rgb = match &rgb_dir {
            Some(d) => images_in(d)?,
            None => Vec::new(),
        };
        let by_stem: BTreeMap<String, PathBuf> = rgb.iter().map(|p| (stem(p), p.clone())).collect();
        let partners: Vec<Option<PathBuf>> = thermal
            .iter()
            .map(|t| by_stem.get(&stem(t)).cloned())
            .collect();
        let used: std::collections::BTreeSet<&PathBuf> = partners.iter().flatten().collect();
        let unpaired_rgb = rgb
            .iter()
            .filter(|p| !used.contains(p))
            .map(|p| file_name(p))
            .collect();
        let words = match &rgb_dir {
            Some(d) => format!("thermal/ and {}/, paired by file name", file_name(d)),
            None => "thermal/ (no RGB folder)".to_owned(),
        };
        return Ok(Layout {
            thermal,
            partners,
            unpaired_rgb,
            words,
        });
    }
    let all = images_in(dir)?;
    let suffix = |p: &Path, s: &[&str]| {
        let st = stem(p);
        s.iter().find_map(|x| st.strip_suffix(x).map(str::to_owned))
    };
    if all.iter().any(|p| suffix(p, &["_T"]).is_some()) {
        let mut rgb: BTreeMap<String, PathBuf> = BTreeMap::new();
        let mut thermal = Vec::new();
        for p in &all {
            if let Some(prefix) = suffix(p, &["_T"]) {
                thermal.push((prefix, p.clone()));
            } else if let Some(prefix) = suffix(p, &["_W", "_V"]) {
                rgb.insert(prefix, p.clone());
            }
        }
        let partners: Vec<Option<PathBuf>> =
            thermal.iter().map(|(pre, _)| rgb.remove(pre)).collect();
        return Ok(Layout {
            thermal: thermal.into_iter().map(|(_, p)| p).collect(),
            partners,
            unpaired_rgb: rgb.values().map(|p| file_name(p)).collect(),
            words: "DJI names: _T thermal, _W/_V partners by prefix".to_owned(),
        });
    }
    // Two sizes: the smaller thermal, the larger partners by capture time.
    let sizes: Vec<(u32, u32)> = all
        .iter()
        .map(|p| image_size(p))
        .collect::<Result<_, _>>()?;
    let mut distinct: Vec<(u32, u32)> = sizes.clone();
    distinct.sort_by_key(|&(w, h)| u64::from(w) * u64::from(h));
    distinct.dedup();
    match distinct.len() {
        0 | 1 => Ok(Layout {
            partners: vec![None; all.len()],
            thermal: all,
            unpaired_rgb: Vec::new(),
            words: "every image thermal".to_owned(),
        }),
        2 => {
            let small = distinct[0];
            let (thermal, rgb): (Vec<_>, Vec<_>) =
                all.iter().zip(&sizes).partition(|(_, s)| **s == small);
            let thermal: Vec<PathBuf> = thermal.into_iter().map(|(p, _)| p.clone()).collect();
            let rgb: Vec<PathBuf> = rgb.into_iter().map(|(p, _)| p.clone()).collect();
            let times = |v: &[PathBuf]| -> Vec<Option<f64>> {
                v.par_iter()
                    .map(|p| {
                        ImageMeta::read(p)
                            .ok()
                            .and_then(|m| m.capture_time.as_deref().and_then(exif_seconds))
                    })
                    .collect()
            };
            let (tt, rt) = (times(&thermal), times(&rgb));
            let mut taken = vec![false; rgb.len()];
            let partners: Vec<Option<PathBuf>> = tt
                .iter()
                .map(|t| {
                    let t = (*t)?;
                    let best = rt
                        .iter()
                        .enumerate()
                        .filter(|(i, r)| !taken[*i] && r.is_some())
                        .map(|(i, r)| (i, (r.unwrap_or(f64::NAN) - t).abs()))
                        .filter(|(_, d)| *d <= PAIR_WITHIN_S)
                        .min_by(|a, b| a.1.total_cmp(&b.1))?;
                    taken[best.0] = true;
                    Some(rgb[best.0].clone())
                })
                .collect();
            let unpaired_rgb = rgb
                .iter()
                .zip(&taken)
                .filter(|(_, t)| !**t)
                .map(|(p, _)| file_name(p))
                .collect();
            Ok(Layout {
                thermal,
                partners,
                unpaired_rgb,
                words: format!(
                    "two sizes: {}×{} thermal, {}×{} partners by capture time (within {PAIR_WITHIN_S} s)",
                    small.0, small.1, distinct[1].0, distinct[1].1
                ),
            })
        }
        _ => {
            let mut by_size: BTreeMap<(u32, u32), Vec<String>> = BTreeMap::new();
            for (p, s) in all.iter().zip(&sizes) {
                by_size.entry(*s).or_default().push(file_name(p));
            }
            let listing: Vec<String> = by_size
                .iter()
                .map(|((w, h), names)| {
                    let shown: Vec<&str> = names.iter().take(3).map(String::as_str).collect();
                    format!(
                        "{w}×{h}: {} image(s) ({}{})",
                        names.len(),
                        shown.join(", "),
                        if names.len() > 3 { ", …" } else { "" }
                    )
                })
                .collect();
            Err(folder_err(
                dir,
                format!(
                    "images of {} different sizes ({}): one thermal camera's images (and optionally one partner camera's) expected; put other images elsewhere",
                    distinct.len(),
                    listing.join("; ")
                ),
            ))
        }
    }
}

/// Seconds since the epoch of the year 0 (only differences are used) of an EXIF time
/// `YYYY:MM:DD HH:MM:SS[.fff]`.
pub fn exif_seconds(t: &str) -> Option<f64> {
    let (date, time) = t.trim().split_once(' ')?;
    let d: Vec<i64> = date
        .split(':')
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    let (hms, frac) = match time.split_once('.') {
        Some((a, b)) => (a, format!("0.{b}").parse::<f64>().ok()?),
        None => (time, 0.0),
    };
    let h: Vec<i64> = hms
        .split(':')
        .map(|x| x.parse().ok())
        .collect::<Option<_>>()?;
    if d.len() != 3 || h.len() != 3 {
        return None;
    }
    // Days from a civil date (Howard Hinnant's algorithm), enough for differences.
    let (y, m, day) = (d[0] - i64::from(d[1] <= 2), d[1], d[2]);
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe;
    Some((days * 86_400 + h[0] * 3600 + h[1] * 60 + h[2]) as f64 + frac)
}

/// One thermal file read and converted (module docs).
fn read_shot(
    path: &Path,
    units: Option<Units>,
    overrides: &ConditionOverrides,
) -> Result<(Shot, PixelKind, bool), PosesError> {
    let read_err = |e: Box<dyn std::error::Error + Send + Sync>| PosesError::ImageRead {
        path: path.to_path_buf(),
        source: e,
    };
    let meta = ImageMeta::read(path).map_err(|e| read_err(Box::new(e)))?;
    let file = ThermalFile::read(path, units).map_err(|e| read_err(Box::new(e)))?;
    let (width, height) = file.size();
    let mut colour = false;
    let (pixels, kind, conditions) = match file {
        ThermalFile::Radiometric(r) => {
            let c = overrides
                .apply(&r.camera.conditions)
                .map_err(|e| read_err(Box::new(e)))?;
            (
                Pixels::Words(centikelvin_words(&r.kelvin(&c))),
                PixelKind::CentiKelvin,
                Some(c),
            )
        }
        ThermalFile::Scaled { values, units, .. } => match units {
            Units::Raw => (
                Pixels::Words(
                    values
                        .iter()
                        .map(|&v| v.round().clamp(0.0, 65535.0) as u16)
                        .collect(),
                ),
                PixelKind::Counts,
                None,
            ),
            u => {
                let k: Vec<f64> = values
                    .iter()
                    .map(|&v| u.kelvin(v).unwrap_or(f64::NAN))
                    .collect();
                (
                    Pixels::Words(centikelvin_words(&k)),
                    PixelKind::CentiKelvin,
                    None,
                )
            }
        },
        ThermalFile::Picture8 { .. } => {
            let img = image::open(path).map_err(|e| read_err(Box::new(e)))?;
            // Grey stored in three channels (common for thermal JPEGs) is not a palette.
            colour = img.color().has_color() && {
                let rgb = img.to_rgb8();
                let tinted = rgb
                    .pixels()
                    .step_by(7)
                    .filter(|p| {
                        let [r, g, b] = p.0;
                        r.abs_diff(g) > 8 || g.abs_diff(b) > 8
                    })
                    .count();
                tinted * 7 * 100 > rgb.len() / 3
            };
            (
                Pixels::Grey8(img.into_luma8().into_raw()),
                PixelKind::Grey8,
                None,
            )
        }
    };
    let n = match &pixels {
        Pixels::Words(w) => w.len(),
        Pixels::Grey8(g) => g.len(),
    };
    if n != width * height {
        return Err(folder_err(
            path,
            format!("decoded {n} pixels, its header says {width}×{height}"),
        ));
    }
    Ok((
        Shot {
            path: path.to_path_buf(),
            name: file_name(path),
            width,
            height,
            pixels,
            meta,
            conditions,
            rgb: None,
        },
        kind,
        colour,
    ))
}

/// Scans `dir` (module docs): every thermal image read and converted, in parallel.
pub fn scan(
    dir: &Path,
    units: Option<Units>,
    overrides: &ConditionOverrides,
    progress: &dyn Progress,
) -> Result<Folder, PosesError> {
    if !dir.is_dir() {
        return Err(folder_err(dir, "not a folder"));
    }
    let layout = find_layout(dir)?;
    if layout.thermal.is_empty() {
        return Err(folder_err(
            dir,
            format!(
                "no images ({} files, or a thermal/ subfolder with them, expected)",
                IMAGE_EXTENSIONS.join(", ")
            ),
        ));
    }
    progress.start("reading images", Some(layout.thermal.len() as u64));
    let read: Vec<(Shot, PixelKind, bool)> = layout
        .thermal
        .par_iter()
        .map(|p| {
            let r = read_shot(p, units, overrides);
            progress.advance(1);
            r
        })
        .collect::<Result<_, _>>()?;
    progress.finish();
    let (w, h) = (read[0].0.width, read[0].0.height);
    let odd: Vec<String> = read
        .iter()
        .filter(|(s, _, _)| (s.width, s.height) != (w, h))
        .map(|(s, _, _)| format!("{} ({}×{})", s.name, s.width, s.height))
        .collect();
    if !odd.is_empty() {
        return Err(folder_err(
            dir,
            format!(
                "thermal images of mixed sizes: {} is {w}×{h} but {}",
                read[0].0.name,
                odd.join(", ")
            ),
        ));
    }
    let kind = read[0].1;
    let other: Vec<&str> = read
        .iter()
        .filter(|(_, k, _)| *k != kind)
        .map(|(s, _, _)| s.name.as_str())
        .collect();
    if !other.is_empty() {
        return Err(folder_err(
            dir,
            format!(
                "thermal images of mixed kinds: {} reads as {kind:?} but {} do not (radiometric and plain pictures, or different units, in one folder)",
                read[0].0.name,
                other.join(", ")
            ),
        ));
    }
    let colour_pictures = read.iter().filter(|(_, _, c)| *c).count();
    let shots = read
        .into_iter()
        .zip(layout.partners)
        .map(|((mut s, _, _), rgb)| {
            s.rgb = rgb;
            s
        })
        .collect();
    Ok(Folder {
        dir: dir.to_path_buf(),
        kind,
        shots,
        layout: layout.words,
        colour_pictures,
        unpaired_rgb: layout.unpaired_rgb,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::expect_used)]

    use super::*;

    #[test]
    fn exif_times_differ_by_their_seconds() {
        let a = exif_seconds("2024:02:28 23:59:59").expect("parses");
        let b = exif_seconds("2024:02:29 00:00:01.5").expect("parses");
        assert!((b - a - 2.5).abs() < 1e-9, "leap day crossing: {}", b - a);
        let c = exif_seconds("2025:01:01 00:00:00").expect("parses");
        assert!((c - a - (307.0 * 86400.0 + 1.0)).abs() < 1e-6, "{}", c - a);
        assert!(exif_seconds("2024-02-28").is_none());
    }
}
