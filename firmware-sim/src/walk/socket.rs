//! Serving a walk on a Unix socket ([`serve_walk`]): the announcements, the first client, the
//! frames sent at their due time and stamped on the walk's clock, then the truth.

use std::io::Write as _;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::frames::{WALK_RGB_HZ, run_walk};
use super::truth::write_truth;
use super::{WalkRig, WalkSpec};
use crate::error::SimError;
use crate::serve::monotonic_ns;

/// Serves a walk on `socket`: announces `socket`, `thermal`, `rgb`, `walk` and `ready`, waits
/// for the first client, sends every frame (to every client connected by then), writes the
/// truth, announces `walk_done: thermal=N rgb=M`, then keeps the socket open until `stop`.
pub fn serve_walk(
    socket: &Path,
    rig: &WalkRig,
    spec: &WalkSpec,
    stop: Arc<AtomicBool>,
    announce: &mut dyn FnMut(&str, &str),
) -> Result<(), SimError> {
    let io = |what: &'static str| {
        let path = socket.to_path_buf();
        move |source| SimError::Io { path, what, source }
    };
    let _ = std::fs::remove_file(socket);
    let listener = UnixListener::bind(socket).map_err(io("bind socket"))?;
    listener
        .set_nonblocking(true)
        .map_err(io("set non-blocking"))?;
    announce("socket", &socket.display().to_string());
    announce(
        "thermal",
        &format!(
            "{} {}x{} Y16 {} Hz",
            rig.thermal.name,
            rig.thermal.camera.width_px,
            rig.thermal.camera.height_px,
            rig.thermal.rate_hz
        ),
    );
    if let Some(p) = rig.rgb {
        announce(
            "rgb",
            &format!(
                "{}x{} MJPG {WALK_RGB_HZ} Hz",
                p.camera.width_px, p.camera.height_px
            ),
        );
    }
    announce(
        "walk",
        &format!("{} {} s", spec.kind.name(), spec.duration_s),
    );
    announce("ready", "1");
    let mut clients: Vec<UnixStream> = Vec::new();
    let accept = |clients: &mut Vec<UnixStream>| {
        while let Ok((c, _)) = listener.accept() {
            let _ = c.set_nonblocking(false);
            clients.push(c);
        }
    };
    // Streaming starts with the first client, as V4L2 streaming starts on STREAMON.
    while clients.is_empty() {
        if stop.load(Ordering::Relaxed) {
            let _ = std::fs::remove_file(socket);
            return Ok(());
        }
        accept(&mut clients);
        std::thread::sleep(Duration::from_millis(5));
    }
    let start = Instant::now();
    let start_ns = monotonic_ns();
    let peer = socket.display().to_string();
    let mut stamps: Vec<u64> = Vec::new();
    let mut truth = run_walk(rig, spec, &stop, |mut frame, t_s| {
        accept(&mut clients);
        let due = start + Duration::from_secs_f64(t_s);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        frame.monotonic_ns = start_ns + (t_s * 1e9).round() as u64;
        stamps.push(frame.monotonic_ns);
        clients.retain_mut(|c| frame.write_to(c, &peer).is_ok());
        Ok(())
    })?;
    for (f, ns) in truth.iter_mut().zip(&stamps) {
        f.monotonic_ns = *ns;
    }
    if let Some(dir) = &spec.truth_dir {
        write_truth(dir, rig, spec, &truth)?;
    }
    let count = |s: &str| truth.iter().filter(|f| f.stream == s).count();
    announce(
        "walk_done",
        &format!("thermal={} rgb={}", count("thermal"), count("rgb")),
    );
    for c in &mut clients {
        let _ = c.flush();
    }
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = std::fs::remove_file(socket);
    Ok(())
}
