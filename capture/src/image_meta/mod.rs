//! What an image file says about where and how it was taken: EXIF (camera, capture time, GPS,
//! focal length, size) through `kamadak-exif`, and XMP packets parsed as XML (`quick-xml`,
//! namespaces resolved, so a prefix can be anything): DJI's `drone-dji` namespace (GPS to 1e-7°,
//! barometric and absolute altitude, gimbal and flight yaw/pitch/roll), and every other XMP
//! property kept by its namespace and name for inspection.
//!
//! - [`exif`]: the EXIF fields read.
//! - [`xmp`]: the XMP packet found in a JPEG and its properties.
//!
//! A file without metadata reads as empty metadata (posing then works without priors and says
//! so); a file whose metadata is damaged is an error naming the file.

pub mod exif;
pub mod xmp;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

/// DJI's XMP namespace.
pub const DJI_NS: &str = "http://www.dji.com/drone-dji/1.0/";

/// Why an image's metadata could not be read.
#[derive(Debug, thiserror::Error)]
pub enum MetaError {
    #[error("{path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {part}: {reason}")]
    Damaged {
        path: PathBuf,
        part: &'static str,
        reason: String,
    },
}

/// A position on the WGS84 ellipsoid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GeoPosition {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    /// Altitude, metres (EXIF: above sea level; DJI XMP: its `AbsoluteAltitude`).
    pub altitude_m: Option<f64>,
}

/// Yaw (clockwise from north), pitch (up positive) and roll, degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Attitude {
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
}

/// An image's metadata (each field `None` where the file does not say).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ImageMeta {
    pub make: Option<String>,
    pub model: Option<String>,
    /// EXIF `DateTimeOriginal` as written (`YYYY:MM:DD HH:MM:SS`, local time of the camera),
    /// with its sub-seconds when given.
    pub capture_time: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub focal_length_mm: Option<f64>,
    pub focal_length_35mm: Option<f64>,
    /// EXIF GPS (whole seconds of arc on many drones).
    pub gps_exif: Option<GeoPosition>,
    /// DJI XMP GPS (1e-7 degrees).
    pub gps_xmp: Option<GeoPosition>,
    /// Height above the take-off point, metres (DJI's barometric `RelativeAltitude`).
    pub relative_altitude_m: Option<f64>,
    pub gimbal: Option<Attitude>,
    pub flight: Option<Attitude>,
    /// Every XMP property, `namespace-uri#Name` → value.
    pub xmp: BTreeMap<String, String>,
}

impl ImageMeta {
    /// The best position the file gives: DJI's XMP one (finer), else EXIF's.
    pub fn position(&self) -> Option<GeoPosition> {
        self.gps_xmp.or(self.gps_exif)
    }

    /// Reads the metadata of the image at `path` (JPEG, TIFF, PNG: whatever carries EXIF; XMP
    /// from JPEGs).
    pub fn read(path: &Path) -> Result<Self, MetaError> {
        let bytes = std::fs::read(path).map_err(|source| MetaError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::decode(&bytes).map_err(|(part, reason)| MetaError::Damaged {
            path: path.to_path_buf(),
            part,
            reason,
        })
    }

    /// [`ImageMeta::read`] of bytes in memory; `Err((part, reason))`.
    pub fn decode(bytes: &[u8]) -> Result<Self, (&'static str, String)> {
        let mut meta = exif::read(bytes).map_err(|r| ("EXIF", r))?;
        if let Some(packet) = xmp::packet_in_jpeg(bytes).map_err(|r| ("JPEG", r))? {
            let props = xmp::properties(packet).map_err(|r| ("XMP", r))?;
            xmp::apply_dji(&props, &mut meta).map_err(|r| ("XMP", r))?;
            meta.xmp = props;
        }
        Ok(meta)
    }
}
