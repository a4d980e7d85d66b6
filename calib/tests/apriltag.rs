//! AprilTag (tag36h11) detection through `s3tir_calib::tags`.
//!
//! Proves, on the C library's own test images (`shared/data/apriltag/*.jpg`, NASA Swarmathon)
//! with the settings of its `test_detection.c` (quad_decimate = 1, refine_edges = false):
//! - every ground-truth tag is found with the right id, and no extra tag or id is reported;
//! - fed the C test's exact input (the JPEG's Y plane from the library's own pjpeg decoder),
//!   corners (same order, converted to our pixel-centre convention) agree with the ground truth
//!   to <= 0.02 px for 45 of 47 tags and <= 0.15 px for all. NOT proven: the C test's 0.1 px
//!   bound for every tag — two tags are off by 0.110 and 0.141 px (see
//!   `c_test_input_matches_ground_truth`);
//! - fed our public path (`image` decode + `tags::luma_bt601`), every tag is still found, all
//!   corners within 0.35 px, >= 35 of 47 within 0.01 px.
//!
//! Proves, on rendered axis-aligned tags whose border edges fall exactly on pixel boundaries:
//! the corners come out on those boundaries in OUR convention (origin at the centre of the
//! top-left pixel; the -0.5 px conversion from the C convention is right), in the order
//! bottom-left, bottom-right, top-right, top-left; refine_edges shifts them by about -1/8 px;
//! the allowed-id filter drops ids not on the board.
//!
//! Does not prove: accuracy under blur, noise, perspective or in thermal imagery (the ground
//! truth is the C library's own output, so it checks the binding, image hand-over and
//! convention, not the detector against true geometry); decimation > 1; use of tags in the
//! calibration pipeline (not wired in).
#![allow(clippy::unwrap_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use image::{GrayImage, Luma};
use s3tir_calib::tags::{self, TagConfig, TagDetection, TagDetector};

fn data_dir() -> PathBuf {
    let dir = std::env::var_os("S3TIR_SHARED_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data/apriltag");
    assert!(
        dir.join("33369213973_9d9bb4cc96_c.jpg").is_file(),
        "{} has no 33369213973_9d9bb4cc96_c.jpg: the shared/ folder must sit beside the clone (or set S3TIR_SHARED_DIR)",
        dir.display()
    );
    dir
}

/// One line of the C library's ground truth: `id, (x y), (x y), (x y), (x y)`, corners in the
/// C convention (origin at the top-left pixel's corner) and in the library's corner order.
struct Truth {
    id: u32,
    corners_c_px: [[f64; 2]; 4],
}

fn read_truth(path: &Path) -> Vec<Truth> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|line| {
            let cleaned: String = line
                .chars()
                .map(|c| if matches!(c, '(' | ')' | ',') { ' ' } else { c })
                .collect();
            let fields: Vec<&str> = cleaned.split_whitespace().collect();
            assert_eq!(fields.len(), 9, "{}: bad line {line:?}", path.display());
            let v: Vec<f64> = fields[1..].iter().map(|f| f.parse().unwrap()).collect();
            Truth {
                id: fields[0].parse().unwrap(),
                corners_c_px: [[v[0], v[1]], [v[2], v[3]], [v[4], v[5]], [v[6], v[7]]],
            }
        })
        .collect()
}

/// Largest corner distance (px) between a detection and a ground-truth tag, corner by corner.
fn max_corner_error_px(det: &TagDetection, truth: &Truth) -> f64 {
    det.corners_px
        .iter()
        .zip(&truth.corners_c_px)
        .map(|(d, t)| {
            let t = tags::from_apriltag_px(*t);
            (d[0] - t[0]).hypot(d[1] - t[1])
        })
        .fold(0.0, f64::max)
}

const STEMS: [&str; 3] = [
    "33369213973_9d9bb4cc96_c",
    "34085369442_304b6bafd9_c",
    "34139872896_defdb2f8d9_c",
];

/// Layout of the C library's `image_u8_t` (common/image_types.h).
#[repr(C)]
struct CImageU8 {
    width: i32,
    height: i32,
    stride: i32,
    buf: *mut u8,
}

// The C library's baseline JPEG decoder, compiled into the static library apriltag-sys builds
// (all of `common/`), but not exposed by its bindings. The C test detects on its output.
unsafe extern "C" {
    fn pjpeg_create_from_file(
        path: *const std::ffi::c_char,
        flags: u32,
        error: *mut i32,
    ) -> *mut std::ffi::c_void;
    fn pjpeg_to_u8_baseline(pj: *mut std::ffi::c_void) -> *mut CImageU8;
    fn pjpeg_destroy(pj: *mut std::ffi::c_void);
    fn image_u8_destroy(im: *mut CImageU8);
}

/// The JPEG's Y plane exactly as the C test (`test_detection.c`) feeds it to the detector.
fn c_test_grey(path: &Path) -> GrayImage {
    let c_path = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    let mut error = 0;
    // SAFETY: c_path is a valid NUL-terminated string; pjpeg returns NULL or a decoder that we
    // destroy once; the image it returns is width x height with `stride` bytes per row, read
    // only within those bounds, then destroyed once.
    unsafe {
        let pj = pjpeg_create_from_file(c_path.as_ptr(), 0, &mut error);
        assert!(
            !pj.is_null() && error == 0,
            "pjpeg could not decode {} (error {error})",
            path.display()
        );
        let im = pjpeg_to_u8_baseline(pj);
        assert!(
            !im.is_null(),
            "pjpeg_to_u8_baseline({}) failed",
            path.display()
        );
        let (w, h, stride) = ((*im).width, (*im).height, (*im).stride);
        let grey = GrayImage::from_fn(w as u32, h as u32, |x, y| {
            Luma([*(*im).buf.add(y as usize * stride as usize + x as usize)])
        });
        image_u8_destroy(im);
        pjpeg_destroy(pj);
        grey
    }
}

/// Per image: tags found, and the max corner error (px) of every ground-truth tag, matched
/// one-to-one to the closest unused detection of the same id. Asserts ids and counts.
fn compare_to_truth(decode: &str, grey_of: impl Fn(&Path) -> GrayImage) -> Vec<(String, Vec<f64>)> {
    let dir = data_dir();
    // The settings of the C library's test_detection.c.
    let config = TagConfig {
        quad_decimate: 1.0,
        refine_edges: false,
        ..TagConfig::default()
    };
    let mut detector = TagDetector::new(config).unwrap();
    let mut out = Vec::new();
    for stem in STEMS {
        let jpg = dir.join(format!("{stem}.jpg"));
        let truth = read_truth(&dir.join(format!("{stem}.txt")));
        assert!(!truth.is_empty(), "{stem}.txt has no tags");
        let found = detector.detect(&grey_of(&jpg), &jpg).unwrap();

        let truth_ids: BTreeSet<u32> = truth.iter().map(|t| t.id).collect();
        let extra_ids: Vec<u32> = found
            .iter()
            .map(|d| d.id)
            .filter(|id| !truth_ids.contains(id))
            .collect();
        assert!(
            extra_ids.is_empty(),
            "{decode} {stem}: ids {extra_ids:?} detected but not in the ground truth {truth_ids:?}"
        );
        assert_eq!(
            found.len(),
            truth.len(),
            "{decode} {stem}: expected {} tags (ground truth), detected {}",
            truth.len(),
            found.len()
        );
        let mut used = vec![false; found.len()];
        let mut errors_px = Vec::new();
        for (k, t) in truth.iter().enumerate() {
            let best = found
                .iter()
                .enumerate()
                .filter(|(i, d)| !used[*i] && d.id == t.id)
                .map(|(i, d)| (i, max_corner_error_px(d, t)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let Some((i, err_px)) = best else {
                panic!(
                    "{decode} {stem}: ground-truth tag #{k} (id {}) has no detection left",
                    t.id
                );
            };
            used[i] = true;
            errors_px.push(err_px);
        }
        let worst = errors_px.iter().copied().fold(0.0, f64::max);
        let within = errors_px.iter().filter(|e| **e <= 0.1).count();
        eprintln!(
            "{decode} {stem}: {} tags, {within} within 0.1 px, max corner error {worst:.4} px, per tag {:?}",
            truth.len(),
            errors_px
                .iter()
                .map(|e| format!("{e:.3}"))
                .collect::<Vec<_>>()
        );
        out.push((stem.to_string(), errors_px));
    }
    out
}

/// The C test's exact input (pjpeg's Y plane) and settings. 45 of the 47 tags agree with the
/// ground truth to <= 0.012 px (most to 0.0000); two tags (one in 33369213973, one in
/// 34139872896) are off by 0.110 and 0.141 px. With identical input bytes and settings that
/// residual comes from the detector build (the pinned apriltag-sys 0.3.0 bundles AprilTag
/// 3.2.0; the ground truth is from the upstream repository's later test data), so the C test's
/// 0.1 px bound is asserted for all but those two, which are held to 0.15 px.
#[test]
fn c_test_input_matches_ground_truth() {
    let results = compare_to_truth("pjpeg", c_test_grey);
    let all: Vec<f64> = results
        .iter()
        .flat_map(|(_, e)| e.iter().copied())
        .collect();
    assert_eq!(all.len(), 47, "ground-truth tags over the 3 images");
    let over: Vec<String> = results
        .iter()
        .flat_map(|(stem, e)| {
            e.iter()
                .enumerate()
                .filter(|(_, e)| **e > 0.1)
                .map(move |(k, e)| format!("{stem} #{k}: {e:.4} px"))
        })
        .collect();
    assert!(
        over.len() <= 2,
        "expected at most 2 tags (of 47) beyond 0.1 px, got {}: {over:?}",
        over.len()
    );
    let worst = all.iter().copied().fold(0.0, f64::max);
    assert!(
        worst <= 0.15,
        "max corner error expected <= 0.15 px, got {worst:.4} px ({over:?})"
    );
    let tight = all.iter().filter(|e| **e <= 0.02).count();
    assert!(
        tight >= 45,
        "expected >= 45 of 47 tags within 0.02 px of the C library's corners, got {tight}"
    );
}

/// The public path: `image` decodes the JPEG, [`tags::luma_bt601`] makes the grey image. Its
/// IDCT differs from pjpeg's by a few grey levels, which moves a few quads' segmentation:
/// every tag is still found with the right id and nothing extra, corners stay within 0.35 px
/// and most agree to 0.01 px.
#[test]
fn image_crate_decode_finds_every_ground_truth_tag() {
    let results = compare_to_truth("image+bt601", |p| {
        tags::luma_bt601(&image::open(p).unwrap().to_rgb8())
    });
    let all: Vec<f64> = results
        .iter()
        .flat_map(|(_, e)| e.iter().copied())
        .collect();
    let worst = all.iter().copied().fold(0.0, f64::max);
    assert!(
        worst <= 0.35,
        "max corner error expected <= 0.35 px, got {worst:.4} px"
    );
    let tight = all.iter().filter(|e| **e <= 0.01).count();
    assert!(
        tight >= 35,
        "expected >= 35 of 47 tags within 0.01 px of the C library's corners, got {tight}"
    );
}

/// tag36h11 codes of ids 0 and 1 and the bit layout, from the C library's `tag36h11.c`
/// (bit i of the 36, most significant first, sits at cell (BIT_X[i], BIT_Y[i]) of the 8×8
/// black-bordered square).
const CODES: [u64; 2] = [0x0000_000d_7e00_984b, 0x0000_000d_da66_4ca7];
const BIT_X: [u32; 36] = [
    1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2, 5, 4, 3, 4, 1, 1, 1, 1, 1,
    2, 2, 2, 3,
];
const BIT_Y: [u32; 36] = [
    1, 1, 1, 1, 1, 2, 2, 2, 3, 1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2,
    5, 4, 3, 4,
];

/// Paint tag `id` upright: its 8×8-cell black square covers pixels
/// `x0 .. x0 + 8·cell_px` × `y0 .. y0 + 8·cell_px` (white around it).
fn paint_tag(img: &mut GrayImage, id: usize, x0: u32, y0: u32, cell_px: u32) {
    for cy in 0..8u32 {
        for cx in 0..8u32 {
            let border = cx == 0 || cy == 0 || cx == 7 || cy == 7;
            let white = !border
                && (0..36)
                    .any(|i| BIT_X[i] == cx && BIT_Y[i] == cy && (CODES[id] >> (35 - i)) & 1 == 1);
            let v = if white { 255 } else { 0 };
            for dy in 0..cell_px {
                for dx in 0..cell_px {
                    img.put_pixel(x0 + cx * cell_px + dx, y0 + cy * cell_px + dy, Luma([v]));
                }
            }
        }
    }
}

#[test]
fn rendered_tag_corners_land_on_pixel_boundaries_in_our_convention() {
    let (x0, y0, cell) = (40u32, 30u32, 12u32);
    let side = f64::from(8 * cell);
    let mut img = GrayImage::from_pixel(220, 180, Luma([255]));
    paint_tag(&mut img, 0, x0, y0, cell);
    // Black pixels x0 ..= x0 + 96 - 1: the outer edge is half a pixel before x0's centre.
    let left = f64::from(x0) - 0.5;
    let top = f64::from(y0) - 0.5;
    let expected = [
        [left, top + side],        // bottom-left
        [left + side, top + side], // bottom-right
        [left + side, top],        // top-right
        [left, top],               // top-left
    ];
    let detect = |refine_edges: bool| {
        let mut detector = TagDetector::new(TagConfig {
            refine_edges,
            ..TagConfig::default()
        })
        .unwrap();
        let found = detector.detect(&img, Path::new("rendered-id0")).unwrap();
        assert_eq!(
            found.len(),
            1,
            "refine_edges={refine_edges}: expected 1 tag, got {found:?}"
        );
        let d = found.into_iter().next().unwrap();
        assert_eq!(d.id, 0, "refine_edges={refine_edges}: id");
        assert_eq!(d.hamming, 0, "refine_edges={refine_edges}: hamming");
        d
    };

    // Without edge refinement the corners are exact (measured: within 1e-13 px).
    let d = detect(false);
    for (k, (got, want)) in d.corners_px.iter().zip(&expected).enumerate() {
        let err = (got[0] - want[0]).hypot(got[1] - want[1]);
        assert!(
            err < 1e-6,
            "refine_edges=false: corner {k} expected {want:?}, got {got:?} ({err:.2e} px)"
        );
    }
    let centre = [left + side / 2.0, top + side / 2.0];
    let err = (d.centre_px[0] - centre[0]).hypot(d.centre_px[1] - centre[1]);
    assert!(
        err < 1e-6,
        "centre expected {centre:?}, got {:?}",
        d.centre_px
    );

    // The C library's edge refinement (0.25 px search steps over truncated sample positions)
    // shifts these exact corners by about -1/8 px on both axes (measured: x -0.125 at all four,
    // y -0.125 at the bottom ones, -0.08 / -0.14 at the top ones). This pins that behaviour so
    // a library change shows up; it is why TagConfig defaults to refine_edges = false.
    let d = detect(true);
    let n = d.corners_px.len() as f64;
    let mean_dx = d
        .corners_px
        .iter()
        .zip(&expected)
        .map(|(g, w)| g[0] - w[0])
        .sum::<f64>()
        / n;
    let mean_dy = d
        .corners_px
        .iter()
        .zip(&expected)
        .map(|(g, w)| g[1] - w[1])
        .sum::<f64>()
        / n;
    assert!(
        (-0.15..=-0.10).contains(&mean_dx) && (-0.15..=-0.08).contains(&mean_dy),
        "refine_edges=true: mean corner shift expected about (-0.125, -0.125) px, got ({mean_dx:.4}, {mean_dy:.4}) (corners {:?})",
        d.corners_px
    );
}

#[test]
fn allowed_ids_drop_tags_not_on_the_board() {
    let mut img = GrayImage::from_pixel(260, 140, Luma([255]));
    paint_tag(&mut img, 0, 20, 20, 10);
    paint_tag(&mut img, 1, 150, 20, 10);
    let all = TagDetector::new(TagConfig::default())
        .unwrap()
        .detect(&img, Path::new("rendered-id0-id1"))
        .unwrap();
    let ids: Vec<u32> = all.iter().map(|d| d.id).collect();
    assert_eq!(
        ids,
        vec![0, 1],
        "without a filter both rendered tags are expected"
    );

    let only_1 = TagDetector::new(TagConfig::default().with_board_ids(&[1, 7]))
        .unwrap()
        .detect(&img, Path::new("rendered-id0-id1"))
        .unwrap();
    let ids: Vec<u32> = only_1.iter().map(|d| d.id).collect();
    assert_eq!(ids, vec![1], "board ids [1, 7] should keep only id 1");
    assert!(
        only_1[0].corners_px[3][0] > 140.0,
        "the kept tag should be the right-hand one, got corners {:?}",
        only_1[0].corners_px
    );
}
