//! `s3tir-train render RUN --path orbit|spiral|views|FILE --out DIR`: novel views of a run
//! along a path, as palette frames with a colour bar and a video.

use std::path::PathBuf;

#[cfg(not(feature = "vulkan"))]
use anyhow::bail;
use anyhow::{Context, Result};
use clap::Args;
use s3tir_calib::model::palette::Colormap;
use s3tir_trainer::look::flight::{
    FlightOptions, FlightWritten, PathKind, VideoFormat, render_flight,
};
use s3tir_trainer::train::{BackendKind, CpuBackend};

/// Options of `s3tir-train render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Run folder written by training.
    pub run_dir: PathBuf,
    /// The camera path: `views` (the held-out views' cameras: each frame is the view's render),
    /// `orbit` (around the scene's centre at the training cameras' distance and height, over
    /// the arc they span), `spiral` (a loop across the training cameras' spread, for walls and
    /// nadir flights), or a JSON file `{"up": [x,y,z], "frames": [{"eye": [x,y,z], "target":
    /// [x,y,z]}, …]}` in the dataset's world frame.
    #[arg(long, default_value = "orbit")]
    pub path: PathKind,
    /// Output folder: frame_00000.png, … (palette images with a colour bar in K and °C, their
    /// scale in PNG text chunks) and flight.mp4 (ffmpeg) or flight.gif (without ffmpeg).
    #[arg(long)]
    pub out: PathBuf,
    /// Frames of an orbit or spiral.
    #[arg(long, default_value_t = 120)]
    pub frames: usize,
    /// Frames per second of the video.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Palette of the frames: ironbow, inferno or grey.
    #[arg(long, default_value = "ironbow", value_parser = parse_palette)]
    pub palette: Colormap,
    /// The video: auto (H.264 MP4 through ffmpeg when it is installed, else an animated GIF),
    /// mp4 (an error without ffmpeg) or gif.
    #[arg(long, value_enum, default_value_t = VideoFormat::Auto)]
    pub video: VideoFormat,
    /// Frames only, no video.
    #[arg(long, conflicts_with = "video")]
    pub no_video: bool,
    /// Backend that renders the frames: cpu (the reference) or vulkan.
    #[arg(long, value_enum, default_value_t = BackendKind::Cpu)]
    pub backend: BackendKind,
    /// Vulkan device index (see `devices`; default: the best device).
    #[arg(long)]
    pub device_index: Option<usize>,
    /// Print one JSON object (frames, video, size, scale) instead of lines.
    #[arg(long)]
    pub json: bool,
}

fn parse_palette(s: &str) -> std::result::Result<Colormap, String> {
    match Colormap::from_name(s) {
        Some(c) if c.sequential() => Ok(c),
        _ => Err(format!("unknown palette {s:?} (ironbow, inferno or grey)")),
    }
}

/// `render`: the frames and video with a progress bar; prints where they are.
pub fn run(a: &RenderArgs) -> Result<()> {
    if !(a.fps.is_finite() && a.fps > 0.0) {
        anyhow::bail!("--fps must be a positive number, not {}", a.fps);
    }
    let opts = FlightOptions {
        path: a.path.clone(),
        frames: a.frames,
        fps: a.fps,
        palette: a.palette,
        video: (!a.no_video).then_some(a.video),
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("rendering [{bar:30}] {pos}/{len} frames {eta}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let mut progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let what = || {
        format!(
            "rendering {} along {:?} into {}",
            a.run_dir.display(),
            a.path,
            a.out.display()
        )
    };
    let w: FlightWritten = match a.backend {
        #[cfg(feature = "vulkan")]
        BackendKind::Vulkan => {
            let mut b = s3tir_trainer::gpu::backend::VulkanBackend::new(
                &super::vulkan_options(a.device_index, false),
                s3tir_trainer::render::RenderSettings::default(),
            )
            .context("opening the Vulkan backend (see `s3tir-train devices`)")?;
            render_flight(&a.run_dir, &a.out, &opts, &mut b, &mut progress).with_context(what)?
        }
        #[cfg(not(feature = "vulkan"))]
        BackendKind::Vulkan => {
            bail!("this s3tir-train was built without the `vulkan` feature: use --backend cpu")
        }
        BackendKind::Cpu => {
            let mut b = CpuBackend::default();
            render_flight(&a.run_dir, &a.out, &opts, &mut b, &mut progress).with_context(what)?
        }
    };
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&w)?);
        return Ok(());
    }
    println!(
        "{} frames of {}×{} in {} ({} over {:.2}–{:.2} {})",
        w.frames.len(),
        w.width,
        w.height,
        a.out.display(),
        a.palette.name(),
        w.scale_lo,
        w.scale_hi,
        w.unit
    );
    match &w.video {
        Some(v) => println!("video: {} ({})", v.display(), w.video_how),
        None => println!("no video: {}", w.video_how),
    }
    Ok(())
}
