//! Training checkpoints: one JSON file (`checkpoint.json` in the run folder) holding the
//! iteration, the training time so far, the primitives and the Adam moments. f32 values go
//! through JSON exactly (shortest round-trip formatting), so a resumed run continues from the
//! same numbers.
//!
//! Writes are atomic: the file is written to `checkpoint.json.tmp`, synced, then renamed over the
//! old one, so a kill at any moment leaves either the previous or the new checkpoint, never a
//! torn one. A checkpoint with a non-finite value is refused before anything is written (JSON
//! has no NaN: serde_json would write `null`, which no resume can read), so a diverged run
//! keeps its last good checkpoint.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::primitive::Primitives;

/// Version written into every checkpoint; others are refused.
pub const CHECKPOINT_VERSION: u32 = 1;

#[derive(Debug, Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("checkpoint {path} is not valid: {reason}")]
    Format { path: PathBuf, reason: String },
    /// The state to save holds NaN or infinity (a diverged run); nothing was written.
    #[error(
        "checkpoint {path} not written: {group}[{index}] is {value} (the run diverged); the \
         previous checkpoint is kept"
    )]
    NonFinite {
        path: PathBuf,
        group: String,
        index: usize,
        value: f64,
    },
}

/// The first non-finite value of `p`, as (parameter group, index, value).
fn first_non_finite(p: &Primitives<f32>) -> Option<(&'static str, usize, f32)> {
    p.groups().into_iter().find_map(|(name, v)| {
        v.iter()
            .position(|x| !x.is_finite())
            .map(|i| (name, i, v[i]))
    })
}

/// Serialisable mirror of [`Primitives<f32>`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrimitivesData {
    pub bands: usize,
    pub sh_degree: Option<usize>,
    pub means: Vec<f32>,
    pub log_scales: Vec<f32>,
    pub quats: Vec<f32>,
    pub opacity_logits: Vec<f32>,
    pub beta_raw: Vec<f32>,
    pub omega_low: Vec<f32>,
    pub band_amp: Vec<f32>,
    pub band_freq: Vec<f32>,
    pub band_phase: Vec<f32>,
    pub sh: Vec<f32>,
    /// Live bands per primitive (missing in checkpoints written before the mask existed: then
    /// every slot is live).
    #[serde(default)]
    pub band_count: Vec<u32>,
}

impl From<&Primitives<f32>> for PrimitivesData {
    fn from(p: &Primitives<f32>) -> Self {
        Self {
            bands: p.bands,
            sh_degree: p.sh_degree,
            means: p.means.clone(),
            log_scales: p.log_scales.clone(),
            quats: p.quats.clone(),
            opacity_logits: p.opacity_logits.clone(),
            beta_raw: p.beta_raw.clone(),
            omega_low: p.omega_low.clone(),
            band_amp: p.band_amp.clone(),
            band_freq: p.band_freq.clone(),
            band_phase: p.band_phase.clone(),
            sh: p.sh.clone(),
            band_count: p.band_count.clone(),
        }
    }
}

impl From<PrimitivesData> for Primitives<f32> {
    fn from(d: PrimitivesData) -> Self {
        let band_count = if d.band_count.is_empty() {
            vec![u32::try_from(d.bands).unwrap_or(u32::MAX); d.opacity_logits.len()]
        } else {
            d.band_count
        };
        Self {
            bands: d.bands,
            sh_degree: d.sh_degree,
            means: d.means,
            log_scales: d.log_scales,
            quats: d.quats,
            opacity_logits: d.opacity_logits,
            beta_raw: d.beta_raw,
            omega_low: d.omega_low,
            band_amp: d.band_amp,
            band_freq: d.band_freq,
            band_phase: d.band_phase,
            sh: d.sh,
            band_count,
        }
    }
}

/// Everything a resumed run needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    pub version: u32,
    /// Iterations completed.
    pub iteration: u64,
    /// Training wall time so far (evaluation excluded), seconds.
    pub train_seconds: f64,
    pub primitives: PrimitivesData,
    pub adam_m: PrimitivesData,
    pub adam_v: PrimitivesData,
    pub adam_step: u64,
    /// Loop state that is not parameters (capacity decisions, …).
    pub state: serde_json::Value,
}

/// Atomically writes `ck` to `path`.
pub fn save(path: &Path, ck: &Checkpoint) -> Result<(), CheckpointError> {
    let io = |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    };
    for (what, d) in [
        ("primitives", &ck.primitives),
        ("adam_m", &ck.adam_m),
        ("adam_v", &ck.adam_v),
    ] {
        if let Some((group, index, value)) = first_non_finite(&Primitives::from(d.clone())) {
            return Err(CheckpointError::NonFinite {
                path: path.to_path_buf(),
                group: format!("{what}.{group}"),
                index,
                value: f64::from(value),
            });
        }
    }
    if !ck.train_seconds.is_finite() {
        return Err(CheckpointError::NonFinite {
            path: path.to_path_buf(),
            group: "train_seconds".into(),
            index: 0,
            value: ck.train_seconds,
        });
    }
    let json = serde_json::to_vec(ck).map_err(|e| CheckpointError::Format {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let mut f = fs::File::create(&tmp).map_err(io)?;
    f.write_all(&json).map_err(io)?;
    f.sync_all().map_err(io)?;
    drop(f);
    fs::rename(&tmp, path).map_err(io)?;
    Ok(())
}

/// Reads a checkpoint and checks its version and shapes.
pub fn load(path: &Path) -> Result<Checkpoint, CheckpointError> {
    let data = fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |reason: String| CheckpointError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let ck: Checkpoint = serde_json::from_slice(&data).map_err(|e| bad(e.to_string()))?;
    if ck.version != CHECKPOINT_VERSION {
        return Err(bad(format!(
            "version {} (this build reads {CHECKPOINT_VERSION})",
            ck.version
        )));
    }
    for (what, d) in [
        ("primitives", &ck.primitives),
        ("adam_m", &ck.adam_m),
        ("adam_v", &ck.adam_v),
    ] {
        Primitives::from(d.clone())
            .validate()
            .map_err(|e| bad(format!("{what}: {e}")))?;
    }
    Ok(ck)
}
