//! Format negotiation and buffer interpretation for V4L2 devices: pure functions over the
//! format list and `v4l2_buffer` fields, so they are tested without a camera.

use crate::device::{FormatInfo, FourCc, Role};
use crate::error::CaptureError;
use crate::frame::{FfcState, RawFrame, StreamKind, ThermalUnits};

/// The format a device was asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Negotiated {
    pub fourcc: FourCc,
    pub width: u32,
    pub height: u32,
    /// Requested frame rate (highest the size offers), Hz; `None` when the driver lists none.
    pub rate_hz: Option<f64>,
}

/// Picks the capture format for a role:
/// - thermal: `Y16 ` only (radiometric 16-bit data; 8-bit AGC output is useless for
///   calibration and training), at the largest size;
/// - RGB: `MJPG` (compressed, cheap to record) else `YUYV`, at the largest size not above
///   `max_size` (all sizes when `None`).
pub fn negotiate(
    device: &str,
    role: Role,
    formats: &[FormatInfo],
    max_size: Option<(u32, u32)>,
) -> Result<Negotiated, CaptureError> {
    let wanted: &[FourCc] = match role {
        Role::Thermal => &[FourCc::Y16],
        Role::Rgb | Role::Unknown => &[FourCc::MJPG, FourCc::YUYV],
    };
    for want in wanted {
        let Some(f) = formats.iter().find(|f| f.fourcc == *want) else {
            continue;
        };
        let best = f
            .sizes
            .iter()
            .filter(|s| max_size.is_none_or(|(w, h)| s.width <= w && s.height <= h))
            .max_by_key(|s| (u64::from(s.width) * u64::from(s.height), s.width));
        match best {
            Some(s) => {
                return Ok(Negotiated {
                    fourcc: *want,
                    width: s.width,
                    height: s.height,
                    rate_hz: s.rates_hz.iter().copied().reduce(f64::max),
                });
            }
            // A format without discrete sizes: take the caller's size, or let the driver pick.
            None if f.sizes.is_empty() => {
                let (width, height) = max_size.unwrap_or((0, 0));
                return Ok(Negotiated {
                    fourcc: *want,
                    width,
                    height,
                    rate_hz: None,
                });
            }
            None => {}
        }
    }
    Err(CaptureError::NoUsableFormat {
        device: device.to_owned(),
        role: role.to_string(),
        offered: formats
            .iter()
            .map(|f| f.fourcc.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        wanted: wanted
            .iter()
            .map(|f| f.to_string())
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// Telemetry rows a thermal format carries: the Lepton's 160×122 mode (PureThermal) has two.
pub fn telemetry_rows_for(width: u32, height: u32) -> u32 {
    if width == 160 && height == 122 { 2 } else { 0 }
}

/// Fields of a dequeued `v4l2_buffer` (+ the negotiated format) the pipeline needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DequeuedMeta {
    pub bytesused: u32,
    pub sequence: u32,
    pub timestamp_sec: i64,
    pub timestamp_usec: i64,
    /// `V4L2_BUF_FLAG_ERROR`: the driver flagged the buffer as corrupt.
    pub error_flag: bool,
}

/// Builds the device buffer from a dequeued mmap buffer. Copies `bytesused` bytes (the whole
/// mapping when a driver reports 0, as some do for uncompressed formats); a buffer the driver
/// flagged with `V4L2_BUF_FLAG_ERROR` is rejected here so it is counted, never recorded.
pub fn raw_from_dequeued(
    device: &str,
    stream: StreamKind,
    fmt: &Negotiated,
    bytes_per_line: u32,
    units: ThermalUnits,
    mapping: &[u8],
    meta: DequeuedMeta,
) -> Result<RawFrame, CaptureError> {
    if meta.error_flag {
        return Err(CaptureError::CorruptBuffer {
            device: device.to_owned(),
            sequence: meta.sequence,
            reason: "driver set V4L2_BUF_FLAG_ERROR".into(),
        });
    }
    let used = if meta.bytesused == 0 {
        mapping.len()
    } else {
        (meta.bytesused as usize).min(mapping.len())
    };
    let monotonic_ns = (meta.timestamp_sec.max(0) as u64) * 1_000_000_000
        + (meta.timestamp_usec.max(0) as u64) * 1_000;
    Ok(RawFrame {
        stream,
        fourcc: fmt.fourcc,
        width: fmt.width,
        height: fmt.height,
        bytes_per_line,
        telemetry_rows: if stream == StreamKind::Thermal {
            telemetry_rows_for(fmt.width, fmt.height)
        } else {
            0
        },
        units,
        ffc_hint: FfcState::Unknown,
        sequence: meta.sequence,
        monotonic_ns,
        payload: mapping[..used].to_vec(),
    })
}

#[cfg(test)]
mod tests {
    //! Proves: negotiation picks Y16 for thermal (never 8-bit grey), MJPEG over YUYV for RGB
    //! within a size cap, and names the device and formats when nothing fits; dequeued
    //! buffers are cut to `bytesused`, stamped in ns, and rejected on the driver's error
    //! flag. Uses format lists shaped like a PureThermal 2, a Boson and a UVC webcam; does not
    //! touch a device.
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::device::FrameSize;
    use crate::frame::CapturedFrame;

    fn f(code: &str, sizes: &[(u32, u32, f64)]) -> FormatInfo {
        FormatInfo {
            fourcc: FourCc::parse(code).unwrap(),
            description: code.into(),
            sizes: sizes
                .iter()
                .map(|&(width, height, r)| FrameSize {
                    width,
                    height,
                    rates_hz: vec![r / 2.0, r],
                })
                .collect(),
        }
    }

    #[test]
    fn thermal_takes_y16_largest() {
        let purethermal = [
            f("UYVY", &[(160, 120, 9.0)]),
            f("Y16 ", &[(160, 120, 9.0), (160, 122, 9.0)]),
            f("GREY", &[(160, 120, 9.0)]),
        ];
        let n = negotiate("/dev/video0", Role::Thermal, &purethermal, None).unwrap();
        assert_eq!((n.fourcc, n.width, n.height), (FourCc::Y16, 160, 122));
        assert_eq!(telemetry_rows_for(n.width, n.height), 2);
        let boson = [
            f("Y16 ", &[(640, 512, 60.0)]),
            f("I420", &[(640, 512, 60.0)]),
        ];
        let n = negotiate("b", Role::Thermal, &boson, None).unwrap();
        assert_eq!((n.width, n.height, n.rate_hz), (640, 512, Some(60.0)));
        let err = negotiate(
            "/dev/video4",
            Role::Thermal,
            &[f("GREY", &[(1, 1, 1.0)])],
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("/dev/video4") && err.contains("GREY") && err.contains("Y16"),
            "{err}"
        );
    }

    #[test]
    fn rgb_prefers_mjpeg_within_cap() {
        let cam = [
            f("YUYV", &[(640, 480, 30.0), (1920, 1080, 5.0)]),
            f(
                "MJPG",
                &[(640, 480, 30.0), (1920, 1080, 30.0), (3840, 2160, 15.0)],
            ),
        ];
        let n = negotiate("c", Role::Rgb, &cam, Some((1920, 1080))).unwrap();
        assert_eq!((n.fourcc, n.width, n.height), (FourCc::MJPG, 1920, 1080));
        let yuyv_only = [f("YUYV", &[(640, 480, 30.0)])];
        assert_eq!(
            negotiate("c", Role::Rgb, &yuyv_only, None).unwrap().fourcc,
            FourCc::YUYV
        );
    }

    #[test]
    fn dequeued_buffers_are_cut_stamped_and_flag_checked() {
        let fmt = Negotiated {
            fourcc: FourCc::MJPG,
            width: 8,
            height: 8,
            rate_hz: None,
        };
        let mut mapping = vec![0u8; 4096];
        mapping[..6].copy_from_slice(&[0xFF, 0xD8, 7, 7, 0xFF, 0xD9]);
        let meta = DequeuedMeta {
            bytesused: 6,
            sequence: 41,
            timestamp_sec: 12,
            timestamp_usec: 345,
            error_flag: false,
        };
        let raw = raw_from_dequeued(
            "v",
            StreamKind::Rgb,
            &fmt,
            0,
            ThermalUnits::RawCounts,
            &mapping,
            meta,
        )
        .unwrap();
        assert_eq!(raw.payload.len(), 6);
        assert_eq!(raw.monotonic_ns, 12_000_345_000);
        assert!(CapturedFrame::from_raw("v", &raw, 0).is_ok());
        let bad = DequeuedMeta {
            error_flag: true,
            ..meta
        };
        assert!(
            raw_from_dequeued(
                "v",
                StreamKind::Rgb,
                &fmt,
                0,
                ThermalUnits::RawCounts,
                &mapping,
                bad
            )
            .is_err()
        );
        // A Y16 buffer with row padding (bytesperline 336 for 160 px) parses word-exact.
        let th = Negotiated {
            fourcc: FourCc::Y16,
            width: 160,
            height: 122,
            rate_hz: None,
        };
        let mut map = vec![0u8; 336 * 122];
        map[336 * 120] = 0x33; // telemetry row A word 0 = 0x5333 (simulated layout)
        map[336 * 120 + 1] = 0x53;
        map[2] = 0x34;
        map[3] = 0x12;
        let raw = raw_from_dequeued(
            "v",
            StreamKind::Thermal,
            &th,
            336,
            ThermalUnits::CentiKelvin,
            &map,
            DequeuedMeta {
                bytesused: 0,
                ..meta
            },
        )
        .unwrap();
        let CapturedFrame::Thermal(t) = CapturedFrame::from_raw("v", &raw, 0).unwrap() else {
            panic!()
        };
        assert_eq!((t.width, t.height), (160, 120));
        assert_eq!(t.pixels[1], 0x1234);
        assert_eq!(t.telemetry_words[0], 0x5333);
    }
}
