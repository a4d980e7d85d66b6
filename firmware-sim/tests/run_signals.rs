//! Proves that SIGINT (Ctrl-C) and SIGTERM stop `s3tir-firmware-sim run` cleanly — exit
//! status 0 and the socket removed — now that the binary, not the `serve` library, handles
//! signals (it sets the library's stop flag). Stdin is /dev/null, so stdin EOF does not stop it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

fn stops_cleanly_on(signal: Signal) {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("rig.sock");
    let mut child = Command::new(env!("CARGO_BIN_EXE_s3tir-firmware-sim"))
        .args(["run", "--duration", "120", "--socket"])
        .arg(&socket)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let mut ready = false;
    for line in BufReader::new(stdout).lines() {
        if line.unwrap().starts_with("ready:") {
            ready = true;
            break;
        }
    }
    assert!(ready, "the rig never announced `ready`");
    assert!(socket.exists(), "the socket exists while the rig runs");
    kill(Pid::from_raw(child.id() as i32), signal).unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("{signal:?} did not stop the rig within 20 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{signal:?}: exit status {status}");
    assert!(!socket.exists(), "{signal:?}: the socket is removed");
}

#[test]
fn sigint_stops_the_rig_and_removes_its_socket() {
    stops_cleanly_on(Signal::SIGINT);
}

#[test]
fn sigterm_stops_the_rig_and_removes_its_socket() {
    stops_cleanly_on(Signal::SIGTERM);
}
