//! `s3tir-capture list`: the V4L2 capture devices with their formats, sizes, rates and role
//! guess.

use anyhow::Result;
use clap::Args;

/// Options of `s3tir-capture list`.
#[derive(Debug, Args)]
pub struct ListArgs {
    /// Print one JSON array instead of the table.
    #[arg(long)]
    json: bool,
}

/// Runs `list`.
#[cfg(feature = "v4l")]
pub fn run(a: &ListArgs) -> Result<()> {
    let json = a.json;
    let mut devices = Vec::new();
    for entry in s3tir_capture::backend::v4l2::list_devices() {
        match entry {
            Ok(d) => devices.push(d),
            // Reported, not fatal: one unreadable node must not hide the others.
            Err(e) => eprintln!("warning: {}", s3tir_capture::Chain(&e)),
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

/// Runs `list` in a build without V4L2: an error saying so.
#[cfg(not(feature = "v4l"))]
pub fn run(_a: &ListArgs) -> Result<()> {
    anyhow::bail!(
        "this s3tir-capture was built without the `v4l` feature: it cannot list V4L2 devices"
    )
}
