//! Device descriptions shared by the V4L2 backend and the simulated rig, and the role guess
//! (`thermal` for cameras that only offer 8/16-bit grey, `rgb` for colour formats).

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::error::CaptureError;

/// A V4L2 four-character pixel-format code, e.g. `Y16 `, `YUYV`, `MJPG`.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FourCc(pub [u8; 4]);

impl FourCc {
    /// 16-bit little-endian grey: Lepton/Boson radiometric and raw output.
    pub const Y16: FourCc = FourCc(*b"Y16 ");
    /// 8-bit grey (AGC output of thermal cores).
    pub const GREY: FourCc = FourCc(*b"GREY");
    pub const YUYV: FourCc = FourCc(*b"YUYV");
    pub const MJPG: FourCc = FourCc(*b"MJPG");
    /// Packed 24-bit RGB (PureThermal's colourised stream offers it).
    pub const RGB3: FourCc = FourCc(*b"RGB3");
    pub const NV12: FourCc = FourCc(*b"NV12");
    pub const UYVY: FourCc = FourCc(*b"UYVY");

    /// Parses exactly four ASCII characters (`"Y16 "`, `"MJPG"`).
    pub fn parse(text: &str) -> Result<Self, CaptureError> {
        let bytes = text.as_bytes();
        if bytes.len() != 4 || !bytes.iter().all(u8::is_ascii) {
            return Err(CaptureError::InvalidFourcc {
                text: text.to_owned(),
            });
        }
        Ok(FourCc([bytes[0], bytes[1], bytes[2], bytes[3]]))
    }

    /// True for the grey formats thermal cores deliver.
    pub fn is_grey(self) -> bool {
        self == Self::Y16 || self == Self::GREY
    }
}

impl fmt::Display for FourCc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&String::from_utf8_lossy(&self.0))
    }
}

impl fmt::Debug for FourCc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FourCc({self})")
    }
}

impl Serialize for FourCc {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for FourCc {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        FourCc::parse(&text).map_err(serde::de::Error::custom)
    }
}

/// One frame size a format offers, with the frame rates at that size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameSize {
    pub width: u32,
    pub height: u32,
    /// Discrete rates in Hz; empty when the driver reports none (or a continuous range).
    pub rates_hz: Vec<f64>,
}

/// A pixel format and the sizes it comes in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FormatInfo {
    pub fourcc: FourCc,
    pub description: String,
    pub sizes: Vec<FrameSize>,
}

/// What a camera on the rig is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    Thermal,
    Rgb,
    Unknown,
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::Thermal => "thermal",
            Role::Rgb => "rgb",
            Role::Unknown => "unknown",
        })
    }
}

/// Guesses a device's role from its formats: a device offering only grey formats (Y16/GREY),
/// with Y16 among them or a thermal-core resolution, is thermal; one offering any colour format
/// is RGB. PureThermal boards offer Y16 *and* colourised RGB: Y16 present wins, since only a
/// radiometric core offers 16-bit grey.
pub fn guess_role(formats: &[FormatInfo]) -> Role {
    if formats.is_empty() {
        return Role::Unknown;
    }
    if formats.iter().any(|f| f.fourcc == FourCc::Y16) {
        return Role::Thermal;
    }
    if formats.iter().all(|f| f.fourcc.is_grey()) {
        return Role::Thermal;
    }
    let colour = [
        FourCc::YUYV,
        FourCc::MJPG,
        FourCc::RGB3,
        FourCc::NV12,
        FourCc::UYVY,
    ];
    if formats.iter().any(|f| colour.contains(&f.fourcc)) {
        Role::Rgb
    } else {
        Role::Unknown
    }
}

/// A capture device as `s3tir-capture list` reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// Device node, e.g. `/dev/video0`.
    pub path: String,
    pub driver: String,
    pub card: String,
    pub bus: String,
    pub formats: Vec<FormatInfo>,
    pub role: Role,
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn fmt(code: &str) -> FormatInfo {
        FormatInfo {
            fourcc: FourCc::parse(code).unwrap(),
            description: code.into(),
            sizes: vec![],
        }
    }

    #[test]
    fn role_guess_follows_formats() {
        assert_eq!(guess_role(&[fmt("Y16 "), fmt("GREY")]), Role::Thermal);
        assert_eq!(guess_role(&[fmt("GREY")]), Role::Thermal);
        // PureThermal: Y16 next to its colourised RGB stream.
        assert_eq!(
            guess_role(&[fmt("UYVY"), fmt("Y16 "), fmt("RGB3")]),
            Role::Thermal
        );
        assert_eq!(guess_role(&[fmt("MJPG"), fmt("YUYV")]), Role::Rgb);
        assert_eq!(guess_role(&[fmt("H264")]), Role::Unknown);
        assert_eq!(guess_role(&[]), Role::Unknown);
    }

    #[test]
    fn fourcc_parses_and_prints_round_trip() {
        assert_eq!(FourCc::parse("Y16 ").unwrap(), FourCc::Y16);
        assert_eq!(FourCc::Y16.to_string(), "Y16 ");
        assert!(
            FourCc::parse("Y16").is_err(),
            "three characters must be rejected"
        );
        let json = serde_json::to_string(&FourCc::MJPG).unwrap();
        assert_eq!(json, "\"MJPG\"");
        assert_eq!(serde_json::from_str::<FourCc>(&json).unwrap(), FourCc::MJPG);
    }
}
