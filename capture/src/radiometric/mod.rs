//! Radiometric thermal files from cameras other than the rig's core: FLIR's FFF container (the
//! `.fff` frames of FLIR's SDKs and ResearchIR, and the radiometric JPEGs of FLIR hand-helds and
//! DJI Zenmuse XT/XT2 and Duo Pro R, which carry an FFF in APP1 segments) decoded to the raw
//! 16-bit image, the camera's calibration and conditions, and kelvin.
//!
//! - [`fff`]: the container — its record directory (either byte order), the raw image record
//!   (raw words or an embedded PNG, whose words FLIR stores byte-swapped) and the camera-info
//!   record (Planck constants, atmosphere, conditions, camera and lens names).
//! - [`jpeg`]: the FFF reassembled from a JPEG's `FLIR` APP1 segments.
//! - [`file`]: any thermal image file by its content — a FLIR file, a 16-bit or float grey
//!   PNG/TIFF in a unit the user states, or an 8-bit picture (no temperature).
//! - [`planck`]: raw words to kelvin and back with FLIR's published model (Planck R1, R2, B, F,
//!   O; emissivity, reflected apparent temperature, atmospheric temperature and humidity,
//!   object distance, the atmospheric transmission constants, the IR window), each condition
//!   overridable.
//!
//! One owner: posing of image folders, the trainer and inspection read these files through this
//! module only. Every length and offset read from a file is checked against the file before it
//! is used, and an image is at most [`MAX_PIXELS`]: a crafted file is an error naming what is
//! wrong, never a panic or an unbounded allocation.
//!
//! Why not a crate: the registry's FLIR readers (`thermal`, `flir_rs`) are unmaintained partial
//! ports that read only JPEGs, pull in image decoders for everything, and panic on bad input.

pub mod fff;
pub mod file;
pub mod jpeg;
pub mod planck;

use std::path::{Path, PathBuf};

pub use fff::{CameraInfo, Fff, RawThermal};
pub use file::{ThermalFile, Units};
pub use planck::{ConditionOverrides, Conditions, PlanckCurve, RawToKelvin};

/// The largest raw image accepted (a 1280×1024 core has 1.3 M pixels).
pub const MAX_PIXELS: usize = 8 << 20;

/// Why a radiometric file could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum RadiometricError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The bytes are not what the format says (`what`: which part).
    #[error("{what}: {reason}")]
    Format { what: &'static str, reason: String },
    /// A file's decoding failed; `source` says how.
    #[error("{path}")]
    File {
        path: PathBuf,
        #[source]
        source: Box<RadiometricError>,
    },
}

impl RadiometricError {
    pub(crate) fn format(what: &'static str, reason: impl Into<String>) -> Self {
        Self::Format {
            what,
            reason: reason.into(),
        }
    }
}

/// A decoded radiometric file: the raw image and the camera's calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Radiometric {
    pub raw: RawThermal,
    pub camera: CameraInfo,
    /// The FFF's own GPS record (FLIR's drone cores write one), when valid.
    pub gps: Option<crate::image_meta::GeoPosition>,
}

impl Radiometric {
    /// Reads a `.fff` frame or a radiometric JPEG (told apart by their first bytes).
    pub fn read(path: &Path) -> Result<Self, RadiometricError> {
        read_file(path, Self::decode)
    }

    /// [`Radiometric::read`] of bytes in memory.
    pub fn decode(bytes: &[u8]) -> Result<Self, RadiometricError> {
        Self::decode_if_radiometric(bytes)?.ok_or_else(|| {
            RadiometricError::format(
                "radiometric file",
                if bytes.starts_with(&[0xff, 0xd8]) {
                    "no FLIR segment: not a radiometric JPEG (an 8-bit picture has no temperatures)"
                } else {
                    "neither a FLIR FFF frame nor a radiometric JPEG"
                },
            )
        })
    }

    /// The file's radiometric content, `None` for a file that has none (a JPEG without FLIR
    /// segments, a file that is not FFF), an error for one that is damaged.
    pub fn decode_if_radiometric(bytes: &[u8]) -> Result<Option<Self>, RadiometricError> {
        let fff_bytes;
        let fff = if bytes.starts_with(&[0xff, 0xd8]) {
            match jpeg::fff_from_jpeg(bytes)? {
                Some(b) => fff_bytes = b,
                None => return Ok(None),
            }
            Fff::parse(&fff_bytes)?
        } else if fff::looks_like_fff(bytes) {
            Fff::parse(bytes)?
        } else {
            return Ok(None);
        };
        Ok(Some(Self {
            raw: fff.raw_thermal()?,
            camera: fff.camera_info()?,
            gps: fff.gps()?,
        }))
    }

    /// Kelvin per pixel under `conditions` (the file's own: `self.camera.conditions`).
    pub fn kelvin(&self, conditions: &Conditions) -> Vec<f64> {
        let model = RawToKelvin::new(&self.camera.planck, conditions);
        self.raw
            .data
            .iter()
            .map(|&w| model.kelvin(f64::from(w)))
            .collect()
    }
}

/// Kelvin as the 16-bit centikelvin words of s3tir's datasets (0.01 K per count, rounded;
/// 0 where the value is not finite or below 0 K, 65535 above 655.35 K).
pub fn centikelvin_words(kelvin: &[f64]) -> Vec<u16> {
    kelvin
        .iter()
        .map(|&k| {
            if k.is_finite() && k > 0.0 {
                (k * 100.0).round().min(65535.0) as u16
            } else {
                0
            }
        })
        .collect()
}

/// `decode` of the file at `path`, its errors naming the file.
pub(crate) fn read_file<T>(
    path: &Path,
    decode: impl FnOnce(&[u8]) -> Result<T, RadiometricError>,
) -> Result<T, RadiometricError> {
    let bytes = std::fs::read(path).map_err(|source| RadiometricError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(&bytes).map_err(|e| RadiometricError::File {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}
