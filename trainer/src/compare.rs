//! Comparing training runs (`s3tir-train compare`). A run's held-out metrics are one sample of
//! its configuration: timing decides how many steps fall before each evaluation, and the seed
//! decides the initial subsampling, the bands and the view order, so runs of one configuration
//! differ (three training seeds on one simulated scene ended up to 4.3 dB apart after 2 minutes).
//! A [`Group`] holds repeated runs of one configuration (e.g. `--seed 0, 1, 2`); [`group_curve`]
//! gives per evaluation the mean and range of its runs, and [`leads`] counts, after the warm-up,
//! at how many evaluations the first group is ahead of each other group: on the means, beyond
//! the run-to-run range (the first group's worst run above the other's best), and with runs
//! paired in the order given (the same seed or scene) in every pair.
//!
//! Runs are matched evaluation by evaluation (the k-th row of each `metrics.csv`), so the runs
//! of a comparison need the same evaluation interval (`--eval-every-s`, or `--eval-every` in
//! iterations); [`group_curve`] refuses runs, and [`check_aligned`] entries, whose k-th
//! evaluations lie apart.

use std::path::{Path, PathBuf};

use s3tir_capture::Chain;
use serde::Serialize;
use thiserror::Error;

use crate::report::{self, Curve, CurvePoint, MetricsRow, ReportError, Spread};
use crate::train::{self, files};

#[derive(Debug, Error)]
pub enum CompareError {
    #[error("reading the metrics of run {run}")]
    Metrics {
        run: PathBuf,
        #[source]
        source: ReportError,
    },
    #[error("group `{label}` has no runs")]
    EmptyGroup { label: String },
    #[error("run {run} has no evaluations in its metrics.csv (the run has not evaluated yet)")]
    NoEvaluations { run: PathBuf },
    #[error(
        "group `{label}`: evaluation {index} is at {seconds:.1} s in {run} but at {expected:.1} s \
         in {first}; runs compared evaluation by evaluation need the same evaluation interval \
         (--eval-every-s)"
    )]
    Misaligned {
        label: String,
        index: usize,
        run: PathBuf,
        seconds: f64,
        first: PathBuf,
        expected: f64,
    },
    #[error(
        "evaluation {index} is at {seconds:.1} s in `{label}` but at {expected:.1} s in \
         `{first}`; entries compared evaluation by evaluation need the same evaluation interval \
         (--eval-every-s)"
    )]
    EntriesMisaligned {
        label: String,
        index: usize,
        seconds: f64,
        first: String,
        expected: f64,
    },
}

/// One run's held-out metrics and what the comparison needs of its configuration.
#[derive(Debug, Clone)]
pub struct RunMetrics {
    pub dir: PathBuf,
    /// `s3tir`, `3dgs`, … (`?` when its configuration could not be read).
    pub mode: String,
    pub rows: Vec<MetricsRow>,
    /// Training seconds at which its warm-up ended (β ≡ 2 and no bands before it): with a time
    /// budget the schedule's fraction `warmup / iters` of the budget; otherwise the first
    /// evaluation at or after the warm-up's iteration. `None` when unknown.
    pub warmup_end_s: Option<f64>,
}

/// Reads a run folder's `metrics.csv` and configuration.
pub fn load_run(dir: &Path) -> Result<RunMetrics, CompareError> {
    let rows = report::read_rows(&dir.join(files::METRICS_CSV)).map_err(|source| {
        CompareError::Metrics {
            run: dir.to_path_buf(),
            source,
        }
    })?;
    if rows.is_empty() {
        return Err(CompareError::NoEvaluations {
            run: dir.to_path_buf(),
        });
    }
    // The metrics are what is compared: a configuration this version cannot read (a run of an
    // older version) leaves the mode and the warm-up unknown rather than failing.
    let cfg = match train::load_config(dir) {
        Ok(cfg) => Some(cfg),
        Err(e) => {
            tracing::warn!(run = %dir.display(), error = %Chain(&e), "configuration not read: mode and warm-up unknown");
            None
        }
    };
    let warmup_end_s = cfg
        .as_ref()
        .and_then(|cfg| cfg.warmup_end_s(rows.iter().map(|r| (r.iteration, r.seconds))));
    Ok(RunMetrics {
        dir: dir.to_path_buf(),
        mode: cfg.map_or_else(|| "?".to_owned(), |c| c.mode.to_string()),
        rows,
        warmup_end_s,
    })
}

/// Repeated runs of one configuration under one label.
#[derive(Debug, Clone)]
pub struct Group {
    pub label: String,
    pub runs: Vec<RunMetrics>,
}

impl Group {
    /// The runs' modes, e.g. `s3tir` (or `s3tir/3dgs` when they differ).
    pub fn modes(&self) -> String {
        let mut modes: Vec<&str> = Vec::new();
        for r in &self.runs {
            if !modes.contains(&r.mode.as_str()) {
                modes.push(&r.mode);
            }
        }
        modes.join("/")
    }

    /// The latest warm-up end of its runs.
    pub fn warmup_end_s(&self) -> Option<f64> {
        self.runs
            .iter()
            .filter_map(|r| r.warmup_end_s)
            .reduce(f64::max)
    }
}

/// Two runs' k-th evaluations are "the same evaluation" when their times differ by at most this
/// fraction of the first run's evaluation interval (plus [`ALIGN_SLACK_S`]).
const ALIGN_FRACTION: f64 = 0.25;
const ALIGN_SLACK_S: f64 = 0.5;

/// Whether `seconds` is the evaluation of `reference` at index `k` (see [`ALIGN_FRACTION`]).
fn same_evaluation(reference: &[f64], k: usize, seconds: f64) -> bool {
    let expected = reference[k];
    let interval = if k > 0 {
        expected - reference[k - 1]
    } else {
        reference.get(1).map_or(0.0, |t| t - expected)
    };
    (seconds - expected).abs() <= ALIGN_FRACTION * interval.abs() + ALIGN_SLACK_S
}

/// Checks that the curves' k-th evaluations are at the same training time as the first
/// curve's (up to the shortest curve), so [`leads`] compares like with like.
pub fn check_aligned(curves: &[Curve]) -> Result<(), CompareError> {
    let Some((first, others)) = curves.split_first() else {
        return Ok(());
    };
    let reference: Vec<f64> = first.points.iter().map(|p| p.seconds).collect();
    for c in others {
        for (k, p) in c.points.iter().enumerate().take(reference.len()) {
            if !same_evaluation(&reference, k, p.seconds) {
                return Err(CompareError::EntriesMisaligned {
                    label: c.label.clone(),
                    index: k,
                    seconds: p.seconds,
                    first: first.label.clone(),
                    expected: reference[k],
                });
            }
        }
    }
    Ok(())
}

/// The group's curve: per evaluation (up to the shortest run's count) the mean and range of its
/// runs' figures. A figure some run's log lacks (e.g. `psnr_aligned` in old logs) is `None`.
pub fn group_curve(group: &Group) -> Result<Curve, CompareError> {
    let first = group.runs.first().ok_or_else(|| CompareError::EmptyGroup {
        label: group.label.clone(),
    })?;
    let n = group.runs.iter().map(|r| r.rows.len()).min().unwrap_or(0);
    let mut points = Vec::with_capacity(n);
    let reference: Vec<f64> = first.rows.iter().map(|r| r.seconds).collect();
    for k in 0..n {
        for run in &group.runs[1..] {
            let seconds = run.rows[k].seconds;
            if !same_evaluation(&reference, k, seconds) {
                return Err(CompareError::Misaligned {
                    label: group.label.clone(),
                    index: k,
                    run: run.dir.clone(),
                    seconds,
                    first: first.dir.clone(),
                    expected: reference[k],
                });
            }
        }
        let rows: Vec<&MetricsRow> = group.runs.iter().map(|r| &r.rows[k]).collect();
        let all = |get: &dyn Fn(&MetricsRow) -> Option<f64>| {
            let vals: Option<Vec<f64>> = rows.iter().map(|r| get(r)).collect();
            vals.and_then(|v| Spread::of(&v))
        };
        let mean = |get: &dyn Fn(&MetricsRow) -> f64| {
            rows.iter().map(|r| get(r)).sum::<f64>() / rows.len() as f64
        };
        let spread = |get: &dyn Fn(&MetricsRow) -> f64| {
            let v: Vec<f64> = rows.iter().map(|r| get(r)).collect();
            Spread::of(&v).unwrap_or(Spread::one(f64::NAN))
        };
        points.push(CurvePoint {
            seconds: mean(&|r| r.seconds),
            psnr: spread(&|r| r.psnr),
            psnr_aligned: all(&|r| r.psnr_aligned),
            ssim: spread(&|r| r.ssim),
            kelvin_mae: all(&|r| r.kelvin_mae),
            kelvin_mae_aligned: all(&|r| r.kelvin_mae_aligned),
            lpips: all(&|r| r.lpips),
            primitives: mean(&|r| r.primitives as f64),
        });
    }
    Ok(Curve {
        label: group.label.clone(),
        runs: group.runs.len(),
        points,
    })
}

/// Where the first curve stands against another one on one figure (PSNR: higher is better;
/// LPIPS: lower is better), over the evaluations at or after `from_s`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Lead {
    pub leader: String,
    pub other: String,
    /// `psnr`, `psnr_aligned` or `lpips`.
    pub metric: &'static str,
    /// Evaluations compared (both curves have the figure there).
    pub evaluations: usize,
    /// Evaluations where the leader's mean is as good as the other's or better.
    pub ahead: usize,
    /// Evaluations where the leader's worst run is as good as the other's best or better (a
    /// lead beyond the run-to-run range).
    pub ahead_beyond_range: usize,
    /// With as many runs in both groups, paired in the order given (the same seed or scene):
    /// evaluations where the leader's run is as good as its partner or better in every pair.
    pub ahead_in_every_pair: Option<usize>,
    /// Smallest and largest lead of the means, in the figure's unit and signed so that positive
    /// is better for the leader (PSNR: leader − other, dB; LPIPS: other − leader).
    pub min_lead: f64,
    pub max_lead: f64,
    /// The leader's mean lead at the last evaluation compared.
    pub final_lead: f64,
}

/// The first group against each other group (`curves[i]` is [`group_curve`] of `groups[i]`), on
/// held-out PSNR and (when both curves have them) aligned PSNR and LPIPS, over the evaluations at or after
/// `from_s` training seconds (e.g. the warm-up's end). Curves are matched evaluation by
/// evaluation, and with as many runs per group, runs pair up in the order given.
pub fn leads(groups: &[Group], curves: &[Curve], from_s: f64) -> Vec<Lead> {
    let (Some((leader_runs, other_runs)), Some((leader, others))) =
        (groups.split_first(), curves.split_first())
    else {
        return Vec::new();
    };
    type Get = fn(&CurvePoint) -> Option<Spread>;
    type GetRow = fn(&MetricsRow) -> Option<f64>;
    // (name, figure of a curve point, of a row, +1: higher is better / −1: lower is better)
    let metrics: [(&'static str, Get, GetRow, f64); 3] = [
        ("psnr", |p| Some(p.psnr), |r| Some(r.psnr), 1.0),
        ("psnr_aligned", |p| p.psnr_aligned, |r| r.psnr_aligned, 1.0),
        ("lpips", |p| p.lpips, |r| r.lpips, -1.0),
    ];
    let mut out = Vec::new();
    for (other_group, other) in other_runs.iter().zip(others) {
        let paired = leader_runs.runs.len() == other_group.runs.len();
        for (metric, get, get_row, sign) in metrics {
            let pairs: Vec<(usize, Spread, Spread)> = leader
                .points
                .iter()
                .zip(&other.points)
                .enumerate()
                .filter(|(_, (a, b))| a.seconds.max(b.seconds) >= from_s)
                .filter_map(|(k, (a, b))| Some((k, get(a)?, get(b)?)))
                .collect();
            if pairs.is_empty() {
                continue;
            }
            let diffs: Vec<f64> = pairs
                .iter()
                .map(|(_, a, b)| sign * (a.mean - b.mean))
                .collect();
            // The leader's worst run against the other's best, in the figure's direction.
            let beyond = |a: &Spread, b: &Spread| {
                if sign > 0.0 {
                    a.min >= b.max
                } else {
                    a.max <= b.min
                }
            };
            // Every pair of runs at evaluation k: the leader's run at or above its partner.
            let every_pair = |k: usize| {
                leader_runs
                    .runs
                    .iter()
                    .zip(&other_group.runs)
                    .all(|(a, b)| {
                        match (
                            a.rows.get(k).and_then(get_row),
                            b.rows.get(k).and_then(get_row),
                        ) {
                            (Some(x), Some(y)) => sign * (x - y) >= 0.0,
                            _ => false,
                        }
                    })
            };
            out.push(Lead {
                leader: leader.label.clone(),
                other: other.label.clone(),
                metric,
                evaluations: pairs.len(),
                ahead: diffs.iter().filter(|d| **d >= 0.0).count(),
                ahead_beyond_range: pairs.iter().filter(|(_, a, b)| beyond(a, b)).count(),
                ahead_in_every_pair: paired
                    .then(|| pairs.iter().filter(|(k, _, _)| every_pair(*k)).count()),
                min_lead: diffs.iter().copied().fold(f64::INFINITY, f64::min),
                max_lead: diffs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                final_lead: diffs.last().copied().unwrap_or(f64::NAN),
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn row(seconds: f64, psnr: f64) -> MetricsRow {
        MetricsRow {
            iteration: (seconds * 10.0) as u64,
            seconds,
            loss: 0.1,
            psnr,
            ssim: 0.9,
            kelvin_mae: None,
            kelvin_rmse: None,
            primitives: 100,
            memory_bytes: 1000,
            psnr_aligned: Some(psnr + 0.5),
            kelvin_mae_aligned: None,
            lpips: None,
        }
    }

    fn run(name: &str, psnr: &[f64]) -> RunMetrics {
        RunMetrics {
            dir: PathBuf::from(name),
            mode: "s3tir".into(),
            rows: psnr
                .iter()
                .enumerate()
                .map(|(k, &p)| row(10.0 * k as f64 + 0.03 * k as f64, p))
                .collect(),
            warmup_end_s: Some(12.0),
        }
    }

    #[test]
    fn a_group_curve_is_the_mean_and_range_of_its_runs_per_evaluation() {
        let g = Group {
            label: "a".into(),
            runs: vec![run("a1", &[10.0, 20.0, 30.0]), run("a2", &[12.0, 22.0])],
        };
        let c = group_curve(&g).unwrap();
        assert_eq!(c.runs, 2);
        assert_eq!(c.points.len(), 2, "the curve stops at the shortest run");
        assert_eq!(
            c.points[1].psnr,
            Spread {
                mean: 21.0,
                min: 20.0,
                max: 22.0
            }
        );
        let aligned = c.points[1]
            .psnr_aligned
            .expect("both runs log aligned PSNR");
        assert!((aligned.mean - 21.5).abs() < 1e-12, "{aligned:?}");
        assert!(c.points[0].kelvin_mae.is_none(), "no run is radiometric");
    }

    #[test]
    fn a_run_folder_is_read_and_an_unreadable_one_is_named() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("old_run");
        std::fs::create_dir(&dir).unwrap();
        // No metrics yet: the error names the folder.
        match load_run(&dir) {
            Err(e @ CompareError::Metrics { .. }) => {
                assert!(e.to_string().contains("old_run"), "{e}");
            }
            other => panic!("expected a metrics error naming the run, got {other:?}"),
        }
        let csv = dir.join(files::METRICS_CSV);
        for r in run("x", &[10.0, 20.0]).rows {
            report::append_row(&csv, &r).unwrap();
        }
        // A configuration this version cannot read (an older run's): compared all the same.
        std::fs::write(dir.join(files::CONFIG), "{\"not\": \"a config\"}").unwrap();
        let got = load_run(&dir).unwrap();
        assert_eq!(got.rows.len(), 2, "both evaluations read back");
        assert_eq!(got.mode, "?", "mode unknown without a readable config");
        assert_eq!(got.warmup_end_s, None);
    }

    #[test]
    fn runs_evaluated_at_different_times_are_refused() {
        let mut late = run("late", &[10.0, 20.0, 30.0]);
        late.rows[2].seconds = 60.0;
        let g = Group {
            label: "g".into(),
            runs: vec![run("a", &[10.0, 20.0, 30.0]), late],
        };
        match group_curve(&g) {
            Err(CompareError::Misaligned { index, run, .. }) => {
                assert_eq!(index, 2);
                assert_eq!(run, PathBuf::from("late"));
            }
            other => panic!("expected a misalignment error, got {other:?}"),
        }
        // Entries (groups) evaluated at different intervals are refused too.
        let every_10 = group_curve(&Group {
            label: "every 10 s".into(),
            runs: vec![run("a", &[10.0, 20.0, 30.0])],
        })
        .unwrap();
        let mut every_30 = every_10.clone();
        every_30.label = "every 30 s".into();
        for (k, p) in every_30.points.iter_mut().enumerate() {
            p.seconds = 30.0 * k as f64;
        }
        assert!(check_aligned(&[every_10.clone(), every_10.clone()]).is_ok());
        match check_aligned(&[every_10, every_30]) {
            Err(CompareError::EntriesMisaligned { index, label, .. }) => {
                assert_eq!((index, label.as_str()), (1, "every 30 s"));
            }
            other => panic!("expected entries misaligned at evaluation 1, got {other:?}"),
        }
        let empty = Group {
            label: "none".into(),
            runs: vec![],
        };
        assert!(matches!(
            group_curve(&empty),
            Err(CompareError::EmptyGroup { .. })
        ));
    }

    #[test]
    fn leads_count_mean_and_beyond_range_wins_after_the_warm_up() {
        // Evaluations at 0, 10, 20 and 30 s. Leader: ahead on the mean at evaluations 1 and 3,
        // behind at 2; beyond the range only at 3. Evaluation 0 (before a warm-up ending at 5 s)
        // is not counted although the leader is far behind there.
        // Paired in order: s1 with g1 (+1.0, -1.0, +3.0), s2 with g2 (-0.5, -0.5, +1.0), so
        // in every pair only at evaluation 3.
        let groups = [
            Group {
                label: "s3tir".into(),
                runs: vec![
                    run("s1", &[0.0, 21.0, 20.0, 33.0]),
                    run("s2", &[0.0, 19.5, 21.0, 32.0]),
                ],
            },
            Group {
                label: "3dgs".into(),
                runs: vec![
                    run("g1", &[30.0, 20.0, 21.0, 30.0]),
                    run("g2", &[30.0, 20.0, 21.5, 31.0]),
                ],
            },
        ];
        let curves: Vec<Curve> = groups.iter().map(|g| group_curve(g).unwrap()).collect();
        let l = leads(&groups, &curves, 5.0);
        assert_eq!(l.len(), 2, "raw and aligned PSNR: {l:?}");
        let raw = &l[0];
        assert_eq!(raw.metric, "psnr");
        assert_eq!(raw.evaluations, 3, "evaluations after the warm-up: {raw:?}");
        assert_eq!(raw.ahead, 2, "{raw:?}");
        assert_eq!(raw.ahead_beyond_range, 1, "{raw:?}");
        assert_eq!(raw.ahead_in_every_pair, Some(1), "{raw:?}");
        assert!((raw.min_lead - (-0.75)).abs() < 1e-12, "{raw:?}");
        assert!((raw.max_lead - 2.0).abs() < 1e-12, "{raw:?}");
        assert!((raw.final_lead - 2.0).abs() < 1e-12, "{raw:?}");
        assert_eq!(l[1].metric, "psnr_aligned");
        assert_eq!(l[1].ahead, 2);

        // Unequal groups are not paired.
        let mut three = groups.clone();
        three[1].runs.push(run("g3", &[30.0, 20.0, 21.0, 30.0]));
        let curves: Vec<Curve> = three.iter().map(|g| group_curve(g).unwrap()).collect();
        assert_eq!(leads(&three, &curves, 5.0)[0].ahead_in_every_pair, None);
    }

    /// LPIPS is lower-is-better: a leader with the lower LPIPS leads, by `other − leader`.
    #[test]
    fn an_lpips_lead_is_the_lower_figure() {
        let with_lpips = |name: &str, lpips: &[f64]| {
            let mut r = run(name, &[20.0, 20.0, 20.0]);
            for (row, &l) in r.rows.iter_mut().zip(lpips) {
                row.lpips = Some(l);
            }
            r
        };
        let groups = [
            Group {
                label: "s3tir".into(),
                runs: vec![with_lpips("s1", &[0.5, 0.30, 0.20])],
            },
            Group {
                label: "3dgs".into(),
                runs: vec![with_lpips("g1", &[0.5, 0.25, 0.26])],
            },
        ];
        let curves: Vec<Curve> = groups.iter().map(|g| group_curve(g).unwrap()).collect();
        let l = leads(&groups, &curves, 5.0);
        let lp = l
            .iter()
            .find(|l| l.metric == "lpips")
            .expect("both groups log LPIPS: an lpips lead");
        assert_eq!(lp.evaluations, 2, "{lp:?}");
        assert_eq!(
            lp.ahead, 1,
            "lower LPIPS only at the last evaluation: {lp:?}"
        );
        assert_eq!(lp.ahead_beyond_range, 1, "{lp:?}");
        assert_eq!(lp.ahead_in_every_pair, Some(1), "{lp:?}");
        assert!((lp.final_lead - 0.06).abs() < 1e-12, "0.26 − 0.20: {lp:?}");
        assert!((lp.min_lead - (-0.05)).abs() < 1e-12, "0.25 − 0.30: {lp:?}");
        // Without LPIPS in the logs there is no lpips lead (the first test's groups).
        let plain = [groups[0].clone(), groups[1].clone()].map(|mut g| {
            g.runs[0].rows.iter_mut().for_each(|r| r.lpips = None);
            g
        });
        let curves: Vec<Curve> = plain.iter().map(|g| group_curve(g).unwrap()).collect();
        assert!(
            leads(&plain, &curves, 5.0)
                .iter()
                .all(|l| l.metric != "lpips"),
            "no LPIPS logged, no LPIPS lead"
        );
    }
}
