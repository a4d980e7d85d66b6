//! The firmware the simulated rig runs: the Boson's FSLP command set ([`handle_fslp`]: serial,
//! FFC, FPA temperature) and the rig controller's ([`handle_rig`]: a drifting clock, the
//! trigger and its event log, the board's heater/cooler setpoint), over the state all of the
//! rig's threads share ([`Shared`]).

use std::sync::{Mutex, MutexGuard};

use s3tir_capture::wire::fslp::{self, FfcModeCode, FfcStateCode, FslpPacket};
use s3tir_capture::wire::rig_protocol::{
    self, RigFrame, RigMessage, RigStatus, TriggerEvent, nack_code,
};

use super::monotonic_ns;
use crate::board::{BoardSpec, BoardThermal};
use crate::physics::ZERO_CELSIUS_K;
use crate::sensor::ThermalSensor;

/// The simulated core's serial number (GET_SERIAL).
pub const SIM_SERIAL: u32 = 0x0005_3354;
/// Ambient temperature around the board when the heater/cooler is off, kelvin.
pub const AMBIENT_K: f64 = ZERO_CELSIUS_K - 20.0;

/// The rig controller's crystal runs this much fast against the host clock, ppm (a typical
/// 20–50 ppm part): its trigger timestamps must be mapped to the camera clock, never taken as
/// host time.
pub const CONTROLLER_DRIFT_PPM: f64 = 37.0;
/// The controller's clock reads this when the simulator starts (it booted earlier), ns.
pub const CONTROLLER_CLOCK_AT_START_NS: u64 = 123_456_789_012;
/// While the trigger runs, each pulse exposes one frame per camera this long after the pulse
/// edge (thermal, RGB), nanoseconds, with a uniform jitter of ± [`TRIGGER_JITTER_NS`] from
/// the seeded generator: the stamp the camera reports.
pub const TRIGGER_LATENCY_NS: [u64; 2] = [350_000, 120_000];
/// See [`TRIGGER_LATENCY_NS`].
pub const TRIGGER_JITTER_NS: u64 = 25_000;

/// State of the rig controller firmware.
#[derive(Debug)]
pub(super) struct Controller {
    pub(super) running: bool,
    pub(super) rate_mhz: u32,
    pub(super) count: u32,
    /// Controller-clock time of the next pulse (pulses are exact multiples of the period on
    /// the controller's own clock).
    pub(super) next_pulse_ctrl_ns: u64,
    pub(super) events: std::collections::VecDeque<TriggerEvent>,
    pub(super) setpoint_ck: u16,
    pub(super) boot_ns: u64,
}

const MAX_EVENT_LOG: usize = 4096;

impl Controller {
    /// The controller's clock at host monotonic time `mono_ns`.
    pub(super) fn ctrl_ns(&self, mono_ns: u64) -> u64 {
        let dt = mono_ns.saturating_sub(self.boot_ns) as f64;
        CONTROLLER_CLOCK_AT_START_NS + (dt * (1.0 + CONTROLLER_DRIFT_PPM * 1e-6)).round() as u64
    }

    /// The host monotonic time at which the controller's clock reads `ctrl_ns`.
    pub(super) fn mono_ns(&self, ctrl_ns: u64) -> u64 {
        let dc = ctrl_ns.saturating_sub(CONTROLLER_CLOCK_AT_START_NS) as f64;
        self.boot_ns + (dc / (1.0 + CONTROLLER_DRIFT_PPM * 1e-6)).round() as u64
    }

    pub(super) fn start(&mut self, rate_mhz: u32, now_mono_ns: u64) {
        self.running = true;
        self.rate_mhz = rate_mhz;
        self.next_pulse_ctrl_ns = self.ctrl_ns(now_mono_ns);
    }

    pub(super) fn update(&mut self, now_mono_ns: u64) {
        if !self.running || self.rate_mhz == 0 {
            return;
        }
        let period_ns = ((1e12 / f64::from(self.rate_mhz)) as u64).max(1);
        let now = self.ctrl_ns(now_mono_ns);
        while self.next_pulse_ctrl_ns <= now {
            self.count = self.count.wrapping_add(1);
            self.events.push_back(TriggerEvent {
                count: self.count,
                time_ns: self.next_pulse_ctrl_ns,
            });
            if self.events.len() > MAX_EVENT_LOG {
                self.events.pop_front();
            }
            self.next_pulse_ctrl_ns += period_ns;
        }
    }

    /// The host monotonic time of pulse `count`, if it has happened and is still logged.
    pub(super) fn pulse_mono_ns(&self, count: u32) -> Option<u64> {
        let first = self.events.front()?.count;
        let e = self.events.get(count.wrapping_sub(first) as usize)?;
        (e.count == count).then(|| self.mono_ns(e.time_ns))
    }
}

/// Everything the threads share.
#[derive(Debug)]
pub(super) struct Shared {
    pub(super) sensor: ThermalSensor,
    pub(super) board: BoardThermal,
    pub(super) controller: Controller,
    pub(super) ffc_mode: FfcModeCode,
    pub(super) auto_ffc_period_s: f64,
}

impl Shared {
    /// The state at start: the board at 25 °C in the ambient [`AMBIENT_K`] (the TGA-GS
    /// induction), the trigger stopped, FFC automatic when `auto_ffc_period_s` > 0; the
    /// controller booted at host time `boot_ns`.
    pub(super) fn new(
        sensor: ThermalSensor,
        board: BoardSpec,
        auto_ffc_period_s: f64,
        boot_ns: u64,
    ) -> Self {
        Self {
            sensor,
            board: BoardThermal::new(board, Default::default(), ZERO_CELSIUS_K + 25.0, AMBIENT_K),
            controller: Controller {
                running: false,
                rate_mhz: 0,
                count: 0,
                next_pulse_ctrl_ns: 0,
                events: Default::default(),
                setpoint_ck: 0,
                boot_ns,
            },
            ffc_mode: if auto_ffc_period_s > 0.0 {
                FfcModeCode::Auto
            } else {
                FfcModeCode::Manual
            },
            auto_ffc_period_s,
        }
    }
}

pub(super) fn lock(m: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    // A panicking thread leaves consistent data behind (all updates are single assignments).
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Handles one FSLP request; returns the reply.
pub(super) fn handle_fslp(shared: &Mutex<Shared>, req: &FslpPacket) -> FslpPacket {
    use fslp::{command, status};
    let mut s = lock(shared);
    let need = |n: usize| -> Result<(), u32> {
        match req.payload.len() {
            l if l < n => Err(status::INSUFFICIENT_BYTES),
            l if l > n => Err(status::EXCESS_BYTES),
            _ => Ok(()),
        }
    };
    let result: Result<Vec<u8>, u32> = match req.command {
        command::GET_SERIAL => need(0).map(|()| SIM_SERIAL.to_be_bytes().to_vec()),
        command::RUN_FFC => need(0).map(|()| {
            s.sensor.request_ffc();
            Vec::new()
        }),
        command::GET_FFC_STATE => need(0).map(|()| {
            let st = if s.sensor.ffc_in_progress() {
                FfcStateCode::InProgress
            } else if s.sensor.ffc_ever() {
                FfcStateCode::Complete
            } else {
                FfcStateCode::NeverCommanded
            };
            (st as u32).to_be_bytes().to_vec()
        }),
        command::SET_FFC_MODE => need(4).and_then(|()| {
            let v = u32::from_be_bytes([
                req.payload[0],
                req.payload[1],
                req.payload[2],
                req.payload[3],
            ]);
            let mode = FfcModeCode::from_u32(v).ok_or(status::BAD_PAYLOAD)?;
            s.ffc_mode = mode;
            s.sensor.profile.auto_ffc_period_s = if mode == FfcModeCode::Auto {
                s.auto_ffc_period_s
            } else {
                0.0
            };
            Ok(Vec::new())
        }),
        command::GET_FFC_MODE => need(0).map(|()| (s.ffc_mode as u32).to_be_bytes().to_vec()),
        command::GET_FPA_TEMP => need(0).map(|()| {
            let deci_c = ((s.sensor.fpa_temp_k - ZERO_CELSIUS_K) * 10.0).round() as i16;
            deci_c.to_be_bytes().to_vec()
        }),
        _ => Err(status::BAD_COMMAND),
    };
    match result {
        Ok(payload) => req.reply(status::OK, payload),
        Err(code) => req.reply(code, Vec::new()),
    }
}

/// Handles one rig-controller request; returns the reply.
pub(super) fn handle_rig(shared: &Mutex<Shared>, req: &RigFrame) -> RigFrame {
    let mut s = lock(shared);
    let now = monotonic_ns();
    s.controller.update(now);
    let t = req.message.type_byte();
    let nack = |code| RigMessage::Nack {
        request_type: t,
        code,
    };
    let reply = match &req.message {
        RigMessage::GetStatus => RigMessage::Status(RigStatus {
            trigger_running: s.controller.running,
            trigger_rate_mhz: if s.controller.running {
                s.controller.rate_mhz
            } else {
                0
            },
            trigger_count: s.controller.count,
            board_setpoint_ck: s.controller.setpoint_ck,
            board_temp_ck: (s.board.mean_uncoated_temp_k() * 100.0).round() as u16,
            ambient_ck: (AMBIENT_K * 100.0).round() as u16,
            // The controller's own clock (the one its trigger timestamps use).
            uptime_ns: s.controller.ctrl_ns(now),
        }),
        RigMessage::StartTrigger { rate_mhz } => {
            if (100..=240_000).contains(rate_mhz) {
                s.controller.start(*rate_mhz, now);
                RigMessage::Ack { request_type: t }
            } else {
                nack(nack_code::OUT_OF_RANGE)
            }
        }
        RigMessage::StopTrigger => {
            s.controller.running = false;
            RigMessage::Ack { request_type: t }
        }
        RigMessage::GetTriggers { since_count } => {
            let events: Vec<TriggerEvent> = s
                .controller
                .events
                .iter()
                .filter(|e| e.count > *since_count)
                .take(rig_protocol::MAX_TRIGGER_EVENTS)
                .copied()
                .collect();
            RigMessage::Triggers {
                total_count: s.controller.count,
                events,
            }
        }
        RigMessage::SetBoardSetpoint { setpoint_ck } => {
            if *setpoint_ck == 0 || (23_315..=37_315).contains(setpoint_ck) {
                s.controller.setpoint_ck = *setpoint_ck;
                s.board.env_k = if *setpoint_ck == 0 {
                    AMBIENT_K
                } else {
                    f64::from(*setpoint_ck) / 100.0
                };
                RigMessage::Ack { request_type: t }
            } else {
                nack(nack_code::OUT_OF_RANGE)
            }
        }
        // Replies sent to the controller are not requests.
        _ => nack(nack_code::UNKNOWN_TYPE),
    };
    RigFrame::new(req.seq, reply)
}
