//! The board description (`board.toml`) and the board folder: which images exist, how they
//! pair, and how each file is decoded into a scalar image for detection.
//!
//! ```toml
//! [board]
//! inner_corners = [9, 6]      # cols, rows of inner corners
//! square_mm = 25.0
//! thermal_polarity = "auto"   # "auto" | "coated_dark" | "coated_bright" (thermal image values)
//! thermal_palette = "auto"    # "auto" | "ironbow" | "inferno" | "luminance" (pseudo-colour input)
//! apriltag_ids = []           # tag36h11 ids printed in the uncoated squares (see below)
//! apriltag_ratio = 0.7        # tag side (outer black border) / square side
//! ```
//!
//! Board coordinates: inner corner (c, r) sits at (c·square, r·square, 0) metres; the square
//! diagonally outward from corner (0, 0) is a *coated* square (black in RGB).
//!
//! # AprilTags (ChArUco-style)
//!
//! The board has `(cols + 1) × (rows + 1)` squares; square `(i, j)` spans
//! `[(i − 1)·s, i·s] × [(j − 1)·s, j·s]` (its corners are inner corners `(i − 1, j − 1)` to
//! `(i, j)` where those exist), so square `(0, 0)` is the coated one diagonally outward of
//! corner `(0, 0)`. A square is uncoated (white in RGB) when `i + j` is odd. Tag `apriltag_ids[k]` is printed in the k-th uncoated square counted
//! row by row (j, then i), centred, upright (its top towards row 0), with its black border
//! `apriltag_ratio` of the square side wide. Fewer ids than uncoated squares fill the first
//! squares only. RGB sees the tags; a thermal camera usually does not (printer ink and paper
//! emit alike), so tags there are used only where they are found.
//!
//! Where a board carries tags, board detection uses them (the tag board, `tagboard`): they fix
//! the corner order and the board's identity without relying on square colour (a colour-symmetric
//! board gets the same order in both cameras), and they let a partly visible board give the
//! corners around them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::detect::scalar::Palette;
use crate::error::CalibError;

/// Contents of `board.toml`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BoardFile {
    pub board: BoardSpec,
}

/// Most inner corners per board side accepted from a board file (printed boards have tens).
pub const MAX_INNER_CORNERS: u32 = 200;

/// One chessboard (emissivity-coated on its dark squares).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BoardSpec {
    /// Inner corners `[cols, rows]`.
    pub inner_corners: [u32; 2],
    /// Side of one square in millimetres.
    pub square_mm: f64,
    /// Which way the coated squares appear in thermal images.
    #[serde(default)]
    pub thermal_polarity: ThermalPolarity,
    /// Palette to invert for pseudo-colour thermal images.
    #[serde(default)]
    pub thermal_palette: Palette,
    /// tag36h11 ids printed in the uncoated squares, row by row (see the module docs).
    #[serde(default)]
    pub apriltag_ids: Vec<u32>,
    /// Tag side (outer black border) over square side.
    #[serde(default = "default_apriltag_ratio")]
    pub apriltag_ratio: f64,
}

/// How the coated squares appear in thermal images (image values, after palette inversion).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThermalPolarity {
    /// Decided per session by a vote over the thermal/RGB pairs, where the thermal corner
    /// order is made to agree with RGB (`views`).
    #[default]
    Auto,
    /// Coated squares have the lower values.
    CoatedDark,
    /// Coated squares have the higher values.
    CoatedBright,
}

/// Default [`BoardSpec::apriltag_ratio`]: the quiet zone between tag and square edge is 0.15 of
/// the square, room for a corner refinement window that does not reach the tag.
pub const DEFAULT_APRILTAG_RATIO: f64 = 0.7;

fn default_apriltag_ratio() -> f64 {
    DEFAULT_APRILTAG_RATIO
}

/// Number of tag36h11 codes (ids `0..TAG36H11_IDS`).
pub const TAG36H11_IDS: u32 = 587;

impl BoardSpec {
    pub fn cols(&self) -> u32 {
        self.inner_corners[0]
    }
    pub fn rows(&self) -> u32 {
        self.inner_corners[1]
    }
    pub fn corner_count(&self) -> usize {
        (self.cols() * self.rows()) as usize
    }
    pub fn square_m(&self) -> f64 {
        self.square_mm * 1e-3
    }

    /// Inner corners in board coordinates (metres), row-major.
    pub fn object_points_m(&self) -> Vec<DVec3> {
        let s = self.square_m();
        (0..self.rows())
            .flat_map(|r| {
                (0..self.cols()).map(move |c| DVec3::new(f64::from(c) * s, f64::from(r) * s, 0.0))
            })
            .collect()
    }

    /// True when a 180° rotation maps the board's colouring onto itself (cols + rows even):
    /// then corner ordering cannot come from square colours alone.
    pub fn is_colour_symmetric(&self) -> bool {
        (self.cols() + self.rows()).is_multiple_of(2)
    }

    /// True when the board carries AprilTags.
    pub fn has_tags(&self) -> bool {
        !self.apriltag_ids.is_empty()
    }

    /// Squares `(i, j)` that carry a tag, in `apriltag_ids` order (see the module docs).
    pub fn tag_squares(&self) -> Vec<(u32, u32)> {
        (0..=self.rows())
            .flat_map(|j| (0..=self.cols()).map(move |i| (i, j)))
            .filter(|(i, j)| (i + j) % 2 == 1)
            .take(self.apriltag_ids.len())
            .collect()
    }

    /// Outer border corners of the tag `id` in board units of one square (inner corner
    /// `(c, r)` at `(c, r)`), in the AprilTag library's order (bottom-left, bottom-right,
    /// top-right, top-left of the upright tag); `None` when the board does not carry `id`.
    pub fn tag_corners_sq(&self, id: u32) -> Option<[glam::DVec2; 4]> {
        let k = self.apriltag_ids.iter().position(|&t| t == id)?;
        let (i, j) = *self.tag_squares().get(k)?;
        let c = glam::DVec2::new(f64::from(i) - 0.5, f64::from(j) - 0.5);
        let h = 0.5 * self.apriltag_ratio;
        Some([
            c + glam::DVec2::new(-h, h),
            c + glam::DVec2::new(h, h),
            c + glam::DVec2::new(h, -h),
            c + glam::DVec2::new(-h, -h),
        ])
    }

    /// Checks sizes.
    pub fn validate(&self, path: &Path) -> Result<(), CalibError> {
        if self.cols() < 3 || self.rows() < 2 {
            return Err(CalibError::BoardFile {
                path: path.to_path_buf(),
                reason: format!(
                    "inner_corners = {:?}: need at least 3x2 inner corners",
                    self.inner_corners
                ),
            });
        }
        // Before any count is multiplied out (sizes come from a file).
        if self.cols() > MAX_INNER_CORNERS || self.rows() > MAX_INNER_CORNERS {
            return Err(CalibError::BoardFile {
                path: path.to_path_buf(),
                reason: format!(
                    "inner_corners = {:?}: at most {MAX_INNER_CORNERS} per side",
                    self.inner_corners
                ),
            });
        }
        if self.cols() == self.rows() {
            return Err(CalibError::BoardFile {
                path: path.to_path_buf(),
                reason: format!(
                    "inner_corners = {:?}: square boards are 90°-symmetric and their corner order cannot be fixed; use cols != rows (one even, one odd is best)",
                    self.inner_corners
                ),
            });
        }
        if !(self.square_mm.is_finite() && self.square_mm > 0.0) {
            return Err(CalibError::BoardFile {
                path: path.to_path_buf(),
                reason: format!("square_mm = {} must be positive", self.square_mm),
            });
        }
        self.validate_tags(path)
    }

    fn validate_tags(&self, path: &Path) -> Result<(), CalibError> {
        let err = |reason: String| CalibError::BoardFile {
            path: path.to_path_buf(),
            reason,
        };
        let white = ((self.cols() + 1) * (self.rows() + 1) / 2) as usize;
        if self.apriltag_ids.len() > white {
            return Err(err(format!(
                "apriltag_ids lists {} tags but the board has {white} uncoated squares",
                self.apriltag_ids.len()
            )));
        }
        let mut seen = std::collections::BTreeSet::new();
        for &id in &self.apriltag_ids {
            if id >= TAG36H11_IDS {
                return Err(err(format!(
                    "apriltag_ids: {id} is not a tag36h11 id (0..{TAG36H11_IDS})"
                )));
            }
            if !seen.insert(id) {
                return Err(err(format!("apriltag_ids: {id} is listed twice")));
            }
        }
        if !(self.apriltag_ratio > 0.3 && self.apriltag_ratio <= 0.9) {
            return Err(err(format!(
                "apriltag_ratio = {}: a tag must be 0.3–0.9 of the square side (its white quiet zone lies inside the square)",
                self.apriltag_ratio
            )));
        }
        Ok(())
    }

    /// Reads and validates `board.toml`.
    pub fn load(path: &Path) -> Result<Self, CalibError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalibError::BoardFileRead {
            path: path.to_path_buf(),
            source,
        })?;
        let file: BoardFile =
            toml::from_str(&text).map_err(|source| CalibError::BoardFileSyntax {
                path: path.to_path_buf(),
                source,
            })?;
        file.board.validate(path)?;
        Ok(file.board)
    }
}

/// The two cameras of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Camera {
    Thermal,
    Rgb,
}

impl Camera {
    pub const BOTH: [Camera; 2] = [Camera::Thermal, Camera::Rgb];
    pub fn name(self) -> &'static str {
        match self {
            Camera::Thermal => "thermal",
            Camera::Rgb => "rgb",
        }
    }
    pub fn index(self) -> usize {
        match self {
            Camera::Thermal => 0,
            Camera::Rgb => 1,
        }
    }
}

/// One view key: the pairing stem and the file each camera contributes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewFiles {
    /// Pairing key: the stem with a leading `name_` prefix dropped.
    pub key: String,
    /// `[thermal, rgb]` files; either may be missing.
    pub files: [Option<PathBuf>; 2],
}

/// A file skipped or rejected, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FileProblem {
    pub path: PathBuf,
    pub reason: String,
}

/// Image extensions read from the camera folders.
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "tif", "tiff", "jpg", "jpeg", "pgm"];

/// The pairing key of a file stem: `thermal_0001` → `0001`, `0001` → `0001`. Only a leading
/// alphabetic prefix followed by `_` is dropped, so `img_01` and `rgb_01` both pair as `01`.
pub fn pairing_key(stem: &str) -> String {
    if let Some((prefix, rest)) = stem.split_once('_')
        && !prefix.is_empty()
        && !rest.is_empty()
        && prefix.chars().all(|c| c.is_ascii_alphabetic())
    {
        return rest.to_string();
    }
    stem.to_string()
}

/// Lists `dir/thermal` and `dir/rgb` and pairs their images. Files that are not images are
/// reported as problems; a missing camera folder is not an error (one-camera calibration).
pub fn list_views(dir: &Path) -> Result<(Vec<ViewFiles>, Vec<FileProblem>), CalibError> {
    if !dir.is_dir() {
        return Err(CalibError::BoardFolder {
            path: dir.to_path_buf(),
            reason: "not a directory".into(),
        });
    }
    let mut views: BTreeMap<String, [Option<PathBuf>; 2]> = BTreeMap::new();
    let mut problems = Vec::new();
    for camera in Camera::BOTH {
        let sub = dir.join(camera.name());
        if !sub.is_dir() {
            continue;
        }
        let entries = std::fs::read_dir(&sub).map_err(|source| CalibError::BoardFolderRead {
            path: sub.clone(),
            source,
        })?;
        let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        files.sort();
        for path in files {
            if !path.is_file() {
                continue;
            }
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
                .unwrap_or_default();
            if !IMAGE_EXTENSIONS.contains(&ext.as_str()) {
                problems.push(FileProblem {
                    path,
                    reason: format!("not an image (extension {ext:?})"),
                });
                continue;
            }
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            let key = pairing_key(stem);
            let slot = &mut views.entry(key).or_default()[camera.index()];
            if let Some(previous) = slot {
                problems.push(FileProblem {
                    path: path.clone(),
                    reason: format!("same pairing key as {}; ignored", previous.display()),
                });
            } else {
                *slot = Some(path);
            }
        }
    }
    let views = views
        .into_iter()
        .map(|(key, files)| ViewFiles { key, files })
        .collect();
    Ok((views, problems))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairing_key_drops_only_an_alphabetic_prefix() {
        assert_eq!(pairing_key("thermal_0001"), "0001");
        assert_eq!(pairing_key("rgb_0001"), "0001");
        assert_eq!(pairing_key("0001"), "0001");
        assert_eq!(pairing_key("left01"), "left01");
        assert_eq!(
            pairing_key("2024_01"),
            "2024_01",
            "numeric prefixes are part of the stem"
        );
    }

    #[test]
    fn board_toml_parses_with_defaults() {
        let file: BoardFile = toml::from_str("[board]\ninner_corners = [9, 6]\nsquare_mm = 25.0\n")
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.board.corner_count(), 54);
        assert_eq!(file.board.thermal_polarity, ThermalPolarity::Auto);
        let p = file.board.object_points_m();
        assert!(
            (p[10] - DVec3::new(0.025, 0.025, 0.0)).length() < 1e-12,
            "corner (1,1) at {}",
            p[10]
        );
        assert!(
            !file.board.is_colour_symmetric(),
            "9x6 has 10x7 squares: asymmetric"
        );
        assert!(!file.board.has_tags());
        assert_eq!(file.board.apriltag_ratio, DEFAULT_APRILTAG_RATIO);
    }

    #[test]
    fn tags_sit_in_uncoated_squares_row_by_row() {
        let toml = "[board]\ninner_corners = [4, 3]\nsquare_mm = 20.0\napriltag_ids = [7, 3, 9]\napriltag_ratio = 0.5\n";
        let board = toml::from_str::<BoardFile>(toml)
            .unwrap_or_else(|e| panic!("{e}"))
            .board;
        board
            .validate(Path::new("board.toml"))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(board.tag_squares(), vec![(1, 0), (3, 0), (0, 1)]);
        // Tag 3 sits in square (3, 0): centre (2.5, -0.5), half side 0.25.
        let c = board
            .tag_corners_sq(3)
            .unwrap_or_else(|| panic!("tag 3 is on the board"));
        let want = [(2.25, -0.25), (2.75, -0.25), (2.75, -0.75), (2.25, -0.75)];
        for (got, (x, y)) in c.iter().zip(want) {
            assert!(
                (got.x - x).abs() < 1e-12 && (got.y - y).abs() < 1e-12,
                "tag 3 corners {c:?}"
            );
        }
        assert!(
            board.tag_corners_sq(4).is_none(),
            "id 4 is not on the board"
        );
    }

    /// Sizes from a hostile or mistyped board.toml are refused before anything is multiplied
    /// out (`(cols + 1) * (rows + 1)` overflowed u32 on [4294967295, 2]).
    #[test]
    fn huge_boards_are_refused_not_overflowed() {
        for corners in [
            "[4294967295, 2]",
            "[3, 4294967295]",
            "[201, 6]",
            "[100000, 100001]",
        ] {
            let text = format!("[board]\ninner_corners = {corners}\nsquare_mm = 20.0\n");
            let board = toml::from_str::<BoardFile>(&text)
                .unwrap_or_else(|e| panic!("{e}"))
                .board;
            let Err(err) = board.validate(Path::new("b/board.toml")) else {
                panic!("{corners} must be refused");
            };
            assert!(
                err.to_string().contains("at most 200 per side"),
                "{corners}: {err}"
            );
        }
    }

    #[test]
    fn bad_tag_lists_are_refused_with_the_reason() {
        let base = "[board]\ninner_corners = [4, 3]\nsquare_mm = 20.0\n";
        for (extra, want) in [
            ("apriltag_ids = [1, 1]\n", "listed twice"),
            ("apriltag_ids = [600]\n", "not a tag36h11 id"),
            (
                "apriltag_ids = [1]\napriltag_ratio = 1.0\n",
                "apriltag_ratio",
            ),
            (
                "apriltag_ids = [0,1,2,3,4,5,6,7,8,9,10]\n",
                "uncoated squares",
            ),
        ] {
            let board = toml::from_str::<BoardFile>(&format!("{base}{extra}"))
                .unwrap_or_else(|e| panic!("{e}"))
                .board;
            let Err(err) = board.validate(Path::new("b/board.toml")) else {
                panic!("{extra} must be refused");
            };
            let msg = err.to_string();
            assert!(
                msg.contains(want) && msg.contains("b/board.toml"),
                "{extra}: {msg}"
            );
        }
    }
}
