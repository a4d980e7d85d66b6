//! Reading a session for the poses stage: one scan for every frame's numbers (no pixels kept),
//! then targeted reads that write only the frames the stage chose.
//!
//! Frames are named by their *session* sequence (capture's [`SessionSequences`]): the
//! device's V4L2 sequence, continued past a reopen (a re-enumerated or stalled camera restarts
//! at 0), so two frames of a stream never share a name and every read numbers them alike.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use s3tir_capture::frame::{CapturedFrame, FfcState};
use s3tir_capture::session::{SessionItem, SessionSequences, parse_recorded, read_session};

use super::PosesError;
use crate::progress::Progress;

/// The two streams of a rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Stream {
    Thermal,
    Rgb,
}

impl Stream {
    pub fn name(self) -> &'static str {
        match self {
            Stream::Thermal => "thermal",
            Stream::Rgb => "rgb",
        }
    }

    /// The file name a frame of this stream gets in COLMAP's workspace (keyframes: RGB as
    /// JPEG) and, for thermal frames, in the dataset.
    pub fn file_name(self, sequence: u32) -> String {
        match self {
            Stream::Thermal => format!("thermal_{sequence:08}.png"),
            Stream::Rgb => format!("rgb_{sequence:08}.jpg"),
        }
    }

    /// The file name a frame of this stream gets in the dataset's `images/`: PNG for both
    /// (thermal 16-bit words, RGB 8-bit as decoded, never re-encoded lossily).
    pub fn dataset_file_name(self, sequence: u32) -> String {
        match self {
            Stream::Thermal => format!("thermal_{sequence:08}.png"),
            Stream::Rgb => format!("rgb_{sequence:08}.png"),
        }
    }

    /// The inverse of [`Stream::file_name`].
    pub fn parse_file_name(name: &str) -> Option<(Stream, u32)> {
        let base = name.rsplit('/').next()?;
        let (stream, rest) = if let Some(r) = base.strip_prefix("thermal_") {
            (Stream::Thermal, r)
        } else if let Some(r) = base.strip_prefix("rgb_") {
            (Stream::Rgb, r)
        } else {
            return None;
        };
        let digits = rest.split('.').next()?;
        digits.parse().ok().map(|s| (stream, s))
    }
}

/// The numbers of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInfo {
    pub sequence: u32,
    pub monotonic_ns: u64,
    pub ffc_frozen: bool,
    /// Variance of the 4-neighbour Laplacian over the variance of the image (scale-free).
    pub sharpness: f64,
}

/// What one read of a session found.
#[derive(Debug, Clone, Default)]
pub struct SessionScan {
    pub path: PathBuf,
    /// In capture-time order.
    pub thermal: Vec<FrameInfo>,
    pub rgb: Vec<FrameInfo>,
    pub thermal_size: Option<(u32, u32)>,
    pub rgb_size: Option<(u32, u32)>,
    /// Frames the recorder or the device dropped (sequence gaps), both streams.
    pub dropped: u64,
    /// Frames that did not parse (counted, skipped).
    pub unreadable: u64,
    pub truncated: bool,
    /// What the reader said about a truncated session, and how much was readable.
    pub note: Option<String>,
    /// Attached files by name (a calibration recorded with the session).
    pub attachments: BTreeMap<String, Vec<u8>>,
}

/// Sharpness of a grey image (row-major, `w × h`): the variance of the 4-neighbour Laplacian
/// divided by the variance of the image, so that contrast and units cancel. Motion blur lowers
/// it; a flat image gives 0.
pub fn sharpness(grey: &[f32], w: usize, h: usize) -> f64 {
    if w < 3 || h < 3 || grey.len() < w * h {
        return 0.0;
    }
    let (mut s, mut s2, mut n) = (0.0f64, 0.0f64, 0.0f64);
    for &v in &grey[..w * h] {
        s += f64::from(v);
        s2 += f64::from(v) * f64::from(v);
        n += 1.0;
    }
    let var = (s2 / n - (s / n).powi(2)).max(0.0);
    if var <= 0.0 {
        return 0.0;
    }
    let (mut l, mut l2, mut m) = (0.0f64, 0.0f64, 0.0f64);
    for y in 1..h - 1 {
        let row = y * w;
        for x in 1..w - 1 {
            let c = f64::from(grey[row + x]);
            let lap = f64::from(grey[row + x - 1])
                + f64::from(grey[row + x + 1])
                + f64::from(grey[row - w + x])
                + f64::from(grey[row + w + x])
                - 4.0 * c;
            l += lap;
            l2 += lap * lap;
            m += 1.0;
        }
    }
    ((l2 / m - (l / m).powi(2)).max(0.0)) / var
}

fn grey_of_rgb(rgb: &[u8]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|p| 0.299 * f32::from(p[0]) + 0.587 * f32::from(p[1]) + 0.114 * f32::from(p[2]))
        .collect()
}

/// Reads the whole session once: every frame's numbers (module docs). `progress` hears one
/// stage without a total, one item per readable frame.
pub fn scan_session(path: &Path, progress: &dyn Progress) -> Result<SessionScan, PosesError> {
    let mut scan = SessionScan {
        path: path.to_path_buf(),
        ..SessionScan::default()
    };
    progress.start(&format!("scanning {}", path.display()), None);
    let mut ids = SessionSequences::default();
    let outcome = read_session(path, |item| {
        match item {
            SessionItem::Frame(f) => {
                let sequence = ids.next(f.raw.stream, f.raw.sequence);
                let Ok(frame) = parse_recorded(path, &f) else {
                    scan.unreadable += 1;
                    return Ok(());
                };
                progress.advance(1);
                match frame {
                    CapturedFrame::Thermal(t) => {
                        let grey: Vec<f32> = t.pixels.iter().map(|&v| f32::from(v)).collect();
                        scan.thermal_size.get_or_insert((t.width, t.height));
                        scan.thermal.push(FrameInfo {
                            sequence,
                            monotonic_ns: t.time.monotonic_ns,
                            ffc_frozen: t.ffc == FfcState::InProgress,
                            sharpness: sharpness(&grey, t.width as usize, t.height as usize),
                        });
                    }
                    CapturedFrame::Rgb(r) => {
                        let Ok(px) = r.to_rgb8(&path.display().to_string()) else {
                            scan.unreadable += 1;
                            return Ok(());
                        };
                        scan.rgb_size.get_or_insert((r.width, r.height));
                        scan.rgb.push(FrameInfo {
                            sequence,
                            monotonic_ns: r.time.monotonic_ns,
                            ffc_frozen: false,
                            sharpness: sharpness(
                                &grey_of_rgb(&px),
                                r.width as usize,
                                r.height as usize,
                            ),
                        });
                    }
                }
            }
            SessionItem::Drop(d) => scan.dropped += u64::from(d.missing),
            _ => {}
        }
        Ok(())
    })
    .map_err(|source| PosesError::SessionRead { source });
    progress.finish();
    let outcome = outcome?;
    scan.thermal.sort_by_key(|f| f.monotonic_ns);
    scan.rgb.sort_by_key(|f| f.monotonic_ns);
    scan.truncated = outcome.truncated;
    scan.attachments = outcome.attachments;
    if outcome.truncated {
        scan.note = Some(format!(
            "session truncated ({}): used what is readable, {} complete chunks: {} thermal and {} RGB frames",
            outcome
                .truncation_reason
                .unwrap_or_else(|| "no footer".into()),
            outcome.chunks,
            scan.thermal.len(),
            scan.rgb.len()
        ));
    }
    Ok(scan)
}

/// The 8-bit grey image COLMAP gets of a thermal frame: the words stretched between the
/// session-wide 1st and 99th percentiles `(lo, hi)` (one mapping for all frames, so SIFT sees
/// the same contrast everywhere).
fn thermal_to_grey8(pixels: &[u16], lo: f64, hi: f64) -> Vec<u8> {
    let span = (hi - lo).max(1.0);
    pixels
        .iter()
        .map(|&v| {
            ((f64::from(v) - lo) / span * 255.0)
                .clamp(0.0, 255.0)
                .round() as u8
        })
        .collect()
}

/// Writes the chosen frames of `stream` into `dir` under [`Stream::file_name`]: RGB as JPEG
/// (quality 95), thermal as 8-bit grey PNG stretched for feature extraction. Returns the names
/// by sequence.
pub fn write_keyframes(
    path: &Path,
    stream: Stream,
    keyframes: &[FrameInfo],
    dir: &Path,
) -> Result<BTreeMap<u32, String>, PosesError> {
    std::fs::create_dir_all(dir).map_err(|e| PosesError::Write {
        path: dir.to_path_buf(),
        source: Box::new(e),
    })?;
    let wanted: BTreeSet<u32> = keyframes.iter().map(|k| k.sequence).collect();
    let mut names = BTreeMap::new();
    let mut thermal_samples: Vec<u16> = Vec::new();
    let mut pending: Vec<(u32, Vec<u16>, u32, u32)> = Vec::new();
    let mut ids = SessionSequences::default();
    read_session(path, |item| {
        let SessionItem::Frame(f) = item else {
            return Ok(());
        };
        let sequence = ids.next(f.raw.stream, f.raw.sequence);
        let is_thermal = f.raw.stream == s3tir_capture::frame::StreamKind::Thermal;
        if is_thermal != (stream == Stream::Thermal) || !wanted.contains(&sequence) {
            return Ok(());
        }
        let Ok(frame) = parse_recorded(path, &f) else {
            return Ok(());
        };
        let invalid = |p: &Path, reason: &str| s3tir_capture::CaptureError::Export {
            path: p.to_path_buf(),
            reason: reason.to_owned(),
        };
        let write_err = |p: &Path, what: &'static str, source: s3tir_capture::error::BoxedCause| {
            s3tir_capture::CaptureError::ExportWrite {
                path: p.to_path_buf(),
                what,
                source,
            }
        };
        match (stream, frame) {
            (Stream::Rgb, CapturedFrame::Rgb(r)) => {
                let name = stream.file_name(sequence);
                let p = dir.join(&name);
                let px = r.to_rgb8(&path.display().to_string())?;
                let img = image::RgbImage::from_raw(r.width, r.height, px)
                    .ok_or_else(|| invalid(&p, "decoded size does not match"))?;
                let file = std::fs::File::create(&p)
                    .map_err(|e| write_err(&p, "creating the keyframe", Box::new(e)))?;
                let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(
                    std::io::BufWriter::new(file),
                    95,
                );
                enc.encode_image(&img)
                    .map_err(|e| write_err(&p, "encoding the keyframe", Box::new(e)))?;
                names.insert(sequence, name);
            }
            (Stream::Thermal, CapturedFrame::Thermal(t)) => {
                // Percentiles need every keyframe: sample, write after the read.
                thermal_samples.extend(t.pixels.iter().step_by(7));
                pending.push((sequence, t.pixels, t.width, t.height));
            }
            _ => {}
        }
        Ok(())
    })
    .map_err(|source| PosesError::SessionRead { source })?;
    if !pending.is_empty() {
        thermal_samples.sort_unstable();
        let q =
            |f: f64| f64::from(thermal_samples[((thermal_samples.len() - 1) as f64 * f) as usize]);
        let (lo, hi) = (q(0.01), q(0.99));
        for (seq, pixels, w, h) in pending {
            let name = stream.file_name(seq);
            let p = dir.join(&name);
            let img = image::GrayImage::from_raw(w, h, thermal_to_grey8(&pixels, lo, hi))
                .ok_or_else(|| PosesError::Output {
                    path: p.clone(),
                    reason: "pixel count does not match size".into(),
                })?;
            img.save(&p).map_err(|e| PosesError::Write {
                path: p.clone(),
                source: Box::new(e),
            })?;
            names.insert(seq, name);
        }
    }
    Ok(names)
}

/// Reads the thermal frames `sequences` (session sequences) and hands each one's words to
/// `write`.
pub fn for_thermal_frames(
    path: &Path,
    sequences: &BTreeSet<u32>,
    mut write: impl FnMut(u32, u32, u32, &[u16]) -> Result<(), PosesError>,
) -> Result<(), PosesError> {
    for_frames(
        path,
        sequences,
        &BTreeSet::new(),
        |seq, w, h, pixels| match pixels {
            Pixels::Thermal(words) => write(seq, w, h, words),
            Pixels::Rgb8(_) => Ok(()),
        },
    )
}

/// The pixels [`for_frames`] hands over: a thermal frame's words as recorded, or an RGB frame
/// decoded to 8-bit RGB (row-major, 3 bytes a pixel), as recorded otherwise (not undistorted).
#[derive(Debug, Clone, Copy)]
pub enum Pixels<'a> {
    Thermal(&'a [u16]),
    Rgb8(&'a [u8]),
}

/// Reads the thermal frames `thermal` and the RGB frames `rgb` (session sequences) in one pass
/// over the session and hands each one's pixels to `write`. A frame that does not parse or
/// decode is not handed over (the caller checks that every wanted frame came).
pub fn for_frames(
    path: &Path,
    thermal: &BTreeSet<u32>,
    rgb: &BTreeSet<u32>,
    mut write: impl FnMut(u32, u32, u32, Pixels<'_>) -> Result<(), PosesError>,
) -> Result<(), PosesError> {
    let mut failure: Option<PosesError> = None;
    let mut ids = SessionSequences::default();
    let label = path.display().to_string();
    read_session(path, |item| {
        let SessionItem::Frame(f) = item else {
            return Ok(());
        };
        let sequence = ids.next(f.raw.stream, f.raw.sequence);
        let wanted = match f.raw.stream {
            s3tir_capture::frame::StreamKind::Thermal => thermal,
            s3tir_capture::frame::StreamKind::Rgb => rgb,
        };
        if failure.is_some() || !wanted.contains(&sequence) {
            return Ok(());
        }
        let result = match parse_recorded(path, &f) {
            Ok(CapturedFrame::Thermal(t)) => {
                write(sequence, t.width, t.height, Pixels::Thermal(&t.pixels))
            }
            Ok(CapturedFrame::Rgb(r)) => match r.to_rgb8(&label) {
                Ok(px) => write(sequence, r.width, r.height, Pixels::Rgb8(&px)),
                Err(_) => Ok(()),
            },
            Err(_) => Ok(()),
        };
        if let Err(e) = result {
            failure = Some(e);
        }
        Ok(())
    })
    .map_err(|source| PosesError::SessionRead { source })?;
    failure.map_or(Ok(()), Err)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn file_names_carry_stream_and_sequence() {
        for (s, q) in [(Stream::Thermal, 0), (Stream::Rgb, 123_456)] {
            let n = s.file_name(q);
            assert_eq!(Stream::parse_file_name(&n), Some((s, q)), "{n}");
            let d = s.dataset_file_name(q);
            assert!(d.ends_with(".png"), "{d}");
            assert_eq!(Stream::parse_file_name(&d), Some((s, q)), "{d}");
            assert_eq!(
                Stream::parse_file_name(&format!("images/{n}")),
                Some((s, q))
            );
        }
        assert_eq!(Stream::parse_file_name("0001.png"), None);
    }

    #[test]
    fn blur_lowers_sharpness_and_flat_is_zero() {
        let (w, h) = (64usize, 48usize);
        let sharp: Vec<f32> = (0..w * h)
            .map(|i| {
                if ((i % w) / 4 + (i / w) / 4).is_multiple_of(2) {
                    0.0
                } else {
                    1.0
                }
            })
            .collect();
        // 5-tap horizontal box blur.
        let blurred: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                (0..5usize)
                    .map(|k| sharp[y * w + (x + k).saturating_sub(2).min(w - 1)])
                    .sum::<f32>()
                    / 5.0
            })
            .collect();
        let (a, b) = (sharpness(&sharp, w, h), sharpness(&blurred, w, h));
        // A 5-px horizontal blur of 4-px squares about halves it (measured 5.70 → 2.97).
        assert!(
            b < 0.6 * a,
            "blur must lower sharpness: sharp {a}, blurred {b}"
        );
        assert_eq!(sharpness(&vec![3.0; w * h], w, h), 0.0, "flat image");
        // Contrast cancels.
        let scaled: Vec<f32> = sharp.iter().map(|v| 100.0 * v + 7.0).collect();
        assert!((sharpness(&scaled, w, h) - a).abs() < 1e-6 * a);
    }
}
