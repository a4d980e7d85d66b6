//! `s3tir-train compare`: several runs' error-vs-time curves on one plot, or groups of repeated
//! runs (one configuration, several seeds) as mean-and-range curves with a table of where the
//! first group leads the others after the warm-up.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use s3tir_trainer::compare::{self, Group, Lead};
use s3tir_trainer::report::{self, Curve};
use serde::Serialize;

/// Options of `s3tir-train compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Run folders, or groups of repeated runs of one configuration written
    /// LABEL=RUN,RUN,... (e.g. `s3tir=run_a,run_b,run_c 3dgs=run_d,run_e,run_f`). Each group is
    /// plotted as the mean of its runs with their range shaded; with groups of one run this is
    /// the plain overlay. The runs are matched evaluation by evaluation, so they need the same
    /// evaluation interval (--eval-every-s). The first entry leads: the table counts at how
    /// many evaluations after the warm-up its mean is at or above each other entry's, its worst
    /// run above the other's best, and (groups of as many runs, paired in the order given: the
    /// same seed or scene) its run above its partner in every pair.
    #[arg(required = true, value_name = "RUN|LABEL=RUN,RUN,...")]
    pub runs: Vec<String>,
    /// Output PNG.
    #[arg(long, default_value = "compare.png")]
    pub out: PathBuf,
    /// Print one JSON object (`curves`: per entry and evaluation the mean and range of each
    /// held-out figure; `leads`: the first entry against each other one; `warmup_end_s`)
    /// instead of the tables.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct CompareReport<'a> {
    warmup_end_s: Option<f64>,
    curves: &'a [Curve],
    leads: &'a [Lead],
}

/// Splits an entry into its label and run folders: an existing folder is a run by itself
/// (whatever its name holds), `LABEL=RUN,RUN,...` a group.
fn parse_entry(entry: &str) -> Result<(String, Vec<PathBuf>)> {
    let as_path = PathBuf::from(entry);
    if as_path.is_dir() {
        let label = as_path
            .file_name()
            .map_or_else(|| entry.to_owned(), |n| n.to_string_lossy().into_owned());
        return Ok((label, vec![as_path]));
    }
    match entry.split_once('=') {
        Some((label, runs)) if !label.is_empty() => {
            let runs: Vec<PathBuf> = runs
                .split(',')
                .filter(|r| !r.is_empty())
                .map(PathBuf::from)
                .collect();
            if runs.is_empty() {
                bail!("group `{label}` lists no run folders (expected {label}=RUN,RUN,...)");
            }
            Ok((label.to_owned(), runs))
        }
        _ => bail!("{entry}: no such run folder (an entry is a run folder or LABEL=RUN,RUN,...)"),
    }
}

/// `compare`: prints each run's last metrics row (and with groups the comparison table) and
/// writes the plot.
pub fn run(a: &CompareArgs) -> Result<()> {
    let mut groups = Vec::new();
    for entry in &a.runs {
        let (label, dirs) = parse_entry(entry)?;
        let runs = dirs
            .iter()
            .map(|d| compare::load_run(d))
            .collect::<Result<Vec<_>, _>>()?;
        groups.push(Group { label, runs });
    }
    let curves = groups
        .iter()
        .map(compare::group_curve)
        .collect::<Result<Vec<_>, _>>()?;
    compare::check_aligned(&curves)?;
    let warmup_end_s = groups
        .iter()
        .filter_map(Group::warmup_end_s)
        .reduce(f64::max);
    let leads = compare::leads(&groups, &curves, warmup_end_s.unwrap_or(0.0));
    report::plot_curves(&a.out, &curves)
        .with_context(|| format!("plotting {}", a.out.display()))?;
    if a.json {
        let report = CompareReport {
            warmup_end_s,
            curves: &curves,
            leads: &leads,
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    for g in &groups {
        for r in &g.runs {
            let Some(last) = r.rows.last() else { continue };
            let name = r.dir.file_name().map_or_else(
                || r.dir.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            println!(
                "{name:<20} {:<6} iter {:>6}  {:8.1} s  PSNR {:6.2} dB (aligned {})  SSIM {:.4}  LPIPS {}  MAE {}  {} primitives",
                r.mode,
                last.iteration,
                last.seconds,
                last.psnr,
                last.psnr_aligned
                    .map_or_else(|| "—".into(), |v| format!("{v:.2} dB")),
                last.ssim,
                last.lpips.map_or_else(|| "—".into(), |v| format!("{v:.4}")),
                last.kelvin_mae
                    .map_or_else(|| "—".into(), |v| format!("{v:.3} K")),
                last.primitives
            );
        }
    }
    if groups.iter().any(|g| g.runs.len() > 1) {
        print_table(&groups, &curves);
    }
    if !leads.is_empty() {
        println!(
            "after the warm-up ({}):",
            warmup_end_s.map_or_else(
                || "end unknown: every evaluation".into(),
                |s| format!("evaluations from {s:.1} s")
            )
        );
        for l in &leads {
            let pairs = l.ahead_in_every_pair.map_or_else(String::new, |n| {
                format!(", {n}/{} in every pair of runs", l.evaluations)
            });
            // PSNR leads in dB; LPIPS leads (other − leader, lower is better) unitless.
            let (unit, digits) = if l.metric == "lpips" {
                ("", 4)
            } else {
                (" dB", 2)
            };
            println!(
                "  {} vs {} on {}: ahead at {}/{} evaluations on the mean ({}/{} beyond the \
                 runs' range{pairs}), lead {:+.digits$} … {:+.digits$}{unit}, {:+.digits$}{unit} at the last",
                l.leader,
                l.other,
                l.metric,
                l.ahead,
                l.evaluations,
                l.ahead_beyond_range,
                l.evaluations,
                l.min_lead,
                l.max_lead,
                l.final_lead
            );
        }
    }
    println!("plot: {}", a.out.display());
    Ok(())
}

/// Per evaluation: time and each group's mean held-out PSNR with its range (and mean LPIPS where
/// the logs have it).
fn print_table(groups: &[Group], curves: &[Curve]) {
    print!("{:>8}", "s");
    for (g, c) in groups.iter().zip(curves) {
        print!(
            "  {:>24}",
            format!("{} ({}, {} runs)", c.label, g.modes(), c.runs)
        );
    }
    println!();
    let n = curves.iter().map(|c| c.points.len()).min().unwrap_or(0);
    for k in 0..n {
        print!("{:>8.1}", curves[0].points[k].seconds);
        for c in curves {
            let p = c.points[k].psnr;
            let lpips = c.points[k]
                .lpips
                .map_or_else(String::new, |l| format!(" {:.3}", l.mean));
            print!(
                "  {:>24}",
                format!("{:.2} ({:.2}–{:.2}){lpips}", p.mean, p.min, p.max)
            );
        }
        println!();
    }
}
