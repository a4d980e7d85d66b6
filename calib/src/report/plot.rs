//! PNG plots that render anywhere: a plotters bitmap canvas whose text is drawn from a bundled
//! font (`assets/fonts/DejaVuSans.ttf`, compiled in, rendered by `ab_glyph`), encoded with the
//! workspace's `image` crate. No fontconfig lookup (a headless rig with no fonts installed still
//! gets labelled plots) and no second `image` version (plotters' own encoder pins an older one).
//! Used by calibration reports and the trainer's error-vs-time plots.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::{BitMapBackend, DrawingArea, IntoDrawingArea};
use plotters::style::FontStyle;

/// The font family every plot of the workspace names (`("sans-serif", size)`).
pub const FONT_FAMILY: &str = "sans-serif";

/// DejaVu Sans, bundled (licence beside it in `assets/fonts/`).
static FONT_TTF: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The bundled font did not parse (a corrupt checkout).
    #[error("the bundled plot font (assets/fonts/DejaVuSans.ttf) is not a readable TrueType font")]
    Font,
    /// Encoding or writing the PNG failed.
    #[error("cannot write plot {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// Registers the bundled font under [`FONT_FAMILY`] for every style, once per process.
pub fn register_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        [
            FontStyle::Normal,
            FontStyle::Bold,
            FontStyle::Italic,
            FontStyle::Oblique,
        ]
        .into_iter()
        .all(|style| plotters::style::register_font(FONT_FAMILY, style, FONT_TTF).is_ok())
    });
    if ok { Ok(()) } else { Err(PlotError::Font) }
}

/// An RGB canvas of `width × height` pixels to draw one plot on, then [`PngCanvas::save`].
///
/// ```ignore
/// let mut canvas = PngCanvas::new(800, 400)?;
/// {
///     let root = canvas.area();
///     root.fill(&WHITE)?;
///     // … charts …
///     root.present()?;
/// }
/// canvas.save(path)?;
/// ```
#[derive(Debug)]
pub struct PngCanvas {
    rgb: Vec<u8>,
    width: u32,
    height: u32,
}

impl PngCanvas {
    /// A white canvas; registers the bundled font first.
    pub fn new(width: u32, height: u32) -> Result<Self, PlotError> {
        register_font()?;
        let len = width as usize * height as usize * 3;
        Ok(Self {
            rgb: vec![255; len],
            width,
            height,
        })
    }

    /// The drawing area (plotters' root) over this canvas's pixels.
    pub fn area(&mut self) -> DrawingArea<BitMapBackend<'_>, Shift> {
        BitMapBackend::with_buffer(&mut self.rgb, (self.width, self.height)).into_drawing_area()
    }

    /// The canvas's pixels, RGB8 row-major.
    pub fn pixels(&self) -> &[u8] {
        &self.rgb
    }

    /// Writes the canvas as an 8-bit RGB PNG.
    pub fn save(&self, path: &Path) -> Result<(), PlotError> {
        image::save_buffer_with_format(
            path,
            &self.rgb,
            self.width,
            self.height,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|source| PlotError::Write {
            path: path.to_path_buf(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use plotters::prelude::*;

    /// Text renders from the bundled font: a caption darkens pixels that a blank canvas does not.
    #[test]
    fn captions_render_from_the_bundled_font() {
        let mut canvas = PngCanvas::new(200, 60).unwrap();
        {
            let root = canvas.area();
            root.draw(&Text::new("s3tir 20.5 dB", (10, 20), (FONT_FAMILY, 20)))
                .unwrap();
            root.present().unwrap();
        }
        let dark = canvas.pixels().chunks(3).filter(|p| p[0] < 128).count();
        assert!(
            dark > 100,
            "a 20 px caption should darken well over 100 pixels, got {dark}"
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("caption.png");
        canvas.save(&path).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back.as_raw().as_slice(), canvas.pixels(), "PNG round trip");
    }
}
