//! Per-frame radiometric response effects of real thermal exports, with their truth
//! (`response.json`), for the scene datasets ([`super`]):
//!
//! - **Automatic gain control** on 8-bit exports: each frame's apparent temperatures are
//!   stretched linearly from the frame's own minimum…maximum to 0…255, so the same wall has
//!   another grey level in every frame (what a camera app's 8-bit export does; real AGC is
//!   often histogram-based, this is its affine core).
//! - **Offset drift between flat-field corrections** on the 16-bit radiometric stream: a random
//!   walk in kelvin from frame to frame (1σ step `drift_step_k`) that a flat-field correction
//!   resets to zero every `ffc_every` frames.
//!
//! The truth of both goes to `response.json`: per frame, the AGC window (kelvin) and the drift
//! offset (kelvin).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

/// Which effects a scene's thermal images get.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ResponseEffects {
    /// Write 8-bit grey images with per-frame automatic gain control instead of 16-bit
    /// centikelvin.
    pub agc: bool,
    /// Offset drift: 1σ random-walk step per frame, kelvin (0: none).
    pub drift_step_k: f64,
    /// A flat-field correction (drift back to zero) before every this many frames (0: only
    /// before the first).
    pub ffc_every: usize,
}

impl ResponseEffects {
    pub fn any(&self) -> bool {
        self.agc || self.drift_step_k > 0.0
    }
}

/// One frame's truth.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct FrameResponse {
    pub image: String,
    /// Added to every apparent temperature of the frame, kelvin.
    pub drift_offset_k: f64,
    /// A flat-field correction happened just before this frame.
    pub ffc_before: bool,
    /// AGC window: the temperatures mapped to grey 0 and 255 (8-bit exports only).
    pub agc_low_k: Option<f64>,
    pub agc_high_k: Option<f64>,
}

/// `response.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ResponseTruth {
    pub agc: bool,
    pub drift_step_k: f64,
    pub ffc_every: usize,
    /// How an image value follows from the apparent temperature T (kelvin) of a pixel.
    pub model: &'static str,
    pub frames: Vec<FrameResponse>,
}

/// Applies the effects frame by frame (in the order the frames are taken).
#[derive(Debug)]
pub struct ResponseSimulator {
    effects: ResponseEffects,
    rng: ChaCha8Rng,
    drift_k: f64,
    frame: usize,
    frames: Vec<FrameResponse>,
}

/// A frame as it is written.
#[derive(Debug, Clone, PartialEq)]
pub enum ExportedFrame {
    /// 16-bit centikelvin words.
    CentiKelvin(Vec<u16>),
    /// 8-bit grey after AGC.
    Grey8(Vec<u8>),
}

impl ResponseSimulator {
    pub fn new(effects: ResponseEffects, seed: u64) -> Self {
        Self {
            effects,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xA6C0_D21F),
            drift_k: 0.0,
            frame: 0,
            frames: Vec::new(),
        }
    }

    /// The exported frame of the sensor's centikelvin words `words` (the radiometric truth of
    /// this frame before drift), recorded under `image`.
    pub fn export(&mut self, image: &str, words: &[u16]) -> ExportedFrame {
        let e = self.effects;
        let ffc_before =
            self.frame == 0 || (e.ffc_every > 0 && self.frame.is_multiple_of(e.ffc_every));
        if ffc_before {
            self.drift_k = 0.0;
        } else if e.drift_step_k > 0.0 {
            let z: f64 = StandardNormal.sample(&mut self.rng);
            self.drift_k += e.drift_step_k * z;
        }
        self.frame += 1;
        let drift_ck = self.drift_k * 100.0;
        let kelvin: Vec<f64> = words
            .iter()
            .map(|&w| (f64::from(w) + drift_ck) / 100.0)
            .collect();
        let (out, low, high) = if e.agc {
            let lo = kelvin.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = kelvin.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let span = if hi > lo { hi - lo } else { 1.0 };
            let grey = kelvin
                .iter()
                .map(|t| ((t - lo) / span * 255.0).round().clamp(0.0, 255.0) as u8)
                .collect();
            (ExportedFrame::Grey8(grey), Some(lo), Some(lo + span))
        } else {
            let words = kelvin
                .iter()
                .map(|t| (t * 100.0).round().clamp(0.0, 65535.0) as u16)
                .collect();
            (ExportedFrame::CentiKelvin(words), None, None)
        };
        self.frames.push(FrameResponse {
            image: image.to_owned(),
            drift_offset_k: self.drift_k,
            ffc_before,
            agc_low_k: low,
            agc_high_k: high,
        });
        out
    }

    /// The truth of every frame exported so far.
    pub fn truth(&self) -> ResponseTruth {
        ResponseTruth {
            agc: self.effects.agc,
            drift_step_k: self.effects.drift_step_k,
            ffc_every: self.effects.ffc_every,
            model: if self.effects.agc {
                "grey = round(255 (T + drift_offset_k - agc_low_k) / (agc_high_k - agc_low_k))"
            } else {
                "word = round(100 (T + drift_offset_k)) (centikelvin)"
            },
            frames: self.frames.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    #[test]
    fn agc_maps_each_frame_to_full_range_and_drift_resets_at_ffc() {
        let mut sim = ResponseSimulator::new(
            ResponseEffects {
                agc: true,
                drift_step_k: 0.5,
                ffc_every: 3,
            },
            1,
        );
        let words: Vec<u16> = (0..100).map(|k| 29_000 + 10 * k).collect();
        for k in 0..7 {
            let ExportedFrame::Grey8(g) = sim.export(&format!("{k}"), &words) else {
                panic!("AGC must write 8-bit frames");
            };
            assert_eq!(
                g.first(),
                Some(&0),
                "frame {k}: the coldest pixel maps to 0"
            );
            assert_eq!(g.last(), Some(&255), "frame {k}: the warmest maps to 255");
        }
        let t = sim.truth();
        for (k, f) in t.frames.iter().enumerate() {
            assert_eq!(f.ffc_before, k % 3 == 0, "frame {k}");
            if f.ffc_before {
                assert_eq!(f.drift_offset_k, 0.0, "frame {k}: FFC resets the drift");
            }
            let lo = f.agc_low_k.expect("AGC window recorded");
            assert!(
                (lo - (290.0 + f.drift_offset_k)).abs() < 1e-9,
                "frame {k}: window starts at the drifted minimum, {lo}"
            );
        }
        assert!(
            t.frames.iter().any(|f| f.drift_offset_k.abs() > 0.05),
            "a 0.5 K step must drift"
        );
    }
}
