//! The frame model.
//!
//! Thermal frames keep the sensor's 16-bit words untouched: whether they are raw counts or
//! TLinear centikelvin is recorded in [`ThermalUnits`], never converted on the way in.
//! RGB frames keep what the camera delivered (MJPEG bytes, or YUYV) and decode only on demand.

use serde::{Deserialize, Serialize};

use crate::device::FourCc;
use crate::error::CaptureError;

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
        let row_bytes = width as usize * 2;
        let stride = (bytes_per_line as usize).max(row_bytes);
        let expected_bytes = if height == 0 {
            0
        } else {
            stride * (height as usize - 1) + row_bytes
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
        })
    }
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
}
