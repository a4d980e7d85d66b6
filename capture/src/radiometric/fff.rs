//! FLIR's FFF container: a 64-byte header, a directory of 32-byte record entries, the records.
//!
//! Layout (ExifTool's FLIR module documents it; checked here against flirpy's public test
//! frames, big- and little-endian):
//!
//! - header: `FFF\0` (or another 3-letter tag and NUL), the creator (16 bytes), the format
//!   version at 0x14 (100–199 in the header's byte order: how the order is told), the
//!   directory's offset at 0x18 and its entry count at 0x1c;
//! - entry: record type (u16; 0 = unused), subtype (u16), version (u32), index (u32), offset
//!   (u32) and length (u32) of the record's data;
//! - a record's data starts with the u16 2 in its own byte order (little-endian in every file
//!   seen, even where the header is big-endian);
//! - raw data (type 1): width at 2, height at 4 (u16), the image from byte 32 — raw u16 words,
//!   or a 16-bit grey PNG whose words are byte-swapped (FLIR writes its native little-endian
//!   words where PNG means big-endian);
//! - camera info (type 0x20): the fields at the offsets in [`CameraInfo`]'s reader;
//! - GPS (type 0x2b): valid flag (u32), references at 8 and 10 (`N`/`S`, `E`/`W`), latitude and
//!   longitude (f64, signed) at 0x10 and 0x18, altitude (f32, metres) at 0x20.

use super::planck::{Conditions, PlanckCurve};
use super::{MAX_PIXELS, RadiometricError};
use crate::image_meta::GeoPosition;

/// Record types read here.
pub const RAW_DATA: u16 = 0x0001;
pub const CAMERA_INFO: u16 = 0x0020;
pub const GPS_INFO: u16 = 0x002b;
/// The directory holds at most this many entries (a real file has a handful).
const MAX_ENTRIES: usize = 4096;

/// The raw thermal image of a file, row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawThermal {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u16>,
    /// How the record stored it.
    pub encoding: RawEncoding,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RawEncoding {
    /// Raw u16 words.
    Words { big_endian: bool },
    /// A 16-bit grey PNG (its words byte-swapped).
    Png,
}

impl std::fmt::Display for RawEncoding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Words { big_endian: false } => "raw words, little-endian",
            Self::Words { big_endian: true } => "raw words, big-endian",
            Self::Png => "embedded 16-bit PNG",
        })
    }
}

/// What the camera-info record says: the calibration, the conditions the operator set, the
/// camera and lens.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CameraInfo {
    pub planck: PlanckCurve,
    pub conditions: Conditions,
    pub camera_model: String,
    pub camera_part_number: String,
    pub camera_serial_number: String,
    pub camera_software: String,
    pub lens_model: String,
    /// Horizontal field of view, degrees (0 when the camera does not say).
    pub field_of_view_deg: f64,
    /// The camera's measurement range, kelvin.
    pub range_k: (f64, f64),
    /// The camera's own median and range of the raw image (its display statistics; `None`
    /// when the record is too short to hold them).
    pub raw_value_median: Option<u16>,
    pub raw_value_range: Option<u16>,
}

/// A parsed FFF container over its bytes.
#[derive(Debug, Clone)]
pub struct Fff<'a> {
    bytes: &'a [u8],
    /// The creator (`FLIR`, `ResearchIR`, …).
    pub creator: String,
    records: Vec<Record>,
}

#[derive(Debug, Clone, Copy)]
struct Record {
    kind: u16,
    offset: usize,
    len: usize,
}

/// Reads of fixed-size values from a checked slice in one byte order.
#[derive(Debug, Clone, Copy)]
struct Reader<'a> {
    bytes: &'a [u8],
    big_endian: bool,
    what: &'static str,
}

impl<'a> Reader<'a> {
    fn take<const N: usize>(&self, at: usize) -> Result<[u8; N], RadiometricError> {
        self.bytes
            .get(at..at + N)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or_else(|| {
                RadiometricError::format(
                    self.what,
                    format!(
                        "{N} bytes at {at:#x} lie past its end ({} bytes)",
                        self.bytes.len()
                    ),
                )
            })
    }
    fn u16(&self, at: usize) -> Result<u16, RadiometricError> {
        let b = self.take::<2>(at)?;
        Ok(if self.big_endian {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        })
    }
    fn u32(&self, at: usize) -> Result<u32, RadiometricError> {
        let b = self.take::<4>(at)?;
        Ok(if self.big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }
    fn i32(&self, at: usize) -> Result<i32, RadiometricError> {
        Ok(self.u32(at)? as i32)
    }
    fn f32(&self, at: usize) -> Result<f64, RadiometricError> {
        Ok(f64::from(f32::from_bits(self.u32(at)?)))
    }
    /// A NUL-terminated string field of `len` bytes (lossy UTF-8, trimmed).
    fn text(&self, at: usize, len: usize) -> Result<String, RadiometricError> {
        let s = self.bytes.get(at..at + len).ok_or_else(|| {
            RadiometricError::format(
                self.what,
                format!("a {len}-byte text at {at:#x} lies past its end"),
            )
        })?;
        let end = s.iter().position(|&b| b == 0).unwrap_or(s.len());
        Ok(String::from_utf8_lossy(&s[..end]).trim().to_string())
    }
}

/// Whether `bytes` start like an FFF container (a 3-letter upper-case tag and NUL).
pub fn looks_like_fff(bytes: &[u8]) -> bool {
    bytes.len() >= 4 && bytes[3] == 0 && bytes[..3].iter().all(u8::is_ascii_uppercase)
}

impl<'a> Fff<'a> {
    /// Parses the header and the record directory; every entry's data must lie in the file.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, RadiometricError> {
        let head = bytes.get(..0x40).ok_or_else(|| {
            RadiometricError::format(
                "FFF header",
                format!("{} bytes, a header is 64", bytes.len()),
            )
        })?;
        if !looks_like_fff(head) {
            return Err(RadiometricError::format(
                "FFF header",
                format!(
                    "starts {:?}, not a FLIR tag such as \"FFF\\0\"",
                    String::from_utf8_lossy(&head[..4])
                ),
            ));
        }
        let be = Reader {
            bytes,
            big_endian: true,
            what: "FFF header",
        };
        let version = be.u32(0x14)?;
        let big_endian = (100..200).contains(&version);
        let r = Reader { big_endian, ..be };
        if !big_endian && !(100..200).contains(&r.u32(0x14)?) {
            return Err(RadiometricError::format(
                "FFF header",
                format!("format version {version:#x} is neither 1xx big- nor little-endian"),
            ));
        }
        let creator = r.text(4, 16)?;
        let dir = r.u32(0x18)? as usize;
        let count = r.u32(0x1c)? as usize;
        if count > MAX_ENTRIES {
            return Err(RadiometricError::format(
                "FFF directory",
                format!("{count} entries (at most {MAX_ENTRIES})"),
            ));
        }
        let mut records = Vec::new();
        for k in 0..count {
            let at = dir
                .checked_add(k * 32)
                .ok_or_else(|| RadiometricError::format("FFF directory", "offset overflows"))?;
            let e = Reader {
                what: "FFF directory",
                ..r
            };
            let kind = e.u16(at)?;
            if kind == 0 {
                continue;
            }
            let offset = e.u32(at + 12)? as usize;
            let len = e.u32(at + 16)? as usize;
            if offset.checked_add(len).is_none_or(|end| end > bytes.len()) {
                return Err(RadiometricError::format(
                    "FFF directory",
                    format!(
                        "record {k} (type {kind:#x}) spans {offset:#x}+{len} past the file's {} bytes",
                        bytes.len()
                    ),
                ));
            }
            records.push(Record { kind, offset, len });
        }
        Ok(Self {
            bytes,
            creator,
            records,
        })
    }

    /// The data of the first record of type `kind`, read little-endian until its byte order
    /// is told.
    fn record_data(&self, kind: u16, what: &'static str) -> Result<Reader<'a>, RadiometricError> {
        let rec = self
            .records
            .iter()
            .find(|r| r.kind == kind)
            .ok_or_else(|| RadiometricError::format(what, "the file has no such record"))?;
        Ok(Reader {
            bytes: &self.bytes[rec.offset..rec.offset + rec.len],
            big_endian: false,
            what,
        })
    }

    /// The first record of type `kind` with its byte order, told by its first u16, which is 2.
    fn record(&self, kind: u16, what: &'static str) -> Result<Reader<'a>, RadiometricError> {
        let le = self.record_data(kind, what)?;
        let big_endian = match le.u16(0)? {
            2 => false,
            0x0200 => true,
            other => {
                return Err(RadiometricError::format(
                    what,
                    format!("starts with {other:#06x}, not the byte-order mark 2"),
                ));
            }
        };
        Ok(Reader { big_endian, ..le })
    }

    /// The raw image: raw words or an embedded PNG.
    pub fn raw_thermal(&self) -> Result<RawThermal, RadiometricError> {
        let r = self.record(RAW_DATA, "raw thermal record")?;
        let width = usize::from(r.u16(2)?);
        let height = usize::from(r.u16(4)?);
        let n = width * height;
        if n == 0 || n > MAX_PIXELS {
            return Err(RadiometricError::format(
                "raw thermal record",
                format!("{width}×{height} pixels (1 to {MAX_PIXELS})"),
            ));
        }
        let body = r.bytes.get(32..).unwrap_or_default();
        if body.starts_with(b"\x89PNG\r\n\x1a\n") {
            return decode_png(body, width, height);
        }
        if body.len() < 2 * n {
            return Err(RadiometricError::format(
                "raw thermal record",
                format!(
                    "{width}×{height} words need {} bytes, it holds {}",
                    2 * n,
                    body.len()
                ),
            ));
        }
        let data = body[..2 * n]
            .chunks_exact(2)
            .map(|w| {
                let w = [w[0], w[1]];
                if r.big_endian {
                    u16::from_be_bytes(w)
                } else {
                    u16::from_le_bytes(w)
                }
            })
            .collect();
        Ok(RawThermal {
            width,
            height,
            data,
            encoding: RawEncoding::Words {
                big_endian: r.big_endian,
            },
        })
    }

    /// The camera-info record: calibration, conditions, camera and lens.
    pub fn camera_info(&self) -> Result<CameraInfo, RadiometricError> {
        let r = self.record(CAMERA_INFO, "camera info record")?;
        let humidity = r.f32(0x3c)?;
        let info = CameraInfo {
            conditions: Conditions {
                emissivity: r.f32(0x20)?,
                object_distance_m: r.f32(0x24)?,
                reflected_k: r.f32(0x28)?,
                atmosphere_k: r.f32(0x2c)?,
                window_k: r.f32(0x30)?,
                window_transmission: r.f32(0x34)?,
                // some cameras store per cent
                relative_humidity: if humidity > 2.0 {
                    humidity / 100.0
                } else {
                    humidity
                },
            },
            planck: PlanckCurve {
                r1: r.f32(0x58)?,
                b: r.f32(0x5c)?,
                f: r.f32(0x60)?,
                alpha1: r.f32(0x70)?,
                alpha2: r.f32(0x74)?,
                beta1: r.f32(0x78)?,
                beta2: r.f32(0x7c)?,
                x: r.f32(0x80)?,
                o: f64::from(r.i32(0x308)?),
                r2: r.f32(0x30c)?,
            },
            range_k: (r.f32(0x94)?, r.f32(0x90)?),
            camera_model: r.text(0xd4, 32)?,
            camera_part_number: r.text(0xf4, 16)?,
            camera_serial_number: r.text(0x104, 16)?,
            camera_software: r.text(0x114, 16)?,
            lens_model: r.text(0x170, 32)?,
            field_of_view_deg: r.f32(0x1b4)?,
            raw_value_median: r.u16(0x338).ok(),
            raw_value_range: r.u16(0x33c).ok(),
        };
        let p = &info.planck;
        let c = &info.conditions;
        let finite = [
            p.r1,
            p.r2,
            p.b,
            p.f,
            c.emissivity,
            c.reflected_k,
            c.atmosphere_k,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !finite || p.r1 <= 0.0 || p.r2 <= 0.0 || p.b <= 0.0 {
            return Err(RadiometricError::format(
                "camera info record",
                format!(
                    "no usable Planck curve (R1 {}, R2 {}, B {}, F {})",
                    p.r1, p.r2, p.b, p.f
                ),
            ));
        }
        Ok(info)
    }
}

impl Fff<'_> {
    /// The GPS record's position, when the file has one marked valid.
    pub fn gps(&self) -> Result<Option<GeoPosition>, RadiometricError> {
        if !self.records.iter().any(|r| r.kind == GPS_INFO) {
            return Ok(None);
        }
        let r = self.record_any_order(GPS_INFO, "GPS record")?;
        if r.u32(0)? == 0 {
            return Ok(None);
        }
        let f64_at = |at: usize| -> Result<f64, RadiometricError> {
            let b = r.take::<8>(at)?;
            Ok(if r.big_endian {
                f64::from_be_bytes(b)
            } else {
                f64::from_le_bytes(b)
            })
        };
        // signed already in the files seen; a positive value with a S/W reference is negated
        let signed = |v: f64, reference: u8, negative: u8| {
            if reference == negative && v > 0.0 {
                -v
            } else {
                v
            }
        };
        let (lat, lon) = (f64_at(0x10)?, f64_at(0x18)?);
        let refs = r.take::<4>(8)?;
        let pos = GeoPosition {
            latitude_deg: signed(lat, refs[0], b'S'),
            longitude_deg: signed(lon, refs[2], b'W'),
            altitude_m: Some(r.f32(0x20)?).filter(|a| a.is_finite()),
        };
        let plausible = pos.latitude_deg.abs() <= 90.0 && pos.longitude_deg.abs() <= 180.0;
        Ok(plausible.then_some(pos))
    }

    /// The first record of type `kind`, its byte order told by its first u32 (records without
    /// the u16 mark: GPS's first field is its valid flag, 0 or 1).
    fn record_any_order(
        &self,
        kind: u16,
        what: &'static str,
    ) -> Result<Reader<'_>, RadiometricError> {
        let le = self.record_data(kind, what)?;
        let big_endian = le.u32(0)? > 1
            && Reader {
                big_endian: true,
                ..le
            }
            .u32(0)?
                <= 1;
        Ok(Reader { big_endian, ..le })
    }
}

/// The raw image from an embedded 16-bit grey PNG (bounded: the PNG must be `width`×`height`).
fn decode_png(bytes: &[u8], width: usize, height: usize) -> Result<RawThermal, RadiometricError> {
    let bad = |reason: String| RadiometricError::format("raw thermal PNG", reason);
    let mut decoder = png::Decoder::new_with_limits(
        std::io::Cursor::new(bytes),
        png::Limits {
            bytes: 2 * MAX_PIXELS + (1 << 16),
        },
    );
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(|e| bad(e.to_string()))?;
    let info = reader.info();
    if (info.width as usize, info.height as usize) != (width, height)
        || info.color_type != png::ColorType::Grayscale
        || info.bit_depth != png::BitDepth::Sixteen
    {
        return Err(bad(format!(
            "{}×{} {:?} {:?}, the record says {width}×{height} 16-bit grey",
            info.width, info.height, info.color_type, info.bit_depth
        )));
    }
    let mut buf = vec![0; 2 * width * height];
    reader
        .next_frame(&mut buf)
        .map_err(|e| bad(e.to_string()))?;
    // PNG's words are big-endian; FLIR wrote little-endian ones: read them as such.
    let data = buf
        .chunks_exact(2)
        .map(|w| u16::from_le_bytes([w[0], w[1]]))
        .collect();
    Ok(RawThermal {
        width,
        height,
        data,
        encoding: RawEncoding::Png,
    })
}
