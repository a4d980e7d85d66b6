//! `s3tir-train view RUN`: the local web viewer of a run's thermal mesh (meshing the run first
//! when it has none), until Ctrl-C.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};
use clap::Args;
use s3tir_trainer::look::view::assets::{Vendored, default_dir};
use s3tir_trainer::look::view::http::ViewServer;
use s3tir_trainer::look::view::scene::scene_info;
use s3tir_trainer::train::BackendKind;

/// Options of `s3tir-train view`.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// Run folder written by training; its mesh (`s3tir-train mesh RUN --out RUN/mesh.ply`) is
    /// written first when it has none.
    pub run_dir: PathBuf,
    /// Port to listen on (0: any free port; the address is printed).
    #[arg(long, default_value_t = 8765)]
    pub port: u16,
    /// Address to listen on. The default serves this machine only; another address (e.g.
    /// 0.0.0.0, to look from a laptop at a rig's run) lets anyone who can reach it read the run
    /// folder's files.
    #[arg(long, default_value_t = IpAddr::V4(Ipv4Addr::LOCALHOST))]
    pub bind: IpAddr,
    /// A host name the viewer answers to besides localhost and IP addresses (repeatable), e.g.
    /// the rig's name with --bind 0.0.0.0; requests naming any other host are refused (DNS
    /// rebinding).
    #[arg(long = "allow-host")]
    pub allow_host: Vec<String>,
    /// Backend that renders the views when the run must be meshed first.
    #[arg(long, value_enum, default_value_t = BackendKind::Cpu)]
    pub backend: BackendKind,
}

/// `view`: checks the renderer is installed, meshes the run if needed, prints the URL and
/// serves until Ctrl-C (or SIGTERM).
pub fn run(a: &ViewArgs) -> Result<()> {
    let assets = default_dir()
        .context("no data folder to find the viewer's renderer in: set S3TIR_DATA_HOME or HOME")?;
    let vendored = Vendored::load(&assets)?;
    if !a
        .run_dir
        .join(s3tir_trainer::train::files::CONFIG)
        .is_file()
    {
        anyhow::bail!(
            "{} is not a run folder (no {}): give the --out folder of a training run",
            a.run_dir.display(),
            s3tir_trainer::train::files::CONFIG
        );
    }
    let mut scene = scene_info(&a.run_dir)?;
    if scene.meshes.is_empty() {
        let out = a.run_dir.join("mesh.ply");
        if out.exists() {
            anyhow::bail!(
                "{} holds no triangles and the viewer would mesh the run into it: move it \
                 away, or mesh with s3tir-train mesh {} --out OTHER.ply",
                out.display(),
                a.run_dir.display()
            );
        }
        eprintln!(
            "{} has no mesh: meshing it first (s3tir-train mesh {} --out {})",
            a.run_dir.display(),
            a.run_dir.display(),
            out.display()
        );
        super::mesh::mesh_with_defaults(&a.run_dir, &out, a.backend)?;
        scene = scene_info(&a.run_dir)?;
    }
    let json = serde_json::to_vec(&scene).context("the scene description")?;
    if !a.bind.is_loopback() {
        tracing::warn!(
            bind = %a.bind,
            "the viewer listens beyond this machine: whoever reaches it reads the run folder's files"
        );
    }
    let server = ViewServer::bind(
        &a.run_dir,
        SocketAddr::new(a.bind, a.port),
        vendored,
        json,
        &a.allow_host,
    )
    .with_context(|| {
        format!(
            "starting the viewer (is port {} taken? --port 0 picks a free one)",
            a.port
        )
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    ctrlc::set_handler(move || flag.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    for m in &scene.meshes {
        let range = match (m.lo, m.hi) {
            (Some(lo), Some(hi)) => format!("{lo:.2}–{hi:.2} {} (1st–99th percentile)", scene.unit),
            _ => "no vertex has a value".to_string(),
        };
        eprintln!(
            "{}: {} vertices, {} triangles, {range}",
            m.name, m.vertices, m.triangles
        );
    }
    // The URL on stdout, alone on its line and flushed: scripts and tests read it.
    println!("viewer: {}", server.url());
    use std::io::Write as _;
    std::io::stdout().flush().ok();
    eprintln!("open it in a browser; Ctrl-C stops the viewer");
    let stats = server.serve_until(&stop)?;
    eprintln!(
        "viewer stopped: {} requests answered, {} refused",
        stats.requests, stats.refused
    );
    Ok(())
}
