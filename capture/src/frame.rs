//! The frame model.
//!
//! Thermal frames keep the sensor's 16-bit words untouched: whether they are raw counts or
//! TLinear centikelvin is recorded in [`ThermalUnits`], never converted on the way in.
//! RGB frames keep what the camera delivered (MJPEG bytes, or YUYV) and decode only on demand.

use serde::{Deserialize, Serialize};

use crate::device::FourCc;
use crate::error::CaptureError;
use crate::telemetry::{self, LeptonTelemetry, TelemetryFfc};

/// What the 16-bit words of a thermal frame mean.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThermalUnits {
    /// Raw sensor counts (AGC off, radiometry off): monotone in in-band radiance.
    RawCounts,
    /// TLinear output: equivalent black-body temperature in centikelvin (0.01 K per count).
    CentiKelvin,
}

/// Flat-field-correction state of the thermal core when the frame was produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FfcState {
    /// Normal imaging.
    Idle,
    /// FFC requested but the shutter has not closed yet.
    Imminent,
    /// FFC in progress: the frame is a frozen copy and must never be used for pairing.
    InProgress,
    /// Not reported by the device.
    Unknown,
}

impl From<TelemetryFfc> for FfcState {
    /// The frame-level FFC state the telemetry status bits mean: only "in progress" freezes
    /// the frame.
    fn from(t: TelemetryFfc) -> Self {
        match t {
            TelemetryFfc::Imminent => FfcState::Imminent,
            TelemetryFfc::InProgress => FfcState::InProgress,
            TelemetryFfc::NeverCommanded | TelemetryFfc::Complete => FfcState::Idle,
        }
    }
}

/// Capture timestamps of one frame. See `docs/CONVENTIONS.md` ("Clocks").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameTime {
    /// Driver's sequence number (V4L2 `sequence`); gaps mean dropped frames.
    pub sequence: u32,
    /// CLOCK_MONOTONIC time the driver stamped on the buffer, in nanoseconds.
    pub monotonic_ns: u64,
    /// Wall-clock (CLOCK_REALTIME) time when the host dequeued it, nanoseconds since the Unix epoch.
    pub wall_unix_ns: u64,
}

/// One thermal frame with its 16-bit data kept exactly as the sensor produced it.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalFrame {
    pub width: u32,
    pub height: u32,
    /// Row-major, `width * height` words, no padding.
    pub pixels: Vec<u16>,
    pub units: ThermalUnits,
    pub time: FrameTime,
    pub ffc: FfcState,
    /// Telemetry rows exactly as delivered (Lepton 160×122 mode: 2 rows of `width` words
    /// below the image; empty when the core sends none). Never part of `pixels`.
    pub telemetry_words: Vec<u16>,
    /// `telemetry_words` decoded.
    pub telemetry: Option<LeptonTelemetry>,
}

/// Row bytes, stride and the bytes a `width`×`height` buffer of `bytes_per_pixel` needs with
/// rows `bytes_per_line` apart (0 or less than a row: packed). `None` for an empty size or one
/// whose byte counts overflow: sizes come from devices, files and sockets, never trusted.
pub fn buffer_geometry(
    width: u32,
    height: u32,
    bytes_per_pixel: u32,
    bytes_per_line: u32,
) -> Option<(usize, usize, usize)> {
    if width == 0 || height == 0 {
        return None;
    }
    let row = usize::try_from(width)
        .ok()?
        .checked_mul(usize::try_from(bytes_per_pixel).ok()?)?;
    let stride = usize::try_from(bytes_per_line).ok()?.max(row);
    let need = stride
        .checked_mul(usize::try_from(height - 1).ok()?)?
        .checked_add(row)?;
    Some((row, stride, need))
}

impl ThermalFrame {
    /// Builds a frame from a V4L2 `Y16 ` buffer (little-endian words, rows `bytes_per_line` apart).
    ///
    /// Fails, naming `device`, when the buffer is shorter than the format requires; a longer
    /// buffer (drivers round up to pages) is accepted and the excess ignored.
    pub fn from_y16_buffer(
        device: &str,
        buffer: &[u8],
        width: u32,
        height: u32,
        bytes_per_line: u32,
        units: ThermalUnits,
        time: FrameTime,
    ) -> Result<Self, CaptureError> {
        let Some((row_bytes, stride, expected_bytes)) =
            buffer_geometry(width, height, 2, bytes_per_line)
        else {
            return Err(CaptureError::CorruptBuffer {
                device: device.to_owned(),
                sequence: time.sequence,
                reason: format!(
                    "Y16 {width}x{height} with {bytes_per_line} bytes per line is not a frame size"
                ),
            });
        };
        if buffer.len() < expected_bytes {
            return Err(CaptureError::BufferSize {
                device: device.to_owned(),
                fourcc: FourCc::Y16.to_string(),
                width,
                height,
                expected_bytes,
                actual_bytes: buffer.len(),
            });
        }
        let mut pixels = Vec::with_capacity(width as usize * height as usize);
        for row in buffer.chunks(stride).take(height as usize) {
            pixels.extend(
                row[..row_bytes]
                    .chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]])),
            );
        }
        Ok(Self {
            width,
            height,
            pixels,
            units,
            time,
            ffc: FfcState::Unknown,
            telemetry_words: Vec::new(),
            telemetry: None,
        })
    }

    /// True when the frame is a frozen copy taken during flat-field correction: it is kept in
    /// the recording but never paired.
    pub fn is_ffc_frozen(&self) -> bool {
        self.ffc == FfcState::InProgress
    }

    /// The frame's words as a V4L2 `Y16 ` buffer would hold them (image rows, then telemetry
    /// rows, little-endian, no padding): the inverse of [`ThermalFrame::from_y16_buffer`].
    pub fn to_y16_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity((self.pixels.len() + self.telemetry_words.len()) * 2);
        for w in self.pixels.iter().chain(&self.telemetry_words) {
            out.extend_from_slice(&w.to_le_bytes());
        }
        out
    }
}

#[cfg(feature = "session")]
impl RgbFrame {
    /// Decodes the payload to packed 8-bit RGB (`width * height * 3` bytes). Only consumers
    /// that need pixels (export, calibration) call this; recording never does. Feature
    /// `session` (the JPEG decoder comes with it).
    pub fn to_rgb8(&self, device: &str) -> Result<Vec<u8>, CaptureError> {
        match &self.payload {
            RgbPayload::Mjpeg(bytes) => {
                let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
                    .map_err(|e| CaptureError::UndecodableBuffer {
                        device: device.to_owned(),
                        sequence: self.time.sequence,
                        what: "MJPEG does not decode",
                        source: e.into(),
                    })?;
                Ok(img.to_rgb8().into_raw())
            }
            RgbPayload::Yuyv(bytes) => Ok(yuyv_to_rgb8(bytes)),
        }
    }
}

/// BT.601 limited-range YUYV 4:2:2 to packed RGB (the UVC default colour space).
pub fn yuyv_to_rgb8(yuyv: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(yuyv.len() / 2 * 3);
    let conv = |y: u8, u: u8, v: u8, out: &mut Vec<u8>| {
        let c = f32::from(y) - 16.0;
        let d = f32::from(u) - 128.0;
        let e = f32::from(v) - 128.0;
        let clamp = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        out.push(clamp(1.164 * c + 1.596 * e));
        out.push(clamp(1.164 * c - 0.392 * d - 0.813 * e));
        out.push(clamp(1.164 * c + 2.017 * d));
    };
    for px in yuyv.chunks_exact(4) {
        conv(px[0], px[1], px[3], &mut out);
        conv(px[2], px[1], px[3], &mut out);
    }
    out
}

/// Which camera of the rig a frame comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StreamKind {
    Thermal,
    Rgb,
}

impl StreamKind {
    pub fn name(self) -> &'static str {
        match self {
            StreamKind::Thermal => "thermal",
            StreamKind::Rgb => "rgb",
        }
    }
}

/// A buffer as a device backend delivers it (V4L2 dequeue, simulated rig, or a recorded
/// session being replayed): bytes plus the fields of `struct v4l2_buffer`/`v4l2_format` the
/// pipeline needs. Every backend produces these; [`CapturedFrame::from_raw`] is the one parser.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawFrame {
    pub stream: StreamKind,
    pub fourcc: FourCc,
    pub width: u32,
    /// Rows in the buffer, telemetry rows included.
    pub height: u32,
    /// Bytes per row (0 for compressed formats).
    pub bytes_per_line: u32,
    /// Rows at the bottom that are telemetry, not image (Lepton: 2).
    pub telemetry_rows: u32,
    pub units: ThermalUnits,
    /// FFC state the device reported out of band (sim flags, FSLP poll); telemetry, when
    /// present, refines it.
    pub ffc_hint: FfcState,
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub payload: Vec<u8>,
}

/// A parsed frame of either stream.
#[derive(Debug, Clone, PartialEq)]
pub enum CapturedFrame {
    Thermal(ThermalFrame),
    Rgb(RgbFrame),
}

impl CapturedFrame {
    pub fn stream(&self) -> StreamKind {
        match self {
            CapturedFrame::Thermal(_) => StreamKind::Thermal,
            CapturedFrame::Rgb(_) => StreamKind::Rgb,
        }
    }

    pub fn time(&self) -> FrameTime {
        match self {
            CapturedFrame::Thermal(f) => f.time,
            CapturedFrame::Rgb(f) => f.time,
        }
    }

    /// Parses a device buffer. Short, oversized-header or corrupt buffers (an MJPEG without
    /// start/end markers, a Y16 buffer shorter than its rows) are errors naming `device`, so
    /// the caller counts them and never records them as good frames.
    pub fn from_raw(device: &str, raw: &RawFrame, wall_unix_ns: u64) -> Result<Self, CaptureError> {
        let time = FrameTime {
            sequence: raw.sequence,
            monotonic_ns: raw.monotonic_ns,
            wall_unix_ns,
        };
        let corrupt = |reason: String| CaptureError::CorruptBuffer {
            device: device.to_owned(),
            sequence: raw.sequence,
            reason,
        };
        match raw.stream {
            StreamKind::Thermal => {
                if raw.fourcc != FourCc::Y16 {
                    return Err(corrupt(format!(
                        "thermal stream delivered {}, expected Y16",
                        raw.fourcc
                    )));
                }
                if raw.telemetry_rows >= raw.height.max(1) {
                    return Err(corrupt(format!(
                        "{} telemetry rows in a {}-row buffer",
                        raw.telemetry_rows, raw.height
                    )));
                }
                // bytes_per_line 0 means packed rows (buffer_geometry).
                let mut f = ThermalFrame::from_y16_buffer(
                    device,
                    &raw.payload,
                    raw.width,
                    raw.height,
                    raw.bytes_per_line,
                    raw.units,
                    time,
                )?;
                let image_rows = raw.height - raw.telemetry_rows;
                let split = image_rows as usize * raw.width as usize;
                f.telemetry_words = f.pixels.split_off(split);
                f.height = image_rows;
                f.ffc = raw.ffc_hint;
                if raw.telemetry_rows > 0 {
                    let t = telemetry::decode(&f.telemetry_words).map_err(|e| {
                        CaptureError::UndecodableBuffer {
                            device: device.to_owned(),
                            sequence: raw.sequence,
                            what: "telemetry rows",
                            source: e.into(),
                        }
                    })?;
                    if raw.ffc_hint != FfcState::InProgress {
                        f.ffc = FfcState::from(t.ffc);
                    }
                    f.telemetry = Some(t);
                }
                Ok(CapturedFrame::Thermal(f))
            }
            StreamKind::Rgb => {
                let payload = if raw.fourcc == FourCc::MJPG {
                    RgbPayload::Mjpeg(
                        mjpeg_frame(&raw.payload)
                            .map_err(|e| corrupt(e.to_string()))?
                            .to_vec(),
                    )
                } else if raw.fourcc == FourCc::YUYV {
                    let (row, stride, need) =
                        buffer_geometry(raw.width, raw.height, 2, raw.bytes_per_line).ok_or_else(
                            || {
                                corrupt(format!(
                                    "YUYV {}x{} with {} bytes per line is not a frame size",
                                    raw.width, raw.height, raw.bytes_per_line
                                ))
                            },
                        )?;
                    if raw.payload.len() < need {
                        return Err(CaptureError::BufferSize {
                            device: device.to_owned(),
                            fourcc: raw.fourcc.to_string(),
                            width: raw.width,
                            height: raw.height,
                            expected_bytes: need,
                            actual_bytes: raw.payload.len(),
                        });
                    }
                    let mut packed = Vec::with_capacity(row * raw.height as usize);
                    for r in raw.payload.chunks(stride).take(raw.height as usize) {
                        packed.extend_from_slice(&r[..row]);
                    }
                    RgbPayload::Yuyv(packed)
                } else {
                    return Err(corrupt(format!(
                        "RGB stream delivered {}, expected MJPG or YUYV",
                        raw.fourcc
                    )));
                };
                Ok(CapturedFrame::Rgb(RgbFrame {
                    width: raw.width,
                    height: raw.height,
                    payload,
                    time,
                }))
            }
        }
    }
}

/// Checks a V4L2 MJPEG buffer and returns the JPEG inside it: it must start with SOI
/// (`FF D8`) and contain an EOI (`FF D9`); bytes after the last EOI (drivers pad `bytesused`)
/// are cut. A frame the camera truncated (USB packet loss) has no EOI and is rejected.
pub fn mjpeg_frame(buffer: &[u8]) -> Result<&[u8], MjpegError> {
    if buffer.len() < 4 || buffer[0] != 0xFF || buffer[1] != 0xD8 {
        return Err(MjpegError::NoSoi {
            bytes: buffer.len(),
        });
    }
    let end = buffer
        .windows(2)
        .rposition(|w| w == [0xFF, 0xD9])
        .ok_or(MjpegError::NoEoi {
            bytes: buffer.len(),
        })?;
    Ok(&buffer[..end + 2])
}

/// Why a V4L2 MJPEG buffer holds no JPEG ([`mjpeg_frame`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MjpegError {
    #[error("MJPEG buffer of {bytes} bytes does not start with SOI (FF D8)")]
    NoSoi { bytes: usize },
    #[error("MJPEG buffer of {bytes} bytes has no EOI (FF D9): truncated")]
    NoEoi { bytes: usize },
}

/// RGB payload as delivered by the camera.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RgbPayload {
    /// A complete JPEG image (V4L2 `MJPG`), kept compressed.
    Mjpeg(Vec<u8>),
    /// Packed YUYV 4:2:2, `width * 2` bytes per row, no padding.
    Yuyv(Vec<u8>),
}

/// One RGB frame as the camera delivered it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RgbFrame {
    pub width: u32,
    pub height: u32,
    pub payload: RgbPayload,
    pub time: FrameTime,
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn t0() -> FrameTime {
        FrameTime {
            sequence: 7,
            monotonic_ns: 1_000,
            wall_unix_ns: 2_000,
        }
    }

    #[test]
    fn y16_buffer_with_row_padding_is_unpacked_word_exact() {
        // 3x2 frame, 8 bytes per line (2 bytes padding per row), little-endian words.
        let buf = [
            0x01, 0x00, 0x02, 0x00, 0xff, 0xff, 0xaa, 0xaa, //
            0x34, 0x12, 0x00, 0x80, 0x00, 0x00,
        ];
        let f =
            ThermalFrame::from_y16_buffer("test", &buf, 3, 2, 8, ThermalUnits::CentiKelvin, t0())
                .unwrap();
        assert_eq!(f.pixels, vec![1, 2, 0xffff, 0x1234, 0x8000, 0]);
        assert_eq!(f.time.sequence, 7);
    }

    #[test]
    fn short_y16_buffer_is_an_error_naming_the_device() {
        let err = ThermalFrame::from_y16_buffer(
            "/dev/video9",
            &[0u8; 10],
            4,
            2,
            8,
            ThermalUnits::RawCounts,
            t0(),
        )
        .unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("/dev/video9") && msg.contains("expected 16"),
            "got: {msg}"
        );
    }

    fn lepton_raw(status: u16) -> RawFrame {
        let (w, h) = (8u32, 3u32);
        let mut words: Vec<u16> = (0..w * h).map(|i| i as u16 * 100).collect();
        let mut tele = vec![0u16; (w * 2) as usize];
        tele[..10].copy_from_slice(&[
            crate::telemetry::SIM_TELEMETRY_REVISION,
            0,
            5,
            status,
            0,
            77,
            30_000,
            1,
            0,
            0,
        ]);
        words.extend_from_slice(&tele);
        RawFrame {
            stream: StreamKind::Thermal,
            fourcc: FourCc::Y16,
            width: w,
            height: h + 2,
            bytes_per_line: w * 2,
            telemetry_rows: 2,
            units: ThermalUnits::CentiKelvin,
            ffc_hint: FfcState::Unknown,
            sequence: 3,
            monotonic_ns: 10,
            payload: words.iter().flat_map(|w| w.to_le_bytes()).collect(),
        }
    }

    #[test]
    fn telemetry_rows_are_split_off_decoded_and_round_trip() {
        let raw = lepton_raw(2 << 4);
        let CapturedFrame::Thermal(f) = CapturedFrame::from_raw("sim", &raw, 1).unwrap() else {
            panic!("expected a thermal frame");
        };
        assert_eq!(f.height, 3, "image rows exclude telemetry");
        assert_eq!(f.pixels.len(), 24);
        assert_eq!(f.telemetry_words.len(), 16);
        assert_eq!(f.ffc, FfcState::InProgress, "status bits 4-5 = 10");
        assert!(f.is_ffc_frozen());
        assert_eq!(f.telemetry.unwrap().frame_counter, 77);
        assert_eq!(f.to_y16_bytes(), raw.payload, "words round-trip byte-exact");
    }

    #[test]
    fn corrupt_and_short_buffers_are_rejected() {
        let mut raw = lepton_raw(0);
        raw.payload.truncate(10);
        assert!(
            CapturedFrame::from_raw("sim", &raw, 1).is_err(),
            "short Y16"
        );
        let mj = RawFrame {
            stream: StreamKind::Rgb,
            fourcc: FourCc::MJPG,
            width: 8,
            height: 8,
            bytes_per_line: 0,
            telemetry_rows: 0,
            units: ThermalUnits::RawCounts,
            ffc_hint: FfcState::Unknown,
            sequence: 1,
            monotonic_ns: 1,
            payload: vec![0xFF, 0xD8, 1, 2, 3],
        };
        let err = CapturedFrame::from_raw("/dev/video2", &mj, 1).unwrap_err();
        assert!(err.to_string().contains("EOI"), "got {err}");
        let mut ok = mj.clone();
        ok.payload = vec![0xFF, 0xD8, 1, 0xFF, 0xD9, 0, 0, 0];
        let CapturedFrame::Rgb(f) = CapturedFrame::from_raw("x", &ok, 1).unwrap() else {
            panic!("rgb expected")
        };
        assert_eq!(
            f.payload,
            RgbPayload::Mjpeg(vec![0xFF, 0xD8, 1, 0xFF, 0xD9]),
            "padding after EOI is cut"
        );
    }

    #[test]
    fn yuyv_grey_decodes_to_grey() {
        let rgb = yuyv_to_rgb8(&[126, 128, 126, 128]);
        assert_eq!(rgb.len(), 6);
        assert!(rgb.iter().all(|&c| (127..=129).contains(&c)), "got {rgb:?}");
    }
}
