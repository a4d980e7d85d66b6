//! AprilTag (tag36h11) detection in 8-bit grey images, through the `apriltag` crate (the
//! AprilRobotics C library, built from its bundled source: see `.cargo/config.toml`).
//!
//! # Pixel convention
//!
//! The C library puts the origin at the *top-left corner* of the top-left pixel: pixel `(i, j)`
//! covers `[i, i + 1) × [j, j + 1)` and its centre is `(i + 0.5, j + 0.5)`. This is visible in
//! its source: boundary points between pixels are shifted by `delta = 0.5` "for pixel center
//! bias" (`apriltag_quad_thresh.c`), bilinear sampling uses `floor(px - 0.5)`, and decimated
//! coordinates are mapped back with `(p - 0.5)·d + 0.5` (`apriltag.c`).
//!
//! s3tir puts the origin at the *centre* of the top-left pixel (OpenCV's), so every coordinate
//! returned here is the library's minus 0.5 px on both axes ([`from_apriltag_px`]).
//! `tests/apriltag.rs` checks this on a rendered tag whose edges lie on known pixel
//! boundaries, and against the C library's own ground truth (which is in the C convention).
//!
//! # Corner order
//!
//! Corners keep the library's order: they wind around the tag starting at the tag's
//! bottom-left corner (tag frame, code bits read upright), then bottom-right, top-right,
//! top-left. For an upright tag in an image (y down) that is: bottom-left, bottom-right,
//! top-right, top-left — counter-clockwise as seen on screen.
//!
//! Corners are the outer corners of the black border (the 8×8-cell square of tag36h11), not of
//! the white quiet zone.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use apriltag::families::{ApriltagFamily, Tag36h11};
use apriltag::{Detector, Family, Image};
use image::{GrayImage, RgbImage};

/// Offset added to a C-library coordinate to get an s3tir coordinate (pixel-centre origin).
pub const APRILTAG_TO_OURS_PX: f64 = -0.5;

/// Largest image side the C library accepts (its quad segmentation packs coordinates in 16 bits).
pub const MAX_SIDE_PX: u32 = 32767;

/// Errors of tag detection. Each variant names the image (or the parameter) it is about.
#[derive(Debug, Clone, thiserror::Error)]
pub enum TagError {
    /// A detector setting out of range.
    #[error("AprilTag detector: {parameter} = {value} is not valid ({why})")]
    InvalidConfig {
        parameter: &'static str,
        value: f64,
        why: &'static str,
    },
    /// The C detector could not be created.
    #[error("AprilTag detector could not be created")]
    Detector {
        #[source]
        source: apriltag::Error,
    },
    /// The image cannot be handed to the detector (empty, too large).
    #[error("AprilTag detection in {image} ({width}x{height} px): {reason}")]
    Image {
        image: PathBuf,
        width: u32,
        height: u32,
        reason: String,
    },
    /// The detector's image buffer could not be allocated.
    #[error("AprilTag detection in {image} ({width}x{height} px)")]
    Buffer {
        image: PathBuf,
        width: u32,
        height: u32,
        #[source]
        source: apriltag::Error,
    },
    /// The detector returned something that does not fit the typed result.
    #[error("AprilTag detection in {image}: {reason}")]
    Detection { image: PathBuf, reason: String },
}

/// Detector settings. `Default` gives tag36h11, `quad_decimate = 1`, `refine_edges = false`,
/// up to 2 corrected bits (the C library's default), every id allowed.
#[derive(Debug, Clone, PartialEq)]
pub struct TagConfig {
    /// Quad detection runs on the image decimated by this factor (1 = full resolution; bits
    /// are always decoded at full resolution). Must be ≥ 1.
    pub quad_decimate: f32,
    /// Snap quad edges to strong nearby gradients (the C library applies it at every
    /// decimation, despite what the Rust crate's doc says). Off by default: on a rendered tag
    /// with edges exactly on pixel boundaries it moves the otherwise exact corners by about
    /// -1/8 px on both axes (its 0.25 px search step; `tests/apriltag.rs` pins this). Turn it on
    /// with `quad_decimate > 1`, where the unrefined quad is coarse.
    pub refine_edges: bool,
    /// Gaussian blur (σ in px) of the segmented image; 0 = none. Must be ≥ 0.
    pub quad_sigma: f32,
    /// Bit errors corrected when decoding (0..=3; each bit allowed costs memory and false
    /// positives).
    pub max_bits_corrected: u8,
    /// Keep only these ids (`None` = keep every id). A board lists its ids in `board.toml`
    /// (`apriltag_ids`); an empty list there means "any id" — see [`TagConfig::with_board_ids`].
    pub allowed_ids: Option<BTreeSet<u32>>,
}

impl Default for TagConfig {
    fn default() -> Self {
        Self {
            quad_decimate: 1.0,
            refine_edges: false,
            quad_sigma: 0.0,
            max_bits_corrected: 2,
            allowed_ids: None,
        }
    }
}

impl TagConfig {
    /// Restrict to a board's `apriltag_ids`; an empty list keeps every id.
    pub fn with_board_ids(mut self, ids: &[u32]) -> Self {
        self.allowed_ids = if ids.is_empty() {
            None
        } else {
            Some(ids.iter().copied().collect())
        };
        self
    }

    fn validate(&self) -> Result<(), TagError> {
        if !(self.quad_decimate.is_finite() && self.quad_decimate >= 1.0) {
            return Err(TagError::InvalidConfig {
                parameter: "quad_decimate",
                value: f64::from(self.quad_decimate),
                why: "must be a finite factor >= 1",
            });
        }
        if !(self.quad_sigma.is_finite() && self.quad_sigma >= 0.0) {
            return Err(TagError::InvalidConfig {
                parameter: "quad_sigma",
                value: f64::from(self.quad_sigma),
                why: "must be finite and >= 0",
            });
        }
        if self.max_bits_corrected > 3 {
            return Err(TagError::InvalidConfig {
                parameter: "max_bits_corrected",
                value: f64::from(self.max_bits_corrected),
                why: "at most 3 bits (the C library's quick-decode table grows combinatorially)",
            });
        }
        Ok(())
    }
}

/// One decoded tag, coordinates in pixels with the origin at the centre of the top-left pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct TagDetection {
    /// tag36h11 id (0..587).
    pub id: u32,
    /// Bit errors corrected to decode it.
    pub hamming: u32,
    /// Mean difference between the intensity of a bit and the decision threshold (higher is
    /// more confident; the C library's `decision_margin`).
    pub decision_margin: f32,
    /// Image of the tag centre (homography of the tag-frame origin), `[x, y]` px.
    pub centre_px: [f64; 2],
    /// Outer corners of the black border, `[x, y]` px, in the library's winding order
    /// (bottom-left, bottom-right, top-right, top-left of the upright tag).
    pub corners_px: [[f64; 2]; 4],
}

/// Map a C-library coordinate (origin at the top-left pixel's corner) to ours (its centre).
pub fn from_apriltag_px(p: [f64; 2]) -> [f64; 2] {
    [p[0] + APRILTAG_TO_OURS_PX, p[1] + APRILTAG_TO_OURS_PX]
}

/// Map one of our coordinates to the C library's convention.
pub fn to_apriltag_px(p: [f64; 2]) -> [f64; 2] {
    [p[0] - APRILTAG_TO_OURS_PX, p[1] - APRILTAG_TO_OURS_PX]
}

/// BT.601 luma `0.299 R + 0.587 G + 0.114 B`, rounded. For a decoded JPEG this reproduces the
/// file's Y plane to ±1 grey level (what the C library's own tests detect on), unlike
/// `image`'s `to_luma8`, which uses Rec. 709 weights.
pub fn luma_bt601(rgb: &RgbImage) -> GrayImage {
    GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let [r, g, b] = rgb.get_pixel(x, y).0;
        let y_val = (299 * u32::from(r) + 587 * u32::from(g) + 114 * u32::from(b) + 500) / 1000;
        // y_val ≤ 255 because the weights sum to 1000.
        image::Luma([u8::try_from(y_val).unwrap_or(u8::MAX)])
    })
}

/// A configured tag36h11 detector (single-threaded; not `Send`, create one per thread).
pub struct TagDetector {
    inner: Detector,
    config: TagConfig,
}

impl std::fmt::Debug for TagDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TagDetector")
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl TagDetector {
    /// Create a tag36h11 detector with `config`.
    pub fn new(config: TagConfig) -> Result<Self, TagError> {
        config.validate()?;
        let mut inner = Detector::builder()
            .add_family_bits(Family::tag_36h11(), usize::from(config.max_bits_corrected))
            .build()
            .map_err(|source| TagError::Detector { source })?;
        inner.set_thread_number(1);
        inner.set_decimation(config.quad_decimate);
        inner.set_refine_edges(config.refine_edges);
        inner.set_sigma(config.quad_sigma);
        Ok(Self { inner, config })
    }

    pub fn config(&self) -> &TagConfig {
        &self.config
    }

    /// Detect tags in `grey`; `image` names it in errors and logs. Results are filtered to
    /// the allowed ids and sorted by id, then by first corner (y, x), so output order is
    /// deterministic.
    pub fn detect(
        &mut self,
        grey: &GrayImage,
        image: &Path,
    ) -> Result<Vec<TagDetection>, TagError> {
        let (width, height) = grey.dimensions();
        let image_err = |reason: String| TagError::Image {
            image: image.to_path_buf(),
            width,
            height,
            reason,
        };
        if width == 0 || height == 0 {
            return Err(image_err("the image is empty".to_string()));
        }
        if width > MAX_SIDE_PX || height > MAX_SIDE_PX {
            return Err(image_err(format!(
                "sides above {MAX_SIDE_PX} px are not supported by the C detector"
            )));
        }
        let w = width as usize;
        let h = height as usize;
        let mut buf = Image::zeros_with_alignment(w, h, apriltag::image_buf::DEFAULT_ALIGNMENT_U8)
            .map_err(|source| TagError::Buffer {
                image: image.to_path_buf(),
                width,
                height,
                source,
            })?;
        let stride = buf.stride();
        let dst = buf.as_slice_mut();
        for (row, src) in grey.as_raw().chunks_exact(w).enumerate() {
            let start = row * stride;
            let Some(line) = dst.get_mut(start..start + w) else {
                return Err(image_err(format!(
                    "detector buffer too small for row {row} (stride {stride})"
                )));
            };
            line.copy_from_slice(src);
        }

        let raw = self.inner.detect(&buf);
        let found = raw.len();
        let mut out = Vec::with_capacity(found);
        for det in raw {
            let detection_err = |what: &str, value: usize| TagError::Detection {
                image: image.to_path_buf(),
                reason: format!("{what} {value} does not fit in u32"),
            };
            let id = u32::try_from(det.id()).map_err(|_| detection_err("id", det.id()))?;
            if let Some(allowed) = &self.config.allowed_ids
                && !allowed.contains(&id)
            {
                tracing::debug!(image = %image.display(), id, "tag id not on the board, dropped");
                continue;
            }
            let hamming = u32::try_from(det.hamming())
                .map_err(|_| detection_err("hamming", det.hamming()))?;
            let corners = det.corners();
            out.push(TagDetection {
                id,
                hamming,
                decision_margin: det.decision_margin(),
                centre_px: from_apriltag_px(det.center()),
                corners_px: corners.map(from_apriltag_px),
            });
        }
        out.sort_by(|a, b| {
            a.id.cmp(&b.id)
                .then(a.corners_px[0][1].total_cmp(&b.corners_px[0][1]))
                .then(a.corners_px[0][0].total_cmp(&b.corners_px[0][0]))
        });
        tracing::debug!(
            image = %image.display(),
            found,
            kept = out.len(),
            "AprilTag detection"
        );
        Ok(out)
    }
}

/// The tag36h11 codes and bit layout, read once from the C library's own family table (so a
/// rendered tag is exactly what the detector decodes).
struct FamilyTable {
    codes: Vec<u64>,
    /// Cell `(x, y)` of each code bit, most significant first, in the 8×8 black-bordered square.
    bits: Vec<(u32, u32)>,
}

fn tag36h11_table() -> &'static FamilyTable {
    static TABLE: OnceLock<FamilyTable> = OnceLock::new();
    TABLE.get_or_init(|| {
        // The family is created once and deliberately leaked: the table is read for the life
        // of the process (about 5 KB).
        let raw = Tag36h11::default().into_raw();
        // SAFETY: `raw` is the non-null family the C library's `tag36h11_create` returned,
        // never freed (leaked above); `codes` holds `ncodes` entries and `bit_x`/`bit_y`
        // hold `nbits` entries each, as `tag36h11.c` allocates them.
        unsafe {
            let f = &*raw;
            let codes = std::slice::from_raw_parts(f.codes, f.ncodes as usize).to_vec();
            let bx = std::slice::from_raw_parts(f.bit_x, f.nbits as usize);
            let by = std::slice::from_raw_parts(f.bit_y, f.nbits as usize);
            FamilyTable {
                codes,
                bits: bx.iter().copied().zip(by.iter().copied()).collect(),
            }
        }
    })
}

/// The 8×8 cells of tag36h11 `id` (outer black border included), `cells[y][x]`, true = white;
/// `None` for an id outside the family. Printing (or rendering) these upright gives the tag
/// the detector decodes as `id`.
pub fn tag36h11_cells(id: u32) -> Option<[[bool; 8]; 8]> {
    let table = tag36h11_table();
    let code = *table.codes.get(id as usize)?;
    let n = table.bits.len();
    let mut cells = [[false; 8]; 8];
    for (i, &(x, y)) in table.bits.iter().enumerate() {
        if (code >> (n - 1 - i)) & 1 == 1
            && let Some(cell) = cells
                .get_mut(y as usize)
                .and_then(|row| row.get_mut(x as usize))
        {
            *cell = true;
        }
    }
    Some(cells)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn family_table_is_tag36h11() {
        let table = tag36h11_table();
        assert_eq!(table.codes.len(), 587, "tag36h11 has 587 codes");
        assert_eq!(table.bits.len(), 36);
        // The first two codes of tag36h11.c (also pinned in tests/apriltag.rs).
        assert_eq!(table.codes[0], 0x0000_000d_7e00_984b);
        assert_eq!(table.codes[1], 0x0000_000d_da66_4ca7);
        let cells = tag36h11_cells(0).unwrap();
        assert!(
            cells[0].iter().chain(cells[7].iter()).all(|c| !c),
            "the outer border is black"
        );
        assert!(tag36h11_cells(587).is_none());
    }

    #[test]
    fn rendered_cells_decode_as_their_id() {
        for id in [0u32, 5, 34, 586] {
            let cells = tag36h11_cells(id).unwrap();
            let cell = 6u32;
            let mut img = GrayImage::from_pixel(12 * cell, 12 * cell, image::Luma([255]));
            for (y, row) in cells.iter().enumerate() {
                for (x, white) in row.iter().enumerate() {
                    for dy in 0..cell {
                        for dx in 0..cell {
                            let v = if *white { 255 } else { 0 };
                            img.put_pixel(
                                (x as u32 + 2) * cell + dx,
                                (y as u32 + 2) * cell + dy,
                                image::Luma([v]),
                            );
                        }
                    }
                }
            }
            let mut det = TagDetector::new(TagConfig::default()).unwrap();
            let found = det.detect(&img, Path::new("cells")).unwrap();
            assert_eq!(
                found.iter().map(|t| t.id).collect::<Vec<_>>(),
                vec![id],
                "tag rendered from tag36h11_cells({id})"
            );
        }
    }

    #[test]
    fn convention_round_trip() {
        let p = [12.25, -3.5];
        assert_eq!(to_apriltag_px(from_apriltag_px(p)), p);
        assert_eq!(from_apriltag_px([0.5, 0.5]), [0.0, 0.0]);
    }

    #[test]
    fn board_ids_empty_means_all() {
        assert_eq!(TagConfig::default().with_board_ids(&[]).allowed_ids, None);
        let ids = TagConfig::default().with_board_ids(&[3, 1]).allowed_ids;
        assert_eq!(ids, Some([1, 3].into_iter().collect()));
    }

    #[test]
    fn rejects_bad_config_and_empty_image() {
        let bad = TagConfig {
            quad_decimate: 0.5,
            ..TagConfig::default()
        };
        assert!(matches!(
            TagDetector::new(bad),
            Err(TagError::InvalidConfig {
                parameter: "quad_decimate",
                ..
            })
        ));
        let mut det = TagDetector::new(TagConfig::default()).unwrap();
        let err = det
            .detect(&GrayImage::new(0, 0), Path::new("empty.png"))
            .unwrap_err();
        assert!(
            err.to_string().contains("empty.png"),
            "error should name the image: {err}"
        );
    }

    #[test]
    fn bt601_weights() {
        let rgb = RgbImage::from_fn(3, 1, |x, _| match x {
            0 => image::Rgb([255, 0, 0]),
            1 => image::Rgb([0, 255, 0]),
            _ => image::Rgb([0, 0, 255]),
        });
        let y = luma_bt601(&rgb);
        assert_eq!(y.as_raw(), &vec![76, 150, 29], "BT.601 luma of R, G, B");
    }
}
