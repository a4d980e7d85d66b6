//! Proves, in-process and in real time, one behaviour per test (each on its own served rig):
//! - `serve` announces its socket and ptys, streams V4L2-shaped Y16 frames (with telemetry
//!   rows, TLinear flag, increasing sequence and CLOCK_MONOTONIC stamps) over the Unix socket,
//!   and removes the socket on shutdown;
//! - the Boson FSLP firmware on its pty answers GET_SERIAL and rejects an unknown command;
//! - an FSLP RUN_FFC freezes exactly `ffc_frames` consecutive frames (flagged, identical
//!   images), then the stream is live again;
//! - the rig controller on its pty acknowledges a board setpoint, refuses an out-of-range one,
//!   reports it in its status, and the board warms toward it;
//! - trigger pulses are timestamped at the set rate;
//! - with `--rgb` in YUYV, RGB frames of the right size arrive on the same socket.
//!
//! Does not prove behaviour under a real serial driver's timing.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use s3tir_capture::wire::fslp::{self, FslpPacket, FslpStreamDecoder};
use s3tir_capture::wire::rig_protocol::{RigFrame, RigMessage, RigStreamDecoder};
use s3tir_capture::wire::simwire::{self, WireFrame};
use s3tir_firmware_sim::sensor::ThermalProfile;
use s3tir_firmware_sim::serve::{RgbFormat, ServeConfig, serve};

fn wait_readable(f: &File, timeout: Duration) -> bool {
    let mut fds = [nix::poll::PollFd::new(
        f.as_fd(),
        nix::poll::PollFlags::POLLIN,
    )];
    let ms = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
    nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(ms)).unwrap_or(0) > 0
}

fn fslp_call(port: &mut File, dec: &mut FslpStreamDecoder, req: &FslpPacket) -> FslpPacket {
    port.write_all(&req.encode().unwrap()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut buf = [0u8; 256];
    while Instant::now() < deadline {
        if wait_readable(port, Duration::from_millis(100)) {
            let n = port.read(&mut buf).unwrap();
            if let Some(r) = dec.push(&buf[..n]).into_iter().next() {
                return r.unwrap();
            }
        }
    }
    panic!("no FSLP reply to {req}");
}

fn rig_call(port: &mut File, dec: &mut RigStreamDecoder, seq: u8, m: RigMessage) -> RigMessage {
    port.write_all(&RigFrame::new(seq, m).encode().unwrap())
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut buf = [0u8; 1024];
    while Instant::now() < deadline {
        if wait_readable(port, Duration::from_millis(100)) {
            let n = port.read(&mut buf).unwrap();
            if let Some(r) = dec.push(&buf[..n]).into_iter().next() {
                let f = r.unwrap();
                assert_eq!(f.seq, seq, "reply carries the request's seq");
                return f.message;
            }
        }
    }
    panic!("no rig controller reply");
}

/// A rig served in-process on a temporary socket: its announcements, the frame stream, and the
/// stop flag. Dropping it stops the server and checks it shut down cleanly.
struct ServedRig {
    _dir: tempfile::TempDir,
    socket: std::path::PathBuf,
    keys: HashMap<String, String>,
    stop: Arc<AtomicBool>,
    server: Option<std::thread::JoinHandle<Result<(), s3tir_firmware_sim::error::SimError>>>,
}

impl ServedRig {
    /// A Lepton 3.5 at 20 Hz with 2 telemetry rows and 6-frame FFCs (no automatic FFC).
    fn lepton() -> Self {
        let mut profile = ThermalProfile::lepton35();
        profile.rate_hz = 20.0;
        profile.ffc_frames = 6;
        profile.telemetry_rows = 2;
        profile.auto_ffc_period_s = 0.0;
        Self::start(profile, None, RgbFormat::Mjpeg, 1)
    }

    fn start(
        thermal: ThermalProfile,
        rgb: Option<s3tir_firmware_sim::sensor::RgbProfile>,
        rgb_format: RgbFormat,
        seed: u64,
    ) -> Self {
        let dir = tempfile::tempdir().unwrap();
        let socket = dir.path().join("rig.sock");
        let stop = Arc::new(AtomicBool::new(false));
        let cfg = ServeConfig {
            thermal,
            rgb,
            rgb_format,
            socket: socket.clone(),
            duration_s: Some(60.0),
            seed,
            stop_on_stdin_eof: false,
            stop: stop.clone(),
        };
        let (tx, rx) = mpsc::channel::<(String, String)>();
        let server = std::thread::spawn(move || {
            serve(cfg, &mut |k, v| {
                let _ = tx.send((k.to_owned(), v.to_owned()));
            })
        });
        let mut keys = HashMap::new();
        while !keys.contains_key("ready") {
            let (k, v) = rx
                .recv_timeout(Duration::from_secs(30))
                .expect("announcement");
            keys.insert(k, v);
        }
        Self {
            _dir: dir,
            socket,
            keys,
            stop,
            server: Some(server),
        }
    }

    fn stream(&self) -> UnixStream {
        let stream = UnixStream::connect(&self.socket).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        stream
    }

    fn pty(&self, key: &str) -> File {
        File::options()
            .read(true)
            .write(true)
            .open(&self.keys[key])
            .unwrap()
    }

    /// Stops the server and returns once it has shut down.
    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(server) = self.server.take() {
            server.join().unwrap().unwrap();
        }
    }
}

impl Drop for ServedRig {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(server) = self.server.take() {
            let _ = server.join();
        }
    }
}

fn read_frame(stream: &mut UnixStream) -> WireFrame {
    WireFrame::read_from(stream, "test")
        .unwrap()
        .expect("frame")
}

#[test]
fn serve_announces_and_streams_v4l2_shaped_y16_frames() {
    let mut rig = ServedRig::lepton();
    assert_eq!(rig.keys["socket"], rig.socket.display().to_string());
    for pty in ["fslp_pty", "rig_pty"] {
        assert!(
            rig.keys[pty].starts_with("/dev/"),
            "{pty} path: {}",
            rig.keys[pty]
        );
    }
    let mut stream = rig.stream();
    let first = read_frame(&mut stream);
    assert_eq!(first.fourcc, s3tir_capture::device::FourCc::Y16);
    assert_eq!(
        (first.width, first.height, first.bytes_per_line),
        (160, 122, 320)
    );
    assert_eq!(first.payload.len(), 320 * 122);
    assert!(first.flags & simwire::FLAG_TLINEAR != 0 && first.flags & simwire::FLAG_TELEMETRY != 0);
    let second = read_frame(&mut stream);
    assert!(
        second.sequence > first.sequence && second.monotonic_ns > first.monotonic_ns,
        "sequence and time increase"
    );
    drop(stream);
    rig.shutdown();
    assert!(!rig.socket.exists(), "socket removed on shutdown");
}

#[test]
fn boson_fslp_answers_get_serial_and_rejects_unknown_commands() {
    let rig = ServedRig::lepton();
    let mut port = rig.pty("fslp_pty");
    let mut dec = FslpStreamDecoder::new();
    let serial = fslp_call(
        &mut port,
        &mut dec,
        &FslpPacket::request(1, fslp::command::GET_SERIAL, vec![]),
    );
    assert_eq!((serial.sequence, serial.status), (1, fslp::status::OK));
    assert_eq!(serial.payload.len(), 4, "serial is a u32");
    let bad = fslp_call(
        &mut port,
        &mut dec,
        &FslpPacket::request(2, 0x00AB_CDEF, vec![]),
    );
    assert_eq!(bad.status, fslp::status::BAD_COMMAND);
}

#[test]
fn fslp_run_ffc_freezes_exactly_ffc_frames_then_the_stream_is_live() {
    let rig = ServedRig::lepton();
    let mut stream = rig.stream();
    let second = {
        read_frame(&mut stream);
        read_frame(&mut stream)
    };
    let mut port = rig.pty("fslp_pty");
    let mut dec = FslpStreamDecoder::new();
    let ffc = fslp_call(
        &mut port,
        &mut dec,
        &FslpPacket::request(3, fslp::command::RUN_FFC, vec![]),
    );
    assert_eq!(ffc.status, fslp::status::OK);

    // Frames already queued are live; then exactly 6 frozen, then live again.
    let img_bytes = 320 * 120;
    let mut frames = Vec::new();
    loop {
        let f = read_frame(&mut stream);
        let frozen = f.flags & simwire::FLAG_FFC_FROZEN != 0;
        frames.push(f);
        let n_frozen = frames
            .iter()
            .filter(|f| f.flags & simwire::FLAG_FFC_FROZEN != 0)
            .count();
        if n_frozen > 0 && !frozen {
            break;
        }
        assert!(frames.len() < 100, "no end of FFC within 100 frames");
    }
    let start = frames
        .iter()
        .position(|f| f.flags & simwire::FLAG_FFC_FROZEN != 0)
        .unwrap();
    let frozen: Vec<&WireFrame> = frames[start..frames.len() - 1].iter().collect();
    assert_eq!(
        frozen.len(),
        6,
        "FFC must freeze exactly ffc_frames = 6 frames, froze {}",
        frozen.len()
    );
    let before = if start > 0 {
        &frames[start - 1]
    } else {
        &second
    };
    for f in &frozen {
        assert_eq!(
            f.payload[..img_bytes],
            before.payload[..img_bytes],
            "frozen frame {} repeats the last live image",
            f.sequence
        );
    }
    let after = frames.last().unwrap();
    assert_ne!(
        after.payload[..img_bytes],
        before.payload[..img_bytes],
        "live again after FFC"
    );
}

#[test]
fn rig_controller_sets_the_board_refuses_out_of_range_and_the_board_warms() {
    let rig = ServedRig::lepton();
    let mut port = rig.pty("rig_pty");
    let mut dec = RigStreamDecoder::new();
    let ack = rig_call(
        &mut port,
        &mut dec,
        1,
        RigMessage::SetBoardSetpoint {
            setpoint_ck: 34_315,
        },
    );
    assert_eq!(ack, RigMessage::Ack { request_type: 0x05 });
    let nack = rig_call(
        &mut port,
        &mut dec,
        2,
        RigMessage::SetBoardSetpoint { setpoint_ck: 5 },
    );
    assert!(
        matches!(
            nack,
            RigMessage::Nack {
                request_type: 0x05,
                ..
            }
        ),
        "out-of-range setpoint refused: {nack:?}"
    );
    let board_before_ck = match rig_call(&mut port, &mut dec, 3, RigMessage::GetStatus) {
        RigMessage::Status(s) => {
            assert_eq!(s.board_setpoint_ck, 34_315);
            assert!(!s.trigger_running);
            s.board_temp_ck
        }
        other => panic!("expected Status, got {other:?}"),
    };
    // The 70 °C setpoint heats the board's surroundings: the board warms at ≈ 0.4 K/s, so
    // ≥ 0.05 K after 0.4 s of frames (the simulation advances with the frame stream a client
    // reads).
    let mut stream = rig.stream();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(400) {
        read_frame(&mut stream);
    }
    match rig_call(&mut port, &mut dec, 4, RigMessage::GetStatus) {
        RigMessage::Status(s) => assert!(
            s.board_temp_ck >= board_before_ck + 5,
            "board must warm toward the setpoint: {board_before_ck} -> {} ck",
            s.board_temp_ck
        ),
        other => panic!("expected Status, got {other:?}"),
    }
}

#[test]
fn rig_controller_timestamps_trigger_pulses_at_the_set_rate() {
    let rig = ServedRig::lepton();
    let mut port = rig.pty("rig_pty");
    let mut dec = RigStreamDecoder::new();
    let ack = rig_call(
        &mut port,
        &mut dec,
        1,
        RigMessage::StartTrigger { rate_mhz: 50_000 },
    );
    assert_eq!(ack, RigMessage::Ack { request_type: 0x02 });
    std::thread::sleep(Duration::from_millis(400));
    match rig_call(
        &mut port,
        &mut dec,
        2,
        RigMessage::GetTriggers { since_count: 0 },
    ) {
        RigMessage::Triggers {
            total_count,
            events,
        } => {
            assert!(
                total_count >= 10,
                "50 Hz for 0.4 s: ≥ 10 pulses, got {total_count}"
            );
            let gaps: Vec<u64> = events
                .windows(2)
                .map(|w| w[1].time_ns - w[0].time_ns)
                .collect();
            assert!(
                gaps.iter().all(|&g| g == 20_000_000),
                "pulses 20 ms apart: {gaps:?}"
            );
        }
        other => panic!("expected Triggers, got {other:?}"),
    }
}

#[test]
fn rig_serves_rgb_yuyv_frames_next_to_thermal() {
    let rig = ServedRig::start(
        ThermalProfile::lepton35(),
        Some(s3tir_firmware_sim::sensor::RgbProfile::hd720()),
        RgbFormat::Yuyv,
        2,
    );
    assert_eq!(rig.keys["rgb"], "1280x720 YUYV 30 Hz");
    let mut stream = rig.stream();
    let (mut rgb, mut thermal) = (Vec::new(), 0);
    while rgb.len() < 2 {
        let f = read_frame(&mut stream);
        match f.stream {
            simwire::StreamId::Rgb => rgb.push(f),
            simwire::StreamId::Thermal => thermal += 1,
        }
        assert!(
            thermal < 200,
            "no RGB frames among {thermal} thermal frames"
        );
    }
    for f in &rgb {
        assert_eq!(f.fourcc, s3tir_capture::device::FourCc::YUYV);
        assert_eq!((f.width, f.height, f.bytes_per_line), (1280, 720, 2560));
        assert_eq!(f.payload.len(), 1280 * 720 * 2);
    }
    assert!(rgb[1].sequence > rgb[0].sequence && rgb[1].monotonic_ns > rgb[0].monotonic_ns);
}
