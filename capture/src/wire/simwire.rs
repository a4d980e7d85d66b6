//! Frames in the shape of a V4L2 buffer, over a local stream socket.
//!
//! The simulated rig (`s3tir-firmware-sim run`) writes them to a Unix socket; the capture
//! daemon's simulated device reads them, so both go through the same code as a V4L2 buffer:
//! bytes, fourcc, width, height, bytesperline, sequence, monotonic timestamp.
//!
//! One message per frame, all integers little-endian (like the Y16 words they carry):
//!
//! ```text
//! offset size field
//!  0      4   magic "S3WF"
//!  4      2   version (1)
//!  6      1   stream id (0 thermal, 1 rgb)
//!  7      1   reserved (0)
//!  8      4   flags (FLAG_*)
//! 12      4   fourcc (e.g. "Y16 ", "YUYV", "MJPG")
//! 16      4   width (pixels)
//! 20      4   height (rows, telemetry rows included)
//! 24      4   bytesperline (0 for compressed formats)
//! 28      4   sequence (V4L2 sequence; gaps mean dropped frames)
//! 32      8   timestamp, CLOCK_MONOTONIC nanoseconds
//! 40      4   payload length in bytes
//! 44      …   payload
//! ```

use std::io::{self, Read, Write};

use crate::device::FourCc;

/// Message magic.
pub const MAGIC: [u8; 4] = *b"S3WF";
/// Wire version this module writes and reads.
pub const VERSION: u16 = 1;
/// Header bytes before the payload.
pub const HEADER_BYTES: usize = 44;
/// Largest payload accepted (a 4K YUYV frame is 16.6 MB).
pub const MAX_PAYLOAD_BYTES: u32 = 64 * 1024 * 1024;

/// The frame was produced during a flat-field correction: a frozen copy of the last frame.
pub const FLAG_FFC_FROZEN: u32 = 1 << 0;
/// The last rows of the frame are telemetry rows, not image (Lepton: 2 rows).
pub const FLAG_TELEMETRY: u32 = 1 << 1;
/// Thermal words are TLinear centikelvin (else raw counts).
pub const FLAG_TLINEAR: u32 = 1 << 2;
/// An FFC is imminent (Lepton/Boson warn before closing the shutter).
pub const FLAG_FFC_IMMINENT: u32 = 1 << 3;

/// Which camera a frame comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamId {
    Thermal,
    Rgb,
}

impl StreamId {
    fn to_byte(self) -> u8 {
        match self {
            StreamId::Thermal => 0,
            StreamId::Rgb => 1,
        }
    }
}

/// One V4L2-shaped frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WireFrame {
    pub stream: StreamId,
    pub flags: u32,
    pub fourcc: FourCc,
    pub width: u32,
    pub height: u32,
    pub bytes_per_line: u32,
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub payload: Vec<u8>,
}

/// Errors reading or writing wire frames.
#[derive(Debug, thiserror::Error)]
pub enum SimWireError {
    #[error("simwire {peer}: I/O error")]
    Io {
        peer: String,
        #[source]
        source: io::Error,
    },
    #[error("simwire {peer}: bad magic {found:02X?}, expected \"S3WF\"")]
    BadMagic { peer: String, found: [u8; 4] },
    #[error("simwire {peer}: version {found}, this build reads {VERSION}")]
    Version { peer: String, found: u16 },
    #[error("simwire {peer}: unknown stream id {found}")]
    UnknownStream { peer: String, found: u8 },
    #[error("simwire {peer}: payload of {len} bytes exceeds {MAX_PAYLOAD_BYTES}")]
    PayloadTooLarge { peer: String, len: u32 },
    #[error("simwire {peer}: stream ended inside a frame")]
    TruncatedFrame { peer: String },
}

impl WireFrame {
    /// The 44-byte header.
    pub fn header(&self) -> [u8; HEADER_BYTES] {
        let mut h = [0u8; HEADER_BYTES];
        h[0..4].copy_from_slice(&MAGIC);
        h[4..6].copy_from_slice(&VERSION.to_le_bytes());
        h[6] = self.stream.to_byte();
        h[8..12].copy_from_slice(&self.flags.to_le_bytes());
        h[12..16].copy_from_slice(&self.fourcc.0);
        h[16..20].copy_from_slice(&self.width.to_le_bytes());
        h[20..24].copy_from_slice(&self.height.to_le_bytes());
        h[24..28].copy_from_slice(&self.bytes_per_line.to_le_bytes());
        h[28..32].copy_from_slice(&self.sequence.to_le_bytes());
        h[32..40].copy_from_slice(&self.monotonic_ns.to_le_bytes());
        h[40..44].copy_from_slice(&(self.payload.len() as u32).to_le_bytes());
        h
    }

    /// Writes the frame; `peer` names the socket in errors.
    pub fn write_to<W: Write>(&self, w: &mut W, peer: &str) -> Result<(), SimWireError> {
        let io = |source| SimWireError::Io {
            peer: peer.to_owned(),
            source,
        };
        if self.payload.len() > MAX_PAYLOAD_BYTES as usize {
            return Err(SimWireError::PayloadTooLarge {
                peer: peer.to_owned(),
                len: self.payload.len() as u32,
            });
        }
        w.write_all(&self.header()).map_err(io)?;
        w.write_all(&self.payload).map_err(io)?;
        Ok(())
    }

    /// Reads one frame. `Ok(None)` on a clean end of stream (between frames).
    pub fn read_from<R: Read>(r: &mut R, peer: &str) -> Result<Option<Self>, SimWireError> {
        let mut h = [0u8; HEADER_BYTES];
        // Distinguish EOF before the first byte (clean) from EOF inside the header.
        let mut filled = 0;
        while filled < HEADER_BYTES {
            match r.read(&mut h[filled..]) {
                Ok(0) if filled == 0 => return Ok(None),
                Ok(0) => {
                    return Err(SimWireError::TruncatedFrame {
                        peer: peer.to_owned(),
                    });
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(source) => {
                    return Err(SimWireError::Io {
                        peer: peer.to_owned(),
                        source,
                    });
                }
            }
        }
        let u32_at = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        let magic = [h[0], h[1], h[2], h[3]];
        if magic != MAGIC {
            return Err(SimWireError::BadMagic {
                peer: peer.to_owned(),
                found: magic,
            });
        }
        let version = u16::from_le_bytes([h[4], h[5]]);
        if version != VERSION {
            return Err(SimWireError::Version {
                peer: peer.to_owned(),
                found: version,
            });
        }
        let stream = match h[6] {
            0 => StreamId::Thermal,
            1 => StreamId::Rgb,
            found => {
                return Err(SimWireError::UnknownStream {
                    peer: peer.to_owned(),
                    found,
                });
            }
        };
        let len = u32_at(40);
        if len > MAX_PAYLOAD_BYTES {
            return Err(SimWireError::PayloadTooLarge {
                peer: peer.to_owned(),
                len,
            });
        }
        let mut payload = vec![0u8; len as usize];
        r.read_exact(&mut payload).map_err(|source| {
            if source.kind() == io::ErrorKind::UnexpectedEof {
                SimWireError::TruncatedFrame {
                    peer: peer.to_owned(),
                }
            } else {
                SimWireError::Io {
                    peer: peer.to_owned(),
                    source,
                }
            }
        })?;
        let mut ts = [0u8; 8];
        ts.copy_from_slice(&h[32..40]);
        Ok(Some(Self {
            stream,
            flags: u32_at(8),
            fourcc: FourCc([h[12], h[13], h[14], h[15]]),
            width: u32_at(16),
            height: u32_at(20),
            bytes_per_line: u32_at(24),
            sequence: u32_at(28),
            monotonic_ns: u64::from_le_bytes(ts),
            payload,
        }))
    }
}

#[cfg(test)]
mod tests {
    //! Proves: frames round-trip through the wire format, a clean EOF between frames is
    //! `None`, and truncated or foreign data are typed errors. Does not exercise a real socket.
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn frame() -> WireFrame {
        WireFrame {
            stream: StreamId::Thermal,
            flags: FLAG_FFC_FROZEN | FLAG_TELEMETRY,
            fourcc: FourCc::Y16,
            width: 160,
            height: 122,
            bytes_per_line: 320,
            sequence: 42,
            monotonic_ns: 1_234_567_890_123,
            payload: (0..320 * 122).map(|i| (i % 251) as u8).collect(),
        }
    }

    #[test]
    fn frames_round_trip_and_eof_is_clean() {
        let mut buf = Vec::new();
        frame().write_to(&mut buf, "test").unwrap();
        let mut rgb = frame();
        rgb.stream = StreamId::Rgb;
        rgb.fourcc = FourCc::MJPG;
        rgb.payload = vec![0xFF, 0xD8, 0xFF, 0xD9];
        rgb.write_to(&mut buf, "test").unwrap();
        let mut r = buf.as_slice();
        assert_eq!(WireFrame::read_from(&mut r, "t").unwrap().unwrap(), frame());
        assert_eq!(WireFrame::read_from(&mut r, "t").unwrap().unwrap(), rgb);
        assert!(
            WireFrame::read_from(&mut r, "t").unwrap().is_none(),
            "EOF between frames is None"
        );
    }

    #[test]
    fn truncated_and_foreign_data_are_errors() {
        let mut buf = Vec::new();
        frame().write_to(&mut buf, "test").unwrap();
        for cut in [1, HEADER_BYTES - 1, HEADER_BYTES + 10] {
            let err = WireFrame::read_from(&mut &buf[..cut], "sock").unwrap_err();
            assert!(
                matches!(err, SimWireError::TruncatedFrame { .. }),
                "cut {cut}: {err}"
            );
        }
        let mut bad = buf.clone();
        bad[0] = b'X';
        let err = WireFrame::read_from(&mut bad.as_slice(), "sock").unwrap_err();
        assert!(
            err.to_string().contains("sock"),
            "error names the peer: {err}"
        );
    }
}
