//! Training checkpoints: `checkpoint.json` in the run folder is a small JSON header — the
//! format version, the iteration, the training time so far, the Adam steps (the run's and each
//! parameter group's: their bias corrections; headers without the latter read as every group
//! at the run's count, which is what their runs used), the loop state
//! (capacity decisions, responses, …), each parameter set's band and SH layout, and the name of
//! the arrays file — and the parameter arrays (the primitives and both Adam moments: f32, the
//! live-band counts u32) are a safetensors file beside it (`checkpoint.a.safetensors` or
//! `checkpoint.b.safetensors`). Values are stored as their little-endian bytes, so a resumed run
//! continues from bit-for-bit the same numbers.
//!
//! Writes are atomic: the arrays go into the slot (`a` or `b`) the current header does *not*
//! name, synced; then the header is written to `checkpoint.json.tmp`, synced and renamed over
//! the old one — that rename is the commit — and the previous slot is removed. A kill at any
//! moment leaves either the previous header with its arrays or the new header with its arrays,
//! never a torn pair. A checkpoint with a non-finite value is refused before anything is
//! written, so a diverged run keeps its last good checkpoint (a NaN state is never worth
//! resuming; checkpoints of format 1, all JSON, could not even store one: serde_json writes
//! `null`).
//!
//! Checkpoints of format 1 (everything in one `checkpoint.json`, written before the arrays
//! moved out) are still read, so an old run resumes; its next checkpoint is written in the new
//! format.
//!
//! Size and write time for 100 000 primitives (M = 4 bands, no colour; parameters and both
//! Adam moments random full-precision floats, as trained values are), measured with
//! `cargo test -p s3tir-trainer --lib checkpoint::tests::size_and_time_100k -- --ignored
//! --nocapture` (dev profile, a busy 2-core x86-64 VM, files in the page cache; a write
//! includes its fsyncs; three runs):
//!
//! | format | size | write | read |
//! | --- | --- | --- | --- |
//! | 1: all JSON | 129.5 MB | 0.7–1.0 s | 0.8–1.4 s |
//! | 2: JSON header + safetensors | 40.8 MB (header 0.4 kB) | 0.14–0.22 s | 0.05–0.06 s |

use std::borrow::Cow;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensorError, SafeTensors};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::error::RenderError;
use crate::primitive::{Groups, Primitives};

/// Format written into every checkpoint: 2 is the JSON header with a safetensors arrays file.
pub const CHECKPOINT_VERSION: u32 = 2;

/// Format 1: the whole checkpoint in one JSON file (read for old runs, never written).
pub const CHECKPOINT_VERSION_JSON: u32 = 1;

#[derive(Debug, Error)]
pub enum CheckpointError {
    #[error("checkpoint {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The header (or a format-1 checkpoint) is not the JSON expected, or could not be made.
    #[error("checkpoint {path} is not valid")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// The arrays file is not a readable safetensors file (or lacks a tensor).
    #[error("checkpoint arrays {path} are not valid")]
    Arrays {
        path: PathBuf,
        #[source]
        source: SafeTensorError,
    },
    /// A parameter set's arrays do not fit its layout (lengths, bands, SH degree).
    #[error("checkpoint {path} is not valid: {set}")]
    Shape {
        path: PathBuf,
        set: &'static str,
        #[source]
        source: Box<RenderError>,
    },
    /// Anything else the reader checks (version, tensor types, the arrays file's name).
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
            .map(|i| (name.name(), i, v[i]))
    })
}

/// A parameter set's layout as the header keeps it.
fn layout(p: &Primitives<f32>) -> Layout {
    Layout {
        bands: p.bands,
        sh_degree: p.sh_degree,
    }
}

/// Checkpoints of format 1 written before the live-band mask existed have no `band_count`:
/// every slot of theirs is live.
fn fill_legacy_band_count(p: &mut Primitives<f32>) {
    if p.band_count.is_empty() {
        let all = u32::try_from(p.bands).unwrap_or(u32::MAX);
        p.band_count = vec![all; p.opacity_logits.len()];
    }
}

/// Everything a resumed run needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// The format read ([`CHECKPOINT_VERSION`] or [`CHECKPOINT_VERSION_JSON`]); [`save`]
    /// always writes [`CHECKPOINT_VERSION`].
    pub version: u32,
    /// Iterations completed.
    pub iteration: u64,
    /// Training wall time so far (evaluation excluded), seconds.
    pub train_seconds: f64,
    pub primitives: Primitives<f32>,
    pub adam_m: Primitives<f32>,
    pub adam_v: Primitives<f32>,
    pub adam_step: u64,
    /// Each parameter group's Adam steps (its bias corrections, [`crate::train::adam`]).
    /// Absent in checkpoints written before groups kept their own count: every group at
    /// `adam_step`, the count their bias corrections used.
    #[serde(default)]
    pub adam_group_steps: Groups<u64>,
    /// Loop state that is not parameters (capacity decisions, …).
    pub state: serde_json::Value,
}

/// A parameter set's layout, kept in the header (the arrays file holds only arrays).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Layout {
    bands: usize,
    sh_degree: Option<usize>,
}

/// `checkpoint.json` of format 2.
#[derive(Debug, Serialize, Deserialize)]
struct Header {
    version: u32,
    iteration: u64,
    train_seconds: f64,
    adam_step: u64,
    #[serde(default)]
    adam_group_steps: Groups<u64>,
    state: serde_json::Value,
    /// The arrays file, beside the header (a bare file name).
    arrays: String,
    primitives: Layout,
    adam_m: Layout,
    adam_v: Layout,
}

/// What the reader needs first: the format, and (format 2) the arrays file.
#[derive(Debug, Deserialize)]
struct Probe {
    version: u32,
    #[serde(default)]
    arrays: Option<String>,
    /// Whether the checkpoint has each group's Adam steps (see [`Header`]).
    #[serde(default)]
    adam_group_steps: Option<serde::de::IgnoredAny>,
}

/// The two arrays files beside `path` (`<stem>.a.safetensors`, `<stem>.b.safetensors`).
fn slots(path: &Path) -> [String; 2] {
    let stem = path.file_stem().map_or_else(
        || "checkpoint".to_owned(),
        |s| s.to_string_lossy().into_owned(),
    );
    [
        format!("{stem}.a.safetensors"),
        format!("{stem}.b.safetensors"),
    ]
}

/// `v`'s little-endian bytes (borrowed on little-endian machines).
fn le_bytes<T: bytemuck::Pod>(v: &[T], to_le: fn(&T) -> T) -> Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        Cow::Borrowed(bytemuck::cast_slice(v))
    } else {
        Cow::Owned(bytemuck::cast_slice(&v.iter().map(to_le).collect::<Vec<T>>()).to_vec())
    }
}

/// The tensors of one checkpoint as (name, dtype, little-endian bytes).
fn tensors(ck: &Checkpoint) -> Vec<(String, Dtype, usize, Cow<'_, [u8]>)> {
    let mut out = Vec::new();
    for (set, d) in [
        ("primitives", &ck.primitives),
        ("adam_m", &ck.adam_m),
        ("adam_v", &ck.adam_v),
    ] {
        for (group, v) in d.groups() {
            out.push((
                format!("{set}.{group}"),
                Dtype::F32,
                v.len(),
                le_bytes(v, |x| f32::from_bits(x.to_bits().to_le())),
            ));
        }
        out.push((
            format!("{set}.band_count"),
            Dtype::U32,
            d.band_count.len(),
            le_bytes(&d.band_count, |x| x.to_le()),
        ));
    }
    out
}

/// Writes `bytes` to `path` and syncs it.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), CheckpointError> {
    let io = |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut f = fs::File::create(path).map_err(io)?;
    f.write_all(bytes).map_err(io)?;
    f.sync_all().map_err(io)
}

/// Atomically writes `ck` to `path` (the header) and its arrays file beside it.
pub fn save(path: &Path, ck: &Checkpoint) -> Result<(), CheckpointError> {
    for (what, d) in [
        ("primitives", &ck.primitives),
        ("adam_m", &ck.adam_m),
        ("adam_v", &ck.adam_v),
    ] {
        if let Some((group, index, value)) = first_non_finite(d) {
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
    // The slot the live header does not name (an unreadable or format-1 header names none).
    let [a, b] = slots(path);
    let live = fs::read(path)
        .ok()
        .and_then(|text| serde_json::from_slice::<Probe>(&text).ok())
        .and_then(|p| p.arrays);
    let (slot, other) = if live.as_deref() == Some(a.as_str()) {
        (b, a)
    } else {
        (a, b)
    };
    let arrays_path = path.with_file_name(&slot);
    let owned = tensors(ck);
    let mut views = Vec::with_capacity(owned.len());
    for (name, dtype, n, bytes) in &owned {
        let view =
            TensorView::new(*dtype, vec![*n], bytes).map_err(|source| CheckpointError::Arrays {
                path: arrays_path.clone(),
                source,
            })?;
        views.push((name.clone(), view));
    }
    let arrays = safetensors::serialize(views, None).map_err(|source| CheckpointError::Arrays {
        path: arrays_path.clone(),
        source,
    })?;
    write_synced(&arrays_path, &arrays)?;

    let header = Header {
        version: CHECKPOINT_VERSION,
        iteration: ck.iteration,
        train_seconds: ck.train_seconds,
        adam_step: ck.adam_step,
        adam_group_steps: ck.adam_group_steps,
        state: ck.state.clone(),
        arrays: slot,
        primitives: layout(&ck.primitives),
        adam_m: layout(&ck.adam_m),
        adam_v: layout(&ck.adam_v),
    };
    let json = serde_json::to_vec_pretty(&header).map_err(|source| CheckpointError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    write_synced(&tmp, &json)?;
    fs::rename(&tmp, path).map_err(|source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    // The previous arrays are no longer named by anything.
    let old = path.with_file_name(&other);
    if let Err(e) = fs::remove_file(&old)
        && e.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!(path = %old.display(), error = %e, "could not remove the previous checkpoint arrays");
    }
    Ok(())
}

/// Reads a checkpoint (format 2, or format 1 of older runs) and checks its version and shapes.
pub fn load(path: &Path) -> Result<Checkpoint, CheckpointError> {
    let text = fs::read(path).map_err(|source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let json = |source| CheckpointError::Json {
        path: path.to_path_buf(),
        source,
    };
    let bad = |reason: String| CheckpointError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let probe: Probe = serde_json::from_slice(&text).map_err(json)?;
    let old_adam = probe.adam_group_steps.is_none();
    let mut ck: Checkpoint = match (probe.version, probe.arrays) {
        (CHECKPOINT_VERSION_JSON, _) => serde_json::from_slice(&text).map_err(json)?,
        (CHECKPOINT_VERSION, Some(_)) => {
            let header: Header = serde_json::from_slice(&text).map_err(json)?;
            load_arrays(path, header)?
        }
        (CHECKPOINT_VERSION, None) => {
            return Err(bad("the header names no arrays file".into()));
        }
        (v, _) => {
            return Err(bad(format!(
                "version {v} (this build reads {CHECKPOINT_VERSION_JSON} and \
                 {CHECKPOINT_VERSION})"
            )));
        }
    };
    if old_adam {
        ck.adam_group_steps = Groups::splat(ck.adam_step);
    }
    for (set, d) in [
        ("primitives", &mut ck.primitives),
        ("adam_m", &mut ck.adam_m),
        ("adam_v", &mut ck.adam_v),
    ] {
        fill_legacy_band_count(d);
        d.validate().map_err(|source| CheckpointError::Shape {
            path: path.to_path_buf(),
            set,
            source: Box::new(source),
        })?;
    }
    Ok(ck)
}

/// The arrays a format-2 `header` (read from `path`) names.
fn load_arrays(path: &Path, header: Header) -> Result<Checkpoint, CheckpointError> {
    // A bare file name beside the header: nothing else is read.
    if Path::new(&header.arrays).file_name() != Some(header.arrays.as_ref()) {
        return Err(CheckpointError::Format {
            path: path.to_path_buf(),
            reason: format!("the arrays file {:?} is not a file name", header.arrays),
        });
    }
    let arrays_path = path.with_file_name(&header.arrays);
    let bytes = fs::read(&arrays_path).map_err(|source| CheckpointError::Io {
        path: arrays_path.clone(),
        source,
    })?;
    let st_err = |source| CheckpointError::Arrays {
        path: arrays_path.clone(),
        source,
    };
    let bad = |reason: String| CheckpointError::Format {
        path: arrays_path.clone(),
        reason,
    };
    let st = SafeTensors::deserialize(&bytes).map_err(st_err)?;
    let tensor = |name: &str, dtype: Dtype| {
        let t = st.tensor(name).map_err(st_err)?;
        if t.dtype() != dtype || t.shape().len() != 1 {
            return Err(bad(format!(
                "tensor {name} is {:?} of shape {:?}, expected a {dtype:?} vector",
                t.dtype(),
                t.shape()
            )));
        }
        Ok(t.data())
    };
    let mut sets = Vec::with_capacity(3);
    for (set, layout) in [
        ("primitives", header.primitives),
        ("adam_m", header.adam_m),
        ("adam_v", header.adam_v),
    ] {
        let mut d = Primitives::<f32>::new(layout.bands, layout.sh_degree);
        for (group, v) in d.groups_mut() {
            *v = tensor(&format!("{set}.{group}"), Dtype::F32)?
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
        }
        d.band_count = tensor(&format!("{set}.band_count"), Dtype::U32)?
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        sets.push(d);
    }
    let [primitives, adam_m, adam_v]: [Primitives<f32>; 3] = sets
        .try_into()
        .map_err(|_| bad("three parameter sets expected".into()))?;
    Ok(Checkpoint {
        version: header.version,
        iteration: header.iteration,
        train_seconds: header.train_seconds,
        primitives,
        adam_m,
        adam_v,
        adam_step: header.adam_step,
        adam_group_steps: header.adam_group_steps,
        state: header.state,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::primitive::PrimitiveInit;

    /// `n` primitives with varied, awkward values (subnormals, signed zeros, extremes).
    fn primitives(n: usize, bands: usize, sh_degree: Option<usize>) -> Primitives<f32> {
        let mut p = Primitives::<f64>::new(bands, sh_degree);
        for k in 0..n {
            let x = k as f64;
            p.push(&PrimitiveInit {
                mean_m: [x * 0.1, (x * 0.37).sin(), 1.0 / 3.0],
                beta: 2.0 + (k % 7) as f64 * 1.7,
                bands: (0..bands)
                    .map(|b| (0.1 * b as f64, [1.0, 2.0, x.cos()], 0.7))
                    .collect(),
                ..Default::default()
            });
        }
        let mut p = p.cast::<f32>();
        if let Some(v) = p.means.first_mut() {
            *v = f32::MIN_POSITIVE / 4.0;
        }
        if let Some(v) = p.omega_low.first_mut() {
            *v = -0.0;
        }
        if let Some(v) = p.log_scales.last_mut() {
            *v = f32::MAX;
        }
        if let Some(c) = p.band_count.last_mut() {
            *c = 1;
        }
        p
    }

    fn checkpoint(p: &Primitives<f32>) -> Checkpoint {
        let mut m = p.zeros_like();
        m.means
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = i as f32 * 1e-7);
        Checkpoint {
            version: CHECKPOINT_VERSION,
            iteration: 1234,
            train_seconds: 5.5,
            primitives: p.clone(),
            adam_m: m,
            adam_v: p.clone(),
            adam_step: 1234,
            adam_group_steps: Groups {
                band_amp: 934,
                ..Groups::splat(1234)
            },
            state: serde_json::json!({"x": 1, "capacity": {"bands": [4, 3]}}),
        }
    }

    fn bits(d: &Primitives<f32>) -> Vec<(&'static str, Vec<u32>)> {
        let mut out: Vec<_> = d
            .groups()
            .into_iter()
            .map(|(n, v)| (n.name(), v.iter().map(|x| x.to_bits()).collect()))
            .collect();
        out.push(("band_count", d.band_count.clone()));
        out
    }

    #[test]
    fn writes_and_reads_back_bit_for_bit() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("checkpoint.json");
        for (bands, sh) in [(4, None), (0, Some(2)), (2, Some(0))] {
            let ck = checkpoint(&primitives(37, bands, sh));
            save(&path, &ck).unwrap();
            let back = load(&path).unwrap();
            for (a, b) in [
                (&ck.primitives, &back.primitives),
                (&ck.adam_m, &back.adam_m),
                (&ck.adam_v, &back.adam_v),
            ] {
                assert_eq!(bits(a), bits(b), "bit-exact arrays");
                assert_eq!(layout(a), layout(b));
            }
            assert_eq!(back, ck);
        }
        // Saves alternate between the two slots and leave nothing else behind.
        let mut names: Vec<String> = fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["checkpoint.a.safetensors", "checkpoint.json"]);
        save(&path, &checkpoint(&primitives(3, 4, None))).unwrap();
        let mut names: Vec<String> = fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["checkpoint.b.safetensors", "checkpoint.json"]);
        // The header is small and readable JSON.
        let header: serde_json::Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
        assert_eq!(header["iteration"], 1234);
        assert_eq!(header["version"], CHECKPOINT_VERSION);
    }

    #[test]
    fn checkpoints_without_group_steps_resume_with_the_runs_count() {
        // Written before each Adam group kept its own step count: every group's bias
        // corrections used the run's count, so that is what a resumed run continues from.
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("checkpoint.json");
        let ck = checkpoint(&primitives(5, 4, None));
        assert_ne!(ck.adam_group_steps, Groups::splat(ck.adam_step));
        save(&path, &ck).unwrap();
        assert_eq!(load(&path).unwrap(), ck, "group steps round trip");
        let strip = |text: &[u8]| {
            let mut v: serde_json::Value = serde_json::from_slice(text).unwrap();
            v.as_object_mut()
                .unwrap()
                .remove("adam_group_steps")
                .expect("the header has the group steps");
            serde_json::to_vec(&v).unwrap()
        };
        fs::write(&path, strip(&fs::read(&path).unwrap())).unwrap();
        let back = load(&path).unwrap();
        assert_eq!(back.adam_group_steps, Groups::splat(1234));
        // Format 1 likewise.
        let mut ck1 = ck.clone();
        ck1.version = CHECKPOINT_VERSION_JSON;
        fs::write(&path, strip(&serde_json::to_vec(&ck1).unwrap())).unwrap();
        assert_eq!(load(&path).unwrap().adam_group_steps, Groups::splat(1234));
    }

    #[test]
    fn format_1_json_checkpoints_still_load() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("checkpoint.json");
        let mut ck = checkpoint(&primitives(11, 4, None));
        ck.version = CHECKPOINT_VERSION_JSON;
        fs::write(&path, serde_json::to_vec(&ck).unwrap()).unwrap();
        let back = load(&path).unwrap();
        assert_eq!(back, ck);
        // Its next save is format 2, and reads back the same.
        save(&path, &back).unwrap();
        let again = load(&path).unwrap();
        assert_eq!(again.version, CHECKPOINT_VERSION);
        assert_eq!(bits(&again.primitives), bits(&ck.primitives));
    }

    #[test]
    fn broken_checkpoints_are_refused_with_their_cause() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("checkpoint.json");
        save(&path, &checkpoint(&primitives(5, 4, None))).unwrap();
        // Truncated arrays.
        let arrays = tmp.path().join("checkpoint.a.safetensors");
        let bytes = fs::read(&arrays).unwrap();
        fs::write(&arrays, &bytes[..bytes.len() / 2]).unwrap();
        let e = load(&path).unwrap_err();
        assert!(matches!(e, CheckpointError::Arrays { .. }), "{e}");
        assert!(std::error::Error::source(&e).is_some());
        // A header naming a file elsewhere.
        let mut h: serde_json::Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
        h["arrays"] = "../x.safetensors".into();
        fs::write(&path, serde_json::to_vec(&h).unwrap()).unwrap();
        let e = load(&path).unwrap_err().to_string();
        assert!(e.contains("not a file name"), "{e}");
        // An unknown version.
        h["version"] = 9.into();
        fs::write(&path, serde_json::to_vec(&h).unwrap()).unwrap();
        let e = load(&path).unwrap_err().to_string();
        assert!(e.contains("version 9"), "{e}");
    }

    #[test]
    fn non_finite_state_is_not_written() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("checkpoint.json");
        let mut ck = checkpoint(&primitives(5, 4, None));
        ck.adam_v.quats[3] = f32::NAN;
        let e = save(&path, &ck).unwrap_err();
        assert!(
            matches!(&e, CheckpointError::NonFinite { group, index: 3, .. } if group == "adam_v.quats"),
            "{e}"
        );
        assert_eq!(
            fs::read_dir(tmp.path()).unwrap().count(),
            0,
            "nothing written"
        );
    }

    /// Size and write/read time of a 100 000-primitive checkpoint in both formats (the figures
    /// in the module doc). Not a timed assertion: run with `--ignored --nocapture`.
    #[test]
    #[ignore = "a measurement (about 3 s), not a check"]
    fn size_and_time_100k() {
        use rand::{Rng, SeedableRng};
        use std::time::Instant;
        let tmp = tempfile::tempdir().unwrap();
        let mut ck = checkpoint(&primitives(100_000, 4, None));
        // Trained values have full-precision mantissas (what makes JSON long): fill every
        // array with random floats of varied magnitude.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for d in [&mut ck.primitives, &mut ck.adam_m, &mut ck.adam_v] {
            for (_, v) in d.groups_mut() {
                v.iter_mut().for_each(|x| {
                    *x = rng.random_range(-1.0f32..1.0) * 10f32.powi(rng.random_range(-8..2))
                });
            }
        }

        // Format 1, as `save` wrote it before: the whole checkpoint as JSON, synced.
        let old = tmp.path().join("old.json");
        let ck1 = Checkpoint {
            version: CHECKPOINT_VERSION_JSON,
            ..ck.clone()
        };
        let t = Instant::now();
        let json = serde_json::to_vec(&ck1).unwrap();
        write_synced(&old, &json).unwrap();
        let old_write = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let back = load(&old).unwrap();
        let old_read = t.elapsed().as_secs_f64();
        assert_eq!(back, ck1);

        let new = tmp.path().join("checkpoint.json");
        let t = Instant::now();
        save(&new, &ck).unwrap();
        let new_write = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let back = load(&new).unwrap();
        let new_read = t.elapsed().as_secs_f64();
        assert_eq!(back, ck);
        let size = |p: &Path| fs::metadata(p).unwrap().len() as f64;
        let arrays = tmp.path().join("checkpoint.a.safetensors");
        println!(
            "format 1: {:.1} MB, write {old_write:.3} s, read {old_read:.3} s",
            size(&old) / 1e6
        );
        println!(
            "format 2: {:.1} MB (header {:.1} kB), write {new_write:.3} s, read {new_read:.3} s",
            (size(&new) + size(&arrays)) / 1e6,
            size(&new) / 1e3
        );
    }
}
