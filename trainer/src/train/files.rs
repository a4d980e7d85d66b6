//! Files of a run folder.

pub const CONFIG: &str = "config.json";
pub const CHECKPOINT: &str = "checkpoint.json";
pub const METRICS_CSV: &str = "metrics.csv";
pub const METRICS_PNG: &str = "error_vs_time.png";
pub const PLY: &str = "point_cloud.ply";
pub const EVAL: &str = "eval.json";
pub const CAPACITY: &str = "capacity.json";
pub const BETA_HIST: &str = "beta_hist.png";
pub const RENDERS: &str = "renders";
/// Super-resolved thermal renders of the held-out thermal views (joint runs, `--sr-scale`).
pub const RENDERS_SR: &str = "renders_sr";
/// The same fused with the recorded held-out thermal image by back-projection
/// ([`crate::superres`]).
pub const RENDERS_SR_FUSED: &str = "renders_sr_fused";
pub const GBUFFERS: &str = "gbuffers";
/// The RGB background colour (runs with RGB views).
pub const BACKGROUND: &str = "rgb_background.json";
/// The run report for people (self-contained HTML) and its Markdown twin ([`crate::look`]).
pub const REPORT_HTML: &str = "report.html";
pub const REPORT_MD: &str = "report.md";
/// The report's figures (PNG), beside the page.
pub const REPORT_DIR: &str = "report";
