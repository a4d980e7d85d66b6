//! Deterministic synthetic device buffers: the load for `s3tir-capture bench` and the frames of
//! the tests' in-process fake rigs. Thermal telemetry rows use the s3tir synthetic layout
//! ([`crate::telemetry::SIM_TELEMETRY_REVISION`]).
//!
//! These are not physically modelled (the simulated rig in `firmware-sim` is): they are
//! V4L2-shaped buffers with the sizes, rates, telemetry, FFC freezes and sequence gaps of
//! the real cores, so the capture path can be exercised and measured.

use std::io::Cursor;

use crate::device::FourCc;
use crate::error::CaptureError;
use crate::frame::{FfcState, RawFrame, StreamKind, ThermalUnits};
use crate::telemetry::SIM_TELEMETRY_REVISION;

/// Thermal core profile of the synthetic rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalSynth {
    pub width: u32,
    pub height: u32,
    pub rate_hz: f64,
    pub telemetry_rows: u32,
    pub units: ThermalUnits,
}

impl ThermalSynth {
    /// FLIR Boson 640: 640×512 Y16 at 60 Hz, no telemetry rows.
    pub fn boson640() -> Self {
        Self {
            width: 640,
            height: 512,
            rate_hz: 60.0,
            telemetry_rows: 0,
            units: ThermalUnits::RawCounts,
        }
    }

    /// FLIR Lepton 3.5 on a PureThermal: 160×120 (+2 telemetry rows) at 8.7 Hz, TLinear.
    pub fn lepton35() -> Self {
        Self {
            width: 160,
            height: 120,
            rate_hz: 8.7,
            telemetry_rows: 2,
            units: ThermalUnits::CentiKelvin,
        }
    }

    pub fn by_name(name: &str) -> Option<Self> {
        match name {
            "boson640" => Some(Self::boson640()),
            "lepton35" => Some(Self::lepton35()),
            _ => None,
        }
    }
}

/// Scripted events of a synthetic recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Script {
    /// Thermal frame indices (0-based, counting produced frames) that are FFC-frozen.
    pub ffc_frames: Vec<u64>,
    /// Thermal frame indices whose sequence number is skipped (dropped by the "driver").
    pub thermal_drops: Vec<u64>,
    /// RGB frame indices that are dropped.
    pub rgb_drops: Vec<u64>,
    /// RGB frame indices delivered truncated (corrupt MJPEG).
    pub rgb_corrupt: Vec<u64>,
}

/// Produces the interleaved buffers of a thermal core and an optional RGB camera, in
/// timestamp order.
#[derive(Debug, Clone)]
pub struct SynthRig {
    pub thermal: ThermalSynth,
    pub rgb: Option<(u32, u32, f64)>,
    pub script: Script,
    jpegs: Vec<Vec<u8>>,
    t_index: u64,
    r_index: u64,
    t_seq: u32,
    r_seq: u32,
    start_ns: u64,
    base: Vec<u16>,
}

impl SynthRig {
    /// `rgb`: width, height, rate (MJPEG). `start_ns`: monotonic time of the first frame.
    pub fn new(
        thermal: ThermalSynth,
        rgb: Option<(u32, u32, f64)>,
        script: Script,
        start_ns: u64,
    ) -> Result<Self, CaptureError> {
        let mut jpegs = Vec::new();
        if let Some((w, h, _)) = rgb {
            for k in 0..4u32 {
                let img = image::RgbImage::from_fn(w, h, |x, y| {
                    image::Rgb([
                        ((x + 7 * k) % 256) as u8,
                        ((y + 13 * k) % 256) as u8,
                        (((x / 32 + y / 32) % 2) * 200) as u8,
                    ])
                });
                let mut buf = Cursor::new(Vec::new());
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, 85)
                    .encode_image(&img)
                    .map_err(|e| CaptureError::UndecodableBuffer {
                        device: "synthetic rgb".into(),
                        sequence: k,
                        what: "JPEG encoding failed",
                        source: e.into(),
                    })?;
                jpegs.push(buf.into_inner());
            }
        }
        let (w, h) = (thermal.width as usize, thermal.height as usize);
        let base = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                // A warm disc on a gradient, in the units' range.
                let d2 = (x as f64 - w as f64 / 2.0).powi(2) + (y as f64 - h as f64 / 2.0).powi(2);
                let warm = if d2 < (h as f64 / 4.0).powi(2) {
                    800.0
                } else {
                    0.0
                };
                (29_315.0 + 3.0 * x as f64 + warm) as u16
            })
            .collect();
        Ok(Self {
            thermal,
            rgb,
            script,
            jpegs,
            t_index: 0,
            r_index: 0,
            t_seq: 0,
            r_seq: 0,
            start_ns,
            base,
        })
    }

    fn t_time(&self, i: u64) -> u64 {
        self.start_ns + (i as f64 * 1e9 / self.thermal.rate_hz) as u64
    }

    fn r_time(&self, i: u64) -> Option<u64> {
        // RGB lags by 2 ms: a realistic, non-zero sync error.
        self.rgb
            .map(|(_, _, hz)| self.start_ns + 2_000_000 + (i as f64 * 1e9 / hz) as u64)
    }

    /// Numbers the following frames from 0 again, as a V4L2 device does when it is reopened
    /// (after a re-enumeration or a stall); the clock goes on.
    pub fn restart_sequences(&mut self) {
        self.t_seq = 0;
        self.r_seq = 0;
    }

    /// Monotonic time of the next buffer.
    pub fn next_time_ns(&self) -> u64 {
        let t = self.t_time(self.t_index);
        self.r_time(self.r_index).map_or(t, |r| r.min(t))
    }

    /// The next buffer in time order, or `None` when the script drops it (the sequence number
    /// is consumed either way).
    pub fn next_buffer(&mut self) -> Option<RawFrame> {
        let t = self.t_time(self.t_index);
        match self.r_time(self.r_index) {
            Some(r) if r < t => self.next_rgb(r),
            _ => self.next_thermal(t),
        }
    }

    fn next_thermal(&mut self, t_ns: u64) -> Option<RawFrame> {
        let i = self.t_index;
        self.t_index += 1;
        let seq = self.t_seq;
        self.t_seq = self.t_seq.wrapping_add(1);
        if self.script.thermal_drops.contains(&i) {
            return None;
        }
        let frozen = self.script.ffc_frames.contains(&i);
        let th = self.thermal;
        let w = th.width as usize;
        let mut words = Vec::with_capacity(w * (th.height + th.telemetry_rows) as usize);
        // Deterministic per-frame noise (xorshift), frozen frames repeat frame 0's pattern.
        let mut s = if frozen {
            0x9E37_79B9
        } else {
            0x9E37_79B9 ^ (i as u32).wrapping_mul(2_654_435_761)
        };
        for &b in &self.base {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            words.push(b.wrapping_add((s % 16) as u16));
        }
        if th.telemetry_rows > 0 {
            let mut tele = vec![0u16; w * th.telemetry_rows as usize];
            let uptime_ms = (t_ns / 1_000_000) as u32;
            let status: u16 = if frozen { 2 << 4 } else { 3 << 4 };
            let vals = [
                SIM_TELEMETRY_REVISION,
                (uptime_ms >> 16) as u16,
                uptime_ms as u16,
                status,
                (i >> 16) as u16,
                i as u16,
                30_815,
                u16::from(th.units == ThermalUnits::CentiKelvin),
                0,
                0,
            ];
            for (d, v) in tele.iter_mut().zip(vals) {
                *d = v;
            }
            words.extend_from_slice(&tele);
        }
        let payload = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        Some(RawFrame {
            stream: StreamKind::Thermal,
            fourcc: FourCc::Y16,
            width: th.width,
            height: th.height + th.telemetry_rows,
            bytes_per_line: th.width * 2,
            telemetry_rows: th.telemetry_rows,
            units: th.units,
            ffc_hint: if frozen {
                FfcState::InProgress
            } else {
                FfcState::Idle
            },
            sequence: seq,
            monotonic_ns: t_ns,
            payload,
        })
    }

    fn next_rgb(&mut self, t_ns: u64) -> Option<RawFrame> {
        let i = self.r_index;
        self.r_index += 1;
        let seq = self.r_seq;
        self.r_seq = self.r_seq.wrapping_add(1);
        let (w, h, _) = self.rgb?;
        if self.script.rgb_drops.contains(&i) {
            return None;
        }
        let mut payload = self
            .jpegs
            .get(i as usize % self.jpegs.len().max(1))?
            .clone();
        if self.script.rgb_corrupt.contains(&i) {
            payload.truncate(payload.len() / 2);
        }
        Some(RawFrame {
            stream: StreamKind::Rgb,
            fourcc: FourCc::MJPG,
            width: w,
            height: h,
            bytes_per_line: 0,
            telemetry_rows: 0,
            units: ThermalUnits::RawCounts,
            ffc_hint: FfcState::Unknown,
            sequence: seq,
            monotonic_ns: t_ns,
            payload,
        })
    }
}

#[cfg(test)]
mod tests {
    //! Proves: the synthetic rig interleaves streams in time order at the profile rates,
    //! applies its script (drops consume sequence numbers, FFC frames carry telemetry state),
    //! and is deterministic. Does not model physics.
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::frame::CapturedFrame;

    #[test]
    fn interleaves_in_time_order_and_applies_script() {
        let script = Script {
            ffc_frames: vec![3],
            thermal_drops: vec![5],
            ..Script::default()
        };
        let mut rig =
            SynthRig::new(ThermalSynth::lepton35(), Some((64, 48, 9.0)), script, 1_000).unwrap();
        let mut last = 0;
        let mut thermal_seqs = Vec::new();
        for _ in 0..20 {
            let t = rig.next_time_ns();
            assert!(t >= last, "time order");
            last = t;
            if let Some(b) = rig.next_buffer()
                && b.stream == StreamKind::Thermal
            {
                let CapturedFrame::Thermal(f) = CapturedFrame::from_raw("s", &b, 0).unwrap() else {
                    panic!()
                };
                assert_eq!(f.is_ffc_frozen(), b.sequence == 3, "seq {}", b.sequence);
                thermal_seqs.push(b.sequence);
            }
        }
        assert!(
            !thermal_seqs.contains(&5),
            "dropped sequence skipped: {thermal_seqs:?}"
        );
        assert!(thermal_seqs.contains(&6));
        let mut again = SynthRig::new(
            ThermalSynth::lepton35(),
            Some((64, 48, 9.0)),
            Script::default(),
            1_000,
        )
        .unwrap();
        let a = again.next_buffer().unwrap();
        let mut again2 = SynthRig::new(
            ThermalSynth::lepton35(),
            Some((64, 48, 9.0)),
            Script::default(),
            1_000,
        )
        .unwrap();
        assert_eq!(a, again2.next_buffer().unwrap(), "deterministic");
    }
}
