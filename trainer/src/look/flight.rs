//! Novel views along a path through the scene (`s3tir-train render RUN --path …`): palette
//! frames with a colour bar (each also carrying its scale in PNG text chunks) and a video.
//!
//! Paths, from the run's dataset:
//! - `views`: the held-out views' own cameras, in order (a frame reproduces the view's render);
//! - `orbit`: around the scene's centre (the sparse points' median) at the training cameras'
//!   mean distance and height, over the arc they span (a full turn when they surround it,
//!   there and back over their arc otherwise: a facade is never seen from behind);
//! - `spiral`: the forward-facing path of a wall or a nadir flight: a loop around the training
//!   cameras' mean position across their spread, looking at the centre;
//! - a JSON file: `{"up": [x, y, z], "frames": [{"eye": [x, y, z], "target": [x, y, z]}, …]}`
//!   (`up` optional: the cameras' mean up).
//!
//! Every frame uses the first training camera's intrinsics and one scale for the whole path
//! (the held-out frames' 1st–99th percentile), so colours compare across frames. The video is
//! an MP4 through `ffmpeg` when it is on PATH (H.264, yuv420p), otherwise an animated GIF.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec3;
use s3tir_calib::model::palette::Colormap;
use serde::Deserialize;

use super::LookError;
use super::figure::{Panel, draw_panel_with_scale};
use super::image::{DisplayUnits, Scale};
use crate::camera::PinholeCamera;
use crate::dataset::Dataset;
use crate::primitive::Primitives;
use crate::train::{Backend, files, load_config};

/// A camera path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PathKind {
    Views,
    Orbit,
    Spiral,
    File(PathBuf),
}

impl std::str::FromStr for PathKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "views" => Self::Views,
            "orbit" => Self::Orbit,
            "spiral" => Self::Spiral,
            "" => return Err("empty path".into()),
            file => Self::File(PathBuf::from(file)),
        })
    }
}

/// What to render.
#[derive(Debug, Clone)]
pub struct FlightOptions {
    pub path: PathKind,
    /// Frames of an orbit or spiral (a file or `views` has its own count).
    pub frames: usize,
    pub fps: f64,
    pub palette: Colormap,
    /// The video to write; frames only with `None`.
    pub video: Option<VideoFormat>,
}

/// The fly-through's video.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VideoFormat {
    /// H.264 MP4 through ffmpeg when it runs, else an animated GIF.
    Auto,
    /// H.264 MP4 through ffmpeg; an error without a working ffmpeg.
    Mp4,
    /// An animated GIF (the `image` crate's encoder; no ffmpeg).
    Gif,
}

/// What [`render_flight`] wrote.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FlightWritten {
    pub frames: Vec<PathBuf>,
    pub video: Option<PathBuf>,
    /// How the video was made (`ffmpeg`, `gif`, or why there is none).
    pub video_how: String,
    pub width: usize,
    pub height: usize,
    pub scale_lo: f64,
    pub scale_hi: f64,
    pub unit: String,
}

/// A path file's contents.
#[derive(Debug, Deserialize)]
struct PathFile {
    #[serde(default)]
    up: Option<[f64; 3]>,
    frames: Vec<PathFrame>,
}

#[derive(Debug, Deserialize)]
struct PathFrame {
    eye: [f64; 3],
    target: [f64; 3],
}

/// Renders the run in `run_dir` along `opts.path` into `out` (frames `frame_00000.png`, …,
/// and `flight.mp4` or `flight.gif`), on `backend`; `progress(done, total)` per frame.
pub fn render_flight<B: Backend>(
    run_dir: &Path,
    out: &Path,
    opts: &FlightOptions,
    backend: &mut B,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<FlightWritten, LookError> {
    let cfg = load_config(run_dir)?;
    let data = Dataset::load(&cfg.data, &cfg.load).map_err(crate::train::TrainError::from)?;
    let range = data.range.ok_or_else(|| LookError::Format {
        path: cfg.data.clone(),
        reason: "the dataset has no thermal images: nothing to draw in a thermal palette".into(),
    })?;
    let prims = read_primitives(run_dir)?;
    let cams = path_cameras(&opts.path, &data, opts.frames)?;
    if cams.is_empty() {
        return Err(LookError::Format {
            path: run_dir.to_path_buf(),
            reason: "the path has no frame".into(),
        });
    }
    std::fs::create_dir_all(out).map_err(|source| LookError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let units = DisplayUnits { range: Some(range) };
    let recorded: Vec<f32> = data
        .test
        .iter()
        .chain(&data.train)
        .take(16)
        .filter_map(|&i| data.views[i].thermal.as_ref())
        .flat_map(|t| t.iter().map(|&v| units.value(v)))
        .collect();
    let scale = Scale::robust(opts.palette, &recorded, 0.01, units.unit());
    let mut frames = Vec::with_capacity(cams.len());
    for (k, (name, cam)) in cams.iter().enumerate() {
        let gb = backend.render(&prims, cam).map_err(|e| LookError::Format {
            path: run_dir.to_path_buf(),
            reason: format!("rendering frame {k}: {e}"),
        })?;
        let plane: Vec<f32> = gb.thermal.iter().map(|&v| units.value(v)).collect();
        let path = out.join(format!("frame_{k:05}.png"));
        draw_panel_with_scale(
            &path,
            &Panel {
                title: name.clone(),
                plane,
                width: cam.width,
                height: cam.height,
                scale: scale.clone(),
            },
        )?;
        frames.push(path);
        progress(k + 1, cams.len());
    }
    let (video, video_how) = match opts.video {
        Some(format) => write_video(out, &frames, opts.fps, format)?,
        None => (None, "not asked for (--no-video)".to_string()),
    };
    Ok(FlightWritten {
        frames,
        video,
        video_how,
        width: cams[0].1.width,
        height: cams[0].1.height,
        scale_lo: scale.lo,
        scale_hi: scale.hi,
        unit: scale.unit,
    })
}

/// The run's primitives: its PLY, or its checkpoint before the PLY is written.
fn read_primitives(run_dir: &Path) -> Result<Primitives<f32>, LookError> {
    let ply = run_dir.join(files::PLY);
    let fmt = |path: &Path, e: &dyn std::fmt::Display| LookError::Format {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    if ply.exists() {
        crate::ply::read_ply(&ply).map_err(|e| fmt(&ply, &e))
    } else {
        let ck = run_dir.join(files::CHECKPOINT);
        crate::checkpoint::load(&ck)
            .map(|c| c.primitives)
            .map_err(|e| fmt(&ck, &e))
    }
}

/// The cameras of a path, each with a frame title.
pub fn path_cameras(
    kind: &PathKind,
    data: &Dataset,
    frames: usize,
) -> Result<Vec<(String, PinholeCamera)>, LookError> {
    let train: Vec<&PinholeCamera> = data.train.iter().map(|&i| &data.views[i].camera).collect();
    let Some(&first) = train.first() else {
        return Err(LookError::Format {
            path: data.root.clone(),
            reason: "no training view to take the path's intrinsics from".into(),
        });
    };
    let rig = Rig::of(&train, data);
    let frames = frames.max(2);
    let cam = |eye: DVec3, target: DVec3, up: DVec3| {
        let mut c = PinholeCamera::look_at(
            eye.to_array(),
            target.to_array(),
            up.to_array(),
            first.fx_px,
            first.width,
            first.height,
        );
        (c.fy_px, c.cx_px, c.cy_px) = (first.fy_px, first.cx_px, first.cy_px);
        c
    };
    Ok(match kind {
        PathKind::Views => data
            .test
            .iter()
            .map(|&i| (data.views[i].name.clone(), data.views[i].camera))
            .collect(),
        PathKind::Orbit => rig
            .orbit(frames)
            .into_iter()
            .enumerate()
            .map(|(k, eye)| (format!("orbit {k}"), cam(eye, rig.target, rig.up)))
            .collect(),
        PathKind::Spiral => rig
            .spiral(frames)
            .into_iter()
            .enumerate()
            .map(|(k, eye)| (format!("spiral {k}"), cam(eye, rig.target, rig.up)))
            .collect(),
        PathKind::File(path) => {
            let text = std::fs::read_to_string(path).map_err(|source| LookError::Io {
                path: path.clone(),
                source,
            })?;
            let file: PathFile = serde_json::from_str(&text).map_err(|e| LookError::Format {
                path: path.clone(),
                reason: format!(
                    "{e} (expected {{\"up\": [x, y, z], \"frames\": [{{\"eye\": [x, y, z], \
                     \"target\": [x, y, z]}}, …]}})"
                ),
            })?;
            let up = file.up.map_or(rig.up, DVec3::from_array);
            file.frames
                .iter()
                .enumerate()
                .map(|(k, f)| {
                    let (eye, target) = (DVec3::from_array(f.eye), DVec3::from_array(f.target));
                    if !(eye.is_finite() && target.is_finite()) || eye.distance(target) < 1e-9 {
                        return Err(LookError::Format {
                            path: path.clone(),
                            reason: format!("frame {k}: eye and target must be finite and apart"),
                        });
                    }
                    Ok((format!("frame {k}"), cam(eye, target, up)))
                })
                .collect::<Result<_, _>>()?
        }
    })
}

/// Where the training cameras are: the scene's centre they look at, their up, mean position
/// and spread.
#[derive(Debug, Clone, Copy)]
struct Rig {
    target: DVec3,
    up: DVec3,
    mean: DVec3,
    /// Orbit: radius and height above the target, the arc's start and angle, in the plane ⟂ up
    /// spanned by `e1`, `e2`.
    radius: f64,
    height: f64,
    e1: DVec3,
    e2: DVec3,
    arc_start: f64,
    arc: f64,
    /// Spiral: half-spreads along the cameras' right and up.
    spread: (f64, f64),
}

impl Rig {
    fn of(cams: &[&PinholeCamera], data: &Dataset) -> Self {
        let centres: Vec<DVec3> = cams
            .iter()
            .map(|c| DVec3::from_array(c.centre_world()))
            .collect();
        let n = centres.len().max(1) as f64;
        let mean = centres.iter().copied().sum::<DVec3>() / n;
        let axis = |row: usize| {
            cams.iter()
                .map(|c| {
                    let r = c.rotation_cam_from_world();
                    DVec3::new(r[3 * row], r[3 * row + 1], r[3 * row + 2])
                })
                .sum::<DVec3>()
                .normalize_or(DVec3::Z)
        };
        let up = -axis(1);
        let fwd = axis(2);
        let target = if data.points_m.is_empty() {
            mean + fwd
        } else {
            let median = |k: usize| {
                let mut v: Vec<f64> = data.points_m.iter().map(|p| p[k]).collect();
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            DVec3::new(median(0), median(1), median(2))
        };
        // The orbit's plane: through the target, ⟂ up.
        let flat = |p: DVec3| {
            let d = p - target;
            d - d.dot(up) * up
        };
        let e1 = flat(mean).normalize_or(up.any_orthonormal_vector());
        let e2 = up.cross(e1).normalize_or(e1.any_orthonormal_vector());
        let mut angles: Vec<f64> = centres
            .iter()
            .map(|&c| {
                let d = flat(c);
                d.dot(e2).atan2(d.dot(e1))
            })
            .collect();
        angles.sort_by(f64::total_cmp);
        let radius = centres.iter().map(|&c| flat(c).length()).sum::<f64>() / n;
        let height = centres.iter().map(|&c| (c - target).dot(up)).sum::<f64>() / n;
        // The largest gap between neighbouring camera angles (around the circle): a full turn
        // when the cameras surround the centre (no gap over 60°), else their arc.
        let tau = std::f64::consts::TAU;
        let (mut gap, mut gap_end) = (0.0, 0.0);
        for (k, &a) in angles.iter().enumerate() {
            let prev = if k == 0 {
                angles.last().copied().unwrap_or(a) - tau
            } else {
                angles[k - 1]
            };
            if a - prev > gap {
                (gap, gap_end) = (a - prev, a);
            }
        }
        let (arc_start, arc) = if angles.len() < 2 || gap < tau / 6.0 {
            (0.0, tau)
        } else {
            (gap_end, tau - gap)
        };
        let right = fwd.cross(up).normalize_or(e2);
        let up_perp = right.cross(fwd).normalize_or(up);
        let spread = |dir: DVec3| {
            let var = centres
                .iter()
                .map(|&c| (c - mean).dot(dir).powi(2))
                .sum::<f64>()
                / n;
            var.sqrt()
        };
        let floor = 0.05 * (target - mean).length().max(1e-6);
        Self {
            target,
            up,
            mean,
            radius: radius.max(floor),
            height,
            e1,
            e2,
            arc_start,
            arc,
            spread: (spread(right).max(floor), spread(up_perp).max(floor)),
        }
    }

    /// Camera centres of the orbit: a full turn, or there and back over the cameras' arc.
    fn orbit(&self, frames: usize) -> Vec<DVec3> {
        let full = (self.arc - std::f64::consts::TAU).abs() < 1e-12;
        (0..frames)
            .map(|k| {
                let t = k as f64 / frames as f64;
                let a = if full {
                    self.arc_start + self.arc * t
                } else {
                    // There and back (a triangle wave over the arc).
                    self.arc_start + self.arc * (1.0 - (2.0 * t - 1.0).abs())
                };
                self.target
                    + self.height * self.up
                    + self.radius * (a.cos() * self.e1 + a.sin() * self.e2)
            })
            .collect()
    }

    /// Camera centres of the spiral: one loop around the mean position across the spread.
    fn spiral(&self, frames: usize) -> Vec<DVec3> {
        let fwd = (self.target - self.mean).normalize_or(DVec3::Z);
        let right = fwd.cross(self.up).normalize_or(self.e2);
        let up = right.cross(fwd).normalize_or(self.up);
        (0..frames)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / frames as f64;
                self.mean + self.spread.0 * a.cos() * right + self.spread.1 * a.sin() * up
            })
            .collect()
    }
}

/// `flight.mp4` through ffmpeg or `flight.gif`, as `format` says (`Auto`: MP4 when ffmpeg runs,
/// else GIF); returns the file and how.
fn write_video(
    out: &Path,
    frames: &[PathBuf],
    fps: f64,
    format: VideoFormat,
) -> Result<(Option<PathBuf>, String), LookError> {
    if format == VideoFormat::Gif {
        let gif = out.join("flight.gif");
        write_gif(&gif, frames, fps)?;
        return Ok((Some(gif), "animated GIF".into()));
    }
    let mp4 = out.join("flight.mp4");
    let ffmpeg = Command::new("ffmpeg")
        .args(["-hide_banner", "-loglevel", "error", "-y", "-framerate"])
        .arg(format!("{fps}"))
        .arg("-i")
        .arg(out.join("frame_%05d.png"))
        // H.264 needs even sizes; yuv420p is what every player reads.
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264"])
        .args(["-pix_fmt", "yuv420p"])
        .arg(&mp4)
        .output();
    match ffmpeg {
        Ok(o) if o.status.success() && mp4.is_file() => {
            return Ok((Some(mp4), "ffmpeg (H.264 MP4)".into()));
        }
        Ok(o) if format == VideoFormat::Mp4 => {
            return Err(LookError::Format {
                path: mp4,
                reason: format!(
                    "ffmpeg failed: {}",
                    String::from_utf8_lossy(&o.stderr).trim()
                ),
            });
        }
        Err(e) if format == VideoFormat::Mp4 => {
            return Err(LookError::Format {
                path: mp4,
                reason: format!("ffmpeg does not run ({e}): install it, or --video gif"),
            });
        }
        Ok(o) => tracing::warn!(
            stderr = %String::from_utf8_lossy(&o.stderr),
            "ffmpeg failed: writing an animated GIF instead"
        ),
        Err(_) => tracing::info!("no ffmpeg on PATH: writing an animated GIF"),
    }
    let gif = out.join("flight.gif");
    write_gif(&gif, frames, fps)?;
    Ok((Some(gif), "animated GIF (no working ffmpeg on PATH)".into()))
}

/// An animated GIF of the frames (the `image` crate's encoder, looping).
fn write_gif(path: &Path, frames: &[PathBuf], fps: f64) -> Result<(), LookError> {
    use ::image::codecs::gif::{GifEncoder, Repeat};
    use ::image::{Delay, Frame};
    let file = std::fs::File::create(path).map_err(|source| LookError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let fmt = |e: &dyn std::fmt::Display| LookError::Format {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let mut enc = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    enc.set_repeat(Repeat::Infinite).map_err(|e| fmt(&e))?;
    let delay = Delay::from_numer_denom_ms((1000.0 / fps.max(0.1)).round() as u32, 1);
    for f in frames {
        let img = ::image::open(f).map_err(|e| fmt(&e))?.to_rgba8();
        enc.encode_frame(Frame::from_parts(img, 0, 0, delay))
            .map_err(|e| fmt(&e))?;
    }
    Ok(())
}
