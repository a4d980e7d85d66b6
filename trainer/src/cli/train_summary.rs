//! What `s3tir-train` prints when a run ends: where the outputs are, what the run left out
//! (colour, consistency, bands, the Gaussian path, the view response), the joint run's terms,
//! density control and the time budget — as lines for a person, and with `--json` as one object
//! on stdout (the lines then go to stderr).

use std::path::{Path, PathBuf};
use std::time::Instant;

use s3tir_trainer::train::{Backend, BandRoundKind, CapacityReport, Trainer, files};

/// A run stopped by Ctrl-C after writing its checkpoint.
pub fn interrupted<B: Backend>(trainer: &Trainer<B>, out: &Path, iteration: u64, json: bool) {
    if json {
        println!(
            "{}",
            serde_json::json!({
                "outcome": "interrupted",
                "out": out,
                "iterations": iteration,
                "train_seconds": trainer.train_seconds,
                "checkpoint": out.join(files::CHECKPOINT),
            })
        );
    }
    say!(
        json,
        "interrupted at iteration {iteration}: checkpoint written to {}; continue with --resume",
        out.join(files::CHECKPOINT).display()
    );
}

/// A finished run: its files, what it left out, and (`--json`) the summary object.
pub fn finished<B: Backend>(
    trainer: &Trainer<B>,
    out: &Path,
    wall: Instant,
    json: bool,
    report: Option<&Path>,
) {
    let cap = trainer.capacity_report();
    say!(
        json,
        "done: {} primitives in {}",
        trainer.prims.len(),
        out.display()
    );
    let written = written_files(out);
    for p in &written {
        say!(json, "  {}", p.display());
    }
    say_left_out(trainer, &cap, json);
    if let Some(r) = report {
        say!(json, "report: {} (open it in a browser)", r.display());
    }
    if let Some(b) = trainer.cfg.time_budget_s {
        say!(
            json,
            "time budget: {:.1} s of training time of {b:.1} s ({} iterations); {:.1} s wall clock with evaluations, checkpoints and outputs",
            trainer.train_seconds,
            trainer.iteration,
            wall.elapsed().as_secs_f64()
        );
    }
    if json {
        print_json(trainer, &cap, out, wall, &written);
    }
}

/// The run's output files that exist.
fn written_files(out: &Path) -> Vec<PathBuf> {
    [
        files::PLY,
        files::METRICS_CSV,
        files::METRICS_PNG,
        files::EVAL,
        files::CAPACITY,
        files::BETA_HIST,
        files::RENDERS,
        files::RENDERS_SR,
        files::GBUFFERS,
        files::REPORT_HTML,
    ]
    .iter()
    .map(|f| out.join(f))
    .filter(|p| p.exists())
    .collect()
}

/// What the run left out or turned off, the joint run's terms, and density control.
fn say_left_out<B: Backend>(trainer: &Trainer<B>, cap: &CapacityReport, json: bool) {
    say!(
        json,
        "left out: colour {}; consistency: {}; bands {} → {} ({} bytes saved); {} primitives on the Gaussian path; view response: {}",
        if cap.colour_allocated {
            "kept"
        } else {
            "not allocated"
        },
        cap.consistency_reason,
        cap.bands_initial,
        cap.bands_now,
        cap.band_bytes_saved,
        cap.gaussian_path_primitives,
        cap.response.as_ref().map_or("none", |r| r.kind.as_str())
    );
    if let Some(g) = cap
        .band_rounds
        .iter()
        .find(|r| r.kind == BandRoundKind::Grant)
    {
        let dropped: usize = cap.band_rounds.iter().map(|r| r.bands_dropped).sum();
        say!(
            json,
            "bands: granted to {} of {} primitives at iteration {} ({} over λ = {}, budget {}; band RMS gradient median {:.2e}, 90th percentile {:.2e}); {} band slots dropped since; {} primitives hold bands at the end",
            g.holders_after,
            g.holders_before,
            g.iteration,
            g.over_threshold,
            trainer.cfg.capacity.band_l1,
            g.budget,
            g.rms_gradient_median,
            g.rms_gradient_p90,
            dropped,
            cap.band_holders
        );
    }
    for note in &cap.notes {
        say!(json, "note: {note}");
    }
    if let Some(r) = &cap.response {
        say!(json, "view response: {}", r.describe());
    }
    if let Some(why) = &cap.rgb_loss {
        say!(
            json,
            "joint RGB + thermal: RGB loss {why}; thermal gradient alignment {}; {}",
            if cap.thermal_align > 0.0 {
                match cap
                    .align_gradient
                    .as_ref()
                    .and_then(|a| a.median.map(|m| (a, m)))
                {
                    Some((a, m)) => format!(
                        "weight {} (its pull on the positions: {m:.3}× the other terms', \
                         median of {} samples, 90th percentile {:.3}×)",
                        cap.thermal_align,
                        a.samples,
                        a.p90.unwrap_or(m)
                    ),
                    None => format!("weight {}", cap.thermal_align),
                }
            } else {
                "off".into()
            },
            if trainer.cfg.joint.pair_steps {
                "each step trains a view with the other camera's image of its instant"
            } else {
                "each step trains one view (--no-pair-steps)"
            }
        );
    }
    say!(
        json,
        "density control: {} rounds, {} cloned, {} split, {} pruned, {} relocated; {} primitives at the end (budget {})",
        cap.densify_rounds.len(),
        cap.densify_cloned,
        cap.densify_split,
        cap.densify_pruned,
        cap.densify_relocated,
        cap.primitives,
        trainer.cfg.budget
    );
}

/// The `--json` summary object, on stdout.
fn print_json<B: Backend>(
    trainer: &Trainer<B>,
    cap: &CapacityReport,
    out: &Path,
    wall: Instant,
    written: &[PathBuf],
) {
    // The held-out figures as `eval` wrote them (absent when nothing is held out).
    let eval: Option<serde_json::Value> = std::fs::read(out.join(files::EVAL))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok());
    println!(
        "{}",
        serde_json::json!({
            "outcome": "finished",
            "out": out,
            "backend": trainer.cfg.backend,
            "iterations": trainer.iteration,
            "train_seconds": trainer.train_seconds,
            "wall_seconds": wall.elapsed().as_secs_f64(),
            "primitives": cap.primitives,
            "budget": trainer.cfg.budget,
            "density_control": {
                "rounds": cap.densify_rounds.len(),
                "cloned": cap.densify_cloned,
                "split": cap.densify_split,
                "pruned": cap.densify_pruned,
                "relocated": cap.densify_relocated,
            },
            "eval": eval,
            "files": written,
        })
    );
}
