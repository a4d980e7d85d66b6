//! Thermal radiometry: in-band (8–14 µm) radiance of a grey body and its inverse.
//!
//! The in-band radiance `L(T) = ∫_{8 µm}^{14 µm} B_λ(λ, T) dλ` is Planck's law integrated
//! numerically (composite Simpson, 600 intervals, relative error < 1e-9 against 4 800
//! intervals) once, tabulated every 0.05 K from 150 K to 700 K, and interpolated linearly
//! (relative interpolation error < 1e-6). The sensor sees, per surface,
//!
//! `L_apparent = ε · L(T_surface) + (1 − ε) · L(T_reflected)`
//!
//! and a radiometric core reports the temperature of the black body with the same in-band
//! radiance (TLinear): `T_apparent = L⁻¹(L_apparent)`.

/// Planck constant, J·s.
const H: f64 = 6.626_070_15e-34;
/// Speed of light, m/s.
const C: f64 = 299_792_458.0;
/// Boltzmann constant, J/K.
const K_B: f64 = 1.380_649e-23;
/// Stefan–Boltzmann constant, W/(m²·K⁴).
pub const SIGMA_SB: f64 = 5.670_374_419e-8;
/// 0 °C in kelvin.
pub const ZERO_CELSIUS_K: f64 = 273.15;

/// Lower end of the LWIR band, metres.
pub const BAND_LOW_M: f64 = 8e-6;
/// Upper end of the LWIR band, metres.
pub const BAND_HIGH_M: f64 = 14e-6;

const TABLE_MIN_K: f64 = 150.0;
const TABLE_MAX_K: f64 = 700.0;
const TABLE_STEP_K: f64 = 0.05;

/// Spectral radiance of a black body, W/(m²·sr·m).
pub fn planck_spectral_radiance(wavelength_m: f64, temp_k: f64) -> f64 {
    let a = 2.0 * H * C * C / wavelength_m.powi(5);
    let x = H * C / (wavelength_m * K_B * temp_k);
    a / x.exp_m1()
}

/// Black-body radiance in 8–14 µm by composite Simpson integration, W/(m²·sr).
pub fn in_band_radiance_exact(temp_k: f64, intervals: usize) -> f64 {
    let n = intervals.max(2) & !1; // even
    let h = (BAND_HIGH_M - BAND_LOW_M) / n as f64;
    let mut sum = planck_spectral_radiance(BAND_LOW_M, temp_k)
        + planck_spectral_radiance(BAND_HIGH_M, temp_k);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        sum += w * planck_spectral_radiance(BAND_LOW_M + h * i as f64, temp_k);
    }
    sum * h / 3.0
}

/// Cells of the uniform-radiance index that speeds up [`Radiometry::temperature_k`].
const HINT_CELLS: usize = 1 << 16;

/// Tabulated in-band radiance and its inverse.
#[derive(Debug, Clone)]
pub struct Radiometry {
    table: Vec<f64>,
    /// `hint[j]` = the table index `i` with `table[i] <= r < table[i + 1]` for the radiance
    /// `r` at the start of uniform radiance cell `j`: the inverse starts its search there and
    /// walks a few entries forward instead of a binary search over the whole table (the live
    /// rig inverts every pixel of every frame). It finds the same `i`, so results are
    /// bit-identical to the binary search.
    hint: Vec<u32>,
    hint_scale: f64,
}

impl Default for Radiometry {
    fn default() -> Self {
        Self::new()
    }
}

impl Radiometry {
    /// Builds the table (≈ 11 000 Simpson integrations, a few milliseconds).
    pub fn new() -> Self {
        let n = ((TABLE_MAX_K - TABLE_MIN_K) / TABLE_STEP_K).round() as usize + 1;
        let table = (0..n)
            .map(|i| in_band_radiance_exact(TABLE_MIN_K + TABLE_STEP_K * i as f64, 600))
            .collect::<Vec<f64>>();
        let (lo, hi) = (table[0], table[table.len() - 1]);
        let hint_scale = HINT_CELLS as f64 / (hi - lo);
        let hint = (0..=HINT_CELLS)
            .map(|j| {
                let r = lo + j as f64 / hint_scale;
                (table.partition_point(|&v| v <= r).saturating_sub(1)) as u32
            })
            .collect();
        Self {
            table,
            hint,
            hint_scale,
        }
    }

    /// The table index `i` with `table[i] <= radiance < table[i + 1]` (`radiance` strictly
    /// inside the table range), found from the uniform-radiance hint.
    fn bracket(&self, radiance: f64) -> usize {
        let t = &self.table;
        let last = t.len() - 1;
        let j = (((radiance - t[0]) * self.hint_scale) as usize).min(self.hint.len() - 1);
        // The hint is exact at the cell start; radiance at or after it can only move forward.
        // Rounding of the cell index may land one cell late: step back while needed.
        let mut i = self.hint[j] as usize;
        while i > 0 && t[i] > radiance {
            i -= 1;
        }
        while i + 1 < last && t[i + 1] <= radiance {
            i += 1;
        }
        i.min(last - 1)
    }

    /// Black-body in-band radiance at `temp_k`, W/(m²·sr). Clamped to the table range
    /// (150–700 K), which covers every scene the simulator builds.
    pub fn radiance(&self, temp_k: f64) -> f64 {
        let x = ((temp_k - TABLE_MIN_K) / TABLE_STEP_K).clamp(0.0, (self.table.len() - 1) as f64);
        let i = (x.floor() as usize).min(self.table.len() - 2);
        let f = x - i as f64;
        let (a, b) = (self.table[i], self.table[i + 1]);
        a + (b - a) * f
    }

    /// dL/dT at `temp_k`, W/(m²·sr·K).
    pub fn radiance_slope(&self, temp_k: f64) -> f64 {
        (self.radiance(temp_k + 0.5) - self.radiance(temp_k - 0.5)) / 1.0
    }

    /// Equivalent black-body temperature of an in-band radiance (TLinear), kelvin.
    pub fn temperature_k(&self, radiance: f64) -> f64 {
        let t = &self.table;
        let last = t.len() - 1;
        if radiance.is_nan() || radiance <= t[0] {
            return TABLE_MIN_K;
        }
        if radiance >= t[last] {
            return TABLE_MAX_K;
        }
        let i = self.bracket(radiance);
        let f = (radiance - t[i]) / (t[i + 1] - t[i]);
        TABLE_MIN_K + TABLE_STEP_K * (i as f64 + f)
    }

    /// Apparent radiance of a grey surface: emitted plus reflected surroundings.
    pub fn apparent_radiance(&self, emissivity: f64, temp_k: f64, reflected_k: f64) -> f64 {
        emissivity * self.radiance(temp_k) + (1.0 - emissivity) * self.radiance(reflected_k)
    }
}

#[cfg(test)]
mod tests {
    //! Proves: the integral converges, the table agrees with it, the inverse inverts, and a
    //! grey body's apparent temperature lies between its own and the reflected temperature.
    //! Does not compare against an external radiometry reference beyond a hand value.
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn simpson_integral_has_converged_and_matches_a_known_value() {
        let coarse = in_band_radiance_exact(300.0, 600);
        let fine = in_band_radiance_exact(300.0, 4800);
        assert!(
            ((coarse - fine) / fine).abs() < 1e-9,
            "600: {coarse}, 4800: {fine}"
        );
        // Known value: a 300 K black body emits ≈ 37.6 % of σT⁴/π in 8–14 µm (≈ 55.0 W/m²/sr).
        let total = SIGMA_SB * 300f64.powi(4) / std::f64::consts::PI;
        let frac = fine / total;
        assert!(
            (0.36..0.39).contains(&frac),
            "in-band fraction {frac}, want ≈ 0.376"
        );
    }

    #[test]
    fn table_matches_integral_and_inverts() {
        let r = Radiometry::new();
        for t in [200.0, 253.15, 298.15, 300.03, 373.0, 650.0] {
            let exact = in_band_radiance_exact(t, 600);
            let got = r.radiance(t);
            assert!(
                ((got - exact) / exact).abs() < 1e-6,
                "L({t}) table {got}, exact {exact}"
            );
            let back = r.temperature_k(got);
            assert!((back - t).abs() < 1e-3, "T(L({t})) = {back}");
        }
    }

    #[test]
    fn hinted_inverse_finds_the_same_bracket_as_a_binary_search() {
        use rand::{Rng, SeedableRng};
        let r = Radiometry::new();
        let (lo, hi) = (r.table[0], r.table[r.table.len() - 1]);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut probes: Vec<f64> = (0..200_000).map(|_| rng.random_range(lo..hi)).collect();
        // Exactly on table entries and on hint-cell starts too.
        probes.extend(r.table[1..r.table.len() - 1].iter().copied());
        probes.extend(
            (1..HINT_CELLS)
                .step_by(97)
                .map(|j| lo + j as f64 / r.hint_scale),
        );
        for l in probes {
            if l <= lo || l >= hi {
                continue;
            }
            let want = r
                .table
                .partition_point(|&v| v <= l)
                .saturating_sub(1)
                .min(r.table.len() - 2);
            assert_eq!(r.bracket(l), want, "radiance {l}: hinted vs binary search");
        }
    }

    #[test]
    fn grey_body_apparent_temperature_is_between_surface_and_surroundings() {
        let r = Radiometry::new();
        let l = r.apparent_radiance(0.3, 300.0, 250.0);
        let t = r.temperature_k(l);
        assert!(t > 250.0 && t < 300.0, "apparent {t}");
        let bb = r.temperature_k(r.apparent_radiance(1.0, 300.0, 250.0));
        assert!(
            (bb - 300.0).abs() < 1e-3,
            "black body must read its own temperature, got {bb}"
        );
    }
}
