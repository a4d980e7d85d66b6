//! Raw words to kelvin with FLIR's published model, and back.
//!
//! The camera measures `raw = R1 / (R2 · (exp(B / T) − F)) − O` for a black body at `T`
//! (kelvin). What reaches it from an object of emissivity ε through air of transmission τ and an
//! IR window of transmission τ_w (FLIR's model as documented by Minkina & Dudzik and ported in
//! Thermimage's `raw2temp`, the window half-way, the same air on both sides):
//!
//! ```text
//! raw = ε τ τ_w τ · obj + (1 − ε) τ τ_w τ · refl + (1 − τ) τ_w τ · atm
//!       + (1 − τ_w) τ · win + (1 − τ) · atm
//! ```
//!
//! solved for the object's radiance `obj`, then inverted through the Planck curve. The air's
//! transmission over distance d with water vapour h (from the relative humidity and the air's
//! temperature) is `X·exp(−√(d/2)·(α1 + β1·√h)) + (1 − X)·exp(−√(d/2)·(α2 + β2·√h))`.

/// A camera's calibration: its Planck curve and atmospheric transmission constants.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PlanckCurve {
    pub r1: f64,
    pub r2: f64,
    pub b: f64,
    pub f: f64,
    pub o: f64,
    pub alpha1: f64,
    pub alpha2: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub x: f64,
}

/// The conditions of a measurement (each can be overridden for a file: the camera stores what
/// its operator set, often the defaults).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Conditions {
    pub emissivity: f64,
    pub object_distance_m: f64,
    /// Reflected apparent temperature, kelvin.
    pub reflected_k: f64,
    /// Air temperature, kelvin.
    pub atmosphere_k: f64,
    /// Relative humidity as a fraction (0.5 = 50 %).
    pub relative_humidity: f64,
    /// IR window temperature, kelvin, and transmission (1: no window).
    pub window_k: f64,
    pub window_transmission: f64,
}

/// The command line's overrides of a file's [`Conditions`] (each `None`: the file's own), the one
/// definition of these options for every command that converts radiometric files
/// (`s3tir-capture inspect`, `s3tir-calib poses DIR`). With the `clap` feature they are a
/// flattenable `clap::Args` group.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ConditionOverrides {
    /// Object emissivity [default: the file's].
    #[cfg_attr(feature = "clap", arg(long))]
    pub emissivity: Option<f64>,
    /// Object distance, metres [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "distance-m"))]
    pub distance_m: Option<f64>,
    /// Reflected apparent temperature, °C [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "reflected-c"))]
    pub reflected_c: Option<f64>,
    /// Air temperature, °C [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "atmosphere-c"))]
    pub atmosphere_c: Option<f64>,
    /// Relative humidity, per cent [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "humidity-percent"))]
    pub humidity_percent: Option<f64>,
    /// IR window temperature, °C [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "window-c"))]
    pub window_c: Option<f64>,
    /// IR window transmission (1: no window) [default: the file's].
    #[cfg_attr(feature = "clap", arg(long = "window-transmission"))]
    pub window_transmission: Option<f64>,
}

impl ConditionOverrides {
    /// `file`'s conditions with these overrides, checked (emissivity in (0, 1], distance ≥ 0,
    /// humidity 0–100 %, window transmission in (0, 1], temperatures above 0 K).
    pub fn apply(&self, file: &Conditions) -> Result<Conditions, super::RadiometricError> {
        let c = Conditions {
            emissivity: self.emissivity.unwrap_or(file.emissivity),
            object_distance_m: self.distance_m.unwrap_or(file.object_distance_m),
            reflected_k: self.reflected_c.map_or(file.reflected_k, |c| c + 273.15),
            atmosphere_k: self.atmosphere_c.map_or(file.atmosphere_k, |c| c + 273.15),
            relative_humidity: self
                .humidity_percent
                .map_or(file.relative_humidity, |p| p / 100.0),
            window_k: self.window_c.map_or(file.window_k, |c| c + 273.15),
            window_transmission: self.window_transmission.unwrap_or(file.window_transmission),
        };
        let ok = c.emissivity > 0.0
            && c.emissivity <= 1.0
            && c.object_distance_m >= 0.0
            && (0.0..=1.0).contains(&c.relative_humidity)
            && c.window_transmission > 0.0
            && c.window_transmission <= 1.0
            && [c.reflected_k, c.atmosphere_k, c.window_k]
                .iter()
                .all(|k| k.is_finite() && *k > 0.0);
        if ok {
            Ok(c)
        } else {
            Err(super::RadiometricError::format(
                "conditions",
                format!(
                    "out of range: emissivity {} (0–1], distance {} m (≥ 0), humidity {} (0–100 %), \
                     window transmission {} (0–1], temperatures above 0 K",
                    c.emissivity,
                    c.object_distance_m,
                    c.relative_humidity * 100.0,
                    c.window_transmission
                ),
            ))
        }
    }
}

impl PlanckCurve {
    /// The raw word a black body at `kelvin` gives.
    pub fn raw_of_black_body(&self, kelvin: f64) -> f64 {
        self.r1 / (self.r2 * ((self.b / kelvin).exp() - self.f)) - self.o
    }

    /// The black-body temperature (kelvin) of the raw word `raw`.
    pub fn black_body_of_raw(&self, raw: f64) -> f64 {
        self.b / (self.r1 / (self.r2 * (raw + self.o)) + self.f).ln()
    }

    /// The air's transmission over `distance_m` at `atmosphere_k` and `relative_humidity`.
    pub fn transmission(&self, distance_m: f64, atmosphere_k: f64, relative_humidity: f64) -> f64 {
        let t = atmosphere_k - 273.15;
        // water vapour (mmHg) from the relative humidity and the air's temperature in °C
        let h = relative_humidity
            * (1.5587 + 0.06939 * t - 0.00027816 * t * t + 0.00000068455 * t * t * t).exp();
        let s = (distance_m / 2.0).sqrt();
        self.x * (-s * (self.alpha1 + self.beta1 * h.sqrt())).exp()
            + (1.0 - self.x) * (-s * (self.alpha2 + self.beta2 * h.sqrt())).exp()
    }
}

/// Raw words ↔ kelvin for one camera under one set of conditions (the conditions' terms
/// computed once).
#[derive(Debug, Clone, Copy)]
pub struct RawToKelvin {
    curve: PlanckCurve,
    /// `obj = raw · gain + offset`.
    gain: f64,
    offset: f64,
}

impl RawToKelvin {
    pub fn new(curve: &PlanckCurve, c: &Conditions) -> Self {
        let e = c.emissivity;
        let tau = curve.transmission(c.object_distance_m, c.atmosphere_k, c.relative_humidity);
        let tw = c.window_transmission;
        let refl = curve.raw_of_black_body(c.reflected_k);
        let atm = curve.raw_of_black_body(c.atmosphere_k);
        let win = curve.raw_of_black_body(c.window_k);
        let gain = 1.0 / (e * tau * tw * tau);
        let offset = -(1.0 - e) / e * refl
            - (1.0 - tau) / (e * tau) * atm
            - (1.0 - tw) / (e * tau * tw) * win
            - (1.0 - tau) * gain * atm;
        Self {
            curve: *curve,
            gain,
            offset,
        }
    }

    /// The object's temperature, kelvin, for the raw word `raw` (NaN where the object's
    /// radiance is not positive: a word below what the surroundings alone give).
    pub fn kelvin(&self, raw: f64) -> f64 {
        let obj = raw * self.gain + self.offset;
        if obj + self.curve.o <= 0.0 {
            return f64::NAN;
        }
        self.curve.black_body_of_raw(obj)
    }

    /// The raw word an object at `kelvin` gives (the inverse of [`RawToKelvin::kelvin`]).
    pub fn raw(&self, kelvin: f64) -> f64 {
        (self.curve.raw_of_black_body(kelvin) - self.offset) / self.gain
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn duo_pro_r() -> PlanckCurve {
        PlanckCurve {
            r1: 364_058.0,
            r2: 1.0,
            b: 1428.0,
            f: 1.0,
            o: -228.0,
            alpha1: 0.006569,
            alpha2: 0.012620,
            beta1: -0.002276,
            beta2: -0.006670,
            x: 1.9,
        }
    }

    /// Under black-body conditions (ε = 1, no distance, no window) the model is the Planck
    /// curve itself; in any conditions `raw(kelvin(w)) = w`.
    #[test]
    fn the_model_inverts_and_reduces_to_the_planck_curve() {
        let curve = duo_pro_r();
        let black = Conditions {
            emissivity: 1.0,
            object_distance_m: 0.0,
            reflected_k: 293.15,
            atmosphere_k: 293.15,
            relative_humidity: 0.5,
            window_k: 293.15,
            window_transmission: 1.0,
        };
        let m = RawToKelvin::new(&curve, &black);
        for w in [2000.0, 2681.0, 9000.0] {
            let k = m.kelvin(w);
            assert!(
                (k - curve.black_body_of_raw(w)).abs() < 1e-9,
                "black-body conditions: {k} K for raw {w}"
            );
        }
        let field = Conditions {
            emissivity: 0.94,
            object_distance_m: 50.0,
            reflected_k: 283.15,
            atmosphere_k: 278.15,
            relative_humidity: 0.8,
            window_k: 295.15,
            window_transmission: 0.9,
        };
        let m = RawToKelvin::new(&curve, &field);
        for w in [2300.0, 2681.0, 5000.0] {
            let back = m.raw(m.kelvin(w));
            assert!((back - w).abs() < 1e-6, "raw {w} → K → raw {back}");
        }
        // Through more air the camera sees less of the object: the same word means a warmer one.
        let near = RawToKelvin::new(
            &curve,
            &Conditions {
                object_distance_m: 1.0,
                ..field
            },
        );
        assert!(
            m.kelvin(3000.0) > near.kelvin(3000.0),
            "the same word at 50 m means a warmer object than at 1 m"
        );
    }
}
