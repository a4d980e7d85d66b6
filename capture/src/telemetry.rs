//! Lepton telemetry rows (160×122 "telemetry footer" mode): the two extra rows below the image.
//!
//! Two layouts are decoded, told apart by the revision word (word 0 of row A):
//!
//! - **FLIR Lepton 3.x** (Lepton Engineering Datasheet, "Telemetry Row A"): word 0 revision,
//!   words 1–2 time counter (ms), words 3–4 status bits (32-bit, least significant word first:
//!   bits 4–5 of word 3 are the FFC state), words 20–21 frame counter, word 24 FPA temperature
//!   in kelvin × 100 (centikelvin), words 30–31 time counter at the last FFC.
//! - **s3tir synthetic layout** (revision word `0x5333`, "S3"; what `firmware-sim` wrote before
//!   it switched to FLIR's layout, and what s3tir's synthetic buffers still write, e.g. in the
//!   committed test session): words 1–2 uptime ms (most significant word first),
//!   word 3 status (bits 4–5 FFC state), words 4–5 frame counter, word 6 FPA centikelvin,
//!   word 7 TLinear flag, words 8–9 ms since the last FFC.
//!
//! In both, the FFC state bits mean 00 never commanded, 01 imminent, 10 in progress,
//! 11 complete. The raw telemetry words are always kept next to the decoded values.

use serde::{Deserialize, Serialize};

/// Revision word the simulated rig writes (ASCII "S3").
pub const SIM_TELEMETRY_REVISION: u16 = 0x5333;

/// FFC state as the telemetry status bits 4–5 report it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TelemetryFfc {
    NeverCommanded,
    Imminent,
    InProgress,
    Complete,
}

impl TelemetryFfc {
    /// Decodes bits 4–5 of a status word.
    pub fn from_status(status_low_word: u16) -> Self {
        match (status_low_word >> 4) & 0b11 {
            0 => Self::NeverCommanded,
            1 => Self::Imminent,
            2 => Self::InProgress,
            _ => Self::Complete,
        }
    }
}

/// Which telemetry layout a row was decoded with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TelemetryLayout {
    Lepton3,
    SimRig,
}

/// Decoded Lepton telemetry of one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct LeptonTelemetry {
    pub layout: TelemetryLayout,
    pub revision: u16,
    /// Camera uptime, milliseconds.
    pub uptime_ms: u32,
    /// Low 16 bits of the status word (bits 4–5: FFC state).
    pub status_low: u16,
    pub ffc: TelemetryFfc,
    /// Frame counter of the core (counts every frame, dropped ones included).
    pub frame_counter: u32,
    /// Focal-plane-array temperature, centikelvin.
    pub fpa_temp_ck: u16,
}

/// Why telemetry words could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TelemetryError {
    #[error("telemetry row of {words} words is too short: need at least {needed}")]
    TooShort { words: usize, needed: usize },
}

/// Decodes telemetry row A (`words` = the telemetry rows, row A first).
pub fn decode(words: &[u16]) -> Result<LeptonTelemetry, TelemetryError> {
    let first = words.first().copied().unwrap_or(0);
    let needed = if first == SIM_TELEMETRY_REVISION {
        10
    } else {
        32
    };
    if words.len() < needed {
        return Err(TelemetryError::TooShort {
            words: words.len(),
            needed,
        });
    }
    let w = |i: usize| words.get(i).copied().unwrap_or(0);
    if first == SIM_TELEMETRY_REVISION {
        let status_low = w(3);
        return Ok(LeptonTelemetry {
            layout: TelemetryLayout::SimRig,
            revision: first,
            uptime_ms: (u32::from(w(1)) << 16) | u32::from(w(2)),
            status_low,
            ffc: TelemetryFfc::from_status(status_low),
            frame_counter: (u32::from(w(4)) << 16) | u32::from(w(5)),
            fpa_temp_ck: w(6),
        });
    }
    let status_low = w(3);
    Ok(LeptonTelemetry {
        layout: TelemetryLayout::Lepton3,
        revision: first,
        uptime_ms: u32::from(w(1)) | (u32::from(w(2)) << 16),
        status_low,
        ffc: TelemetryFfc::from_status(status_low),
        frame_counter: u32::from(w(20)) | (u32::from(w(21)) << 16),
        fpa_temp_ck: w(24),
    })
}

#[cfg(test)]
mod tests {
    //! Proves: both layouts decode FFC state (bits 4–5), frame counter and FPA temperature
    //! from hand-built rows; short rows are errors. Does not prove the Lepton layout against a
    //! buffer captured from hardware (none available here).
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::frame::FfcState;

    #[test]
    fn lepton_row_a_decodes_status_counter_and_fpa() {
        let mut row = vec![0u16; 160];
        row[0] = 0x000E;
        row[1] = 0x5678; // uptime LSW
        row[2] = 0x0001; // uptime MSW
        row[3] = 0b10 << 4 | 0b1000; // FFC in progress + "FFC desired"
        row[20] = 0x0002;
        row[21] = 0x0001;
        row[24] = 30_815;
        let t = decode(&row).unwrap();
        assert_eq!(t.layout, TelemetryLayout::Lepton3);
        assert_eq!(t.ffc, TelemetryFfc::InProgress);
        assert_eq!(FfcState::from(t.ffc), FfcState::InProgress);
        assert_eq!(t.frame_counter, 0x0001_0002, "frame counter LSW first");
        assert_eq!(t.uptime_ms, 0x0001_5678);
        assert_eq!(t.fpa_temp_ck, 30_815);
    }

    #[test]
    fn sim_row_decodes_with_its_own_layout() {
        let row = [
            SIM_TELEMETRY_REVISION,
            0,
            1234,
            0b11 << 4,
            0x0001,
            0x0003,
            30_515,
            1,
            0,
            99,
        ];
        let t = decode(&row).unwrap();
        assert_eq!(t.layout, TelemetryLayout::SimRig);
        assert_eq!(t.ffc, TelemetryFfc::Complete);
        assert_eq!(FfcState::from(t.ffc), FfcState::Idle);
        assert_eq!(t.frame_counter, 0x0001_0003);
        assert_eq!(t.fpa_temp_ck, 30_515);
        assert_eq!(t.uptime_ms, 1234);
    }

    #[test]
    fn every_ffc_bit_pattern_maps() {
        let want = [
            TelemetryFfc::NeverCommanded,
            TelemetryFfc::Imminent,
            TelemetryFfc::InProgress,
            TelemetryFfc::Complete,
        ];
        for (bits, w) in want.iter().enumerate() {
            assert_eq!(TelemetryFfc::from_status((bits as u16) << 4 | 0xFF0F), *w);
        }
    }

    #[test]
    fn short_rows_are_errors() {
        assert_eq!(
            decode(&[1, 2, 3]).unwrap_err(),
            TelemetryError::TooShort {
                words: 3,
                needed: 32
            }
        );
        assert!(decode(&[SIM_TELEMETRY_REVISION, 0, 0]).is_err());
    }
}
