//! Colour palettes of thermal images, one table each: what draws thermal values for people
//! (the trainer's coloured meshes) and what maps pseudo-colour frames back to scalars
//! (calibration's detection, the trainer's pseudo-colour datasets).
//!
//! Each palette is an approximation of the camera makers' palette: a few key colours
//! interpolated linearly to 256 entries (ironbow: black → blue → magenta → orange → yellow →
//! white; inferno: matplotlib's, 9 of its colours; grey: white hot). A camera's own table
//! differs slightly, so a pseudo-colour frame mapped back through one is never radiometric, only
//! a monotone proxy of the scene's temperatures. One more palette is for signed differences,
//! not temperatures: diverging (Moreland's cool-warm: blue below zero, light grey at zero, red
//! above), what the trainer's run report draws errors with.

use std::sync::OnceLock;

/// A colour palette for thermal values (index 0: coldest, 255: hottest).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Colormap {
    Ironbow,
    Inferno,
    /// Black (cold) to white (hot).
    Grey,
    /// Signed values: blue (negative) → light grey (0 at the middle entry) → red (positive).
    Diverging,
}

/// Ironbow's key colours (position in [0, 1], RGB in 0..=255).
const IRONBOW: [(f32, [f32; 3]); 7] = [
    (0.0, [0.0, 0.0, 0.0]),
    (0.15, [32.0, 0.0, 140.0]),
    (0.35, [145.0, 0.0, 155.0]),
    (0.55, [225.0, 65.0, 40.0]),
    (0.75, [250.0, 160.0, 0.0]),
    (0.9, [255.0, 225.0, 60.0]),
    (1.0, [255.0, 255.0, 255.0]),
];

const GREY: [(f32, [f32; 3]); 2] = [(0.0, [0.0, 0.0, 0.0]), (1.0, [255.0, 255.0, 255.0])];

/// Cool-warm's key colours (K. Moreland, "Diverging Color Maps for Scientific Visualization",
/// 2009: its end points and middle, with one colour between each).
const DIVERGING: [(f32, [f32; 3]); 5] = [
    (0.0, [59.0, 76.0, 192.0]),
    (0.25, [141.0, 176.0, 254.0]),
    (0.5, [221.0, 221.0, 221.0]),
    (0.75, [244.0, 154.0, 123.0]),
    (1.0, [180.0, 4.0, 38.0]),
];

/// Inferno's key colours (matplotlib's, every 32nd entry).
const INFERNO: [(f32, [f32; 3]); 9] = [
    (0.0, [0.0, 0.0, 4.0]),
    (0.125, [31.0, 12.0, 72.0]),
    (0.25, [85.0, 15.0, 109.0]),
    (0.375, [136.0, 34.0, 106.0]),
    (0.5, [186.0, 54.0, 85.0]),
    (0.625, [227.0, 89.0, 51.0]),
    (0.75, [249.0, 140.0, 10.0]),
    (0.875, [249.0, 201.0, 50.0]),
    (1.0, [252.0, 255.0, 164.0]),
];

impl Colormap {
    /// Every palette.
    pub const ALL: [Colormap; 4] = [
        Colormap::Ironbow,
        Colormap::Inferno,
        Colormap::Grey,
        Colormap::Diverging,
    ];

    /// The palette's name as the command line and image metadata spell it.
    pub fn name(self) -> &'static str {
        match self {
            Colormap::Ironbow => "ironbow",
            Colormap::Inferno => "inferno",
            Colormap::Grey => "grey",
            Colormap::Diverging => "diverging",
        }
    }

    /// The palette named `name` ([`Self::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    /// Whether the palette orders values from dark to light (a temperature palette), rather
    /// than from one side of zero to the other.
    pub fn sequential(self) -> bool {
        self != Colormap::Diverging
    }

    /// The palette's 256 colours, channels in 0..=255 as f32 (unrounded).
    pub fn lut(self) -> &'static [[f32; 3]; 256] {
        static IRON: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
        static INF: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
        static GRY: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
        static DIV: OnceLock<[[f32; 3]; 256]> = OnceLock::new();
        match self {
            Colormap::Ironbow => IRON.get_or_init(|| interpolate(&IRONBOW)),
            Colormap::Inferno => INF.get_or_init(|| interpolate(&INFERNO)),
            Colormap::Grey => GRY.get_or_init(|| interpolate(&GREY)),
            Colormap::Diverging => DIV.get_or_init(|| interpolate(&DIVERGING)),
        }
    }

    /// The palette's 256 colours as 8-bit RGB (rounded).
    pub fn lut_u8(self) -> &'static [[u8; 3]; 256] {
        static IRON: OnceLock<[[u8; 3]; 256]> = OnceLock::new();
        static INF: OnceLock<[[u8; 3]; 256]> = OnceLock::new();
        static GRY: OnceLock<[[u8; 3]; 256]> = OnceLock::new();
        static DIV: OnceLock<[[u8; 3]; 256]> = OnceLock::new();
        let round =
            |lut: &[[f32; 3]; 256]| lut.map(|c| c.map(|v| v.round().clamp(0.0, 255.0) as u8));
        match self {
            Colormap::Ironbow => IRON.get_or_init(|| round(self.lut())),
            Colormap::Inferno => INF.get_or_init(|| round(self.lut())),
            Colormap::Grey => GRY.get_or_init(|| round(self.lut())),
            Colormap::Diverging => DIV.get_or_init(|| round(self.lut())),
        }
    }

    /// The colour of `t` in [0, 1] (clamped; NaN is the coldest colour).
    pub fn colour(self, t: f64) -> [u8; 3] {
        let i = if t.is_nan() {
            0.0
        } else {
            (t.clamp(0.0, 1.0) * 255.0).round()
        };
        self.lut_u8()[i as usize]
    }

    /// The entry nearest to `rgb` (Euclidean in 8-bit RGB) and its distance: how a pseudo-colour
    /// pixel maps back to a scalar, and how well the palette explains it.
    pub fn nearest(self, rgb: [u8; 3]) -> (usize, f32) {
        let mut best = (0usize, f32::INFINITY);
        for (i, c) in self.lut().iter().enumerate() {
            let d = (c[0] - f32::from(rgb[0])).powi(2)
                + (c[1] - f32::from(rgb[1])).powi(2)
                + (c[2] - f32::from(rgb[2])).powi(2);
            if d < best.1 {
                best = (i, d);
            }
        }
        (best.0, best.1.sqrt())
    }
}

/// Key colours interpolated linearly to 256 entries.
fn interpolate(keys: &[(f32, [f32; 3])]) -> [[f32; 3]; 256] {
    let mut lut = [[0.0; 3]; 256];
    for (i, entry) in lut.iter_mut().enumerate() {
        let t = i as f32 / 255.0;
        let k = keys
            .windows(2)
            .position(|w| t <= w[1].0)
            .unwrap_or(keys.len() - 2);
        let (t0, c0) = keys[k];
        let (t1, c1) = keys[k + 1];
        let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
        for ch in 0..3 {
            entry[ch] = c0[ch] + a * (c1[ch] - c0[ch]);
        }
    }
    lut
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mapping back is exact only if every palette is a path without repeats: each 8-bit entry
    /// is its own nearest, and the ends are the coldest and hottest colours.
    #[test]
    fn every_entry_maps_back_to_itself() {
        for map in Colormap::ALL {
            let lut = map.lut_u8();
            // Rounded to 8 bits, every entry is still nearest to itself (no flat stretch).
            let wrong: Vec<(usize, usize)> = (0..256)
                .map(|i| (i, map.nearest(lut[i]).0))
                .filter(|(i, j)| i != j)
                .collect();
            assert!(
                wrong.is_empty(),
                "{map:?}: entries {wrong:?} map back to another entry"
            );
            let sum = |c: [u8; 3]| c.iter().map(|&v| u32::from(v)).sum::<u32>();
            if map.sequential() {
                assert!(
                    sum(map.colour(0.0)) < sum(map.colour(1.0)),
                    "{map:?}: 0 must be darker than 1"
                );
            } else {
                // The middle is the lightest: zero stands out from both signs.
                let mid = sum(map.colour(0.5));
                assert!(
                    mid > sum(map.colour(0.0)) && mid > sum(map.colour(1.0)),
                    "{map:?}: the middle must be lighter than both ends"
                );
            }
            assert_eq!(
                Colormap::from_name(map.name()),
                Some(map),
                "{map:?} by name"
            );
        }
        assert_eq!(
            Colormap::Ironbow.colour(1.0),
            [255, 255, 255],
            "ironbow ends white"
        );
        assert_eq!(
            Colormap::Ironbow.colour(f64::NAN),
            [0, 0, 0],
            "NaN is the coldest colour"
        );
    }
}
