//! Proves `s3tir-train ablation --study spectral` runs the S³-TIR paper's Table 2 by one
//! command: six runs of the options given (full, β fixed, f = 0, no consistency, no sparsity,
//! 3DGS) in RUN_DIR/<variant>/ with the modes and terms each variant stands for, and a table
//! and JSON whose figures are the runs' own `eval.json` read back. Does NOT compare the
//! variants' quality (a few iterations on a 48×40 scene say nothing about it; the closing
//! notes and README carry equal-time figures).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

use serde_json::Value;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_s3tir-train"))
}

#[test]
fn the_spectral_study_trains_six_variants_and_tabulates_their_own_evaluations() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("scene");
    let st = bin()
        .args(["synth", data.to_str().unwrap()])
        .args(["--views", "9", "--width", "48", "--height", "40"])
        .status()
        .unwrap();
    assert!(st.success(), "synth failed");
    let out = tmp.path().join("ablation");
    let run = bin()
        .args(["ablation", data.to_str().unwrap(), "--study", "spectral"])
        .args(["--out", out.to_str().unwrap()])
        .args(["--iters", "24", "--warmup", "8", "--budget", "150"])
        .args(["--eval-every-s", "1e9", "--checkpoint-every-s", "1e9"])
        .args(["--seed", "2", "--backend", "cpu"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "ablation failed: {text}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let rows: Vec<Value> =
        serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap();
    let want = [
        ("full", "s3tir", "s3tir", true, true),
        ("beta-fixed", "beta-fixed", "gabor", true, true),
        ("no-spectral", "no-spectral", "ges", true, true),
        ("no-consist", "no-consist", "s3tir", false, true),
        ("no-sparse", "no-sparse", "s3tir", true, false),
        ("gaussian", "3dgs", "3dgs", true, true),
    ];
    assert_eq!(rows.len(), want.len(), "six rows: {rows:?}");
    let table = std::fs::read_to_string(out.join("ablation.md")).unwrap();
    for (row, (variant, dir, mode, consist, sparse)) in rows.iter().zip(want) {
        assert_eq!(row["variant"], variant, "{row}");
        let run_dir = out.join(dir);
        let cfg: Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("config.json")).unwrap())
                .unwrap();
        assert_eq!(cfg["mode"], mode, "{variant}: mode");
        assert_eq!(cfg["consist"], consist, "{variant}: consistency term");
        assert_eq!(cfg["sparse"], sparse, "{variant}: sparsity term");
        let eval: Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("eval.json")).unwrap())
                .unwrap();
        assert_eq!(
            row["eval"]["psnr"], eval["psnr"],
            "{variant}: the table's PSNR is the run's own eval.json"
        );
        assert_eq!(row["iterations"], 24, "{variant}: the options given");
        let psnr = eval["psnr"].as_f64().unwrap();
        assert!(
            table.contains(&format!("{psnr:.2} dB")),
            "{variant}: the Markdown table shows PSNR {psnr:.2}: {table}"
        );
    }
}
