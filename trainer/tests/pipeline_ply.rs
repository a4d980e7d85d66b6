//! Proves that the PLY export round-trips S³-TIR primitives bit-exactly (bands, SH, β) and that
//! its 3DGS part is what a standard 3DGS reader expects: checked with a small reader written here
//! from the format's description (ASCII header, `binary_little_endian`, float properties named
//! x/y/z, nx/ny/nz, f_dc_*, f_rest_*, opacity, scale_*, rot_*), including the ½-convention: the
//! 3DGS Gaussian `exp(−½‖Σ₃ᵈᵍˢ^{-½}x‖²)` built from `scale_*` equals s3tir's `exp(−‖Σ^{-½}x‖²)`
//! at β = 2. Does NOT open the file in an actual splat viewer.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use s3tir_trainer::ply::{read_ply, write_ply};
use s3tir_trainer::primitive::{PrimitiveInit, Primitives};

fn random_set(bands: usize, sh: Option<usize>, n: usize) -> Primitives<f32> {
    let mut r = ChaCha8Rng::seed_from_u64(11);
    let mut p = Primitives::<f64>::new(bands, sh);
    for _ in 0..n {
        p.push(&PrimitiveInit {
            mean_m: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(1.0..3.0),
            ],
            scale_m: [
                r.random_range(0.01..0.3),
                r.random_range(0.01..0.3),
                r.random_range(0.01..0.3),
            ],
            quat: [
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                r.random_range(-1.0..1.0),
                0.3,
            ],
            opacity: r.random_range(0.05..0.95),
            beta: if r.random_bool(0.5) {
                2.0
            } else {
                r.random_range(2.0..40.0)
            },
            omega_low: r.random_range(0.0..1.0),
            bands: (0..bands)
                .map(|_| {
                    (
                        r.random_range(-0.2..0.2),
                        [r.random_range(-3.0..3.0); 3],
                        r.random_range(0.0..6.0),
                    )
                })
                .collect(),
            sh: (0..16)
                .map(|_| {
                    [
                        r.random_range(-1.0..1.0),
                        r.random_range(-1.0..1.0),
                        r.random_range(-1.0..1.0),
                    ]
                })
                .collect(),
        });
    }
    p.cast()
}

/// Minimal 3DGS PLY reader: header → property names, then rows of little-endian f32.
fn independent_read(bytes: &[u8]) -> (usize, Vec<HashMap<String, f32>>) {
    let marker = b"end_header\n";
    let end = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .unwrap()
        + marker.len();
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(
        header.starts_with("ply\nformat binary_little_endian 1.0\n"),
        "header: {header}"
    );
    let mut n = 0;
    let mut props = Vec::new();
    for line in header.lines() {
        let t: Vec<&str> = line.split(' ').collect();
        if t[0] == "element" {
            assert_eq!(t[1], "vertex");
            n = t[2].parse().unwrap();
        }
        if t[0] == "property" {
            assert_eq!(t[1], "float", "3DGS readers expect float properties");
            props.push(t[2].to_owned());
        }
    }
    let body = &bytes[end..];
    assert_eq!(body.len(), n * props.len() * 4, "body size");
    let rows = body
        .chunks(props.len() * 4)
        .map(|row| {
            props
                .iter()
                .enumerate()
                .map(|(k, name)| {
                    let b = &row[4 * k..4 * k + 4];
                    (name.clone(), f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                })
                .collect()
        })
        .collect();
    (n, rows)
}

#[test]
fn ply_round_trips_losslessly() {
    let tmp = tempfile::tempdir().unwrap();
    for (bands, sh) in [(4, None), (2, Some(1)), (0, Some(3)), (0, None)] {
        let p = random_set(bands, sh, 37);
        let path = tmp.path().join(format!("m{bands}.ply"));
        write_ply(&path, &p).unwrap();
        let q = read_ply(&path).unwrap();
        assert_eq!(q, p, "round trip with {bands} bands, SH {sh:?}");
    }
}

#[test]
fn ply_3dgs_part_matches_a_standard_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let p = random_set(4, Some(1), 20);
    let path = tmp.path().join("m.ply");
    write_ply(&path, &p).unwrap();
    let (n, rows) = independent_read(&std::fs::read(&path).unwrap());
    assert_eq!(n, 20);
    let k = 4; // SH degree 1
    for (i, row) in rows.iter().enumerate() {
        for (a, name) in ["x", "y", "z"].iter().enumerate() {
            assert_eq!(row[*name], p.means[3 * i + a]);
        }
        for name in ["nx", "ny", "nz"] {
            assert_eq!(row[name], 0.0);
        }
        for c in 0..3 {
            assert_eq!(row[&format!("f_dc_{c}")], p.sh[3 * k * i + c], "f_dc_{c}");
            for kk in 1..k {
                // 3DGS stores f_rest channel-major: index c·(K−1) + (k−1).
                assert_eq!(
                    row[&format!("f_rest_{}", c * (k - 1) + kk - 1)],
                    p.sh[(k * i + kk) * 3 + c]
                );
            }
        }
        assert_eq!(row["opacity"], p.opacity_logits[i], "opacity logit");
        for a in 0..4 {
            assert_eq!(
                row[&format!("rot_{a}")],
                p.quats[4 * i + a],
                "rot_{a} (w x y z)"
            );
        }
        // ½ convention: a point at offset d along local axis 0.
        let s3 = f64::from(p.log_scales[3 * i]).exp();
        let s_3dgs = f64::from(row["scale_0"]).exp();
        for d in [0.0, 0.3 * s3, s3, 2.0 * s3] {
            let ours = (-(d / s3).powi(2)).exp();
            let gs = (-0.5 * (d / s_3dgs).powi(2)).exp();
            assert!(
                (ours - gs).abs() < 1e-6,
                "kernel at d={d}: s3tir {ours} vs 3DGS {gs}"
            );
        }
    }
    // Without colour, f_dc carries the grey of ω_low (viewer colour = ½ + C0·f_dc).
    let p = random_set(0, None, 5);
    write_ply(&path, &p).unwrap();
    let (_, rows) = independent_read(&std::fs::read(&path).unwrap());
    for (i, row) in rows.iter().enumerate() {
        let grey = 0.5 + 0.282_094_79 * f64::from(row["f_dc_0"]);
        assert!(
            (grey - f64::from(p.omega_low[i])).abs() < 1e-5,
            "grey {grey} vs ω_low {}",
            p.omega_low[i]
        );
        assert!(!row.contains_key("f_rest_0"), "no f_rest without colour");
    }
}

#[test]
fn ply_reader_rejects_foreign_layouts() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("x.ply");
    std::fs::write(
        &path,
        b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n",
    )
    .unwrap();
    let e = read_ply(&path).unwrap_err().to_string();
    assert!(e.contains("ascii"), "error: {e}");
}
