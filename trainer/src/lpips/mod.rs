//! LPIPS, the learned perceptual image patch similarity (Zhang et al., CVPR 2018), AlexNet
//! backbone, v0.1 heads — the perceptual error the S³-TIR and TGA-GS papers report.
//!
//! `d(x, y) = Σ_l mean_{h,w} Σ_c w_{l,c} (x̂_l − ŷ_l)²`, where `x̂_l` are AlexNet's `relu_l`
//! activations unit-normalised over channels at each pixel and `w_l` the learned heads. Inputs are
//! RGB in [-1, 1], shifted and scaled per channel as the official implementation does
//! ([`SHIFT`], [`SCALE`]). Checked against the official implementation's values for five image
//! pairs (`tests/lpips_reference.rs`): within 4e-5 of the published four-digit figures.
//!
//! **Thermal planes** go in as grey replicated to three channels, over the dataset's fixed
//! normalised range (the words `min_raw ..= max_raw` of [`crate::dataset::ThermalRange`] map to
//! `0 ..= 1`, then to `-1 ..= 1`), clamped to it as an 8- or 16-bit image of the render would be:
//! the same mapping for every mode and run of a dataset, so their LPIPS compare.
//!
//! The network runs on the CPU ([`net`]: im2col + SGEMM on rayon). Chosen over an inference
//! crate (`tract-onnx`, `candle`) because no registry package ships LPIPS as an ONNX graph, the
//! network is five convolutions, and a crate would add a large dependency tree to the rig's
//! trainer; the cost is measured by `s3tir-train bench --lpips` (ms per view at the run's size).
//!
//! Without the weights file there is no LPIPS: the trainer warns once and leaves the figure out
//! of `eval.json` and `metrics.csv` (never a made-up value). Images under [`MIN_SIDE`] pixels on
//! a side are too small for AlexNet's strides and have no LPIPS either.

pub mod bench;
pub mod held_out;
pub mod net;
pub mod weights;

pub use held_out::{FrameFeatures, installed};

use std::path::{Path, PathBuf};

use thiserror::Error;

use net::{AlexNet, Tensor};

/// The official scaling layer: `x' = (x − SHIFT) / SCALE` per RGB channel, `x ∈ [-1, 1]`.
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// The smallest image side AlexNet's strides and pools leave a feature in (31 px).
pub const MIN_SIDE: usize = 31;
/// `normalize_tensor`'s epsilon in the official implementation.
const NORM_EPS: f32 = 1e-10;

#[derive(Debug, Error)]
pub enum LpipsError {
    #[error(
        "LPIPS weights not installed (looked for {}); run scripts/install-deps.sh \
         (or scripts/install-lpips.py), or set {}",
        searched.as_ref().map_or_else(|| "no data folder: HOME unset".into(), |p| p.display().to_string()),
        weights::WEIGHTS_ENV
    )]
    NotInstalled { searched: Option<PathBuf> },
    #[error("reading LPIPS weights {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "LPIPS weights {path}: SHA-256 {found}, expected {expected} (a different or corrupted \
         file; run scripts/install-lpips.py again)"
    )]
    Checksum {
        path: PathBuf,
        found: String,
        expected: &'static str,
    },
    #[error("LPIPS weights {path}: {reason}")]
    Format { path: PathBuf, reason: String },
}

/// One image's LPIPS features: the five layers' activations, unit-normalised over channels.
/// Computing them once lets a fixed image (a held-out frame) be compared with many renders.
#[derive(Debug, Clone)]
pub struct Features {
    layers: Vec<Tensor>,
}

impl Features {
    /// Bytes the features hold.
    pub fn bytes(&self) -> usize {
        self.layers.iter().map(|t| 4 * t.data.len()).sum()
    }
}

/// The LPIPS network with its weights.
#[derive(Debug, Clone)]
pub struct Lpips {
    net: AlexNet,
    heads: [Vec<f32>; 5],
    path: PathBuf,
}

impl Lpips {
    /// Loads and checks the weights file at `path`.
    pub fn load(path: &Path) -> Result<Self, LpipsError> {
        let (net, heads) = weights::load(path)?;
        Ok(Self {
            net,
            heads,
            path: path.to_path_buf(),
        })
    }

    /// Loads the installed weights ([`weights::default_path`]).
    pub fn load_installed() -> Result<Self, LpipsError> {
        let searched = weights::default_path();
        match &searched {
            Some(p) if p.exists() => Self::load(p),
            _ => Err(LpipsError::NotInstalled { searched }),
        }
    }

    /// The weights file this was loaded from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Features of a planar RGB image (`3 × h × w`, channel-major) in [-1, 1]; `None` under
    /// [`MIN_SIDE`].
    pub fn features_rgb(&self, rgb: &[f32], width: usize, height: usize) -> Option<Features> {
        let n = width * height;
        if rgb.len() != 3 * n {
            return None;
        }
        let mut x = Tensor::zeros(3, height, width);
        for c in 0..3 {
            for (d, s) in x.data[c * n..(c + 1) * n]
                .iter_mut()
                .zip(&rgb[c * n..(c + 1) * n])
            {
                *d = (s - SHIFT[c]) / SCALE[c];
            }
        }
        self.features(&x)
    }

    /// Features of a normalised thermal plane (`0 ..= 1` over the dataset's range, clamped),
    /// replicated to three channels; `None` under [`MIN_SIDE`].
    pub fn features_plane(&self, plane: &[f32], width: usize, height: usize) -> Option<Features> {
        if plane.len() != width * height {
            return None;
        }
        let grey: Vec<f32> = plane
            .iter()
            .map(|s| 2.0 * s.clamp(0.0, 1.0) - 1.0)
            .collect();
        self.features_rgb(&grey.repeat(3), width, height)
    }

    fn features(&self, x: &Tensor) -> Option<Features> {
        if x.width < MIN_SIDE || x.height < MIN_SIDE {
            return None;
        }
        let mut layers = self.net.features(x)?;
        for t in &mut layers {
            normalise_channels(t);
        }
        Some(Features { layers })
    }

    /// LPIPS between two images' features (of the same size).
    pub fn distance(&self, a: &Features, b: &Features) -> f64 {
        let mut d = 0.0;
        for ((fa, fb), w) in a.layers.iter().zip(&b.layers).zip(&self.heads) {
            let n = fa.height * fa.width;
            let mut sum = 0.0f64;
            for (c, &wc) in w.iter().enumerate() {
                let (pa, pb) = (&fa.data[c * n..(c + 1) * n], &fb.data[c * n..(c + 1) * n]);
                let s: f32 = pa.iter().zip(pb).map(|(x, y)| (x - y) * (x - y)).sum();
                sum += f64::from(wc) * f64::from(s);
            }
            d += sum / n as f64;
        }
        d
    }

    /// LPIPS between two normalised thermal planes ([`Lpips::features_plane`]).
    pub fn plane_distance(&self, a: &[f32], b: &[f32], width: usize, height: usize) -> Option<f64> {
        let fa = self.features_plane(a, width, height)?;
        let fb = self.features_plane(b, width, height)?;
        Some(self.distance(&fa, &fb))
    }
}

/// `f / (‖f‖₂ over channels + ε)` at every pixel (the official `normalize_tensor`).
fn normalise_channels(t: &mut Tensor) {
    let n = t.height * t.width;
    let mut norm = vec![0.0f32; n];
    for c in 0..t.channels {
        for (s, v) in norm.iter_mut().zip(&t.data[c * n..(c + 1) * n]) {
            *s += v * v;
        }
    }
    for s in &mut norm {
        *s = 1.0 / (s.sqrt() + NORM_EPS);
    }
    for c in 0..t.channels {
        for (v, s) in t.data[c * n..(c + 1) * n].iter_mut().zip(&norm) {
            *v *= s;
        }
    }
}
