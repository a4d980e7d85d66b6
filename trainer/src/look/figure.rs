//! Figures a person reads: a row of palette panels, each titled, with its colour bar and tick
//! labels under it — kelvin and °C for temperatures, the unit's name otherwise. Drawn on the
//! workspace's plot canvas (`s3tir_calib::report::plot`: bundled font, no system fonts).

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use s3tir_calib::report::plot::{FONT_FAMILY, PngCanvas};

use super::LookError;
use super::image::Scale;

/// 0 °C in kelvin.
pub const ZERO_CELSIUS_K: f64 = 273.15;

/// Panels wider than this are shown at 1/k of their size (block means), k the smallest
/// integer that fits.
const MAX_PANEL_PX: usize = 640;
/// Panels narrower than this are shown k times their size (pixels repeated), k the smallest
/// integer that reaches it: room for the bar's labels.
const MIN_PANEL_PX: usize = 200;
/// Horizontal room one tick label needs (px).
const TICK_ROOM_PX: usize = 90;
const MARGIN: i32 = 10;
const TITLE_PX: i32 = 24;
const BAR_PX: i32 = 14;
const LABEL_PX: i32 = 17;
const FONT_PX: f64 = 14.0;
const TICKS: usize = 5;

/// One panel: a plane, its scale and title.
#[derive(Debug, Clone)]
pub struct Panel {
    pub title: String,
    pub plane: Vec<f32>,
    pub width: usize,
    pub height: usize,
    pub scale: Scale,
}

impl Panel {
    /// Whether the bar is labelled in °C as well (values in kelvin; a difference of
    /// temperatures, unit `K error`, is the same number in °C and gets no second line).
    fn celsius(&self) -> bool {
        self.scale.unit == "K"
    }

    /// How the panel is shown: the plane's size divided by the smallest integer that fits
    /// [`MAX_PANEL_PX`], or multiplied by the smallest that reaches [`MIN_PANEL_PX`].
    fn shown(&self) -> Shown {
        let w = self.width.max(1);
        if w > MAX_PANEL_PX {
            let k = w.div_ceil(MAX_PANEL_PX);
            Shown {
                down: k,
                up: 1,
                width: (w / k).max(1),
                height: (self.height / k).max(1),
            }
        } else {
            let u = MIN_PANEL_PX.div_ceil(w).max(1);
            Shown {
                down: 1,
                up: u,
                width: w * u,
                height: self.height * u,
            }
        }
    }

    /// The value shown at pixel (`x`, `y`) of the shown panel.
    fn sample(&self, s: &Shown, x: usize, y: usize) -> f64 {
        if s.down > 1 {
            block_mean(&self.plane, self.width, x * s.down, y * s.down, s.down)
        } else {
            f64::from(self.plane[(y / s.up) * self.width + x / s.up])
        }
    }
}

/// A panel's shown size: `down`-fold smaller or `up`-fold larger than its plane.
#[derive(Debug, Clone, Copy)]
struct Shown {
    down: usize,
    up: usize,
    width: usize,
    height: usize,
}

/// The text of a tick at value `v` (kelvin: `v K`; the second line: `°C`).
fn tick_text(v: f64, span: f64, unit: &str) -> String {
    let digits = if span >= 50.0 {
        0
    } else if span >= 5.0 {
        1
    } else if span >= 0.5 {
        2
    } else {
        3
    };
    match unit {
        "K" | "K error" => format!("{v:.digits$} K"),
        "beta" | "β" => format!("β {v:.digits$}"),
        _ => format!("{v:.digits$}"),
    }
}

/// Draws `panels` side by side into the PNG `path`, each with its colour bar; returns the
/// figure's size.
pub fn draw_row(path: &Path, panels: &[Panel]) -> Result<(u32, u32), LookError> {
    let (canvas, width, height) = compose_row(path, panels)?;
    canvas.save(path).map_err(|e| LookError::Plot {
        path: path.to_path_buf(),
        source: e.to_string().into(),
    })?;
    Ok((width, height))
}

/// [`draw_row`] of one panel, with the panel's scale also in the PNG's text chunks
/// ([`super::image`]): a frame of a fly-through that reads back as values.
pub fn draw_panel_with_scale(path: &Path, panel: &Panel) -> Result<(u32, u32), LookError> {
    let (canvas, width, height) = compose_row(path, std::slice::from_ref(panel))?;
    super::image::write_rgb_with_scale(
        path,
        canvas.pixels(),
        width as usize,
        height as usize,
        Some(&panel.scale),
    )?;
    Ok((width, height))
}

/// Where a panel's pixels start in a figure of panels (the first panel's top-left corner) and
/// how many figure pixels one plane pixel spans (plane pixel (x, y) of a panel shown `up`-fold
/// is at `origin + up·(x, y)`; shrunk panels, `up` 0, are block means).
pub fn panel_origin_and_up(panel: &Panel) -> ((u32, u32), u32) {
    let s = panel.shown();
    (
        (MARGIN as u32, (MARGIN + TITLE_PX) as u32),
        if s.down > 1 { 0 } else { s.up as u32 },
    )
}

/// The figure's canvas and size (`path`: the file it is for, named in errors).
fn compose_row(path: &Path, panels: &[Panel]) -> Result<(PngCanvas, u32, u32), LookError> {
    if panels.is_empty() {
        return Err(LookError::Format {
            path: path.to_path_buf(),
            reason: "a figure needs at least one panel".into(),
        });
    }
    for p in panels {
        if p.plane.len() != p.width * p.height {
            return Err(LookError::Format {
                path: path.to_path_buf(),
                reason: format!(
                    "panel {:?} has {} values, not {}×{}",
                    p.title,
                    p.plane.len(),
                    p.width,
                    p.height
                ),
            });
        }
    }
    let plot_err = |e: &dyn std::fmt::Display| LookError::Plot {
        path: path.to_path_buf(),
        source: e.to_string().into(),
    };
    let shown: Vec<Shown> = panels.iter().map(Panel::shown).collect();
    let lines = if panels.iter().any(Panel::celsius) {
        2
    } else {
        1
    };
    let max_h = shown.iter().map(|s| s.height).max().unwrap_or(1) as i32;
    let width = MARGIN + shown.iter().map(|s| s.width as i32 + MARGIN).sum::<i32>();
    let height = MARGIN + TITLE_PX + max_h + 6 + BAR_PX + 4 + lines * LABEL_PX + MARGIN;
    let mut canvas = PngCanvas::new(width as u32, height as u32).map_err(|e| plot_err(&e))?;
    {
        let root = canvas.area();
        let font = (FONT_FAMILY, FONT_PX).into_font().color(&BLACK);
        let mut x0 = MARGIN;
        for (p, sh) in panels.iter().zip(&shown) {
            let (w, h) = (sh.width, sh.height);
            root.draw(&Text::new(
                p.title.clone(),
                (x0, MARGIN),
                font.clone().pos(Pos::new(HPos::Left, VPos::Top)),
            ))
            .map_err(|e| plot_err(&e))?;
            let y0 = MARGIN + TITLE_PX;
            for y in 0..h {
                for x in 0..w {
                    let v = p.sample(sh, x, y);
                    let [r, g, b] = p.scale.colour(v);
                    root.draw_pixel((x0 + x as i32, y0 + y as i32), &RGBColor(r, g, b))
                        .map_err(|e| plot_err(&e))?;
                }
            }
            // The colour bar under the panel, its ends at the scale's ends.
            let yb = y0 + max_h + 6;
            for x in 0..w {
                let t = x as f64 / (w.max(2) - 1) as f64;
                let [r, g, b] = p.scale.palette.colour(t);
                root.draw(&PathElement::new(
                    vec![(x0 + x as i32, yb), (x0 + x as i32, yb + BAR_PX - 1)],
                    RGBColor(r, g, b),
                ))
                .map_err(|e| plot_err(&e))?;
            }
            let span = p.scale.hi - p.scale.lo;
            let ticks = (w / TICK_ROOM_PX).clamp(2, TICKS);
            for i in 0..ticks {
                let t = i as f64 / (ticks - 1) as f64;
                let v = p.scale.lo + t * span;
                let x = x0 + (t * (w.max(2) - 1) as f64).round() as i32;
                let hpos = match i {
                    0 => HPos::Left,
                    i if i == ticks - 1 => HPos::Right,
                    _ => HPos::Center,
                };
                root.draw(&PathElement::new(
                    vec![(x, yb + BAR_PX - 4), (x, yb + BAR_PX + 2)],
                    BLACK,
                ))
                .map_err(|e| plot_err(&e))?;
                let style = font.clone().pos(Pos::new(hpos, VPos::Top));
                let ty = yb + BAR_PX + 4;
                root.draw(&Text::new(
                    tick_text(v, span, &p.scale.unit),
                    (x, ty),
                    style.clone(),
                ))
                .map_err(|e| plot_err(&e))?;
                if p.celsius() {
                    root.draw(&Text::new(
                        format!("{} °C", tick_text(v - ZERO_CELSIUS_K, span, "")),
                        (x, ty + LABEL_PX),
                        style,
                    ))
                    .map_err(|e| plot_err(&e))?;
                }
            }
            x0 += w as i32 + MARGIN;
        }
        root.present().map_err(|e| plot_err(&e))?;
    }
    Ok((canvas, width as u32, height as u32))
}

/// Mean of the finite values of the `k × k` block at (`x`, `y`) of a `width`-wide plane (NaN
/// when none is finite).
fn block_mean(plane: &[f32], width: usize, x: usize, y: usize, k: usize) -> f64 {
    let height = plane.len() / width.max(1);
    let (mut sum, mut n) = (0.0, 0);
    for yy in y..(y + k).min(height) {
        for xx in x..(x + k).min(width) {
            let v = f64::from(plane[yy * width + xx]);
            if v.is_finite() {
                sum += v;
                n += 1;
            }
        }
    }
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use s3tir_calib::model::palette::Colormap;

    /// A panel's pixels are its plane through the palette, and its bar runs from the palette's
    /// first colour to its last under the panel.
    #[test]
    fn a_row_draws_each_panel_through_its_palette_with_its_bar() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("row.png");
        let (w, h) = (64, 48);
        let ramp: Vec<f32> = (0..w * h).map(|i| 290.0 + (i % w) as f32 / 4.0).collect();
        let panels = [
            Panel {
                title: "recorded".into(),
                plane: ramp.clone(),
                width: w,
                height: h,
                scale: Scale::new(Colormap::Ironbow, 290.0, 305.75, "K"),
            },
            Panel {
                title: "error".into(),
                plane: vec![0.0; w * h],
                width: w,
                height: h,
                scale: Scale::new(Colormap::Diverging, -1.0, 1.0, "K error"),
            },
        ];
        let (fw, fh) = draw_row(&path, &panels).unwrap();
        let img = ::image::open(&path).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (fw, fh));
        let at = |x: i32, y: i32| img.get_pixel(x as u32, y as u32).0;
        // 64 px wide is shown 4× (the smallest factor reaching 200 px).
        let (u, sw) = (4, 4 * w as i32);
        let y0 = MARGIN + TITLE_PX;
        for x in [0, 10, 40, 63] {
            let want = panels[0].scale.colour(290.0 + f64::from(x) / 4.0);
            assert_eq!(
                at(MARGIN + u * x + 1, y0 + 5),
                want,
                "panel pixel at column {x}"
            );
        }
        let x1 = MARGIN + sw + MARGIN;
        assert_eq!(
            at(x1 + 20, y0 + 5),
            Colormap::Diverging.colour(0.5),
            "zero error is the diverging palette's middle"
        );
        let yb = y0 + u * h as i32 + 6 + 2;
        assert_eq!(
            at(MARGIN, yb),
            Colormap::Ironbow.colour(0.0),
            "bar starts cold"
        );
        assert_eq!(
            at(MARGIN + sw - 1, yb),
            Colormap::Ironbow.colour(1.0),
            "bar ends hot"
        );
        assert_eq!(
            fw as i32,
            MARGIN + 2 * (sw + MARGIN),
            "two panels side by side"
        );
        // The tick labels (two lines: K and °C) darken pixels under the bar.
        let dark = (yb + BAR_PX..fh as i32)
            .flat_map(|y| (0..fw as i32).map(move |x| (x, y)))
            .filter(|&(x, y)| at(x, y).iter().all(|&c| c < 100))
            .count();
        assert!(
            dark > 150,
            "tick labels drawn under the bars: {dark} dark pixels"
        );
    }

    #[test]
    fn ticks_say_kelvin_and_celsius_at_a_sensible_precision() {
        assert_eq!(tick_text(295.123, 20.0, "K"), "295.1 K");
        assert_eq!(tick_text(295.123 - ZERO_CELSIUS_K, 20.0, ""), "22.0");
        assert_eq!(tick_text(0.5, 1.0, "normalised"), "0.50");
        assert_eq!(tick_text(-0.25, 0.4, "K error"), "-0.250 K");
    }
}
