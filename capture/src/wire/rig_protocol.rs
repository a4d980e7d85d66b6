//! The rig controller's serial protocol (s3tir's own design; specified in
//! `firmware-sim/README.md`, "Rig controller protocol").
//!
//! The rig controller is a small microcontroller on the rig: it fires the hardware trigger of
//! both cameras at a set rate, counts and timestamps the trigger pulses, and drives the
//! calibration board's heater/cooler to a setpoint. The capture daemon talks to it; the
//! simulated rig (`s3tir-firmware-sim`) implements it on a pseudo-terminal.
//!
//! Every message, in both directions, is one frame (all integers big-endian):
//!
//! ```text
//! 'R' 'G' | type u8 | seq u8 | len u16 | payload[len] | crc u16
//! ```
//!
//! `crc` is CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final
//! xor) over `type..payload`. There is no byte stuffing: a receiver that loses sync searches
//! for the next `'R' 'G'` whose frame has a valid CRC. `len` is at most [`MAX_PAYLOAD_BYTES`].
//! A reply carries the `seq` of its request. Request types are `0x01..0x7F`, replies
//! `0x80..0xFF`.

/// Frame start: ASCII "RG".
pub const SYNC: [u8; 2] = *b"RG";
/// Largest payload a frame may carry.
pub const MAX_PAYLOAD_BYTES: usize = 512;
/// Sync + type + seq + len.
pub const HEADER_BYTES: usize = 6;
/// Largest number of trigger events in one [`RigMessage::Triggers`] reply.
pub const MAX_TRIGGER_EVENTS: usize = 32;

/// Message type bytes.
pub mod msg_type {
    pub const GET_STATUS: u8 = 0x01;
    pub const START_TRIGGER: u8 = 0x02;
    pub const STOP_TRIGGER: u8 = 0x03;
    pub const GET_TRIGGERS: u8 = 0x04;
    pub const SET_BOARD_SETPOINT: u8 = 0x05;
    pub const ACK: u8 = 0x80;
    pub const STATUS: u8 = 0x81;
    pub const TRIGGERS: u8 = 0x84;
    pub const NACK: u8 = 0xFF;
}

/// Reasons a controller refuses a request ([`RigMessage::Nack`]).
pub mod nack_code {
    /// The request type is not known.
    pub const UNKNOWN_TYPE: u8 = 1;
    /// The payload length is wrong for the type.
    pub const BAD_LENGTH: u8 = 2;
    /// A value is outside what the hardware supports (rate, setpoint).
    pub const OUT_OF_RANGE: u8 = 3;
}

/// One trigger pulse: its running count (first pulse is 1) and controller time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TriggerEvent {
    pub count: u32,
    /// Controller's monotonic clock at the pulse edge, nanoseconds since controller start.
    pub time_ns: u64,
}

/// Controller state as [`RigMessage::Status`] reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RigStatus {
    pub trigger_running: bool,
    /// Trigger rate in millihertz (0 when stopped).
    pub trigger_rate_mhz: u32,
    /// Pulses since controller start.
    pub trigger_count: u32,
    /// Board heater/cooler setpoint in centikelvin; 0 when the heater/cooler is off.
    pub board_setpoint_ck: u16,
    /// Measured board temperature (mean of a thermistor on the uncoated squares), centikelvin.
    pub board_temp_ck: u16,
    /// Ambient temperature, centikelvin.
    pub ambient_ck: u16,
    /// Controller uptime, nanoseconds.
    pub uptime_ns: u64,
}

/// Every message of the protocol.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RigMessage {
    /// Request: report [`RigStatus`]. Empty payload.
    GetStatus,
    /// Request: start pulsing the trigger at `rate_mhz` millihertz (payload u32).
    /// The controller accepts 100 mHz ..= 240 000 mHz.
    StartTrigger { rate_mhz: u32 },
    /// Request: stop the trigger. Empty payload.
    StopTrigger,
    /// Request: trigger events with count > `since_count` (payload u32); at most
    /// [`MAX_TRIGGER_EVENTS`] of the oldest such are returned.
    GetTriggers { since_count: u32 },
    /// Request: board heater/cooler setpoint in centikelvin (payload u16); 0 turns it off.
    /// The controller accepts 0 or 23 315 ..= 37 315 (−50 °C ..= +100 °C).
    SetBoardSetpoint { setpoint_ck: u16 },
    /// Reply: request of type `request_type` done. Payload u8.
    Ack { request_type: u8 },
    /// Reply to GetStatus. Payload: u8 running, u32 rate, u32 count, u16 setpoint, u16 board,
    /// u16 ambient, u64 uptime (23 bytes).
    Status(RigStatus),
    /// Reply to GetTriggers. Payload: u32 total count, u8 n, then n × (u32 count, u64 time_ns).
    Triggers {
        total_count: u32,
        events: Vec<TriggerEvent>,
    },
    /// Reply: request refused. Payload u8 request type, u8 [`nack_code`].
    Nack { request_type: u8, code: u8 },
}

/// A message with its sequence byte.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RigFrame {
    pub seq: u8,
    pub message: RigMessage,
}

/// Why bytes are not a valid rig-controller frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RigProtocolError {
    #[error("rig frame does not start with \"RG\" (found {found:02X?})")]
    MissingSync { found: Vec<u8> },
    #[error("rig frame truncated: {available} bytes, need {needed}")]
    Truncated { available: usize, needed: usize },
    #[error("rig frame declares a {len}-byte payload, maximum {max}")]
    PayloadTooLarge { len: usize, max: usize },
    #[error("rig frame CRC mismatch: frame carries {received:#06x}, contents give {computed:#06x}")]
    CrcMismatch { received: u16, computed: u16 },
    #[error("rig message type {msg_type:#04x} is unknown")]
    UnknownType { msg_type: u8 },
    #[error("rig message type {msg_type:#04x}: payload of {len} bytes, expected {expected}")]
    BadLength {
        msg_type: u8,
        len: usize,
        expected: String,
    },
    #[error("rig Triggers reply carries {events} events, maximum {max}")]
    TooManyEvents { events: usize, max: usize },
}

/// CRC-16/CCITT-FALSE: polynomial 0x1021, initial 0xFFFF, MSB first, no final xor.
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    super::crc16::crc16_1021(0xFFFF, data)
}

impl RigMessage {
    /// The type byte of this message.
    pub fn type_byte(&self) -> u8 {
        match self {
            RigMessage::GetStatus => msg_type::GET_STATUS,
            RigMessage::StartTrigger { .. } => msg_type::START_TRIGGER,
            RigMessage::StopTrigger => msg_type::STOP_TRIGGER,
            RigMessage::GetTriggers { .. } => msg_type::GET_TRIGGERS,
            RigMessage::SetBoardSetpoint { .. } => msg_type::SET_BOARD_SETPOINT,
            RigMessage::Ack { .. } => msg_type::ACK,
            RigMessage::Status(_) => msg_type::STATUS,
            RigMessage::Triggers { .. } => msg_type::TRIGGERS,
            RigMessage::Nack { .. } => msg_type::NACK,
        }
    }

    fn payload(&self) -> Result<Vec<u8>, RigProtocolError> {
        let mut p = Vec::new();
        match self {
            RigMessage::GetStatus | RigMessage::StopTrigger => {}
            RigMessage::StartTrigger { rate_mhz } => p.extend_from_slice(&rate_mhz.to_be_bytes()),
            RigMessage::GetTriggers { since_count } => {
                p.extend_from_slice(&since_count.to_be_bytes());
            }
            RigMessage::SetBoardSetpoint { setpoint_ck } => {
                p.extend_from_slice(&setpoint_ck.to_be_bytes());
            }
            RigMessage::Ack { request_type } => p.push(*request_type),
            RigMessage::Status(s) => {
                p.push(u8::from(s.trigger_running));
                p.extend_from_slice(&s.trigger_rate_mhz.to_be_bytes());
                p.extend_from_slice(&s.trigger_count.to_be_bytes());
                p.extend_from_slice(&s.board_setpoint_ck.to_be_bytes());
                p.extend_from_slice(&s.board_temp_ck.to_be_bytes());
                p.extend_from_slice(&s.ambient_ck.to_be_bytes());
                p.extend_from_slice(&s.uptime_ns.to_be_bytes());
            }
            RigMessage::Triggers {
                total_count,
                events,
            } => {
                if events.len() > MAX_TRIGGER_EVENTS {
                    return Err(RigProtocolError::TooManyEvents {
                        events: events.len(),
                        max: MAX_TRIGGER_EVENTS,
                    });
                }
                p.extend_from_slice(&total_count.to_be_bytes());
                p.push(events.len() as u8);
                for e in events {
                    p.extend_from_slice(&e.count.to_be_bytes());
                    p.extend_from_slice(&e.time_ns.to_be_bytes());
                }
            }
            RigMessage::Nack { request_type, code } => {
                p.push(*request_type);
                p.push(*code);
            }
        }
        Ok(p)
    }

    fn parse(msg_type: u8, p: &[u8]) -> Result<Self, RigProtocolError> {
        let bad = |expected: &str| RigProtocolError::BadLength {
            msg_type,
            len: p.len(),
            expected: expected.to_owned(),
        };
        let exact = |n: usize| {
            if p.len() == n {
                Ok(())
            } else {
                Err(bad(&n.to_string()))
            }
        };
        let u16_at = |i: usize| u16::from_be_bytes([p[i], p[i + 1]]);
        let u32_at = |i: usize| u32::from_be_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
        let u64_at = |i: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&p[i..i + 8]);
            u64::from_be_bytes(b)
        };
        Ok(match msg_type {
            msg_type::GET_STATUS => {
                exact(0)?;
                RigMessage::GetStatus
            }
            msg_type::STOP_TRIGGER => {
                exact(0)?;
                RigMessage::StopTrigger
            }
            msg_type::START_TRIGGER => {
                exact(4)?;
                RigMessage::StartTrigger {
                    rate_mhz: u32_at(0),
                }
            }
            msg_type::GET_TRIGGERS => {
                exact(4)?;
                RigMessage::GetTriggers {
                    since_count: u32_at(0),
                }
            }
            msg_type::SET_BOARD_SETPOINT => {
                exact(2)?;
                RigMessage::SetBoardSetpoint {
                    setpoint_ck: u16_at(0),
                }
            }
            msg_type::ACK => {
                exact(1)?;
                RigMessage::Ack { request_type: p[0] }
            }
            msg_type::STATUS => {
                exact(23)?;
                RigMessage::Status(RigStatus {
                    trigger_running: p[0] != 0,
                    trigger_rate_mhz: u32_at(1),
                    trigger_count: u32_at(5),
                    board_setpoint_ck: u16_at(9),
                    board_temp_ck: u16_at(11),
                    ambient_ck: u16_at(13),
                    uptime_ns: u64_at(15),
                })
            }
            msg_type::TRIGGERS => {
                if p.len() < 5 {
                    return Err(bad("at least 5"));
                }
                let n = usize::from(p[4]);
                if n > MAX_TRIGGER_EVENTS {
                    return Err(RigProtocolError::TooManyEvents {
                        events: n,
                        max: MAX_TRIGGER_EVENTS,
                    });
                }
                exact(5 + 12 * n)?;
                let events = (0..n)
                    .map(|k| {
                        let at = 5 + 12 * k;
                        TriggerEvent {
                            count: u32_at(at),
                            time_ns: u64_at(at + 4),
                        }
                    })
                    .collect();
                RigMessage::Triggers {
                    total_count: u32_at(0),
                    events,
                }
            }
            msg_type::NACK => {
                exact(2)?;
                RigMessage::Nack {
                    request_type: p[0],
                    code: p[1],
                }
            }
            other => return Err(RigProtocolError::UnknownType { msg_type: other }),
        })
    }
}

impl RigFrame {
    pub fn new(seq: u8, message: RigMessage) -> Self {
        Self { seq, message }
    }

    /// Encodes the frame (sync, header, payload, CRC).
    pub fn encode(&self) -> Result<Vec<u8>, RigProtocolError> {
        let payload = self.message.payload()?;
        if payload.len() > MAX_PAYLOAD_BYTES {
            return Err(RigProtocolError::PayloadTooLarge {
                len: payload.len(),
                max: MAX_PAYLOAD_BYTES,
            });
        }
        let mut out = Vec::with_capacity(HEADER_BYTES + payload.len() + 2);
        out.extend_from_slice(&SYNC);
        out.push(self.message.type_byte());
        out.push(self.seq);
        out.extend_from_slice(&(payload.len() as u16).to_be_bytes());
        out.extend_from_slice(&payload);
        let crc = crc16_ccitt_false(&out[2..]);
        out.extend_from_slice(&crc.to_be_bytes());
        Ok(out)
    }

    /// Decodes one frame from the start of `bytes`; returns it and the bytes it used.
    /// Never panics on malformed input.
    pub fn decode(bytes: &[u8]) -> Result<(Self, usize), RigProtocolError> {
        if bytes.len() < HEADER_BYTES + 2 {
            if !SYNC.starts_with(&bytes[..bytes.len().min(2)]) {
                return Err(RigProtocolError::MissingSync {
                    found: bytes[..bytes.len().min(2)].to_vec(),
                });
            }
            return Err(RigProtocolError::Truncated {
                available: bytes.len(),
                needed: HEADER_BYTES + 2,
            });
        }
        if bytes[..2] != SYNC {
            return Err(RigProtocolError::MissingSync {
                found: bytes[..2].to_vec(),
            });
        }
        let len = usize::from(u16::from_be_bytes([bytes[4], bytes[5]]));
        if len > MAX_PAYLOAD_BYTES {
            return Err(RigProtocolError::PayloadTooLarge {
                len,
                max: MAX_PAYLOAD_BYTES,
            });
        }
        let total = HEADER_BYTES + len + 2;
        if bytes.len() < total {
            return Err(RigProtocolError::Truncated {
                available: bytes.len(),
                needed: total,
            });
        }
        let computed = crc16_ccitt_false(&bytes[2..HEADER_BYTES + len]);
        let received =
            u16::from_be_bytes([bytes[HEADER_BYTES + len], bytes[HEADER_BYTES + len + 1]]);
        if computed != received {
            return Err(RigProtocolError::CrcMismatch { received, computed });
        }
        let message = RigMessage::parse(bytes[2], &bytes[HEADER_BYTES..HEADER_BYTES + len])?;
        Ok((
            Self {
                seq: bytes[3],
                message,
            },
            total,
        ))
    }
}

/// Incremental decoder for a serial byte stream. Feed bytes, take frames; on a bad frame it
/// reports the error once and resynchronises at the next `"RG"`.
#[derive(Debug, Default)]
pub struct RigStreamDecoder {
    buf: Vec<u8>,
}

impl RigStreamDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds bytes; returns every frame (or framing error) they complete, in order.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Result<RigFrame, RigProtocolError>> {
        self.buf.extend_from_slice(bytes);
        let mut out = Vec::new();
        loop {
            // Drop bytes before the next sync.
            let start = self.buf.windows(2).position(|w| w == SYNC);
            match start {
                Some(0) => {}
                Some(n) => {
                    self.buf.drain(..n);
                }
                None => {
                    // Keep a trailing 'R' that may begin a sync.
                    let keep = usize::from(self.buf.last() == Some(&SYNC[0]));
                    let cut = self.buf.len() - keep;
                    self.buf.drain(..cut);
                    return out;
                }
            }
            match RigFrame::decode(&self.buf) {
                Ok((frame, used)) => {
                    self.buf.drain(..used);
                    out.push(Ok(frame));
                }
                Err(RigProtocolError::Truncated { .. }) => return out,
                Err(e) => {
                    // Skip this sync and look for the next one.
                    self.buf.drain(..2);
                    out.push(Err(e));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: every message type round-trips through encode/decode (fixed examples and random
    //! values), CRC errors, truncation and garbage are rejected without panics, and the stream
    //! decoder finds frames among noise. Does not prove anything about a real microcontroller.
    #![allow(clippy::unwrap_used)]
    use super::*;
    use proptest::prelude::*;

    fn all_examples() -> Vec<RigMessage> {
        vec![
            RigMessage::GetStatus,
            RigMessage::StartTrigger { rate_mhz: 8_700 },
            RigMessage::StopTrigger,
            RigMessage::GetTriggers { since_count: 41 },
            RigMessage::SetBoardSetpoint {
                setpoint_ck: 25_315,
            },
            RigMessage::Ack { request_type: 2 },
            RigMessage::Status(RigStatus {
                trigger_running: true,
                trigger_rate_mhz: 30_000,
                trigger_count: 123_456,
                board_setpoint_ck: 0,
                board_temp_ck: 29_815,
                ambient_ck: 29_815,
                uptime_ns: 987_654_321_000,
            }),
            RigMessage::Triggers {
                total_count: 9,
                events: vec![
                    TriggerEvent {
                        count: 8,
                        time_ns: 1_000,
                    },
                    TriggerEvent {
                        count: 9,
                        time_ns: u64::MAX,
                    },
                ],
            },
            RigMessage::Nack {
                request_type: 0x42,
                code: nack_code::UNKNOWN_TYPE,
            },
        ]
    }

    #[test]
    fn every_message_round_trips() {
        for (i, m) in all_examples().into_iter().enumerate() {
            let f = RigFrame::new(i as u8, m);
            let wire = f.encode().unwrap();
            let (back, used) = RigFrame::decode(&wire).unwrap();
            assert_eq!(used, wire.len());
            assert_eq!(back, f);
        }
    }

    #[test]
    fn start_trigger_has_the_documented_bytes() {
        // Documented in firmware-sim/README.md: "RG" 02 07 0004 00002BD8 crc.
        let wire = RigFrame::new(7, RigMessage::StartTrigger { rate_mhz: 11_224 })
            .encode()
            .unwrap();
        assert_eq!(
            &wire[..10],
            &[b'R', b'G', 0x02, 0x07, 0x00, 0x04, 0x00, 0x00, 0x2B, 0xD8]
        );
        let crc = crc16_ccitt_false(&wire[2..10]);
        assert_eq!(&wire[10..], &crc.to_be_bytes());
        // CRC-16/CCITT-FALSE check value of "123456789" is 0x29B1.
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
    }

    #[test]
    fn crc_mismatch_and_unknown_type_are_rejected() {
        let mut wire = RigFrame::new(1, RigMessage::GetTriggers { since_count: 5 })
            .encode()
            .unwrap();
        wire[7] ^= 0x10;
        assert!(matches!(
            RigFrame::decode(&wire),
            Err(RigProtocolError::CrcMismatch { .. })
        ));
        let mut raw = vec![b'R', b'G', 0x33, 0, 0, 0];
        let crc = crc16_ccitt_false(&raw[2..]);
        raw.extend_from_slice(&crc.to_be_bytes());
        assert!(matches!(
            RigFrame::decode(&raw),
            Err(RigProtocolError::UnknownType { msg_type: 0x33 })
        ));
    }

    #[test]
    fn stream_decoder_resyncs_after_noise_and_bad_frames() {
        let a = RigFrame::new(1, RigMessage::GetStatus).encode().unwrap();
        let mut bad = RigFrame::new(2, RigMessage::StopTrigger).encode().unwrap();
        bad[6] ^= 1;
        let c = RigFrame::new(
            3,
            RigMessage::SetBoardSetpoint {
                setpoint_ck: 30_000,
            },
        )
        .encode()
        .unwrap();
        let mut stream = b"noiseR".to_vec();
        stream.extend_from_slice(&a);
        stream.extend_from_slice(&bad);
        stream.extend_from_slice(&c);
        let mut dec = RigStreamDecoder::new();
        let mut got = dec.push(&stream[..9]);
        got.extend(dec.push(&stream[9..]));
        let ok: Vec<u8> = got
            .iter()
            .filter_map(|r| r.as_ref().ok())
            .map(|f| f.seq)
            .collect();
        assert_eq!(
            ok,
            vec![1, 3],
            "good frames 1 and 3 must survive, got {got:?}"
        );
        assert_eq!(
            got.iter().filter(|r| r.is_err()).count(),
            1,
            "one bad frame: {got:?}"
        );
    }

    fn any_message() -> impl Strategy<Value = RigMessage> {
        prop_oneof![
            Just(RigMessage::GetStatus),
            Just(RigMessage::StopTrigger),
            any::<u32>().prop_map(|rate_mhz| RigMessage::StartTrigger { rate_mhz }),
            any::<u32>().prop_map(|since_count| RigMessage::GetTriggers { since_count }),
            any::<u16>().prop_map(|setpoint_ck| RigMessage::SetBoardSetpoint { setpoint_ck }),
            (
                any::<u32>(),
                proptest::collection::vec((any::<u32>(), any::<u64>()), 0..=MAX_TRIGGER_EVENTS)
            )
                .prop_map(|(total_count, ev)| RigMessage::Triggers {
                    total_count,
                    events: ev
                        .into_iter()
                        .map(|(count, time_ns)| TriggerEvent { count, time_ns })
                        .collect(),
                }),
            (
                any::<bool>(),
                any::<u32>(),
                any::<u32>(),
                any::<u16>(),
                any::<u16>(),
                any::<u16>(),
                any::<u64>()
            )
                .prop_map(|(a, b, c, d, e, f, g)| RigMessage::Status(RigStatus {
                    trigger_running: a,
                    trigger_rate_mhz: b,
                    trigger_count: c,
                    board_setpoint_ck: d,
                    board_temp_ck: e,
                    ambient_ck: f,
                    uptime_ns: g
                })),
        ]
    }

    proptest! {
        #[test]
        fn random_messages_round_trip(seq in any::<u8>(), m in any_message()) {
            let f = RigFrame::new(seq, m);
            let wire = f.encode().unwrap();
            prop_assert_eq!(RigFrame::decode(&wire).unwrap(), (f, wire.len()));
        }

        #[test]
        fn truncation_and_garbage_never_panic(m in any_message(), cut in any::<prop::sample::Index>(),
                                             junk in proptest::collection::vec(any::<u8>(), 0..64)) {
            let wire = RigFrame::new(0, m).encode().unwrap();
            let n = cut.index(wire.len());
            prop_assert!(RigFrame::decode(&wire[..n]).is_err(), "truncated to {} bytes accepted", n);
            let _ = RigFrame::decode(&junk);
            let _ = RigStreamDecoder::new().push(&junk);
        }
    }
}
