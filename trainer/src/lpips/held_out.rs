//! LPIPS of renders against a dataset's recorded frames, the frames' features computed once.
//!
//! A run evaluates the same held-out frames many times: their features are kept (up to
//! [`CACHE_BYTES`]; past it they are recomputed each time), so an evaluation runs the network on
//! the renders only.

use std::collections::HashMap;
use std::sync::OnceLock;

use super::{Features, Lpips};

/// Most bytes of frame features kept (a 640×512 frame's are ~14 MB).
pub const CACHE_BYTES: usize = 256 << 20;

/// The installed LPIPS weights, loaded once per process; `None` (with one warning) when they are
/// not installed or do not check out.
pub fn installed() -> Option<&'static Lpips> {
    static LPIPS: OnceLock<Option<Lpips>> = OnceLock::new();
    LPIPS
        .get_or_init(|| match Lpips::load_installed() {
            Ok(l) => Some(l),
            Err(e) => {
                tracing::warn!("no LPIPS in evaluations: {}", s3tir_capture::Chain(&e));
                None
            }
        })
        .as_ref()
}

/// Features of recorded frames by view index.
#[derive(Debug, Default)]
pub struct FrameFeatures {
    cache: HashMap<usize, Features>,
    bytes: usize,
}

impl FrameFeatures {
    /// LPIPS of `render` against view `view`'s recorded `frame` (normalised thermal planes of
    /// `width × height`); `None` under [`super::MIN_SIDE`].
    pub fn plane_lpips(
        &mut self,
        lpips: &Lpips,
        view: usize,
        render: &[f32],
        frame: &[f32],
        (width, height): (usize, usize),
    ) -> Option<f64> {
        let r = lpips.features_plane(render, width, height)?;
        if let Some(f) = self.cache.get(&view) {
            return Some(lpips.distance(&r, f));
        }
        let f = lpips.features_plane(frame, width, height)?;
        let d = lpips.distance(&r, &f);
        if self.bytes + f.bytes() <= CACHE_BYTES {
            self.bytes += f.bytes();
            self.cache.insert(view, f);
        }
        Some(d)
    }
}
