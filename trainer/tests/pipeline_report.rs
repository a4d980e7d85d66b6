//! Proves the small pieces of the pipeline against known values: PSNR and kelvin MAE/RMSE of
//! hand-built planes, SSIM of identical images, the metrics CSV round trip (header and optional
//! kelvin columns), that the plots and G-buffer writers produce images, and that checkpoints
//! round-trip exactly and are written atomically (no temporary file left, an old checkpoint
//! replaced whole). Does NOT judge how the plots look.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use s3tir_calib::model::palette::Colormap;
use s3tir_trainer::checkpoint::{self, CHECKPOINT_VERSION, Checkpoint};
use s3tir_trainer::dataset::ThermalRange;
use s3tir_trainer::dataset::ThermalUnits;
use s3tir_trainer::dataset::images::ImageKind;
use s3tir_trainer::metrics::{kelvin_errors, psnr, ssim};
use s3tir_trainer::primitive::{Groups, PrimitiveInit, Primitives};
use s3tir_trainer::render::GBuffers;
use s3tir_trainer::report::{self, CSV_HEADER, MetricsRow};

#[test]
fn psnr_kelvin_errors_and_ssim_have_known_values() {
    let a = vec![0.5f32; 100];
    let b: Vec<f32> = (0..100)
        .map(|i| if i % 2 == 0 { 0.6 } else { 0.4 })
        .collect();
    // MSE = 0.01 → 20 dB.
    let p = psnr(&a, &b);
    assert!((p - 20.0).abs() < 1e-4, "PSNR {p}, want 20 dB");
    assert_eq!(psnr(&a, &a), 100.0, "identical images are capped at 100 dB");
    let range = ThermalRange {
        kind: ImageKind::Thermal16,
        units: Some(ThermalUnits::CentiKelvin),
        min_raw: 29_000.0,
        max_raw: 31_000.0,
    };
    // 0.1 normalised = 2000 ck × 0.1 = 2 K.
    let (mae, rmse) = kelvin_errors(&a, &b, &range).unwrap();
    assert!(
        (mae - 2.0).abs() < 1e-4 && (rmse - 2.0).abs() < 1e-4,
        "MAE {mae}, RMSE {rmse}, want 2 K"
    );
    let counts = ThermalRange {
        units: Some(ThermalUnits::RawCounts),
        ..range
    };
    assert!(
        kelvin_errors(&a, &b, &counts).is_none(),
        "raw counts are not radiometric"
    );
    let img: Vec<f32> = (0..64 * 48)
        .map(|i| ((i * 37) % 101) as f32 / 100.0)
        .collect();
    let s = ssim(&img, &img, 64, 48);
    assert!((s - 1.0).abs() < 1e-6, "SSIM of identical images {s}");
    let s2 = ssim(
        &img,
        &a.iter().cycle().take(64 * 48).copied().collect::<Vec<_>>(),
        64,
        48,
    );
    assert!(s2 < 0.5, "SSIM against a flat image {s2}");
}

#[test]
fn metrics_csv_round_trips_and_plots_are_written() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = tmp.path().join("m.csv");
    let rows: Vec<MetricsRow> = (0..4)
        .map(|i| MetricsRow {
            iteration: i * 10,
            seconds: i as f64 * 1.5,
            loss: 0.1 / (1.0 + i as f64),
            psnr: 20.0 + i as f64,
            ssim: 0.8,
            kelvin_mae: if i == 0 { None } else { Some(1.0 / i as f64) },
            kelvin_rmse: Some(0.5),
            primitives: 100 + i as usize,
            memory_bytes: 1000,
            psnr_aligned: Some(21.0 + i as f64),
            kelvin_mae_aligned: if i == 0 { None } else { Some(0.5 / i as f64) },
            lpips: None,
        })
        .collect();
    for r in &rows {
        report::append_row(&csv, r).unwrap();
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(text.lines().next().unwrap(), CSV_HEADER);
    assert!(CSV_HEADER.starts_with("iteration,seconds,loss,psnr,ssim,kelvin_mae,"));
    let back = report::read_rows(&csv).unwrap();
    assert_eq!(back.len(), 4);
    assert_eq!(
        back[0].kelvin_mae, None,
        "empty kelvin column reads as None"
    );
    assert!((back[2].kelvin_mae.unwrap() - 0.5).abs() < 1e-6);
    assert_eq!(back[1].psnr_aligned, Some(22.0), "aligned PSNR round-trips");
    assert_eq!(back[0].kelvin_mae_aligned, None);
    assert!((back[2].kelvin_mae_aligned.unwrap() - 0.25).abs() < 1e-6);
    // A log written before the aligned columns existed still reads (they are None).
    let old = tmp.path().join("old.csv");
    std::fs::write(
        &old,
        "iteration,seconds,loss,psnr,ssim,kelvin_mae,kelvin_rmse,primitives,memory_bytes\n\
         5,1.0,0.1,20.0,0.8,,,10,100\n",
    )
    .unwrap();
    let old_rows = report::read_rows(&old).unwrap();
    assert_eq!(old_rows.len(), 1);
    assert_eq!(
        old_rows[0].psnr_aligned, None,
        "old logs have no aligned PSNR"
    );
    assert_eq!(back[3].iteration, 30);
    let png = tmp.path().join("p.png");
    report::plot_runs(&png, &[("a".into(), back.clone()), ("b".into(), back)]).unwrap();
    let img = image::open(&png).unwrap();
    assert_eq!(
        (img.width(), img.height()),
        (1100, 450),
        "two panels without LPIPS"
    );

    // With LPIPS: one more column, read back, and a third panel in the plot.
    let with = tmp.path().join("lpips.csv");
    let lp_rows: Vec<MetricsRow> = rows
        .iter()
        .enumerate()
        .map(|(i, r)| MetricsRow {
            lpips: Some(0.4 - 0.05 * i as f64),
            ..r.clone()
        })
        .collect();
    for r in &lp_rows {
        report::append_row(&with, r).unwrap();
    }
    let text = std::fs::read_to_string(&with).unwrap();
    assert_eq!(
        text.lines().next().unwrap(),
        format!("{CSV_HEADER},{}", report::LPIPS_COLUMN),
        "a log whose first row has LPIPS has the column"
    );
    let lp_back = report::read_rows(&with).unwrap();
    assert!(
        (lp_back[3].lpips.unwrap() - 0.25).abs() < 1e-6,
        "LPIPS round-trips: {:?}",
        lp_back[3].lpips
    );
    // A log begun without the column keeps its columns when a row with LPIPS follows.
    report::append_row(&csv, &lp_rows[1]).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(
        text.lines().all(|l| l.split(',').count() == 11),
        "every line keeps the 11 columns the log began with:\n{text}"
    );
    let png3 = tmp.path().join("p3.png");
    report::plot_runs(&png3, &[("a".into(), lp_back)]).unwrap();
    let img = image::open(&png3).unwrap();
    assert_eq!(
        (img.width(), img.height()),
        (1650, 450),
        "a third panel for LPIPS"
    );
    let hist = tmp.path().join("h.png");
    report::plot_beta_histogram(&hist, &[2.0, 2.0, 2.1, 5.0, 30.0, 64.0]).unwrap();
    assert!(std::fs::metadata(&hist).unwrap().len() > 1000);

    let mut gb = GBuffers::<f32>::zeros(8, 4, false);
    for p in 0..32 {
        gb.alpha[p] = 1.0;
        gb.psi_beta[p] = if p % 8 < 4 { 2.0 } else { 10.0 };
        gb.depth[p] = 2.0 + p as f32 * 0.01;
    }
    let files = report::write_gbuffers(tmp.path(), "v", &gb).unwrap();
    assert_eq!(files.len(), 9, "4 PNGs and 5 .npy planes: {files:?}");
    let (w, h, exact) = report::read_npy_f32(&tmp.path().join("v_psi_beta.npy")).unwrap();
    assert_eq!((w, h), (8, 4), "npy shape (width, height)");
    assert_eq!(exact[0], 2.0, "Ψ_β/alpha at (0, 0)");
    assert_eq!(exact[7], 10.0, "Ψ_β/alpha at (7, 0)");
    let (_, _, alpha) = report::read_npy_f32(&tmp.path().join("v_alpha.npy")).unwrap();
    assert!(alpha.iter().all(|&a| a == 1.0), "alpha plane {alpha:?}");
    let png = tmp.path().join("v_psi_beta.png");
    let scale = s3tir_trainer::look::image::read_scale(&png).unwrap();
    assert_eq!(
        (scale.palette, scale.lo, scale.hi, scale.unit.as_str()),
        (Colormap::Inferno, 2.0, 10.0, "beta"),
        "the β PNG says its palette and range"
    );
    let beta = image::open(&png).unwrap().to_rgb8();
    assert_eq!(
        beta.get_pixel(0, 0).0,
        Colormap::Inferno.colour(0.0),
        "β = 2 is the palette's first colour"
    );
    assert_eq!(
        beta.get_pixel(7, 0).0,
        Colormap::Inferno.colour(1.0),
        "the largest β is its last"
    );
}

#[test]
fn checkpoints_round_trip_and_replace_atomically() {
    let tmp = tempfile::tempdir().unwrap();
    let mut p = Primitives::<f64>::new(2, None);
    for k in 0..5 {
        p.push(&PrimitiveInit {
            mean_m: [k as f64 * 0.1, 0.2, 1.0 / 3.0],
            beta: 2.0 + k as f64 * 1.7,
            bands: vec![(0.1, [1.0, 2.0, 3.0], 0.7)],
            ..Default::default()
        });
    }
    let p = p.cast::<f32>();
    let ck = Checkpoint {
        version: CHECKPOINT_VERSION,
        iteration: 1234,
        train_seconds: 5.5,
        primitives: p.clone(),
        adam_m: p.zeros_like(),
        adam_v: p.clone(),
        adam_step: 1234,
        adam_group_steps: Groups::splat(1234),
        state: serde_json::json!({"x": 1}),
    };
    let path = tmp.path().join("checkpoint.json");
    checkpoint::save(&path, &ck).unwrap();
    let mut ck2 = ck.clone();
    ck2.iteration = 2000;
    checkpoint::save(&path, &ck2).unwrap();
    let back = checkpoint::load(&path).unwrap();
    assert_eq!(back, ck2, "checkpoint round trip");
    assert_eq!(back.primitives, p, "f32 parameters bit-exact");
    // The header and the arrays of the second save (the first's slot was removed).
    let mut names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["checkpoint.b.safetensors", "checkpoint.json"],
        "no temporary file left: {names:?}"
    );
    // A torn file is refused with a clear error.
    std::fs::write(&path, b"{\"version\": 1, \"iter").unwrap();
    let e = checkpoint::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("checkpoint.json") && e.contains("not valid"),
        "error: {e}"
    );
}
