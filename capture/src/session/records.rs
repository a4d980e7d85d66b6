//! The records a session holds: topic names, per-frame metadata, pair/drop/status/trigger
//! records, the pipeline's [`SessionRecord`] and the session-level [`SessionInfo`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::device::FourCc;
use crate::frame::{CapturedFrame, FfcState, ThermalUnits};
use crate::session::clock_sync::ClockMap;
use crate::session::pairing::{DropRecord, PairRecord};
use crate::telemetry::LeptonTelemetry;

/// The topic names (the table in the `session` module docs).
pub mod topic {
    pub const THERMAL_IMAGE: &str = "/thermal/image";
    pub const THERMAL_META: &str = "/thermal/meta";
    pub const RGB_COMPRESSED: &str = "/rgb/compressed";
    pub const RGB_IMAGE: &str = "/rgb/image";
    pub const RGB_META: &str = "/rgb/meta";
    pub const PAIRS: &str = "/pairs";
    pub const DROPS: &str = "/drops";
    pub const STATUS: &str = "/capture/status";
    pub const TRIGGERS: &str = "/rig/triggers";
    pub const CLOCK: &str = "/rig/clock";
}

/// Per-frame metadata of a thermal frame (`/thermal/meta`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalMeta {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub wall_unix_ns: u64,
    pub width: u32,
    pub height: u32,
    pub units: ThermalUnits,
    /// State after telemetry decoding (what pairing used).
    pub ffc: FfcState,
    /// State the device reported out of band (kept so replay re-derives `ffc` identically).
    pub ffc_hint: FfcState,
    pub telemetry_rows: u32,
    pub telemetry_words: Vec<u16>,
    pub telemetry: Option<LeptonTelemetry>,
}

/// Per-frame metadata of an RGB frame (`/rgb/meta`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RgbMeta {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub wall_unix_ns: u64,
    pub fourcc: FourCc,
    pub width: u32,
    pub height: u32,
}

/// Counters the recorder writes every second (`/capture/status`); the last one holds totals.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StatusRecord {
    pub wall_unix_ns: u64,
    /// Buffers that failed to parse (short, corrupt): counted, not recorded.
    pub rejected_thermal: u64,
    pub rejected_rgb: u64,
    /// Frames dropped because the recorder's bounded queue was full (slow disk).
    pub queue_drops_thermal: u64,
    pub queue_drops_rgb: u64,
    pub reconnects: u64,
    pub serial_errors: u64,
    /// Times a device delivered nothing for the stall timeout and was reopened (absent in
    /// sessions recorded before the watchdog).
    #[serde(default)]
    pub stalls: u64,
}

/// A rig-controller trigger pulse (`/rig/triggers`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct TriggerRecord {
    pub count: u32,
    /// The controller's clock at the pulse edge, nanoseconds.
    pub controller_ns: u64,
}

/// What the pipeline hands to the writer.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionRecord {
    Frame {
        frame: CapturedFrame,
        ffc_hint: FfcState,
    },
    Pair(PairRecord),
    Drop(DropRecord),
    Status(StatusRecord),
    Trigger(TriggerRecord),
    Clock(ClockMap),
}

/// Session-level description written as the `s3tir.session` metadata record.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SessionInfo {
    pub tool: String,
    pub thermal_device: String,
    pub rgb_device: Option<String>,
    pub thermal_serial: Option<String>,
    pub pairing: String,
    pub notes: String,
}

impl SessionInfo {
    pub(crate) fn to_map(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("tool".into(), self.tool.clone());
        m.insert("thermal_device".into(), self.thermal_device.clone());
        if let Some(r) = &self.rgb_device {
            m.insert("rgb_device".into(), r.clone());
        }
        if let Some(s) = &self.thermal_serial {
            m.insert("thermal_serial".into(), s.clone());
        }
        m.insert("pairing".into(), self.pairing.clone());
        m.insert("notes".into(), self.notes.clone());
        m
    }

    pub(crate) fn from_map(m: &BTreeMap<String, String>) -> Self {
        let get = |k: &str| m.get(k).cloned().unwrap_or_default();
        Self {
            tool: get("tool"),
            thermal_device: get("thermal_device"),
            rgb_device: m.get("rgb_device").cloned(),
            thermal_serial: m.get("thermal_serial").cloned(),
            pairing: get("pairing"),
            notes: get("notes"),
        }
    }
}
