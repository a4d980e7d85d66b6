//! Serial clients: the FLIR Boson (FSLP, [`crate::wire::fslp`]) and the rig controller
//! ([`crate::wire::rig_protocol`]).
//!
//! Both are generic over the port (`Read + Write`), so they run over `serialport` on a rig, over
//! the simulated rig's pseudo-terminal, and over in-memory fakes in tests. Every exchange has
//! a timeout, matches the reply's sequence number to the request's (stale replies are
//! skipped), and retries a request whose reply failed its CRC or framing (counted in
//! `crc_errors`); a reply with an error status is returned as an error and not retried.

use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

use crate::error::{BoxedCause, CaptureError};
use crate::wire::fslp::{self, FfcStateCode, FslpError, FslpPacket, FslpStreamDecoder};
use crate::wire::rig_protocol::{
    RigFrame, RigMessage, RigProtocolError, RigStatus, RigStreamDecoder, TriggerEvent,
};

/// Opens a serial port at 921600 baud (Boson CDC-ACM ignores the rate; the rig controller
/// firmware uses it) with a short read timeout for the clients' polling loop.
pub fn open_port(path: &str) -> Result<Box<dyn serialport::SerialPort>, CaptureError> {
    serialport::new(path, 921_600)
        .timeout(Duration::from_millis(20))
        .open()
        .map_err(|e| CaptureError::SerialIo {
            port: path.to_owned(),
            command: "open".into(),
            what: "open port",
            source: e.into(),
        })
}

fn read_some<P: Read>(port: &mut P, buf: &mut [u8]) -> Result<usize, std::io::Error> {
    match port.read(buf) {
        Ok(n) => Ok(n),
        Err(e)
            if matches!(
                e.kind(),
                ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
            ) =>
        {
            Ok(0)
        }
        Err(e) => Err(e),
    }
}

/// FLIR Boson command client.
#[derive(Debug)]
pub struct BosonClient<P> {
    port: P,
    name: String,
    sequence: u32,
    pub timeout: Duration,
    pub retries: u32,
    decoder: FslpStreamDecoder,
    /// Replies rejected for a bad CRC or framing (each caused a retry).
    pub crc_errors: u64,
}

impl<P: Read + Write> BosonClient<P> {
    pub fn new(port: P, name: &str) -> Self {
        Self {
            port,
            name: name.to_owned(),
            sequence: 0,
            timeout: Duration::from_millis(500),
            retries: 2,
            decoder: FslpStreamDecoder::new(),
            crc_errors: 0,
        }
    }

    fn err(&self, command: u32, reason: String) -> CaptureError {
        CaptureError::Serial {
            port: self.name.clone(),
            command: format!("FSLP {command:#010x}"),
            reason,
        }
    }

    fn io_err(&self, command: u32, what: &'static str, source: BoxedCause) -> CaptureError {
        CaptureError::SerialIo {
            port: self.name.clone(),
            command: format!("FSLP {command:#010x}"),
            what,
            source,
        }
    }

    /// One request/reply exchange; returns the reply payload.
    pub fn transact(&mut self, command: u32, payload: Vec<u8>) -> Result<Vec<u8>, CaptureError> {
        let mut last = String::from("no reply");
        for _attempt in 0..=self.retries {
            self.sequence = self.sequence.wrapping_add(1);
            let seq = self.sequence;
            let bytes = FslpPacket::request(seq, command, payload.clone())
                .encode()
                .map_err(|e| self.io_err(command, "encode request", e.into()))?;
            self.port
                .write_all(&bytes)
                .and_then(|_| self.port.flush())
                .map_err(|e| self.io_err(command, "write", e.into()))?;
            let deadline = Instant::now() + self.timeout;
            let mut buf = [0u8; 256];
            'wait: while Instant::now() < deadline {
                let n = read_some(&mut self.port, &mut buf)
                    .map_err(|e| self.io_err(command, "read", e.into()))?;
                if n == 0 {
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                for r in self.decoder.push(&buf[..n]) {
                    match r {
                        Ok(p) if p.is_request() || p.sequence != seq => {
                            tracing::debug!(port = %self.name, got = p.sequence, want = seq, "skipping stale FSLP packet");
                        }
                        Ok(p) if p.command != command => {
                            return Err(self.err(
                                command,
                                format!("reply is for command {:#010x}", p.command),
                            ));
                        }
                        Ok(p) if p.status != fslp::status::OK => {
                            return Err(self.err(
                                command,
                                format!("camera returned status {:#06x}", p.status),
                            ));
                        }
                        Ok(p) => return Ok(p.payload),
                        Err(e) => {
                            self.crc_errors += 1;
                            tracing::warn!(port = %self.name, "bad FSLP reply ({e}); retrying");
                            last = e.to_string();
                            if matches!(e, FslpError::CrcMismatch { .. }) {
                                break 'wait;
                            }
                        }
                    }
                }
            }
            if last == "no reply" {
                last = format!("no reply within {} ms", self.timeout.as_millis());
            }
        }
        Err(self.err(
            command,
            format!("failed after {} attempts: {last}", self.retries + 1),
        ))
    }

    fn u32_reply(&mut self, command: u32) -> Result<u32, CaptureError> {
        let p = self.transact(command, Vec::new())?;
        let b: [u8; 4] = p.get(..4).and_then(|s| s.try_into().ok()).ok_or_else(|| {
            self.err(
                command,
                format!("reply payload of {} bytes, expected 4", p.len()),
            )
        })?;
        Ok(u32::from_be_bytes(b))
    }

    /// Camera serial number.
    pub fn serial_number(&mut self) -> Result<u32, CaptureError> {
        self.u32_reply(fslp::command::GET_SERIAL)
    }

    /// Starts a flat-field correction now.
    pub fn run_ffc(&mut self) -> Result<(), CaptureError> {
        self.transact(fslp::command::RUN_FFC, Vec::new())
            .map(|_| ())
    }

    pub fn ffc_state(&mut self) -> Result<FfcStateCode, CaptureError> {
        let v = self.u32_reply(fslp::command::GET_FFC_STATE)?;
        FfcStateCode::from_u32(v).ok_or_else(|| {
            self.err(
                fslp::command::GET_FFC_STATE,
                format!("undefined FFC state {v}"),
            )
        })
    }

    /// Focal-plane temperature in centikelvin (the Boson reports 0.1 °C).
    pub fn fpa_temp_ck(&mut self) -> Result<u32, CaptureError> {
        let c = fslp::command::GET_FPA_TEMP;
        let p = self.transact(c, Vec::new())?;
        let b: [u8; 2] = p.get(..2).and_then(|s| s.try_into().ok()).ok_or_else(|| {
            self.err(c, format!("reply payload of {} bytes, expected 2", p.len()))
        })?;
        let deci_c = i32::from(i16::from_be_bytes(b));
        Ok((27_315 + deci_c * 10).max(0) as u32)
    }
}

/// Rig controller client (trigger, trigger timestamps, board heater).
#[derive(Debug)]
pub struct RigClient<P> {
    port: P,
    name: String,
    seq: u8,
    pub timeout: Duration,
    pub retries: u32,
    decoder: RigStreamDecoder,
    pub crc_errors: u64,
}

impl<P: Read + Write> RigClient<P> {
    pub fn new(port: P, name: &str) -> Self {
        Self {
            port,
            name: name.to_owned(),
            seq: 0,
            timeout: Duration::from_millis(500),
            retries: 2,
            decoder: RigStreamDecoder::new(),
            crc_errors: 0,
        }
    }

    fn err(&self, command: &str, reason: String) -> CaptureError {
        CaptureError::Serial {
            port: self.name.clone(),
            command: command.to_owned(),
            reason,
        }
    }

    fn io_err(&self, command: &str, what: &'static str, source: BoxedCause) -> CaptureError {
        CaptureError::SerialIo {
            port: self.name.clone(),
            command: command.to_owned(),
            what,
            source,
        }
    }

    /// One request/reply exchange.
    pub fn transact(&mut self, request: RigMessage) -> Result<RigMessage, CaptureError> {
        let what = format!("{request:?}");
        let mut last = String::from("no reply");
        for _ in 0..=self.retries {
            self.seq = self.seq.wrapping_add(1);
            let seq = self.seq;
            let bytes = RigFrame::new(seq, request.clone())
                .encode()
                .map_err(|e| self.io_err(&what, "encode request", e.into()))?;
            self.port
                .write_all(&bytes)
                .and_then(|_| self.port.flush())
                .map_err(|e| self.io_err(&what, "write", e.into()))?;
            let deadline = Instant::now() + self.timeout;
            let mut buf = [0u8; 512];
            'wait: while Instant::now() < deadline {
                let n = read_some(&mut self.port, &mut buf)
                    .map_err(|e| self.io_err(&what, "read", e.into()))?;
                if n == 0 {
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                for r in self.decoder.push(&buf[..n]) {
                    match r {
                        Ok(f) if f.seq != seq => {}
                        Ok(RigFrame {
                            message: RigMessage::Nack { code, .. },
                            ..
                        }) => {
                            return Err(
                                self.err(&what, format!("controller refused (NACK code {code})"))
                            );
                        }
                        Ok(f) => return Ok(f.message),
                        Err(e) => {
                            self.crc_errors += 1;
                            tracing::warn!(port = %self.name, "bad rig reply ({e}); retrying");
                            last = e.to_string();
                            if matches!(e, RigProtocolError::CrcMismatch { .. }) {
                                break 'wait;
                            }
                        }
                    }
                }
            }
            if last == "no reply" {
                last = format!("no reply within {} ms", self.timeout.as_millis());
            }
        }
        Err(self.err(
            &what,
            format!("failed after {} attempts: {last}", self.retries + 1),
        ))
    }

    fn ack(&mut self, m: RigMessage) -> Result<(), CaptureError> {
        let what = format!("{m:?}");
        match self.transact(m)? {
            RigMessage::Ack { .. } => Ok(()),
            other => Err(self.err(&what, format!("unexpected reply {other:?}"))),
        }
    }

    pub fn start_trigger(&mut self, rate_mhz: u32) -> Result<(), CaptureError> {
        self.ack(RigMessage::StartTrigger { rate_mhz })
    }

    pub fn stop_trigger(&mut self) -> Result<(), CaptureError> {
        self.ack(RigMessage::StopTrigger)
    }

    pub fn set_board_setpoint_ck(&mut self, setpoint_ck: u16) -> Result<(), CaptureError> {
        self.ack(RigMessage::SetBoardSetpoint { setpoint_ck })
    }

    pub fn status(&mut self) -> Result<RigStatus, CaptureError> {
        match self.transact(RigMessage::GetStatus)? {
            RigMessage::Status(s) => Ok(s),
            other => Err(self.err("GetStatus", format!("unexpected reply {other:?}"))),
        }
    }

    /// Trigger events after `since_count` (oldest first, at most 32 per call).
    pub fn triggers(&mut self, since_count: u32) -> Result<(u32, Vec<TriggerEvent>), CaptureError> {
        match self.transact(RigMessage::GetTriggers { since_count })? {
            RigMessage::Triggers {
                total_count,
                events,
            } => Ok((total_count, events)),
            other => Err(self.err("GetTriggers", format!("unexpected reply {other:?}"))),
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: both clients complete exchanges with in-memory fakes of the devices, skip stale
    //! replies, retry after CRC errors (and count them), time out with an error naming the
    //! port, and report error statuses/NACKs without retrying. Does not open a real tty.
    #![allow(clippy::unwrap_used)]
    use super::*;
    use std::collections::VecDeque;

    /// A fake device: answers each complete request via `respond`, corrupting the first
    /// `corrupt_first` replies.
    struct Fake<F> {
        rx: Vec<u8>,
        tx: VecDeque<u8>,
        respond: F,
        corrupt_first: u32,
        /// Which byte (counted from the end) a corrupted reply has flipped.
        corrupt_from_end: usize,
        replies: u32,
    }

    impl<F: FnMut(&[u8]) -> Option<Vec<u8>>> Read for Fake<F> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = buf.len().min(self.tx.len());
            for b in buf.iter_mut().take(n) {
                *b = self.tx.pop_front().unwrap();
            }
            Ok(n)
        }
    }

    impl<F: FnMut(&[u8]) -> Option<Vec<u8>>> Write for Fake<F> {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.rx.extend_from_slice(buf);
            if let Some(mut reply) = (self.respond)(&self.rx) {
                self.rx.clear();
                self.replies += 1;
                if self.replies <= self.corrupt_first {
                    let k = reply.len() - self.corrupt_from_end;
                    reply[k] ^= 0x01; // CRC'd body or CRC: CRC mismatch
                }
                self.tx.extend(reply);
            }
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn boson(corrupt_first: u32, status: u32) -> Fake<impl FnMut(&[u8]) -> Option<Vec<u8>>> {
        Fake {
            rx: Vec::new(),
            tx: VecDeque::new(),
            respond: move |req: &[u8]| {
                let p = FslpPacket::decode(req).ok()?;
                // A stale reply first (older sequence), then the real one.
                let stale = p.reply(0, vec![9, 9, 9, 9]);
                let stale = FslpPacket {
                    sequence: p.sequence.wrapping_sub(7),
                    ..stale
                };
                let payload = match p.command {
                    fslp::command::GET_SERIAL => 123_456u32.to_be_bytes().to_vec(),
                    fslp::command::GET_FFC_STATE => 3u32.to_be_bytes().to_vec(),
                    fslp::command::GET_FPA_TEMP => 312i16.to_be_bytes().to_vec(),
                    _ => vec![],
                };
                let mut out = stale.encode().ok()?;
                out.extend(p.reply(status, payload).encode().ok()?);
                Some(out)
            },
            corrupt_first,
            corrupt_from_end: 4, // last payload byte of the real reply
            replies: 0,
        }
    }

    #[test]
    fn boson_commands_decode_and_skip_stale_replies() {
        let mut c = BosonClient::new(boson(0, 0), "fake-boson");
        assert_eq!(c.serial_number().unwrap(), 123_456);
        assert_eq!(c.ffc_state().unwrap(), FfcStateCode::Complete);
        assert_eq!(c.fpa_temp_ck().unwrap(), 27_315 + 3_120);
        c.run_ffc().unwrap();
        assert_eq!(c.crc_errors, 0);
    }

    #[test]
    fn boson_crc_errors_are_counted_and_retried() {
        // Each exchange's response is a stale packet then the real one; the corruption hits
        // the real one's last payload byte.
        let mut c = BosonClient::new(boson(1, 0), "fake-boson");
        assert_eq!(
            c.serial_number().unwrap(),
            123_456,
            "second attempt succeeds"
        );
        assert_eq!(c.crc_errors, 1, "one CRC error counted");
        let mut c = BosonClient::new(boson(10, 0), "fake-boson");
        let err = c.serial_number().unwrap_err().to_string();
        assert!(
            err.contains("fake-boson") && err.contains("CRC"),
            "got {err}"
        );
        assert_eq!(c.crc_errors, 3, "1 try + 2 retries");
    }

    #[test]
    fn boson_error_status_is_reported_not_retried() {
        let mut c = BosonClient::new(boson(0, fslp::status::BAD_COMMAND), "fake-boson");
        let err = c.run_ffc().unwrap_err().to_string();
        assert!(err.contains("0x0161"), "got {err}");
    }

    #[test]
    fn silent_device_times_out_naming_the_port() {
        let dead = Fake {
            rx: Vec::new(),
            tx: VecDeque::new(),
            respond: |_: &[u8]| None,
            corrupt_first: 0,
            corrupt_from_end: 1,
            replies: 0,
        };
        let mut c = BosonClient::new(dead, "/dev/ttyACM9");
        c.timeout = Duration::from_millis(20);
        let err = c.serial_number().unwrap_err().to_string();
        assert!(
            err.contains("/dev/ttyACM9") && err.contains("no reply"),
            "got {err}"
        );
    }

    fn rig(corrupt_first: u32) -> Fake<impl FnMut(&[u8]) -> Option<Vec<u8>>> {
        Fake {
            rx: Vec::new(),
            tx: VecDeque::new(),
            respond: |req: &[u8]| {
                let (f, _) = RigFrame::decode(req).ok()?;
                let reply = match f.message {
                    RigMessage::GetTriggers { since_count } => RigMessage::Triggers {
                        total_count: since_count + 2,
                        events: vec![
                            TriggerEvent {
                                count: since_count + 1,
                                time_ns: 10,
                            },
                            TriggerEvent {
                                count: since_count + 2,
                                time_ns: 20,
                            },
                        ],
                    },
                    RigMessage::SetBoardSetpoint { setpoint_ck } if setpoint_ck > 40_000 => {
                        RigMessage::Nack {
                            request_type: 5,
                            code: 3,
                        }
                    }
                    other => RigMessage::Ack {
                        request_type: other.type_byte(),
                    },
                };
                RigFrame::new(f.seq, reply).encode().ok()
            },
            corrupt_first,
            corrupt_from_end: 1, // CRC low byte
            replies: 0,
        }
    }

    #[test]
    fn rig_client_triggers_nack_and_crc_retry() {
        let mut c = RigClient::new(rig(1), "fake-rig");
        c.start_trigger(30_000).unwrap();
        assert_eq!(c.crc_errors, 1, "first reply corrupted, retried");
        let (total, ev) = c.triggers(4).unwrap();
        assert_eq!(total, 6);
        assert_eq!(ev.iter().map(|e| e.count).collect::<Vec<_>>(), vec![5, 6]);
        let err = c.set_board_setpoint_ck(50_000).unwrap_err().to_string();
        assert!(err.contains("NACK code 3"), "got {err}");
        c.stop_trigger().unwrap();
    }
}
