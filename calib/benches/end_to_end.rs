//! End-to-end calibration benchmark (`cargo bench -p s3tir-calib --bench end_to_end`): 50
//! synthetic Lepton + 720p pairs, our detection + joint solve next to OpenCV's stereoCalibrate
//! on the same detections, printed as a ratio (see `s3tir_calib::bench`). The same figures
//! come from `s3tir-calib bench --pairs 50`. Not a criterion bench: one end-to-end run takes
//! seconds, and the figure of interest is the ratio against the peer measured in the same run.
#![allow(clippy::unwrap_used, clippy::expect_used)]

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing: run a tiny set then.
    let full = std::env::args().any(|a| a == "--bench");
    let pairs = if full { 50 } else { 6 };
    let dir = tempfile::tempdir().expect("temp dir");
    let bars = s3tir_calib::progress::bars::ProgressBars::new();
    let figures =
        s3tir_calib::bench::run(dir.path(), pairs, 7, false, &bars).expect("benchmark run");
    println!("{figures}");
}
