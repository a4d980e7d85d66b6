//! Proves: `read_ply` refuses hostile headers before they size anything (a vertex count whose
//! byte size overflows, a band count or SH degree far beyond what the trainer writes) with an
//! error naming the file, and a valid file with random byte edits or cuts never panics: it fails
//! with an error naming the file, or reads at most its two records (never, with its header
//! intact, when cut short). Cases per property: 256 in `make test` (`PROPTEST_CASES=N` for a longer run).
#![allow(clippy::unwrap_used)]

use std::sync::OnceLock;

use proptest::prelude::*;
use s3tir_trainer::ply::{read_ply, write_ply};
use s3tir_trainer::primitive::{PrimitiveInit, Primitives};

/// A valid two-primitive PLY (2 bands, SH degree 1).
fn valid() -> &'static Vec<u8> {
    static V: OnceLock<Vec<u8>> = OnceLock::new();
    V.get_or_init(|| {
        let mut p = Primitives::<f64>::new(2, Some(1));
        p.push(&PrimitiveInit::default());
        p.push(&PrimitiveInit {
            mean_m: [0.1, 0.2, 2.0],
            ..PrimitiveInit::default()
        });
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.ply");
        write_ply(&path, &p.cast()).unwrap();
        std::fs::read(&path).unwrap()
    })
}

fn replace_header(from: &str, to: &str) -> Vec<u8> {
    let v = valid();
    let end = v.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8(v[..end].to_vec()).unwrap();
    assert!(header.contains(from), "{from} in {header}");
    let mut out = header.replacen(from, to, 1).into_bytes();
    out.extend_from_slice(&v[end..]);
    out
}

#[test]
fn hostile_headers_are_refused_before_sizing_anything() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("h.ply");
    std::fs::write(&path, valid()).unwrap();
    assert_eq!(read_ply(&path).unwrap().len(), 2, "the valid file reads");
    for (from, to, want) in [
        (
            "element vertex 2",
            "element vertex 18446744073709551615",
            "vertices",
        ),
        (
            "element vertex 2",
            "element vertex 4611686018427387904",
            "vertices",
        ),
        (
            "comment s3tir bands 2",
            "comment s3tir bands 1000000000000",
            "bands",
        ),
        (
            "comment s3tir sh_degree 1",
            "comment s3tir sh_degree 99",
            "SH degree",
        ),
    ] {
        std::fs::write(&path, replace_header(from, to)).unwrap();
        let msg = read_ply(&path)
            .err()
            .unwrap_or_else(|| panic!("{to} must be refused"))
            .to_string();
        assert!(msg.contains(want) && msg.contains("h.ply"), "{to}: {msg}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
    ))]

    #[test]
    fn edited_ply_files_read_or_fail(
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in prop::option::of(any::<prop::sample::Index>()),
    ) {
        let mut b = valid().clone();
        let full = b.len();
        let header_end = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let mut header_edited = false;
        for (at, byte) in &edits {
            let i = at.index(b.len());
            header_edited |= i < header_end && b[i] != *byte;
            b[i] = *byte;
        }
        if let Some(c) = cut {
            let i = c.index(b.len() + 1);
            b.truncate(i);
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("e.ply");
        std::fs::write(&path, &b).unwrap();
        match read_ply(&path) {
            Ok(p) => {
                // The data holds two records: nothing can read more.
                prop_assert!(p.len() <= 2, "{} primitives from a two-record file", p.len());
                // With the header intact, a file cut short cannot read.
                prop_assert!(
                    header_edited || b.len() == full,
                    "a file cut from {full} to {} bytes read as {} primitives",
                    b.len(),
                    p.len()
                );
            }
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.contains("e.ply"), "the error names the file: {msg}");
            }
        }
    }
}
