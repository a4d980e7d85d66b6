//! RGB cameras through nokhwa (feature `nokhwa`, off by default): `--rgb nokhwa:N` opens camera
//! index N with nokhwa's V4L2 bindings behind the same [`crate::backend::FrameSource`] trait as
//! [`crate::backend::v4l2_stream`], for cameras where nokhwa's handling fits better than ours.
//!
//! Limits of nokhwa 0.10, and why the V4L2 backend stays the default:
//! - no 16-bit formats: thermal cores (Y16) are never served through it;
//! - no driver timestamps and no sequence numbers: a frame is stamped with `CLOCK_MONOTONIC`
//!   when nokhwa hands it over (later than the V4L2 capture stamp by the driver → user
//!   latency, typically a few ms, with its jitter, which shows in the pairing's sync error) and
//!   numbered consecutively on arrival, so frames lost inside the driver are invisible (`drops`
//!   stays 0 for this stream);
//! - `frame()` blocks without a timeout: a camera that stops delivering stalls the reader
//!   thread until it returns or is unplugged (then nokhwa errors and the daemon reconnects).
//!
//! Format choice is the V4L2 backend's ([`crate::backend::v4l2_negotiate::negotiate`]: MJPEG else YUYV,
//! largest size within `--rgb-max-size`) over nokhwa's format list translated by
//! [`crate::backend::nokhwa_backend::format_infos`]; only MJPEG and YUYV are recorded (bytes untouched,
//! as with V4L2). The translation is pure and unit-tested without a camera.

use crate::device::{FormatInfo, FourCc, FrameSize};

/// Pixel formats nokhwa reports (mirror of `nokhwa::utils::FrameFormat`, so the mapping is
/// built and tested without the feature).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NokhwaFormat {
    Mjpeg,
    Yuyv,
    Nv12,
    Gray,
    RawRgb,
    RawBgr,
}

impl NokhwaFormat {
    /// The V4L2 fourcc of the format. Formats without one (nokhwa's decoded RGB/BGR) are
    /// listed under a made-up code the negotiation never picks.
    pub fn fourcc(self) -> FourCc {
        match self {
            Self::Mjpeg => FourCc::MJPG,
            Self::Yuyv => FourCc::YUYV,
            Self::Nv12 => FourCc::NV12,
            Self::Gray => FourCc::GREY,
            Self::RawRgb => FourCc(*b"RGB3"),
            Self::RawBgr => FourCc(*b"BGR3"),
        }
    }
}

/// One camera format as nokhwa lists it: format, size, frame rate (Hz).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NokhwaOffer {
    pub format: NokhwaFormat,
    pub width: u32,
    pub height: u32,
    pub fps: u32,
}

/// nokhwa's flat (format, size, rate) list → the per-format size lists the negotiation takes
/// (formats in first-seen order, sizes sorted, rates merged per size).
pub fn format_infos(offers: &[NokhwaOffer]) -> Vec<FormatInfo> {
    let mut out: Vec<FormatInfo> = Vec::new();
    for o in offers {
        let fourcc = o.format.fourcc();
        let idx = match out.iter().position(|f| f.fourcc == fourcc) {
            Some(i) => i,
            None => {
                out.push(FormatInfo {
                    fourcc,
                    description: format!("{:?} (nokhwa)", o.format),
                    sizes: Vec::new(),
                });
                out.len() - 1
            }
        };
        let sizes = &mut out[idx].sizes;
        let rate = f64::from(o.fps);
        match sizes
            .iter_mut()
            .find(|s| (s.width, s.height) == (o.width, o.height))
        {
            Some(s) => {
                if o.fps > 0 && !s.rates_hz.contains(&rate) {
                    s.rates_hz.push(rate);
                }
            }
            None => sizes.push(FrameSize {
                width: o.width,
                height: o.height,
                rates_hz: if o.fps > 0 { vec![rate] } else { Vec::new() },
            }),
        }
    }
    for f in &mut out {
        f.sizes.sort_by_key(|s| (s.width, s.height));
        for s in &mut f.sizes {
            s.rates_hz.sort_by(f64::total_cmp);
        }
    }
    out
}

/// `nokhwa:N` → camera index N.
pub fn parse_spec(device: &str) -> Option<u32> {
    device.strip_prefix("nokhwa:")?.parse().ok()
}

#[cfg(feature = "nokhwa")]
pub use imp::NokhwaSource;

#[cfg(feature = "nokhwa")]
mod imp {
    use std::time::Duration;

    use nokhwa::Camera;
    use nokhwa::pixel_format::RgbFormat;
    use nokhwa::utils::{
        ApiBackend, CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType,
        Resolution,
    };

    use super::{NokhwaFormat, NokhwaOffer, format_infos};
    use crate::backend::FrameSource;
    use crate::backend::stamp::monotonic_now_ns;
    use crate::backend::v4l2_negotiate::negotiate;
    use crate::device::{FourCc, Role};
    use crate::error::CaptureError;
    use crate::frame::{FfcState, RawFrame, StreamKind, ThermalUnits};

    fn from_nokhwa(f: FrameFormat) -> NokhwaFormat {
        match f {
            FrameFormat::MJPEG => NokhwaFormat::Mjpeg,
            FrameFormat::YUYV => NokhwaFormat::Yuyv,
            FrameFormat::NV12 => NokhwaFormat::Nv12,
            FrameFormat::GRAY => NokhwaFormat::Gray,
            FrameFormat::RAWRGB => NokhwaFormat::RawRgb,
            FrameFormat::RAWBGR => NokhwaFormat::RawBgr,
        }
    }

    /// An RGB camera streaming through nokhwa (see the module doc for what it cannot do).
    pub struct NokhwaSource {
        name: String,
        camera: Camera,
        fourcc: FourCc,
        sequence: u32,
    }

    impl std::fmt::Debug for NokhwaSource {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.debug_struct("NokhwaSource")
                .field("name", &self.name)
                .field("fourcc", &self.fourcc)
                .field("sequence", &self.sequence)
                .finish_non_exhaustive()
        }
    }

    impl NokhwaSource {
        /// Opens camera `index`, negotiates MJPEG/YUYV within `max_size` and starts streaming.
        pub fn open(index: u32, max_size: Option<(u32, u32)>) -> Result<Self, CaptureError> {
            let name = format!("nokhwa:{index}");
            let err = |what: &str, e: nokhwa::NokhwaError| CaptureError::DeviceFailed {
                device: name.clone(),
                what: what.to_owned(),
                source: e.into(),
            };
            let mut camera = Camera::with_backend(
                CameraIndex::Index(index),
                RequestedFormat::new::<RgbFormat>(RequestedFormatType::None),
                ApiBackend::Video4Linux,
            )
            .map_err(|e| err("open", e))?;
            let offers: Vec<NokhwaOffer> = camera
                .compatible_camera_formats()
                .map_err(|e| err("list formats", e))?
                .iter()
                .map(|f| NokhwaOffer {
                    format: from_nokhwa(f.format()),
                    width: f.width(),
                    height: f.height(),
                    fps: f.frame_rate(),
                })
                .collect();
            let n = negotiate(&name, Role::Rgb, &format_infos(&offers), max_size)?;
            let format = if n.fourcc == FourCc::MJPG {
                FrameFormat::MJPEG
            } else {
                FrameFormat::YUYV
            };
            let fps = n.rate_hz.map_or(30, |r| r.round() as u32);
            camera
                .set_camera_requset(RequestedFormat::new::<RgbFormat>(
                    RequestedFormatType::Exact(CameraFormat::new(
                        Resolution::new(n.width, n.height),
                        format,
                        fps,
                    )),
                ))
                .map_err(|e| err("set format", e))?;
            camera
                .open_stream()
                .map_err(|e| err("start streaming", e))?;
            Ok(Self {
                name,
                camera,
                fourcc: n.fourcc,
                sequence: 0,
            })
        }
    }

    impl FrameSource for NokhwaSource {
        fn name(&self) -> &str {
            &self.name
        }

        /// Blocks until nokhwa delivers a frame (it has no timeout: `_timeout` is not honoured).
        fn next_frame(&mut self, _timeout: Duration) -> Result<Option<RawFrame>, CaptureError> {
            let buf = self
                .camera
                .frame()
                .map_err(|e| CaptureError::DeviceFailed {
                    device: self.name.clone(),
                    what: "frame".into(),
                    source: e.into(),
                })?;
            // No driver stamp in nokhwa 0.10: stamped on arrival.
            let monotonic_ns = monotonic_now_ns();
            let res = buf.resolution();
            let fourcc = from_nokhwa(buf.source_frame_format()).fourcc();
            let sequence = self.sequence;
            self.sequence = self.sequence.wrapping_add(1);
            Ok(Some(RawFrame {
                stream: StreamKind::Rgb,
                fourcc,
                width: res.width(),
                height: res.height(),
                bytes_per_line: if fourcc == FourCc::YUYV {
                    res.width() * 2
                } else {
                    0
                },
                telemetry_rows: 0,
                units: ThermalUnits::RawCounts,
                ffc_hint: FfcState::Unknown,
                sequence,
                monotonic_ns,
                payload: buf.buffer().to_vec(),
            }))
        }
    }

    impl Drop for NokhwaSource {
        fn drop(&mut self) {
            if let Err(e) = self.camera.stop_stream() {
                tracing::warn!(device = %self.name, "stop streaming: {e}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! Proves: nokhwa's format list translates into the negotiation's per-format sizes (rates
    //! merged, sizes sorted), the shared negotiation then picks MJPEG at the largest size
    //! within the limit (YUYV when no MJPEG, an error naming the device when neither), and
    //! `nokhwa:N` specs parse. The camera itself is exercised by the `hardware` test below,
    //! which skips visibly without one (and only exists with `--features nokhwa`).
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::backend::v4l2_negotiate::negotiate;
    use crate::device::Role;

    fn offer(format: NokhwaFormat, width: u32, height: u32, fps: u32) -> NokhwaOffer {
        NokhwaOffer {
            format,
            width,
            height,
            fps,
        }
    }

    #[test]
    fn offers_translate_and_negotiate_like_v4l2() {
        use NokhwaFormat::*;
        let offers = [
            offer(Yuyv, 640, 480, 30),
            offer(Mjpeg, 1920, 1080, 30),
            offer(Mjpeg, 1280, 720, 60),
            offer(Mjpeg, 1280, 720, 30),
            offer(Mjpeg, 1280, 720, 30),
            offer(RawRgb, 1920, 1080, 5),
        ];
        let infos = format_infos(&offers);
        assert_eq!(
            infos.iter().map(|f| f.fourcc).collect::<Vec<_>>(),
            vec![FourCc::YUYV, FourCc::MJPG, FourCc(*b"RGB3")]
        );
        let mjpg = &infos[1];
        assert_eq!(
            mjpg.sizes
                .iter()
                .map(|s| (s.width, s.height, s.rates_hz.clone()))
                .collect::<Vec<_>>(),
            vec![(1280, 720, vec![30.0, 60.0]), (1920, 1080, vec![30.0])],
            "sizes sorted, duplicate rates merged"
        );
        let n = negotiate("nokhwa:0", Role::Rgb, &infos, Some((1280, 720))).unwrap();
        assert_eq!(
            (n.fourcc, n.width, n.height, n.rate_hz),
            (FourCc::MJPG, 1280, 720, Some(60.0))
        );
        let n = negotiate("nokhwa:0", Role::Rgb, &infos, None).unwrap();
        assert_eq!((n.fourcc, n.width, n.height), (FourCc::MJPG, 1920, 1080));
        // YUYV only: YUYV. Neither: an error naming the device.
        let n = negotiate("nokhwa:0", Role::Rgb, &format_infos(&offers[..1]), None).unwrap();
        assert_eq!(n.fourcc, FourCc::YUYV);
        let e = negotiate("nokhwa:3", Role::Rgb, &format_infos(&offers[5..]), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("nokhwa:3") && e.contains("MJPG"), "{e}");
    }

    #[test]
    fn specs_parse() {
        assert_eq!(parse_spec("nokhwa:2"), Some(2));
        assert_eq!(parse_spec("nokhwa:x"), None);
        assert_eq!(parse_spec("/dev/video2"), None);
    }

    #[cfg(feature = "nokhwa")]
    #[test]
    fn hardware_camera_streams_a_frame() {
        let cams = nokhwa::query(nokhwa::utils::ApiBackend::Video4Linux).unwrap_or_default();
        if cams.is_empty() {
            crate::skip::skip("camera", "no camera for nokhwa (no /dev/video* device)");
            return;
        }
        let mut src = NokhwaSource::open(0, Some((1280, 720))).unwrap();
        let f =
            crate::backend::FrameSource::next_frame(&mut src, std::time::Duration::from_secs(5))
                .unwrap()
                .unwrap();
        assert!(
            !f.payload.is_empty() && f.width > 0 && f.height > 0,
            "a frame with pixels: {}x{}, {} bytes",
            f.width,
            f.height,
            f.payload.len()
        );
    }
}
