//! Any thermal image file, told apart by its content: a FLIR radiometric file (kelvin through
//! the camera's calibration), a 16-bit or floating-point grey PNG/TIFF whose unit the user
//! states (`--units`: kelvin, centikelvin, degrees Celsius, … — the file does not say), or an
//! 8-bit picture (grey levels after the camera's gain: no temperature, the caller decodes it).
//! The one entry point posing and inspection read thermal images through.

use std::path::Path;
use std::str::FromStr;

use super::{MAX_PIXELS, Radiometric, RadiometricError};

/// What the values of a 16-bit or floating-point thermal image mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Units {
    Kelvin,
    DeciKelvin,
    CentiKelvin,
    MilliKelvin,
    Celsius,
    DeciCelsius,
    CentiCelsius,
    MilliCelsius,
    /// Sensor counts: monotone in radiance, no temperature.
    Raw,
}

impl Units {
    pub const NAMES: &'static str = "kelvin, decikelvin, centikelvin, millikelvin, celsius, \
                                     decicelsius, centicelsius, millicelsius, raw";

    /// A stored value in kelvin (`None` for raw counts).
    pub fn kelvin(self, v: f64) -> Option<f64> {
        let (scale, offset) = match self {
            Self::Kelvin => (1.0, 0.0),
            Self::DeciKelvin => (0.1, 0.0),
            Self::CentiKelvin => (0.01, 0.0),
            Self::MilliKelvin => (0.001, 0.0),
            Self::Celsius => (1.0, 273.15),
            Self::DeciCelsius => (0.1, 273.15),
            Self::CentiCelsius => (0.01, 273.15),
            Self::MilliCelsius => (0.001, 273.15),
            Self::Raw => return None,
        };
        Some(v * scale + offset)
    }
}

impl FromStr for Units {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "kelvin" | "k" => Self::Kelvin,
            "decikelvin" => Self::DeciKelvin,
            "centikelvin" => Self::CentiKelvin,
            "millikelvin" => Self::MilliKelvin,
            "celsius" | "c" => Self::Celsius,
            "decicelsius" => Self::DeciCelsius,
            "centicelsius" => Self::CentiCelsius,
            "millicelsius" => Self::MilliCelsius,
            "raw" => Self::Raw,
            other => return Err(format!("unknown unit {other:?} ({})", Self::NAMES)),
        })
    }
}

/// A thermal image file's content.
#[derive(Debug, Clone, PartialEq)]
pub enum ThermalFile {
    /// A FLIR radiometric file.
    Radiometric(Box<Radiometric>),
    /// A grey image of `values` (16-bit words or floats as stored) in `units`.
    Scaled {
        width: usize,
        height: usize,
        values: Vec<f64>,
        units: Units,
    },
    /// An 8-bit picture: no temperature.
    Picture8 { width: usize, height: usize },
}

impl ThermalFile {
    /// Reads `path`; `units` says what a 16-bit or float grey image's values mean (required for
    /// those, unused for the others).
    pub fn read(path: &Path, units: Option<Units>) -> Result<Self, RadiometricError> {
        super::read_file(path, |bytes| Self::decode(bytes, units))
    }

    /// [`ThermalFile::read`] of bytes in memory.
    pub fn decode(bytes: &[u8], units: Option<Units>) -> Result<Self, RadiometricError> {
        if let Some(r) = Radiometric::decode_if_radiometric(bytes)? {
            return Ok(Self::Radiometric(Box::new(r)));
        }
        let (width, height, values) = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
            match grey_png(bytes)? {
                Some(v) => v,
                None => return picture8_png(bytes),
            }
        } else if bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*") {
            match grey_tiff(bytes)? {
                Ok(v) => v,
                Err((width, height)) => return Ok(Self::Picture8 { width, height }),
            }
        } else if bytes.starts_with(&[0xff, 0xd8]) {
            return jpeg_size(bytes);
        } else {
            return Err(RadiometricError::format(
                "thermal image",
                "not a FLIR file, PNG, TIFF or JPEG",
            ));
        };
        let units = units.ok_or_else(|| {
            RadiometricError::format(
                "thermal image",
                format!(
                    "a {width}×{height} 16-bit or float image does not say what its values are: \
                     state it (--units {})",
                    Units::NAMES
                ),
            )
        })?;
        Ok(Self::Scaled {
            width,
            height,
            values,
            units,
        })
    }

    /// Kelvin per pixel, when the file holds temperatures (the FLIR file under its own
    /// conditions).
    pub fn kelvin(&self) -> Option<Vec<f64>> {
        match self {
            Self::Radiometric(r) => Some(r.kelvin(&r.camera.conditions)),
            Self::Scaled { values, units, .. } => {
                units.kelvin(0.0)?;
                Some(values.iter().filter_map(|&v| units.kelvin(v)).collect())
            }
            Self::Picture8 { .. } => None,
        }
    }

    pub fn size(&self) -> (usize, usize) {
        match self {
            Self::Radiometric(r) => (r.raw.width, r.raw.height),
            Self::Scaled { width, height, .. } | Self::Picture8 { width, height } => {
                (*width, *height)
            }
        }
    }
}

type Plane = (usize, usize, Vec<f64>);

fn check_size(what: &'static str, w: u32, h: u32) -> Result<(usize, usize), RadiometricError> {
    if w == 0 || h == 0 || u64::from(w) * u64::from(h) > MAX_PIXELS as u64 {
        return Err(RadiometricError::format(
            what,
            format!("{w}×{h} pixels (1 to {MAX_PIXELS})"),
        ));
    }
    Ok((w as usize, h as usize))
}

/// A 16-bit grey PNG's words (`None`: an 8-bit PNG).
fn grey_png(bytes: &[u8]) -> Result<Option<Plane>, RadiometricError> {
    let bad = |e: png::DecodingError| RadiometricError::format("PNG", e.to_string());
    let mut decoder = png::Decoder::new_with_limits(
        std::io::Cursor::new(bytes),
        png::Limits {
            bytes: 2 * MAX_PIXELS + (1 << 16),
        },
    );
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(bad)?;
    let info = reader.info();
    let (w, h) = check_size("PNG", info.width, info.height)?;
    if info.bit_depth != png::BitDepth::Sixteen {
        return Ok(None);
    }
    if info.color_type != png::ColorType::Grayscale {
        return Err(RadiometricError::format(
            "PNG",
            format!(
                "16-bit {:?}: a thermal image is one grey channel",
                info.color_type
            ),
        ));
    }
    let mut buf = vec![0; 2 * w * h];
    reader.next_frame(&mut buf).map_err(bad)?;
    let values = buf
        .chunks_exact(2)
        .map(|b| f64::from(u16::from_be_bytes([b[0], b[1]])))
        .collect();
    Ok(Some((w, h, values)))
}

/// An 8-bit PNG's size.
fn picture8_png(bytes: &[u8]) -> Result<ThermalFile, RadiometricError> {
    let reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(|e| RadiometricError::format("PNG", e.to_string()))?;
    let (width, height) = check_size("PNG", reader.info().width, reader.info().height)?;
    Ok(ThermalFile::Picture8 { width, height })
}

/// A 16-bit or float grey TIFF's values (`Err((w, h))`: an 8-bit grey TIFF of that size).
fn grey_tiff(bytes: &[u8]) -> Result<Result<Plane, (usize, usize)>, RadiometricError> {
    use tiff::decoder::{Decoder, DecodingResult, Limits};
    let bad = |e: tiff::TiffError| RadiometricError::format("TIFF", e.to_string());
    let mut limits = Limits::default();
    limits.decoding_buffer_size = 8 * MAX_PIXELS;
    let mut d = Decoder::new(std::io::Cursor::new(bytes))
        .map_err(bad)?
        .with_limits(limits);
    let (w, h) = d.dimensions().map_err(bad)?;
    let (w, h) = check_size("TIFF", w, h)?;
    match d.colortype().map_err(bad)? {
        tiff::ColorType::Gray(8) => return Ok(Err((w, h))),
        tiff::ColorType::Gray(16 | 32 | 64) => {}
        other => {
            return Err(RadiometricError::format(
                "TIFF",
                format!("{other:?}: a thermal image is one grey channel of 16 or 32 bits"),
            ));
        }
    }
    let values: Vec<f64> = match d.read_image().map_err(bad)? {
        DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::U32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F64(v) => v,
        _ => {
            return Err(RadiometricError::format(
                "TIFF",
                "an unsupported sample type",
            ));
        }
    };
    if values.len() != w * h {
        return Err(RadiometricError::format(
            "TIFF",
            format!("{} samples for {w}×{h}", values.len()),
        ));
    }
    Ok(Ok((w, h, values)))
}

/// An 8-bit JPEG's size, from its start-of-frame segment.
fn jpeg_size(bytes: &[u8]) -> Result<ThermalFile, RadiometricError> {
    let bad = |r: String| RadiometricError::format("JPEG", r);
    // the segment walker stops at the scan; the frame header comes before it
    for seg in crate::jpeg_segments::segments(bytes).map_err(bad)? {
        if matches!(seg.marker, 0xc0..=0xc3 | 0xc5..=0xc7 | 0xc9..=0xcb | 0xcd..=0xcf)
            && seg.payload.len() >= 5
        {
            let p = seg.payload;
            let h = u32::from(u16::from_be_bytes([p[1], p[2]]));
            let w = u32::from(u16::from_be_bytes([p[3], p[4]]));
            let (width, height) = check_size("JPEG", w, h)?;
            return Ok(ThermalFile::Picture8 { width, height });
        }
    }
    Err(bad("no frame header before the scan".into()))
}
