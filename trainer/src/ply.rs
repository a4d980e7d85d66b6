//! S³-TIR primitives as a PLY file in the standard 3DGS layout, plus documented s3tir
//! properties so the file reads back losslessly.
//!
//! `format binary_little_endian 1.0`, one `vertex` element, every property `float` (f32), in
//! this order:
//!
//! | properties | meaning |
//! |---|---|
//! | `x y z` | centre μ (world metres) |
//! | `nx ny nz` | zero (3DGS writes zeros too) |
//! | `f_dc_0..2` | SH degree-0 colour; with no RGB branch, the grey of ω_low: `(ω_low − ½)/C0` so viewers show the thermal base intensity |
//! | `f_rest_0..` | higher SH coefficients, 3DGS order `f_rest[c·(K−1) + (k−1)]` (none without colour) |
//! | `opacity` | opacity logit (σ⁻¹, same as 3DGS) |
//! | `scale_0..2` | **3DGS** log-scales: `log_scale − ½ ln 2` (see below) |
//! | `rot_0..3` | quaternion `w x y z` as stored (3DGS normalises on load, as s3tir does) |
//! | `s3tir_log_scale_0..2` | the exact s3tir log-scales (f32 `log_scale − ½ ln 2` does not round-trip bit-exactly) |
//! | `s3tir_beta_raw` | β parameter: `β = min(2 + softplus(beta_raw), 64)` |
//! | `s3tir_beta` | β itself (informative; the reader uses `s3tir_beta_raw`) |
//! | `s3tir_omega_low` | base intensity ω_low (normalised units) |
//! | `s3tir_band_count` | live bands (slots `0..count`; the others are dropped and hold zeros); files without it read as all live |
//! | `s3tir_band{j}_amp`, `_fx`, `_fy`, `_fz`, `_phase` | Gabor band j: amplitude, frequency (cycles/m, world), phase (rad) |
//!
//! Header comments `s3tir bands M` and `s3tir sh_degree D` (or `none`) carry the layout.
//!
//! # Scale convention
//! The paper's kernel is `exp(−m^β)` **without** 3DGS's ½: at β = 2, `exp(−m²) = exp(−½(√2 m)²)`,
//! so the 3DGS scale is the s3tir scale / √2. The conversion is exact only at β = 2; sharper
//! primitives (β > 2) have no Gaussian equivalent and a 3DGS viewer shows their Gaussian proxy.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use s3tir_calib::model::ply::{self, Element, Header, Prop, Ty};

use thiserror::Error;

use crate::primitive::{Primitives, beta_of_raw};

/// SH degree-0 constant `Y_0^0`.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;
/// `½ ln 2`: s3tir log-scale − 3DGS log-scale.
pub const HALF_LN_2: f64 = 0.346_573_590_279_972_65;

#[derive(Debug, Error)]
pub enum PlyError {
    #[error("cannot write or read {path}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    /// The primitives do not fit their layout (array lengths, bands, SH degree).
    #[error("{path}")]
    Shape {
        path: PathBuf,
        #[source]
        source: Box<crate::error::RenderError>,
    },
}

/// Property names in file order for a set with `bands` bands and SH degree `sh_degree`.
pub fn property_names(bands: usize, sh_degree: Option<usize>) -> Vec<String> {
    let k = crate::primitive::sh_coeff_count(sh_degree);
    let mut v: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| (*s).to_owned())
    .collect();
    for i in 0..3 * k.saturating_sub(1) {
        v.push(format!("f_rest_{i}"));
    }
    v.push("opacity".into());
    for i in 0..3 {
        v.push(format!("scale_{i}"));
    }
    for i in 0..4 {
        v.push(format!("rot_{i}"));
    }
    for i in 0..3 {
        v.push(format!("s3tir_log_scale_{i}"));
    }
    v.push("s3tir_beta_raw".into());
    v.push("s3tir_beta".into());
    v.push("s3tir_omega_low".into());
    v.push("s3tir_band_count".into());
    for j in 0..bands {
        for s in ["amp", "fx", "fy", "fz", "phase"] {
            v.push(format!("s3tir_band{j}_{s}"));
        }
    }
    v
}

/// Writes `prims` to `path` (write to `path.tmp`, then rename).
pub fn write_ply(path: &Path, prims: &Primitives<f32>) -> Result<(), PlyError> {
    prims.validate().map_err(|source| PlyError::Shape {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    let names = property_names(prims.bands, prims.sh_degree);
    let name_refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let header = Header {
        comments: vec![
            "s3tir primitives: kernel exp(-m^beta) without the 1/2 of 3DGS; scale_* are 3DGS log-scales (s3tir - ln(2)/2)".into(),
            format!("s3tir bands {}", prims.bands),
            format!(
                "s3tir sh_degree {}",
                prims
                    .sh_degree
                    .map_or_else(|| "none".to_owned(), |d| d.to_string())
            ),
        ],
        elements: vec![Element::scalars("vertex", prims.len(), Ty::F32, &name_refs)],
    };
    let mut out = header.text().into_bytes();
    let k = prims.sh_k();
    let m = prims.bands;
    for i in 0..prims.len() {
        let mut row: Vec<f32> = Vec::with_capacity(names.len());
        row.extend_from_slice(&prims.means[3 * i..3 * i + 3]);
        row.extend_from_slice(&[0.0; 3]);
        if k > 0 {
            for c in 0..3 {
                row.push(prims.sh[3 * k * i + c]);
            }
            for c in 0..3 {
                for kk in 1..k {
                    row.push(prims.sh[(k * i + kk) * 3 + c]);
                }
            }
        } else {
            let g = ((f64::from(prims.omega_low[i]) - 0.5) / SH_C0) as f32;
            row.extend_from_slice(&[g; 3]);
        }
        row.push(prims.opacity_logits[i]);
        for a in 0..3 {
            row.push((f64::from(prims.log_scales[3 * i + a]) - HALF_LN_2) as f32);
        }
        row.extend_from_slice(&prims.quats[4 * i..4 * i + 4]);
        row.extend_from_slice(&prims.log_scales[3 * i..3 * i + 3]);
        row.push(prims.beta_raw[i]);
        row.push(beta_of_raw(f64::from(prims.beta_raw[i])).0 as f32);
        row.push(prims.omega_low[i]);
        row.push(prims.live_bands(i) as f32);
        for j in 0..m {
            let b = m * i + j;
            row.push(prims.band_amp[b]);
            row.extend_from_slice(&prims.band_freq[3 * b..3 * b + 3]);
            row.push(prims.band_phase[b]);
        }
        debug_assert_eq!(row.len(), names.len());
        for v in row {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    ply::write_atomic(path, |w| w.write_all(&out)).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Most frequency bands a PLY header may declare (the trainer uses a handful; the cap keeps a
/// hostile header from sizing the property list).
pub const MAX_PLY_BANDS: usize = 256;

/// What a primitives file's header says: bands, SH degree, whether the live-band count is
/// stored (files written before the band mask lack it), vertices and bytes per row.
struct PlyLayout {
    bands: usize,
    sh_degree: Option<usize>,
    has_count: bool,
    vertices: usize,
    /// Bytes of one vertex row (every property a float).
    row_bytes: usize,
}

/// Reads and checks the header of a primitives file: the `s3tir` comments, one `vertex`
/// element of float properties in [`property_names`]' order. Every number is checked before
/// it sizes anything.
fn read_layout(header: &Header) -> Result<PlyLayout, String> {
    let mut bands = None;
    let mut sh_degree: Option<Option<usize>> = None;
    for c in &header.comments {
        match c.split_whitespace().collect::<Vec<_>>().as_slice() {
            ["s3tir", "bands", m] => bands = m.parse::<usize>().ok(),
            ["s3tir", "sh_degree", d] => {
                sh_degree = Some(if *d == "none" { None } else { d.parse().ok() });
            }
            _ => {}
        }
    }
    let vertex = match header.elements.as_slice() {
        [v] if v.name == "vertex" => v,
        _ => {
            let names: Vec<&str> = header.elements.iter().map(|e| e.name.as_str()).collect();
            return Err(format!(
                "elements {names:?}: an s3tir primitives file has one `vertex` element"
            ));
        }
    };
    let mut names = Vec::with_capacity(vertex.props.len());
    for p in &vertex.props {
        match p {
            Prop::Scalar { name, ty: Ty::F32 } => names.push(name.clone()),
            Prop::Scalar { name, ty } => {
                return Err(format!(
                    "property {name} has type {}; only float is read",
                    ty.name()
                ));
            }
            Prop::List { name, .. } => {
                return Err(format!("property {name} is a list; only float is read"));
            }
        }
    }
    let bands = bands.ok_or("missing `comment s3tir bands M`")?;
    let sh_degree = sh_degree.ok_or("missing `comment s3tir sh_degree`")?;
    if bands > MAX_PLY_BANDS {
        return Err(format!("{bands} bands (at most {MAX_PLY_BANDS} are read)"));
    }
    if sh_degree.is_some_and(|d| d > crate::sh::SH_MAX_DEGREE) {
        return Err(format!(
            "SH degree {sh_degree:?} (at most {} is read)",
            crate::sh::SH_MAX_DEGREE
        ));
    }
    let expected = property_names(bands, sh_degree);
    // Files written before the band mask existed lack `s3tir_band_count`: every slot is live.
    let legacy: Vec<String> = expected
        .iter()
        .filter(|n| *n != "s3tir_band_count")
        .cloned()
        .collect();
    if names != expected && names != legacy {
        return Err(format!(
            "properties differ from the s3tir layout: got {names:?}, expected {expected:?}"
        ));
    }
    Ok(PlyLayout {
        bands,
        sh_degree,
        has_count: names != legacy,
        vertices: vertex.count,
        // All scalars (checked above): never the `None` of a list.
        row_bytes: vertex.fixed_row_bytes().unwrap_or(0),
    })
}

/// Appends one vertex row (its floats in [`property_names`]' order) to `prims`; the derived
/// columns (normals, 3DGS scales, β) are skipped.
fn push_row(prims: &mut Primitives<f32>, row: &[f32], has_count: bool) -> Result<(), String> {
    let bands = prims.bands;
    let k = prims.sh_k();
    let mut p = 0;
    let mut take = |len: usize| {
        let s = &row[p..p + len];
        p += len;
        s.to_vec()
    };
    prims.means.extend(take(3));
    take(3); // normals
    let dc = take(3);
    let rest = take(3 * k.saturating_sub(1));
    if k > 0 {
        let mut sh = vec![0.0f32; 3 * k];
        for c in 0..3 {
            sh[c] = dc[c];
            for kk in 1..k {
                sh[kk * 3 + c] = rest[c * (k - 1) + (kk - 1)];
            }
        }
        prims.sh.extend(sh);
    }
    prims.opacity_logits.extend(take(1));
    take(3); // 3DGS scales (derived)
    prims.quats.extend(take(4));
    prims.log_scales.extend(take(3));
    prims.beta_raw.extend(take(1));
    take(1); // β (derived)
    prims.omega_low.extend(take(1));
    let live = if has_count { take(1)[0] } else { bands as f32 };
    if !(live >= 0.0 && live <= bands as f32 && live.fract() == 0.0) {
        return Err(format!(
            "s3tir_band_count {live} is not a whole number in 0..={bands}"
        ));
    }
    prims.band_count.push(live as u32);
    for _ in 0..bands {
        let b = take(5);
        prims.band_amp.push(b[0]);
        prims.band_freq.extend_from_slice(&b[1..4]);
        prims.band_phase.push(b[4]);
    }
    Ok(())
}

/// Reads a file written by [`write_ply`] back into primitives (bit-exact). Every number in the
/// header is checked before it sizes anything.
pub fn read_ply(path: &Path) -> Result<Primitives<f32>, PlyError> {
    let fmt = |reason: String| PlyError::Format {
        path: path.to_path_buf(),
        reason,
    };
    let data = fs::read(path).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (header, end) = Header::read(path, &data).map_err(|e| fmt(e.reason))?;
    let layout = read_layout(&header).map_err(fmt)?;
    let stride = layout.row_bytes;
    let n = layout.vertices;
    let body = &data[end..];
    if n.checked_mul(stride) != Some(body.len()) {
        return Err(fmt(format!(
            "body has {} bytes, expected {n} vertices × {stride}",
            body.len(),
        )));
    }
    let mut prims = Primitives::<f32>::new(layout.bands, layout.sh_degree);
    for (i, bytes) in body.chunks_exact(stride.max(1)).take(n).enumerate() {
        let row: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        push_row(&mut prims, &row, layout.has_count)
            .map_err(|reason| fmt(format!("vertex {i}: {reason}")))?;
    }
    prims.validate().map_err(|source| PlyError::Shape {
        path: path.to_path_buf(),
        source: Box::new(source),
    })?;
    Ok(prims)
}
