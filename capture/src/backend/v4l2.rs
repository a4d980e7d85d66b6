//! Enumeration of real V4L2 capture devices (feature `v4l`).
//!
//! Streaming and negotiation land with the capture daemon; this module lists what is attached,
//! with the formats, sizes and rates each node offers and the role guess of [`guess_role`].

use std::path::Path;

use v4l::frameinterval::FrameIntervalEnum;
use v4l::framesize::FrameSizeEnum;
use v4l::video::Capture;

use crate::device::{DeviceInfo, FormatInfo, FourCc, FrameSize, guess_role};
use crate::error::CaptureError;

/// Lists every V4L2 node that can capture video. Nodes that are not capture devices
/// (metadata nodes of UVC cameras, codecs) are left out; a node that cannot be opened
/// (permissions) is reported as an error entry, not silently skipped.
pub fn list_devices() -> Vec<Result<DeviceInfo, CaptureError>> {
    let mut nodes: Vec<_> = v4l::context::enum_devices()
        .into_iter()
        .map(|n| n.path().to_path_buf())
        .collect();
    nodes.sort();
    nodes
        .into_iter()
        .filter_map(|path| describe(&path).transpose())
        .collect()
}

/// Describes one node; `Ok(None)` when it is not a video-capture device.
pub fn describe(path: &Path) -> Result<Option<DeviceInfo>, CaptureError> {
    let dev_err = |what: &'static str| {
        let path = path.to_path_buf();
        move |source| CaptureError::Device { path, what, source }
    };
    let dev = v4l::Device::with_path(path).map_err(dev_err("open"))?;
    let caps = dev.query_caps().map_err(dev_err("query capabilities"))?;
    if !caps
        .capabilities
        .contains(v4l::capability::Flags::VIDEO_CAPTURE)
    {
        return Ok(None);
    }
    let mut formats = Vec::new();
    for desc in dev.enum_formats().map_err(dev_err("enumerate formats"))? {
        let fourcc = FourCc(desc.fourcc.repr);
        let mut sizes = Vec::new();
        // Some drivers fail ENUM_FRAMESIZES for formats they still stream: keep the format.
        for size in dev.enum_framesizes(desc.fourcc).unwrap_or_default() {
            let FrameSizeEnum::Discrete(d) = size.size else {
                continue;
            };
            let rates_hz = dev
                .enum_frameintervals(desc.fourcc, d.width, d.height)
                .unwrap_or_default()
                .into_iter()
                .filter_map(|iv| match iv.interval {
                    FrameIntervalEnum::Discrete(f) if f.numerator > 0 => {
                        Some(f64::from(f.denominator) / f64::from(f.numerator))
                    }
                    _ => None,
                })
                .collect();
            sizes.push(FrameSize {
                width: d.width,
                height: d.height,
                rates_hz,
            });
        }
        formats.push(FormatInfo {
            fourcc,
            description: desc.description,
            sizes,
        });
    }
    let role = guess_role(&formats);
    Ok(Some(DeviceInfo {
        path: path.display().to_string(),
        driver: caps.driver,
        card: caps.card,
        bus: caps.bus,
        formats,
        role,
    }))
}
