//! `s3tir-firmware-sim`: the simulated s3tir rig.

use anyhow::Result;
use clap::Parser;

/// The simulated s3tir rig: a thermal core, an RGB camera and the rig controller firmware,
/// producing physically plausible frames and ground truth when no hardware is attached.
#[derive(Debug, Parser)]
#[command(name = "s3tir-firmware-sim", version, about, long_about)]
struct Cli {}

fn main() -> Result<()> {
    let _cli = Cli::parse();
    anyhow::bail!("no simulation command is implemented yet; see --help")
}
