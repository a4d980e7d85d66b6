//! `s3tir-capture`: thermal + RGB capture for s3tir rigs.

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Capture radiometric thermal (Y16) and RGB video from a rig's cameras over V4L2.
///
/// Lists the cameras attached to this computer with their formats, sizes and rates, and
/// guesses which is the thermal core (16-bit or grey-only formats) and which the RGB camera.
#[derive(Debug, Parser)]
#[command(name = "s3tir-capture", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List V4L2 capture devices: path, driver, card, formats with sizes and rates, role guess.
    List {
        /// Print one JSON array instead of the table.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::List { json } => list(json),
    }
}

#[cfg(feature = "v4l")]
fn list(json: bool) -> Result<()> {
    let mut devices = Vec::new();
    for entry in s3tir_capture::v4l2::list_devices() {
        match entry {
            Ok(d) => devices.push(d),
            // Reported, not fatal: one unreadable node must not hide the others.
            Err(e) => eprintln!("warning: {e}"),
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&devices)?);
        return Ok(());
    }
    if devices.is_empty() {
        println!("no V4L2 capture devices found (no /dev/video* node can capture video)");
        return Ok(());
    }
    for d in &devices {
        println!(
            "{}  [{}]  {} ({}, {})",
            d.path, d.role, d.card, d.driver, d.bus
        );
        for f in &d.formats {
            println!("    {}  {}", f.fourcc, f.description);
            for s in &f.sizes {
                let rates: Vec<String> = s.rates_hz.iter().map(|r| format!("{r:.2}")).collect();
                println!("        {}x{} @ {} Hz", s.width, s.height, rates.join(", "));
            }
        }
    }
    Ok(())
}

#[cfg(not(feature = "v4l"))]
fn list(_json: bool) -> Result<()> {
    anyhow::bail!(
        "this s3tir-capture was built without the `v4l` feature: it cannot list V4L2 devices"
    )
}
