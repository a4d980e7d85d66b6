//! The one adapter from [`crate::progress`] events to indicatif bars on stderr, for the
//! binaries that draw them (`s3tir-calib`, and `s3tir-train SESSION.mcap` through the poses
//! stage). The only module of the library that uses indicatif.

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressStyle};

use crate::progress::Progress;

/// Draws each stage as a bar (known total) or a spinner (unknown total) on stderr.
#[derive(Debug, Default)]
pub struct ProgressBars {
    bar: Mutex<Option<ProgressBar>>,
}

impl ProgressBars {
    pub fn new() -> Self {
        Self::default()
    }

    fn with_bar(&self, f: impl FnOnce(&ProgressBar)) {
        if let Ok(guard) = self.bar.lock()
            && let Some(bar) = guard.as_ref()
        {
            f(bar);
        }
    }
}

impl Progress for ProgressBars {
    fn start(&self, stage: &str, total: Option<u64>) {
        let bar = match total {
            Some(n) => {
                let b = ProgressBar::new(n);
                if let Ok(style) = ProgressStyle::with_template(
                    "{prefix} {bar:40} {pos}/{len} {elapsed}/{eta} {msg}",
                ) {
                    b.set_style(style);
                }
                b.set_prefix(stage.to_string());
                b
            }
            None => {
                let b = ProgressBar::new_spinner();
                b.set_message(stage.to_string());
                b
            }
        };
        if let Ok(mut guard) = self.bar.lock()
            && let Some(old) = guard.replace(bar)
        {
            old.finish_and_clear();
        }
    }

    fn advance(&self, n: u64) {
        self.with_bar(|b| b.inc(n));
    }

    fn item(&self, name: &str) {
        self.with_bar(|b| b.set_message(name.to_string()));
    }

    fn finish(&self) {
        if let Ok(mut guard) = self.bar.lock()
            && let Some(bar) = guard.take()
        {
            bar.finish_and_clear();
        }
    }
}
