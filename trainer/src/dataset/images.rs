//! Image files → raw scalar planes in their native units.
//!
//! | file | kind | value |
//! |---|---|---|
//! | 16-bit grey PNG/TIFF | [`ImageKind::Thermal16`] | the stored word: centikelvin (TLinear) or raw counts, as the dataset says |
//! | 8-bit grey | [`ImageKind::Grey8`] | 0…255 |
//! | 8-bit colour, pseudo-colour requested | [`ImageKind::PseudoColour8`] | palette index 0…255 (inverted ironbow palette, nearest entry: `s3tir_calib::model::palette`) |
//! | 8-bit colour | [`ImageKind::Rgb8`] | three planes 0…255 |
//!
//! An 8-bit colour image whose three channels are equal everywhere is read as grey.

use std::collections::HashMap;
use std::path::Path;

use image::DynamicImage;
use s3tir_calib::model::palette::Colormap;

use super::DatasetError;

/// How a dataset's 8-bit colour images are to be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColourMode {
    /// Colour images are RGB (trained as colour through the SH branch).
    #[default]
    Rgb,
    /// Colour images are false-colour renderings of a thermal image (ironbow palette).
    Pseudo,
}

/// What a loaded image holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageKind {
    Thermal16,
    Grey8,
    PseudoColour8,
    Rgb8,
}

/// A decoded image: one plane (thermal kinds) or three (RGB), row-major, raw units.
#[derive(Debug, Clone, PartialEq)]
pub struct RawImage {
    pub width: usize,
    pub height: usize,
    pub kind: ImageKind,
    /// `width·height` values, or three planes for [`ImageKind::Rgb8`].
    pub values: Vec<f64>,
}

/// Loads one image file.
pub fn load_image(path: &Path, colour: ColourMode) -> Result<RawImage, DatasetError> {
    if !path.exists() {
        return Err(DatasetError::MissingFile {
            path: path.to_path_buf(),
            what: "image",
        });
    }
    let img = image::open(path).map_err(|source| DatasetError::Image {
        path: path.to_path_buf(),
        source,
    })?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = match img {
        DynamicImage::ImageLuma16(b) => RawImage {
            width: w,
            height: h,
            kind: ImageKind::Thermal16,
            values: b.into_raw().into_iter().map(f64::from).collect(),
        },
        DynamicImage::ImageLumaA16(_)
        | DynamicImage::ImageRgb16(_)
        | DynamicImage::ImageRgba16(_) => {
            // 16-bit colour is not a thermal format; take the first channel only if grey.
            let b = img.to_rgb16();
            if !b.pixels().all(|p| p[0] == p[1] && p[1] == p[2]) {
                return Err(DatasetError::UnsupportedImage {
                    path: path.to_path_buf(),
                    reason: "16-bit colour images are not supported (thermal must be one channel)"
                        .into(),
                });
            }
            RawImage {
                width: w,
                height: h,
                kind: ImageKind::Thermal16,
                values: b.pixels().map(|p| f64::from(p[0])).collect(),
            }
        }
        DynamicImage::ImageLuma8(b) => RawImage {
            width: w,
            height: h,
            kind: ImageKind::Grey8,
            values: b.into_raw().into_iter().map(f64::from).collect(),
        },
        other => {
            let b = other.to_rgb8();
            if b.pixels().all(|p| p[0] == p[1] && p[1] == p[2]) {
                RawImage {
                    width: w,
                    height: h,
                    kind: ImageKind::Grey8,
                    values: b.pixels().map(|p| f64::from(p[0])).collect(),
                }
            } else if colour == ColourMode::Pseudo {
                let mut cache: HashMap<[u8; 3], f64> = HashMap::new();
                let values = b
                    .pixels()
                    .map(|p| {
                        *cache
                            .entry(p.0)
                            .or_insert_with(|| Colormap::Ironbow.nearest(p.0).0 as f64)
                    })
                    .collect();
                RawImage {
                    width: w,
                    height: h,
                    kind: ImageKind::PseudoColour8,
                    values,
                }
            } else {
                let n = w * h;
                let mut values = vec![0.0; 3 * n];
                for (i, p) in b.pixels().enumerate() {
                    for c in 0..3 {
                        values[c * n + i] = f64::from(p[c]);
                    }
                }
                RawImage {
                    width: w,
                    height: h,
                    kind: ImageKind::Rgb8,
                    values,
                }
            }
        }
    };
    Ok(raw)
}
