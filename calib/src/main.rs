//! `s3tir-calib`: calibration of thermal + RGB rigs with an emissivity-coated checkerboard.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use s3tir_calib::detect;

/// Calibrate a thermal + RGB camera rig with an emissivity-coated checkerboard.
///
/// `detect` finds a chessboard's inner corners in images (OpenCV's sector-based detector,
/// then the classic detector with sub-pixel refinement) and prints them.
#[derive(Debug, Parser)]
#[command(name = "s3tir-calib", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Detect a chessboard in each image and print its corners (pixels, origin at the centre
    /// of the top-left pixel). Exits non-zero if any image has no board.
    Detect {
        /// Inner corners as COLSxROWS, e.g. 9x6.
        #[arg(long, value_parser = parse_corners)]
        inner_corners: (u32, u32),
        /// Image files (PNG, JPEG, TIFF; colour is converted to grey).
        #[arg(required = true)]
        images: Vec<PathBuf>,
    },
}

fn parse_corners(text: &str) -> Result<(u32, u32), String> {
    let (c, r) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("{text:?}: expected COLSxROWS, e.g. 9x6"))?;
    let parse = |s: &str| s.trim().parse::<u32>().map_err(|e| format!("{text:?}: {e}"));
    Ok((parse(c)?, parse(r)?))
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Detect {
            inner_corners: (cols, rows),
            images,
        } => {
            let mut missing = 0usize;
            for path in &images {
                let grey = detect::read_grey(path)?;
                let mat = detect::mat_from_luma(&grey)?;
                match detect::find_chessboard(&mat, cols, rows)
                    .with_context(|| format!("detecting the board in {}", path.display()))?
                {
                    Some(d) => {
                        println!("{}: {} corners ({:?})", path.display(), d.corners_px.len(), d.detector);
                        for c in &d.corners_px {
                            println!("  {:.3} {:.3}", c.x, c.y);
                        }
                    }
                    None => {
                        missing += 1;
                        println!("{}: no {cols}x{rows} board found", path.display());
                    }
                }
            }
            if missing > 0 {
                bail!("{missing} of {} images had no {cols}x{rows} board", images.len());
            }
            Ok(())
        }
    }
}
