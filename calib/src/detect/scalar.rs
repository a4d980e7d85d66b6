//! Image files to scalar images: the input of board detection (the detection front end's
//! steps 1–2), OpenCV-free.
//!
//! 1. **Decode to a scalar image** ([`load_scalar`]): 16-bit PNG/TIFF keep their counts
//!    (raw or centikelvin), 8-bit grey its values, RGB/RGBA photos become luminance
//!    (Rec. 601). A thermal image saved as pseudo-colour is mapped back to a scalar by finding,
//!    for each colour, the nearest colour on a known palette curve (ironbow and inferno,
//!    [`crate::model::palette`]); with `palette = "auto"` the palette whose curve fits the image best is used,
//!    and when neither fits (mean colour distance > 24 of 255) luminance is used instead.
//! 2. **Robust 8-bit normalisation** ([`stretch_to_u8`]): a percentile stretch (0.5 % → 0,
//!    99.5 % → 255), so a hot object in a 16-bit frame does not squash the board's few counts
//!    of contrast.

use std::collections::HashMap;
use std::path::Path;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::CalibError;
use crate::model::palette::Colormap;

/// Palette used to map pseudo-colour thermal images back to a scalar (`board.toml`'s
/// `thermal_palette`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Palette {
    /// Best-fitting known palette, else luminance.
    #[default]
    Auto,
    Ironbow,
    Inferno,
    /// Rec. 601 luminance (works for palettes monotonic in brightness).
    Luminance,
}

/// Where a scalar image's values came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SourceKind {
    Grey16,
    Grey8,
    /// Pseudo-colour thermal image inverted through this palette.
    PseudoColour(Palette),
    /// Colour photo reduced to luminance.
    ColourLuminance,
}

/// A single-channel image in f32 (original value scale).
#[derive(Debug, Clone)]
pub struct ScalarImage {
    pub width_px: u32,
    pub height_px: u32,
    pub values: Vec<f32>,
    pub source: SourceKind,
}

impl ScalarImage {
    fn at(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, i64::from(self.width_px) - 1) as usize;
        let y = y.clamp(0, i64::from(self.height_px) - 1) as usize;
        self.values[y * self.width_px as usize + x]
    }

    /// Bilinear sample with pixel centres on integer coordinates (clamped at the border).
    pub fn sample(&self, p: DVec2) -> f64 {
        let x0 = p.x.floor();
        let y0 = p.y.floor();
        let (fx, fy) = (p.x - x0, p.y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let v = |x, y| f64::from(self.at(x, y));
        (1.0 - fy) * ((1.0 - fx) * v(x0, y0) + fx * v(x0 + 1, y0))
            + fy * ((1.0 - fx) * v(x0, y0 + 1) + fx * v(x0 + 1, y0 + 1))
    }
}

/// The palette's table ([`crate::model::palette`]; `None` for `Auto`/`Luminance`).
pub fn palette_lut(palette: Palette) -> Option<&'static [[f32; 3]; 256]> {
    palette_map(palette).map(Colormap::lut)
}

/// The palette a choice names (`None` for `Auto`/`Luminance`).
fn palette_map(palette: Palette) -> Option<Colormap> {
    match palette {
        Palette::Ironbow => Some(Colormap::Ironbow),
        Palette::Inferno => Some(Colormap::Inferno),
        Palette::Auto | Palette::Luminance => None,
    }
}

/// Rec. 601 luminance of an 8-bit RGB colour.
pub fn luminance(rgb: [u8; 3]) -> f32 {
    0.299 * f32::from(rgb[0]) + 0.587 * f32::from(rgb[1]) + 0.114 * f32::from(rgb[2])
}

/// True when the colour image is visibly not grey (some pixels with channel spread > 12).
fn is_pseudo_colour(rgb: &image::RgbImage) -> bool {
    let n = rgb.pixels().len().max(1);
    let coloured = rgb
        .pixels()
        .step_by(7)
        .filter(|p| {
            let (mx, mn) = (p.0.iter().max(), p.0.iter().min());
            matches!((mx, mn), (Some(a), Some(b)) if a - b > 12)
        })
        .count();
    coloured * 7 * 50 > n
}

/// Maps a pseudo-colour image to scalar values by palette inversion (see module docs).
pub fn pseudo_colour_to_scalar(rgb: &image::RgbImage, palette: Palette) -> (Vec<f32>, Palette) {
    let candidates: Vec<Palette> = match palette {
        Palette::Auto => vec![Palette::Ironbow, Palette::Inferno],
        p => vec![p],
    };
    // Fit check on a subsample.
    let mut chosen = Palette::Luminance;
    let mut best_fit = f32::INFINITY;
    for p in candidates {
        let Some(map) = palette_map(p) else {
            continue;
        };
        let sample: Vec<f32> = rgb
            .pixels()
            .step_by(13)
            .map(|px| map.nearest(px.0).1)
            .collect();
        let fit = sample.iter().sum::<f32>() / sample.len().max(1) as f32;
        if fit < best_fit {
            best_fit = fit;
            chosen = p;
        }
    }
    if palette == Palette::Auto && best_fit > 24.0 {
        chosen = Palette::Luminance;
    }
    let values = match palette_map(chosen) {
        None => rgb.pixels().map(|p| luminance(p.0)).collect(),
        Some(map) => {
            let mut cache: HashMap<[u8; 3], f32> = HashMap::new();
            rgb.pixels()
                .map(|p| {
                    *cache
                        .entry(p.0)
                        .or_insert_with(|| map.nearest(p.0).0 as f32)
                })
                .collect()
        }
    };
    (values, chosen)
}

/// Decodes an image file into scalar values. `thermal` enables pseudo-colour inversion.
pub fn load_scalar(
    path: &Path,
    thermal: bool,
    palette: Palette,
) -> Result<ScalarImage, CalibError> {
    let img = image::open(path).map_err(|source| CalibError::ImageFile {
        path: path.to_path_buf(),
        source,
    })?;
    let (w, h) = (img.width(), img.height());
    if w < 16 || h < 16 {
        return Err(CalibError::Image {
            path: path.to_path_buf(),
            reason: format!("{w}x{h} is too small for board detection"),
        });
    }
    use image::DynamicImage as D;
    let (values, source) = match &img {
        D::ImageLuma16(g) => (
            g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            SourceKind::Grey16,
        ),
        D::ImageLumaA16(_) => {
            let g = img.to_luma16();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey16,
            )
        }
        D::ImageLuma8(g) => (
            g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            SourceKind::Grey8,
        ),
        D::ImageLumaA8(_) => {
            let g = img.to_luma8();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey8,
            )
        }
        D::ImageRgb16(_) | D::ImageRgba16(_) | D::ImageRgb32F(_) | D::ImageRgba32F(_) => {
            let g = img.to_luma16();
            (
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
                SourceKind::Grey16,
            )
        }
        _ => {
            let rgb = img.to_rgb8();
            if thermal && is_pseudo_colour(&rgb) {
                let (values, used) = pseudo_colour_to_scalar(&rgb, palette);
                (values, SourceKind::PseudoColour(used))
            } else {
                (
                    rgb.pixels().map(|p| luminance(p.0)).collect(),
                    SourceKind::ColourLuminance,
                )
            }
        }
    };
    Ok(ScalarImage {
        width_px: w,
        height_px: h,
        values,
        source,
    })
}

/// The `lo` and `hi` quantiles (nearest rank) of the finite values, `(0, 0)` when there are
/// none. Two selections instead of a sort (a 4096-bin histogram locating each rank's bin first
/// was slower: 8.3 % of the RGB detection time against 5.9 %).
pub(crate) fn quantiles(values: &[f32], lo: f64, hi: f64) -> (f32, f32) {
    let mut finite: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return (0.0, 0.0);
    }
    let rank = |f: f64| (((finite.len() - 1) as f64 * f).round() as usize).min(finite.len() - 1);
    let (i_lo, i_hi) = (rank(lo.min(hi)), rank(lo.max(hi)));
    let (_, &mut b, _) = finite.select_nth_unstable_by(i_hi, f32::total_cmp);
    // Everything left of i_hi is ≤ b, so the lower quantile is selected within that part.
    let a = if i_lo < i_hi {
        *finite[..i_hi]
            .select_nth_unstable_by(i_lo, f32::total_cmp)
            .1
    } else {
        b
    };
    if lo <= hi { (a, b) } else { (b, a) }
}

/// Percentile stretch to 8 bits: the `lo`/`hi` quantiles map to 0/255.
pub fn stretch_to_u8(img: &ScalarImage, lo: f64, hi: f64) -> image::GrayImage {
    let (a, b) = quantiles(&img.values, lo, hi);
    let scale = if b > a { 255.0 / (b - a) } else { 0.0 };
    let data = img
        .values
        .iter()
        .map(|&v| ((v - a) * scale).clamp(0.0, 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(img.width_px, img.height_px, data).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_listed_file_format_decodes_to_the_right_scalar_kind() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let (w, h) = (32u32, 24u32);
        let tiff = dir.path().join("t16.tiff");
        image::ImageBuffer::<image::Luma<u16>, _>::from_fn(w, h, |x, _| {
            image::Luma([30000 + x as u16])
        })
        .save(&tiff)
        .unwrap_or_else(|e| panic!("{e}"));
        let grey = dir.path().join("g8.png");
        image::GrayImage::from_fn(w, h, |x, _| image::Luma([x as u8]))
            .save(&grey)
            .unwrap_or_else(|e| panic!("{e}"));
        let rgba = dir.path().join("c.png");
        image::RgbaImage::from_fn(w, h, |_, _| image::Rgba([200, 100, 50, 255]))
            .save(&rgba)
            .unwrap_or_else(|e| panic!("{e}"));
        let load = |p: &Path, thermal| {
            load_scalar(p, thermal, Palette::Auto).unwrap_or_else(|e| panic!("{e}"))
        };
        let t = load(&tiff, true);
        assert_eq!(t.source, SourceKind::Grey16, "16-bit TIFF");
        assert_eq!(
            t.values[5], 30005.0,
            "16-bit counts kept, got {}",
            t.values[5]
        );
        assert_eq!(load(&grey, true).source, SourceKind::Grey8, "8-bit grey");
        let c = load(&rgba, false);
        assert_eq!(c.source, SourceKind::ColourLuminance, "RGBA photo");
        let want = 0.299 * 200.0 + 0.587 * 100.0 + 0.114 * 50.0;
        assert!(
            (f64::from(c.values[0]) - want).abs() < 1e-3,
            "luminance {} want {want}",
            c.values[0]
        );
    }

    #[test]
    fn quantiles_match_a_sort() {
        // Values with ties, a wide spread and non-finite entries (ignored).
        let mut values: Vec<f32> = (0..5000u32)
            .map(|i| ((i * 7919) % 1000) as f32 * 0.37 + if i % 97 == 0 { 1e4 } else { 0.0 })
            .collect();
        values[3] = f32::NAN;
        values[10] = f32::INFINITY;
        let mut sorted: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
        sorted.sort_by(f32::total_cmp);
        for (lo, hi) in [(0.005, 0.995), (0.0, 1.0), (0.5, 0.5), (0.25, 0.9)] {
            let rank = |f: f64| ((sorted.len() - 1) as f64 * f).round() as usize;
            assert_eq!(
                quantiles(&values, lo, hi),
                (sorted[rank(lo)], sorted[rank(hi)]),
                "quantiles {lo}, {hi}"
            );
        }
        assert_eq!(quantiles(&[f32::NAN], 0.1, 0.9), (0.0, 0.0));
        assert_eq!(quantiles(&[2.0, 2.0], 0.1, 0.9), (2.0, 2.0));
    }

    #[test]
    fn stretch_ignores_a_hot_outlier() {
        let mut values = vec![1000.0f32; 100 * 100];
        for (i, v) in values.iter_mut().enumerate() {
            *v += (i % 2) as f32 * 20.0;
        }
        values[0] = 60000.0;
        let img = ScalarImage {
            width_px: 100,
            height_px: 100,
            values,
            source: SourceKind::Grey16,
        };
        let g = stretch_to_u8(&img, 0.005, 0.995);
        assert_eq!(
            g.as_raw()[1],
            255,
            "the bright half of the board must reach 255"
        );
        assert_eq!(g.as_raw()[2], 0, "the dark half must reach 0");
    }
}
