//! Proves: the files calib reads from users and other tools refuse hostile content with an
//! error naming the file, never a panic or a read elsewhere. COLMAP models: an image name with
//! `..` or an absolute path (which made the trainer read outside `images/`) and a zero
//! quaternion (which became a NaN pose) are refused in text and binary models; text models
//! mutated at random and binary files of random bytes parse or fail; `board.toml` with any
//! sizes validates or fails (sizes near u32::MAX overflowed `(cols + 1) * (rows + 1)`).
//! Cases per property: 256 in `make test` (`PROPTEST_CASES=N` for a longer run).
#![allow(clippy::unwrap_used)]

use std::path::Path;

use proptest::prelude::*;
use s3tir_calib::detect::board::BoardFile;
use s3tir_calib::model::colmap::{read_binary_model, read_text_model};

const CAMERAS: &str = "# c\n1 PINHOLE 64 48 50 50 32 24\n";
const POINTS: &str = "1 0.1 0.2 3.0 128 128 128 0.5 1 0\n";

fn images(line: &str) -> String {
    format!("# i\n{line}\n\n")
}

fn write_text(dir: &Path, images_txt: &str) {
    std::fs::write(dir.join("cameras.txt"), CAMERAS).unwrap();
    std::fs::write(dir.join("images.txt"), images_txt).unwrap();
    std::fs::write(dir.join("points3D.txt"), POINTS).unwrap();
}

/// images.bin with one image (COLMAP's layout: count, then id, qvec, tvec, camera id, name\0,
/// point count).
fn images_bin(name: &[u8], q: [f64; 4]) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&1u64.to_le_bytes());
    b.extend_from_slice(&1i32.to_le_bytes());
    for x in q.into_iter().chain([0.0, 0.0, 0.0]) {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(&1i32.to_le_bytes());
    b.extend_from_slice(name);
    b.push(0);
    b.extend_from_slice(&0u64.to_le_bytes());
    b
}

fn cameras_bin() -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&1u64.to_le_bytes());
    b.extend_from_slice(&1i32.to_le_bytes()); // camera id
    b.extend_from_slice(&1i32.to_le_bytes()); // PINHOLE
    b.extend_from_slice(&64u64.to_le_bytes());
    b.extend_from_slice(&48u64.to_le_bytes());
    for p in [50.0f64, 50.0, 32.0, 24.0] {
        b.extend_from_slice(&p.to_le_bytes());
    }
    b
}

#[test]
fn image_names_outside_the_images_folder_and_zero_quaternions_are_refused() {
    let ok = "1 1 0 0 0 0 0 0 1 a.png";
    let cases = [
        (
            "1 1 0 0 0 0 0 0 1 ../secret.png",
            "leaves the images folder",
        ),
        (
            "1 1 0 0 0 0 0 0 1 sub/../../x.png",
            "leaves the images folder",
        ),
        ("1 1 0 0 0 0 0 0 1 /etc/passwd", "leaves the images folder"),
        ("1 0 0 0 0 0 0 0 1 a.png", "has no length"),
    ];
    let dir = tempfile::tempdir().unwrap();
    write_text(dir.path(), &images(ok));
    let m = read_text_model(dir.path()).unwrap();
    assert_eq!(m.images[0].name, "a.png");
    for (line, want) in cases {
        write_text(dir.path(), &images(line));
        let err = read_text_model(dir.path())
            .err()
            .unwrap_or_else(|| panic!("{line:?} must be refused"));
        let msg = err.to_string();
        assert!(
            msg.contains(want) && msg.contains("images.txt:2"),
            "{line:?}: {msg}"
        );
    }
    // The same in a binary model.
    let bin = tempfile::tempdir().unwrap();
    std::fs::write(bin.path().join("cameras.bin"), cameras_bin()).unwrap();
    std::fs::write(bin.path().join("points3D.bin"), 0u64.to_le_bytes()).unwrap();
    std::fs::write(
        bin.path().join("images.bin"),
        images_bin(b"cam0/a.png", [1.0, 0.0, 0.0, 0.0]),
    )
    .unwrap();
    let m = read_binary_model(bin.path()).unwrap();
    assert_eq!(m.images[0].name, "cam0/a.png");
    for (name, q, want) in [
        (
            &b"../../etc/shadow"[..],
            [1.0, 0.0, 0.0, 0.0],
            "leaves the images folder",
        ),
        (
            &b"/abs.png"[..],
            [1.0, 0.0, 0.0, 0.0],
            "leaves the images folder",
        ),
        (&b"a.png"[..], [0.0, 0.0, 0.0, 0.0], "has no length"),
    ] {
        std::fs::write(bin.path().join("images.bin"), images_bin(name, q)).unwrap();
        let msg = read_binary_model(bin.path())
            .err()
            .unwrap_or_else(|| panic!("{name:?} must be refused"))
            .to_string();
        assert!(msg.contains(want) && msg.contains("images.bin"), "{msg}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
    ))]

    /// A valid text model with random byte edits (digits, signs, separators, junk, cuts)
    /// parses or fails with an error; it never panics.
    #[test]
    fn mutated_text_models_never_panic(
        file in 0usize..3,
        edits in prop::collection::vec(
            (any::<prop::sample::Index>(), prop_oneof![
                Just(b' '), Just(b'\n'), Just(b'-'), Just(b'.'), Just(b'e'), Just(b'9'),
                Just(b'0'), Just(b'#'), any::<u8>()
            ]),
            1..6,
        ),
        cut in prop::option::of(any::<prop::sample::Index>()),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let mut texts = [
            CAMERAS.as_bytes().to_vec(),
            images("1 0.5 0.5 0.5 0.5 0.1 0.2 0.3 1 img 1.png").into_bytes(),
            POINTS.as_bytes().to_vec(),
        ];
        for (at, b) in &edits {
            let t = &mut texts[file];
            let i = at.index(t.len());
            t[i] = *b;
        }
        if let Some(c) = cut {
            let t = &mut texts[file];
            let i = c.index(t.len() + 1);
            t.truncate(i);
        }
        for (name, t) in ["cameras.txt", "images.txt", "points3D.txt"].iter().zip(&texts) {
            std::fs::write(dir.path().join(name), t).unwrap();
        }
        if let Ok(m) = read_text_model(dir.path()) {
            for im in &m.images {
                prop_assert!(
                    Path::new(&im.name).components().all(|c| matches!(
                        c,
                        std::path::Component::Normal(_) | std::path::Component::CurDir
                    )),
                    "{} leaves the images folder and was accepted",
                    im.name
                );
                prop_assert!(im.cam_from_world.rotation.is_finite(), "non-finite pose accepted");
            }
        }
    }

    /// Binary model files of random bytes (with a plausible or random count first) parse or
    /// fail; counts are checked against the bytes there, so nothing huge is allocated.
    #[test]
    fn random_binary_models_never_panic(
        which in 0usize..3,
        count in prop_oneof![0u64..4, any::<u64>()],
        tail in prop::collection::vec(any::<u8>(), 0..600),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let mut files = [cameras_bin(), images_bin(b"a.png", [1.0, 0.0, 0.0, 0.0]), 0u64.to_le_bytes().to_vec()];
        let mut bytes = count.to_le_bytes().to_vec();
        bytes.extend(tail);
        files[which] = bytes;
        for (name, b) in ["cameras.bin", "images.bin", "points3D.bin"].iter().zip(&files) {
            std::fs::write(dir.path().join(name), b).unwrap();
        }
        let _ = read_binary_model(dir.path());
    }

    /// board.toml with any sizes, square and tag settings validates or is refused.
    #[test]
    fn any_board_file_validates_or_is_refused(
        cols in prop_oneof![0u32..40, any::<u32>()],
        rows in prop_oneof![0u32..40, any::<u32>()],
        square in prop_oneof![-1.0f64..100.0, Just(f64::NAN), Just(f64::INFINITY)],
        ids in prop::collection::vec(prop_oneof![0u32..600, any::<u32>()], 0..12),
        ratio in prop_oneof![0.0f64..1.2, Just(f64::NAN)],
    ) {
        let text = format!(
            "[board]\ninner_corners = [{cols}, {rows}]\nsquare_mm = {}\napriltag_ids = {ids:?}\napriltag_ratio = {}\n",
            if square.is_finite() { format!("{square:?}") } else if square.is_nan() { "nan".into() } else { "inf".into() },
            if ratio.is_nan() { "nan".into() } else { format!("{ratio:?}") },
        );
        let Ok(file) = toml::from_str::<BoardFile>(&text) else {
            return Ok(());
        };
        if file.board.validate(Path::new("board.toml")).is_ok() {
            prop_assert!(file.board.cols() <= 200 && file.board.rows() <= 200);
            let _ = file.board.tag_squares();
            let _ = file.board.object_points_m();
        }
    }
}
