//! What a running recording shows and obeys, in the binary (the daemon only reports events
//! and reads its stop flag): the status line drawn from the daemon's events, SIGINT/SIGTERM
//! setting the stop flag, and the end of a simulated walk setting it too.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use s3tir_capture::daemon::{Counters, DaemonEvent};

/// Sets `stop` at the first SIGINT or SIGTERM (logging which), so the daemon finishes the
/// session cleanly. The handlers are installed before this returns and stay installed: a
/// second signal while the session is being finished does not kill the process.
pub fn stop_on_signals(stop: &Arc<AtomicBool>) -> Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()
        .context("start the signal handler's runtime")?;
    let (mut sigint, mut sigterm) = {
        let _in_runtime = rt.enter();
        (
            signal(SignalKind::interrupt()).context("install the SIGINT handler")?,
            signal(SignalKind::terminate()).context("install the SIGTERM handler")?,
        )
    };
    let stop = stop.clone();
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            let name = rt.block_on(async {
                tokio::select! {
                    _ = sigint.recv() => "SIGINT",
                    _ = sigterm.recv() => "SIGTERM",
                }
            });
            tracing::info!("{name}: finishing the session");
            stop.store(true, Ordering::Relaxed);
            // Keep the handlers (and the runtime driving them) alive: later signals are
            // absorbed, not fatal, while the session is finished.
            rt.block_on(std::future::pending::<()>());
        })
        .context("start the signal handler thread")?;
    Ok(())
}

/// The recorder's live status line on stderr: a spinner with the elapsed time and the last
/// second's rates and counters, drawn only when stderr is a terminal; otherwise (systemd, a
/// pipe) the status goes to the log every 10 s.
pub struct StatusLine {
    bar: indicatif::ProgressBar,
    shown: u64,
}

impl StatusLine {
    /// A status line that has shown nothing yet.
    pub fn new() -> Self {
        let bar = indicatif::ProgressBar::new_spinner();
        bar.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {elapsed} {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
        );
        Self { bar, shown: 0 }
    }

    /// Shows one daemon event.
    pub fn show(&mut self, event: &DaemonEvent) {
        match event {
            DaemonEvent::Status {
                thermal_hz,
                rgb_hz,
                status: s,
                bytes_written,
                ..
            } => {
                let msg = format!(
                    "thermal {thermal_hz:.1} fps | rgb {rgb_hz:.1} fps | rejected {}/{} | queue drops {}/{} | reconnects {} | {:.1} MB",
                    s.rejected_thermal,
                    s.rejected_rgb,
                    s.queue_drops_thermal,
                    s.queue_drops_rgb,
                    s.reconnects,
                    *bytes_written as f64 / 1e6
                );
                self.shown += 1;
                if !self.bar.is_hidden() {
                    self.bar.set_message(msg);
                } else if self.shown.is_multiple_of(10) {
                    tracing::info!("{msg}");
                } else {
                    tracing::debug!("{msg}");
                }
            }
            DaemonEvent::Stopping { why } => tracing::debug!("recording stopping: {why:?}"),
        }
    }

    /// Clears the line (the summary follows).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// Stops the recording when the simulated walk has announced `walk_done: thermal=N rgb=M` and
/// the writer has recorded that many frames of each stream (or 10 s after the announcement,
/// when some were rejected on the way).
pub fn watch_walk_end(
    announced: Arc<std::sync::Mutex<std::collections::BTreeMap<String, String>>>,
    counters: Arc<Counters>,
    stop: Arc<AtomicBool>,
) {
    std::thread::spawn(move || {
        let done = loop {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            let v = announced
                .lock()
                .ok()
                .and_then(|m| m.get("walk_done").cloned());
            if let Some(v) = v {
                break v;
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let want = |key: &str| -> u64 {
            done.split_whitespace()
                .find_map(|kv| kv.strip_prefix(key)?.strip_prefix('=')?.parse().ok())
                .unwrap_or(0)
        };
        let (thermal, rgb) = (want("thermal"), want("rgb"));
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while std::time::Instant::now() < deadline {
            let got = |k: usize| counters.frames[k].load(Ordering::Relaxed);
            if got(0) >= thermal && got(1) >= rgb {
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        tracing::info!("the simulated walk ended ({done}): stopping");
        stop.store(true, Ordering::Relaxed);
    });
}
