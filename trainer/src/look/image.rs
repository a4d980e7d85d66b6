//! A scalar plane drawn through a palette as an 8-bit RGB PNG, with the scale it was drawn
//! over written into the file as PNG `tEXt` chunks (`s3tir:palette`, `s3tir:min`, `s3tir:max`,
//! `s3tir:unit`), so a program — or a person with `exiftool` — reads the colours back as values.
//! Values outside the range take the end colours; non-finite values take the coldest.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use s3tir_calib::model::palette::Colormap;

use crate::dataset::ThermalRange;

/// Why a palette image could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}")]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format {
        path: std::path::PathBuf,
        reason: String,
    },
    #[error("encoding PNG {path}")]
    Encode {
        path: std::path::PathBuf,
        #[source]
        source: png::EncodingError,
    },
    #[error("reading PNG {path}")]
    Decode {
        path: std::path::PathBuf,
        #[source]
        source: png::DecodingError,
    },
}

/// The PNG `tEXt` keywords of a palette image.
pub const KEY_PALETTE: &str = "s3tir:palette";
pub const KEY_MIN: &str = "s3tir:min";
pub const KEY_MAX: &str = "s3tir:max";
pub const KEY_UNIT: &str = "s3tir:unit";

/// How values become colours: the palette, the range mapped onto it and the values' unit.
#[derive(Debug, Clone, PartialEq)]
pub struct Scale {
    pub palette: Colormap,
    /// The value drawn in the palette's first colour.
    pub lo: f64,
    /// The value drawn in its last colour.
    pub hi: f64,
    /// What the values are (Latin-1: it goes into a PNG `tEXt` chunk): `K`, `normalised`,
    /// `beta`, `scene units`.
    pub unit: String,
}

impl Scale {
    pub fn new(palette: Colormap, lo: f64, hi: f64, unit: &str) -> Self {
        Self {
            palette,
            lo,
            hi,
            unit: unit.to_string(),
        }
    }

    /// A scale over the `q`…`1 − q` quantiles of the finite values (a few hot or cold pixels
    /// do not wash the image out); a flat or empty plane gets a unit-wide range around its
    /// value.
    pub fn robust(palette: Colormap, values: &[f32], q: f64, unit: &str) -> Self {
        match (quantile(values, q), quantile(values, 1.0 - q)) {
            (Some(lo), Some(hi)) if hi > lo => Self::new(palette, lo, hi, unit),
            (Some(v), _) => Self::new(palette, v - 0.5, v + 0.5, unit),
            _ => Self::new(palette, 0.0, 1.0, unit),
        }
    }

    /// A scale symmetric about 0 (a diverging palette's middle) over `±` the `1 − q` quantile
    /// of `|values|`.
    pub fn symmetric(palette: Colormap, values: &[f32], q: f64, unit: &str) -> Self {
        let abs: Vec<f32> = values.iter().map(|x| x.abs()).collect();
        let hi = quantile(&abs, 1.0 - q).filter(|&h| h > 0.0).unwrap_or(1.0);
        Self::new(palette, -hi, hi, unit)
    }

    /// The position of `v` along the palette, in [0, 1] (NaN for non-finite values).
    pub fn position(&self, v: f64) -> f64 {
        if !v.is_finite() {
            return f64::NAN;
        }
        let span = if self.hi > self.lo {
            self.hi - self.lo
        } else {
            1.0
        };
        ((v - self.lo) / span).clamp(0.0, 1.0)
    }

    /// The colour of `v`.
    pub fn colour(&self, v: f64) -> [u8; 3] {
        self.palette.colour(self.position(v))
    }

    /// The value a palette entry (0..=255) stands for: what a reader of the image gets back.
    pub fn value_of_entry(&self, entry: u8) -> f64 {
        self.lo + (self.hi - self.lo) * f64::from(entry) / 255.0
    }

    /// `plane` drawn as RGB8, row-major.
    pub fn colourise(&self, plane: &[f32]) -> Vec<u8> {
        plane
            .iter()
            .flat_map(|&v| self.colour(f64::from(v)))
            .collect()
    }
}

/// The `q` quantile of the finite values (nearest rank; `None` when there are none).
pub fn quantile(values: &[f32], q: f64) -> Option<f64> {
    let mut v: Vec<f64> = values
        .iter()
        .map(|&x| f64::from(x))
        .filter(|x| x.is_finite())
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize])
}

/// How normalised thermal values are shown: kelvin for radiometric data, else the dataset's
/// normalised unit.
#[derive(Debug, Clone, Copy)]
pub struct DisplayUnits {
    pub range: Option<ThermalRange>,
}

impl DisplayUnits {
    pub fn radiometric(&self) -> bool {
        self.range.as_ref().is_some_and(ThermalRange::radiometric)
    }
    /// A normalised value in the shown unit.
    pub fn value(&self, normalised: f32) -> f32 {
        match &self.range {
            Some(r) if r.radiometric() => r.kelvin(f64::from(normalised)).unwrap_or(0.0) as f32,
            _ => normalised,
        }
    }
    /// A normalised difference in the shown unit.
    pub fn difference(&self, normalised: f32) -> f32 {
        match self.range.as_ref().and_then(ThermalRange::kelvin_per_unit) {
            Some(k) => (f64::from(normalised) * k) as f32,
            None => normalised,
        }
    }
    pub fn unit(&self) -> &'static str {
        if self.radiometric() {
            "K"
        } else {
            "normalised"
        }
    }
    pub fn error_unit(&self) -> &'static str {
        if self.radiometric() {
            "K error"
        } else {
            "normalised"
        }
    }
    /// A 16-bit render's word (the dataset's raw unit) in the shown unit.
    pub fn value_of_raw(&self, raw: u16) -> f32 {
        match &self.range {
            Some(r) => self.value(r.normalise(f64::from(raw))),
            None => f32::from(raw) / 65535.0,
        }
    }

    /// `{stem}_ironbow.png`: the readable copy written beside a 16-bit thermal output.
    pub fn ironbow_copy_name(stem: &str) -> String {
        format!("{stem}_ironbow.png")
    }

    /// Writes the readable copy of the normalised thermal `plane` beside its 16-bit file:
    /// `DIR/{stem}_ironbow.png` in the shown unit over the 1st–99th percentile of
    /// `reference` (the recorded frame, so a render and its frame share colours), or of the
    /// plane itself without one.
    pub fn write_ironbow_copy(
        &self,
        dir: &Path,
        stem: &str,
        plane: &[f32],
        (width, height): (usize, usize),
        reference: Option<&[f32]>,
    ) -> Result<(), ImageError> {
        let shown: Vec<f32> = plane.iter().map(|&v| self.value(v)).collect();
        let scale = match reference {
            Some(r) => {
                let r: Vec<f32> = r.iter().map(|&v| self.value(v)).collect();
                Scale::robust(Colormap::Ironbow, &r, 0.01, self.unit())
            }
            None => Scale::robust(Colormap::Ironbow, &shown, 0.01, self.unit()),
        };
        write_palette_png(
            &dir.join(Self::ironbow_copy_name(stem)),
            &shown,
            width,
            height,
            &scale,
        )
    }
}

/// Writes `plane` (`width × height`, row-major) through `scale` as an 8-bit RGB PNG with the
/// scale in its `tEXt` chunks.
pub fn write_palette_png(
    path: &Path,
    plane: &[f32],
    width: usize,
    height: usize,
    scale: &Scale,
) -> Result<(), ImageError> {
    if plane.len() != width * height {
        return Err(ImageError::Format {
            path: path.to_path_buf(),
            reason: format!("plane has {} values, not {width}×{height}", plane.len()),
        });
    }
    write_rgb_with_scale(path, &scale.colourise(plane), width, height, Some(scale))
}

/// Writes RGB8 pixels as a PNG, with `scale`'s `tEXt` chunks when given.
pub fn write_rgb_with_scale(
    path: &Path,
    rgb: &[u8],
    width: usize,
    height: usize,
    scale: Option<&Scale>,
) -> Result<(), ImageError> {
    let enc_err = |source| ImageError::Encode {
        path: path.to_path_buf(),
        source,
    };
    let file = File::create(path).map_err(|source| ImageError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut enc = png::Encoder::new(BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    if let Some(s) = scale {
        for (key, text) in [
            (KEY_PALETTE, s.palette.name().to_string()),
            // `{:?}` of an f64 is the shortest text that parses back to the same value.
            (KEY_MIN, format!("{:?}", s.lo)),
            (KEY_MAX, format!("{:?}", s.hi)),
            (KEY_UNIT, latin1(&s.unit)),
        ] {
            enc.add_text_chunk(key.to_string(), text).map_err(enc_err)?;
        }
    }
    let mut w = enc.write_header().map_err(enc_err)?;
    w.write_image_data(rgb).map_err(enc_err)?;
    w.finish().map_err(enc_err)
}

/// The scale a palette PNG was drawn with ([`write_palette_png`]).
pub fn read_scale(path: &Path) -> Result<Scale, ImageError> {
    let file = File::open(path).map_err(|source| ImageError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let reader = png::Decoder::new(BufReader::new(file))
        .read_info()
        .map_err(|source| ImageError::Decode {
            path: path.to_path_buf(),
            source,
        })?;
    let text = &reader.info().uncompressed_latin1_text;
    let get = |key: &str| {
        text.iter()
            .find(|c| c.keyword == key)
            .map(|c| c.text.clone())
            .ok_or_else(|| ImageError::Format {
                path: path.to_path_buf(),
                reason: format!("no `{key}` text chunk: not a palette image written by s3tir"),
            })
    };
    let number = |key: &str| -> Result<f64, ImageError> {
        let t = get(key)?;
        t.parse().map_err(|_| ImageError::Format {
            path: path.to_path_buf(),
            reason: format!("`{key}` is {t:?}, not a number"),
        })
    };
    let name = get(KEY_PALETTE)?;
    let palette = Colormap::from_name(&name).ok_or_else(|| ImageError::Format {
        path: path.to_path_buf(),
        reason: format!("unknown palette {name:?}"),
    })?;
    Ok(Scale {
        palette,
        lo: number(KEY_MIN)?,
        hi: number(KEY_MAX)?,
        unit: get(KEY_UNIT)?,
    })
}

/// `text` with characters outside Latin-1 spelled out (`β` → `beta`, others `?`): `tEXt` is
/// Latin-1.
fn latin1(text: &str) -> String {
    text.chars()
        .map(|c| match c {
            'β' => "beta".to_string(),
            c if (c as u32) < 256 => c.to_string(),
            _ => "?".to_string(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// A palette PNG reads back its scale exactly, and each pixel's colour maps back (through
    /// the palette's nearest entry and the scale) to its value within one palette step.
    #[test]
    fn a_palette_png_round_trips_its_range_and_values() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (40, 30);
        let plane: Vec<f32> = (0..w * h).map(|i| 280.0 + 0.025 * i as f32).collect();
        for palette in Colormap::ALL {
            let scale = Scale::new(palette, 281.3, 305.1, "K");
            let path = dir.path().join(format!("{}.png", palette.name()));
            write_palette_png(&path, &plane, w, h, &scale).unwrap();
            let back = read_scale(&path).unwrap();
            assert_eq!(back, scale, "{palette:?}: the scale in the file");
            let img = ::image::open(&path).unwrap().to_rgb8();
            assert_eq!((img.width(), img.height()), (w as u32, h as u32));
            let step = (scale.hi - scale.lo) / 255.0;
            for (p, &v) in img.pixels().zip(&plane) {
                let want = f64::from(v).clamp(scale.lo, scale.hi);
                let got = back.value_of_entry(palette.nearest(p.0).0 as u8);
                assert!(
                    (got - want).abs() <= step * 0.51 + 1e-9,
                    "{palette:?}: pixel of {v} reads back as {got} (one step is {step})"
                );
            }
        }
        let unit = Scale::new(Colormap::Inferno, 2.0, 6.0, "β");
        let path = dir.path().join("beta.png");
        write_palette_png(&path, &plane, w, h, &unit).unwrap();
        assert_eq!(read_scale(&path).unwrap().unit, "beta", "Latin-1 unit");
    }

    #[test]
    fn a_plain_png_and_a_wrong_size_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plain.png");
        ::image::RgbImage::new(4, 4).save(&path).unwrap();
        let err = read_scale(&path).unwrap_err().to_string();
        assert!(
            err.contains("plain.png") && err.contains("s3tir:palette"),
            "{err}"
        );
        let scale = Scale::new(Colormap::Ironbow, 0.0, 1.0, "K");
        let err = write_palette_png(&path, &[0.0; 5], 4, 4, &scale)
            .unwrap_err()
            .to_string();
        assert!(err.contains("5 values") && err.contains("4×4"), "{err}");
    }

    #[test]
    fn robust_and_symmetric_scales_ignore_outliers() {
        let mut v: Vec<f32> = (0..1000).map(|i| i as f32 / 1000.0).collect();
        v[0] = -1e6;
        v[1] = f32::NAN;
        let s = Scale::robust(Colormap::Ironbow, &v, 0.01, "K");
        assert!(
            s.lo > 0.0 && s.lo < 0.02 && s.hi > 0.98 && s.hi < 1.0,
            "{s:?}"
        );
        let e = Scale::symmetric(Colormap::Diverging, &[-3.0, 1.0, 2.0, 0.5], 0.0, "K");
        assert_eq!((e.lo, e.hi), (-3.0, 3.0), "symmetric about 0 over max |v|");
        let flat = Scale::robust(Colormap::Grey, &[5.0; 10], 0.01, "K");
        assert!(
            flat.hi > flat.lo,
            "a flat plane still gets a range: {flat:?}"
        );
    }
}
