//! Sensor models: the thermal core (NETD noise, drifting fixed-pattern noise reset by FFC,
//! frozen frames during FFC, dropped frames, Lepton telemetry rows) and the RGB camera
//! (exposure, shot and read noise, sRGB encoding, YUYV and MJPEG output).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use s3tir_calib::{BrownConrady, CameraModel, Intrinsics};
use s3tir_capture::frame::ThermalUnits;
use serde::{Deserialize, Serialize};

use crate::error::SimError;
use crate::physics::Radiometry;

/// Reference scene temperature at which NETD is specified (and noise is injected), kelvin.
pub const NETD_REFERENCE_K: f64 = 300.0;

/// A thermal camera core.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThermalProfile {
    pub name: &'static str,
    pub camera: CameraModel,
    pub rate_hz: f64,
    /// Telemetry rows appended below the image (Lepton: 2; 0 = off).
    pub telemetry_rows: u32,
    /// Temporal noise, kelvin (1σ at [`NETD_REFERENCE_K`]).
    pub netd_k: f64,
    /// Frames frozen by one flat-field correction.
    pub ffc_frames: u32,
    /// Automatic FFC period, seconds (0 = manual only).
    pub auto_ffc_period_s: f64,
    /// Fixed-pattern drift: 1σ offset growth per second since the last FFC, kelvin/second.
    pub fpn_drift_k_per_s: f64,
    /// Cap of the fixed-pattern 1σ offset, kelvin.
    pub fpn_max_k: f64,
    /// Optics blur: Gaussian PSF 1σ, pixels.
    pub psf_sigma_px: f64,
    /// Probability that a frame is dropped (its sequence number is skipped).
    pub drop_probability: f64,
    /// Raw-count slope at [`NETD_REFERENCE_K`], counts per kelvin.
    pub raw_counts_per_k: f64,
    /// Raw counts of a [`NETD_REFERENCE_K`] black body.
    pub raw_counts_at_reference: f64,
    /// Output words: TLinear centikelvin or raw counts.
    pub units: ThermalUnits,
}

impl ThermalProfile {
    /// FLIR Lepton 3.5: 160×120, 57° HFOV, 8.7 Hz, NETD 50 mK, ~23 frames frozen per FFC.
    pub fn lepton35() -> Self {
        Self {
            name: "lepton35",
            camera: CameraModel {
                width_px: 160,
                height_px: 120,
                intrinsics: Intrinsics {
                    fx: 147.0,
                    fy: 147.0,
                    cx: 79.6,
                    cy: 59.3,
                },
                distortion: BrownConrady {
                    k1: -0.28,
                    k2: 0.11,
                    p1: 0.0008,
                    p2: -0.0005,
                    k3: -0.015,
                },
            },
            rate_hz: 8.7,
            telemetry_rows: 0,
            netd_k: 0.050,
            ffc_frames: 23,
            auto_ffc_period_s: 180.0,
            fpn_drift_k_per_s: 0.002,
            fpn_max_k: 0.6,
            psf_sigma_px: 0.45,
            drop_probability: 0.0,
            raw_counts_per_k: 30.0,
            raw_counts_at_reference: 8000.0,
            units: ThermalUnits::CentiKelvin,
        }
    }

    /// FLIR Boson 640: 640×512, 50° HFOV, 60 Hz, NETD 40 mK, ~30 frames frozen per FFC.
    pub fn boson640() -> Self {
        Self {
            name: "boson640",
            camera: CameraModel {
                width_px: 640,
                height_px: 512,
                intrinsics: Intrinsics {
                    fx: 686.0,
                    fy: 686.0,
                    cx: 319.2,
                    cy: 256.8,
                },
                distortion: BrownConrady {
                    k1: -0.19,
                    k2: 0.06,
                    p1: 0.0004,
                    p2: -0.0003,
                    k3: 0.0,
                },
            },
            rate_hz: 60.0,
            telemetry_rows: 0,
            netd_k: 0.040,
            ffc_frames: 30,
            auto_ffc_period_s: 180.0,
            fpn_drift_k_per_s: 0.002,
            fpn_max_k: 0.5,
            psf_sigma_px: 0.6,
            drop_probability: 0.0,
            raw_counts_per_k: 40.0,
            raw_counts_at_reference: 8000.0,
            units: ThermalUnits::CentiKelvin,
        }
    }

    /// A profile by name (`lepton35`, `boson640`).
    pub fn by_name(name: &str) -> Result<Self, SimError> {
        match name {
            "lepton35" => Ok(Self::lepton35()),
            "boson640" => Ok(Self::boson640()),
            _ => Err(SimError::UnknownProfile {
                name: name.to_owned(),
                known: "lepton35, boson640",
            }),
        }
    }

    /// Output height including telemetry rows.
    pub fn output_height(&self) -> u32 {
        self.camera.height_px + self.telemetry_rows
    }
}

/// What the sensor did with one frame period.
#[derive(Debug, Clone, PartialEq)]
pub enum ThermalOutput {
    /// The frame was lost (sequence number skipped).
    Dropped {
        sequence: u32,
    },
    Frame(ThermalSensorFrame),
}

/// One frame off the thermal core.
#[derive(Debug, Clone, PartialEq)]
pub struct ThermalSensorFrame {
    pub sequence: u32,
    /// Sensor time at the end of exposure, nanoseconds since sensor start.
    pub time_ns: u64,
    /// `width × output_height` words (telemetry rows last).
    pub words: Vec<u16>,
    /// Frame is a frozen copy produced during FFC.
    pub ffc_frozen: bool,
}

/// FFC state bits in telemetry (Lepton telemetry row A, word 3 bits 4–5).
fn ffc_bits(in_progress: bool, ever: bool) -> u16 {
    match (in_progress, ever) {
        (true, _) => 2 << 4,
        (false, true) => 3 << 4,
        (false, false) => 0,
    }
}

/// The thermal core: turns area-integrated, blurred in-band radiance into output words.
#[derive(Debug, Clone)]
pub struct ThermalSensor {
    pub profile: ThermalProfile,
    radiometry: Radiometry,
    rng: ChaCha8Rng,
    /// Zero-mean, unit-variance offset pattern (per pixel).
    fpn_pattern: Vec<f64>,
    time_since_ffc_s: f64,
    time_s: f64,
    sequence: u32,
    frames_out: u32,
    ffc_remaining: u32,
    ffc_ever: bool,
    last_words: Option<Vec<u16>>,
    /// Standard normals for [`ThermalSensor::expose_fast`] (filled on first use).
    noise_table: Vec<f32>,
    /// Focal-plane temperature, kelvin (reported over FSLP and telemetry).
    pub fpa_temp_k: f64,
}

impl ThermalSensor {
    pub fn new(profile: ThermalProfile, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let fpn_pattern = draw_pattern(&mut rng, &profile);
        Self {
            profile,
            radiometry: Radiometry::new(),
            rng,
            fpn_pattern,
            time_since_ffc_s: 0.0,
            time_s: 0.0,
            sequence: 0,
            frames_out: 0,
            ffc_remaining: 0,
            ffc_ever: false,
            last_words: None,
            noise_table: Vec::new(),
            fpa_temp_k: 306.15,
        }
    }

    pub fn radiometry(&self) -> &Radiometry {
        &self.radiometry
    }

    /// Starts a flat-field correction: the next `ffc_frames` frames are frozen.
    pub fn request_ffc(&mut self) {
        if self.ffc_remaining == 0 {
            self.ffc_remaining = self.profile.ffc_frames;
        }
    }

    /// True while an FFC is freezing frames.
    pub fn ffc_in_progress(&self) -> bool {
        self.ffc_remaining > 0
    }

    /// True once any FFC has completed or started.
    pub fn ffc_ever(&self) -> bool {
        self.ffc_ever
    }

    /// Current 1σ fixed-pattern offset, kelvin.
    pub fn fpn_sigma_k(&self) -> f64 {
        (self.profile.fpn_drift_k_per_s * self.time_since_ffc_s).min(self.profile.fpn_max_k)
    }

    /// Produces the next frame from a `width × height` radiance image (already blurred).
    pub fn next_frame(&mut self, radiance: &[f64]) -> ThermalOutput {
        self.next_frame_with(|s| s.expose(radiance))
    }

    /// [`ThermalSensor::next_frame`] for the live rig: the same FFC, drop, fixed-pattern and
    /// telemetry behaviour, but noise from a table and a linearised radiance → output map
    /// ([`LinearizedRadiance`], [`ThermalSensor::expose_fast`]), ~10× cheaper per pixel.
    pub fn next_frame_fast(&mut self, lin: &LinearizedRadiance) -> ThermalOutput {
        self.next_frame_with(|s| s.expose_fast(lin))
    }

    fn next_frame_with(&mut self, expose: impl FnOnce(&mut Self) -> Vec<u16>) -> ThermalOutput {
        let p = self.profile;
        let dt = 1.0 / p.rate_hz;
        self.time_s += dt;
        self.time_since_ffc_s += dt;
        let sequence = self.sequence;
        self.sequence = self.sequence.wrapping_add(1);
        let time_ns = (self.time_s * 1e9).round() as u64;
        if p.auto_ffc_period_s > 0.0 && self.time_since_ffc_s >= p.auto_ffc_period_s {
            self.request_ffc();
        }
        let dropped = p.drop_probability > 0.0 && self.rng.random::<f64>() < p.drop_probability;
        if self.ffc_remaining > 0 {
            self.ffc_ever = true;
            self.ffc_remaining -= 1;
            if self.ffc_remaining == 0 {
                // Shutter opens: the offset table is fresh, drift restarts with a new pattern.
                self.time_since_ffc_s = 0.0;
                self.fpn_pattern = draw_pattern(&mut self.rng, &p);
            }
            if let Some(last) = &self.last_words {
                let mut words = last.clone();
                self.write_telemetry(&mut words, true);
                if dropped {
                    return ThermalOutput::Dropped { sequence };
                }
                return ThermalOutput::Frame(ThermalSensorFrame {
                    sequence,
                    time_ns,
                    words,
                    ffc_frozen: true,
                });
            }
        }
        let words = expose(self);
        self.last_words = Some(words.clone());
        if dropped {
            return ThermalOutput::Dropped { sequence };
        }
        self.frames_out += 1;
        let mut words = words;
        self.write_telemetry(&mut words, false);
        ThermalOutput::Frame(ThermalSensorFrame {
            sequence,
            time_ns,
            words,
            ffc_frozen: false,
        })
    }

    /// Noise, fixed pattern and the conversion to output words (telemetry rows zero).
    fn expose(&mut self, radiance: &[f64]) -> Vec<u16> {
        let p = self.profile;
        let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
        let slope = self.radiometry.radiance_slope(NETD_REFERENCE_K);
        let noise_l = p.netd_k * slope;
        let fpn_l = self.fpn_sigma_k() * slope;
        let mut words = vec![0u16; w * p.output_height() as usize];
        for (k, &l) in radiance.iter().take(w * h).enumerate() {
            let n: f64 = StandardNormal.sample(&mut self.rng);
            let l = l + noise_l * n + fpn_l * self.fpn_pattern[k];
            let value = match p.units {
                ThermalUnits::CentiKelvin => self.radiometry.temperature_k(l) * 100.0,
                ThermalUnits::RawCounts => {
                    let l_ref = self.radiometry.radiance(NETD_REFERENCE_K);
                    p.raw_counts_at_reference + (l - l_ref) / slope * p.raw_counts_per_k
                }
            };
            words[k] = value.round().clamp(0.0, 65535.0) as u16;
        }
        words
    }

    /// Noise and fixed pattern on a linearised radiance map: output = base + gain·(radiance
    /// noise + fixed-pattern offset). Temporal noise comes from a table of 2²⁰ standard normals
    /// (drawn once from the sensor's generator) read from a random offset per row, as
    /// [`StaticRgbExposer`] does. Telemetry rows are zero.
    pub fn expose_fast(&mut self, lin: &LinearizedRadiance) -> Vec<u16> {
        let p = self.profile;
        let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
        if self.noise_table.is_empty() {
            self.noise_table = (0..NOISE_TABLE_LEN)
                .map(|_| {
                    let n: f64 = StandardNormal.sample(&mut self.rng);
                    n as f32
                })
                .collect();
        }
        let slope = lin.slope_at_reference;
        let noise_l = (p.netd_k * slope) as f32;
        let fpn_l = (self.fpn_sigma_k() * slope) as f32;
        let mut words = vec![0u16; w * p.output_height() as usize];
        let mask = NOISE_TABLE_LEN - 1;
        for y in 0..h.min(lin.base.len() / w.max(1)) {
            let start = self.rng.random::<u32>() as usize & mask;
            let row = y * w..(y + 1) * w;
            for (x, ((out, (b, g)), f)) in words[row.clone()]
                .iter_mut()
                .zip(lin.base[row.clone()].iter().zip(&lin.gain[row.clone()]))
                .zip(&self.fpn_pattern[row])
                .enumerate()
            {
                let n = self.noise_table[(start + x) & mask];
                let v = b + g * (noise_l * n + fpn_l * *f as f32);
                // v ≥ 0 after the clamp: +0.5 and truncation round half away from zero.
                *out = (v.clamp(0.0, 65535.0) + 0.5) as u16;
            }
        }
        words
    }

    /// Fills the telemetry rows in FLIR's Lepton 3.5 "telemetry row A" layout (Lepton
    /// Engineering Datasheet; table in firmware-sim/README.md): 32-bit values least
    /// significant word first, other words zero.
    fn write_telemetry(&self, words: &mut [u16], frozen: bool) {
        let p = self.profile;
        if p.telemetry_rows == 0 {
            return;
        }
        let base = (p.camera.width_px * p.camera.height_px) as usize;
        let uptime_ms = (self.time_s * 1000.0) as u32;
        let since_ffc_ms = (self.time_since_ffc_s * 1000.0) as u32;
        let fpa_ck = (self.fpa_temp_k * 100.0).round() as u16;
        let image = &words[..base.min(words.len())];
        let mean = if image.is_empty() {
            0
        } else {
            (image.iter().map(|&v| u64::from(v)).sum::<u64>() / image.len() as u64) as u16
        };
        let lsw = |v: u32| v as u16;
        let msw = |v: u32| (v >> 16) as u16;
        let at_ffc_ms = uptime_ms.saturating_sub(since_ffc_ms);
        let row: [(usize, u16); 14] = [
            (0, LEPTON_TELEMETRY_REVISION),
            (1, lsw(uptime_ms)),
            (2, msw(uptime_ms)),
            (3, ffc_bits(frozen, self.ffc_ever)),
            (20, lsw(self.frames_out)),
            (21, msw(self.frames_out)),
            (22, mean),
            (24, fpa_ck),
            // Housing temperature: the simulator has one temperature for the core.
            (26, fpa_ck),
            (29, fpa_ck),
            (30, lsw(at_ffc_ms)),
            (31, msw(at_ffc_ms)),
            (32, fpa_ck),
            (4, 0),
        ];
        for (k, v) in row {
            if let Some(slot) = words.get_mut(base + k) {
                *slot = v;
            }
        }
    }
}

/// Telemetry revision word the simulated Lepton writes (row A word 0).
pub const LEPTON_TELEMETRY_REVISION: u16 = 0x000E;

/// A blurred radiance image linearised for [`ThermalSensor::next_frame_fast`]: per pixel, the
/// output value (TLinear centikelvin or raw counts) of its noise-free radiance and the output's
/// derivative with respect to radiance there. Noise of NETD size (and fixed pattern up to
/// 0.6 K) moves the radiance so little that the first-order map errs by < 0.001 K against the
/// exact table inversion [`ThermalSensor::next_frame`] does.
#[derive(Debug, Clone)]
pub struct LinearizedRadiance {
    base: Vec<f32>,
    gain: Vec<f32>,
    slope_at_reference: f64,
}

impl LinearizedRadiance {
    pub fn new(radiometry: &Radiometry, profile: &ThermalProfile, radiance: &[f64]) -> Self {
        let slope_ref = radiometry.radiance_slope(NETD_REFERENCE_K);
        let (base, gain) = radiance
            .iter()
            .map(|&l| match profile.units {
                ThermalUnits::CentiKelvin => {
                    let t = radiometry.temperature_k(l);
                    let s = radiometry.radiance_slope(t);
                    ((t * 100.0) as f32, (100.0 / s) as f32)
                }
                ThermalUnits::RawCounts => {
                    let l_ref = radiometry.radiance(NETD_REFERENCE_K);
                    let g = profile.raw_counts_per_k / slope_ref;
                    (
                        (profile.raw_counts_at_reference + (l - l_ref) * g) as f32,
                        g as f32,
                    )
                }
            })
            .unzip();
        Self {
            base,
            gain,
            slope_at_reference: slope_ref,
        }
    }
}

fn draw_pattern(rng: &mut ChaCha8Rng, p: &ThermalProfile) -> Vec<f64> {
    let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
    // Column stripes (readout amplifiers) plus per-pixel offsets, each half the variance.
    let cols: Vec<f64> = (0..w).map(|_| StandardNormal.sample(rng)).collect();
    let mut v = Vec::with_capacity(w * h);
    for _ in 0..h {
        for c in &cols {
            let n: f64 = StandardNormal.sample(rng);
            v.push(std::f64::consts::FRAC_1_SQRT_2 * (c + n));
        }
    }
    v
}

/// The RGB camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RgbProfile {
    pub camera: CameraModel,
    pub rate_hz: f64,
    /// Full-well capacity, electrons (signal of reflectance 1 at exposure 1).
    pub full_well_e: f64,
    /// Relative exposure (1 = well exposed; low-light ≈ 0.02).
    pub exposure: f64,
    pub read_noise_e: f64,
    pub psf_sigma_px: f64,
}

impl RgbProfile {
    /// 1280×720, 70° HFOV, 30 Hz.
    pub fn hd720() -> Self {
        Self {
            camera: CameraModel {
                width_px: 1280,
                height_px: 720,
                intrinsics: Intrinsics {
                    fx: 914.0,
                    fy: 914.0,
                    cx: 641.3,
                    cy: 358.1,
                },
                distortion: BrownConrady {
                    k1: 0.09,
                    k2: -0.21,
                    p1: 0.0006,
                    p2: 0.0002,
                    k3: 0.1,
                },
            },
            rate_hz: 30.0,
            full_well_e: 9000.0,
            exposure: 1.0,
            read_noise_e: 3.0,
            psf_sigma_px: 0.7,
        }
    }

    /// The same camera in low light: 2 % exposure (shot and read noise dominate).
    pub fn hd720_low_light() -> Self {
        Self {
            exposure: 0.02,
            ..Self::hd720()
        }
    }

    /// The same camera read out at 640×360 (2×2 binning): intrinsics halved about the
    /// pixel-centre origin (`c' = (c + ½)/2 − ½`), distortion unchanged (it acts on normalised
    /// coordinates). The live rig's default RGB size: a quarter of the pixels to expose and
    /// JPEG-encode every frame.
    pub fn binned2(self) -> Self {
        let i = self.camera.intrinsics;
        let half = |c: f64| (c + 0.5) / 2.0 - 0.5;
        Self {
            camera: CameraModel {
                width_px: self.camera.width_px / 2,
                height_px: self.camera.height_px / 2,
                intrinsics: Intrinsics {
                    fx: i.fx / 2.0,
                    fy: i.fy / 2.0,
                    cx: half(i.cx),
                    cy: half(i.cy),
                },
                distortion: self.camera.distortion,
            },
            psf_sigma_px: self.psf_sigma_px / 2.0,
            ..self
        }
    }
}

/// sRGB transfer function of a linear value in [0, 1].
pub fn srgb_encode(linear: f64) -> f64 {
    let l = linear.clamp(0.0, 1.0);
    if l <= 0.003_130_8 {
        12.92 * l
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

/// Exposes a linear reflectance image (one value per pixel, grey scene lit white) with a
/// per-channel tint; returns packed 8-bit sRGB.
pub fn expose_rgb(
    profile: &RgbProfile,
    reflectance: &[f64],
    tint: [f64; 3],
    rng: &mut ChaCha8Rng,
) -> Vec<u8> {
    let [r, g, b] = tint.map(|t| reflectance.iter().map(|v| v * t).collect::<Vec<f64>>());
    expose_rgb_channels(profile, [&r, &g, &b], rng)
}

/// Exposes three linear channels (values in [0, 1] of full scale at exposure 1) with shot and
/// read noise; returns packed 8-bit sRGB.
pub fn expose_rgb_channels(
    profile: &RgbProfile,
    channels: [&[f64]; 3],
    rng: &mut ChaCha8Rng,
) -> Vec<u8> {
    let lut = srgb8_table();
    let n = channels.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = Vec::with_capacity(n * 3);
    let read_var = profile.read_noise_e * profile.read_noise_e;
    for i in 0..n {
        for ch in channels {
            let e = ch[i] * profile.exposure * profile.full_well_e;
            let noise: f64 = StandardNormal.sample(rng);
            let sigma = (e.max(0.0) + read_var).sqrt();
            let signal = ((e + sigma * noise) / profile.full_well_e).clamp(0.0, 1.0);
            out.push(lut[(signal * SRGB_LUT_STEPS as f64).round() as usize]);
        }
    }
    out
}

/// [`expose_rgb_channels`] without shot or read noise: the mean signal at the profile's
/// exposure, clipped at full well and sRGB-encoded to 8 bits through the same table (what a
/// noise-free camera at that exposure would record; the joint scene's RGB truth).
pub fn expose_rgb_channels_noise_free(profile: &RgbProfile, channels: [&[f64]; 3]) -> Vec<u8> {
    let lut = srgb8_table();
    let n = channels.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = Vec::with_capacity(n * 3);
    for i in 0..n {
        for ch in channels {
            let e = ch[i] * profile.exposure * profile.full_well_e;
            let signal = (e / profile.full_well_e).clamp(0.0, 1.0);
            out.push(lut[(signal * SRGB_LUT_STEPS as f64).round() as usize]);
        }
    }
    out
}

/// Steps per unit linear signal of the sRGB encoding table ([`srgb8_table`]).
const SRGB_LUT_STEPS: usize = 1 << 16;

/// sRGB encoding to 8 bits as a table of the linear signal (fraction of full well) in
/// 1/[`SRGB_LUT_STEPS`] steps, entries 0..=SRGB_LUT_STEPS: finer than one 8-bit code
/// everywhere (the steepest slope, 12.92 near black, moves one code per 3·10⁻⁴).
fn srgb8_table() -> Vec<u8> {
    (0..=SRGB_LUT_STEPS)
        .map(|k| (srgb_encode(k as f64 / SRGB_LUT_STEPS as f64) * 255.0).round() as u8)
        .collect()
}

/// Length of the standard-normal table of [`StaticRgbExposer`] (a power of two).
const NOISE_TABLE_LEN: usize = 1 << 20;

/// Per-frame exposure of a *static* scene for the live rig (`run`), an order of magnitude
/// cheaper than [`expose_rgb`]: the mean signal and the noise σ of every sample are computed
/// once, and the per-frame noise is read from a table of 2²⁰ standard normals starting at a
/// random offset per image row (one draw per row instead of one per sample). Every sample's
/// noise is still N(0, σ²) and frames differ, but rows are not independent draws: samples a
/// row apart may reuse a stretch of the table. Used only for the live stream, never for
/// datasets with ground truth (`board`, `scene` use [`expose_rgb`]).
#[derive(Debug, Clone)]
pub struct StaticRgbExposer {
    mean_e: Vec<f32>,
    sigma_e: Vec<f32>,
    noise: Vec<f32>,
    /// Linear signal (fraction of full well) in 1/`LUT_STEPS` steps → 8-bit sRGB.
    lut: Vec<u8>,
    /// Samples per row (width × 3).
    row_len: usize,
    inv_full_well: f32,
}

impl StaticRgbExposer {
    const LUT_STEPS: usize = SRGB_LUT_STEPS;

    /// Precomputes the exposure of `reflectance` (one value per pixel) tinted per channel.
    pub fn new(
        profile: &RgbProfile,
        reflectance: &[f64],
        tint: [f64; 3],
        width: usize,
        rng: &mut ChaCha8Rng,
    ) -> Self {
        let read_var = profile.read_noise_e * profile.read_noise_e;
        let mut mean_e = Vec::with_capacity(reflectance.len() * 3);
        let mut sigma_e = Vec::with_capacity(reflectance.len() * 3);
        for v in reflectance {
            for t in tint {
                let e = v * t * profile.exposure * profile.full_well_e;
                mean_e.push(e as f32);
                sigma_e.push((e.max(0.0) + read_var).sqrt() as f32);
            }
        }
        let noise = (0..NOISE_TABLE_LEN)
            .map(|_| {
                let n: f64 = StandardNormal.sample(rng);
                n as f32
            })
            .collect();
        let lut = srgb8_table();
        Self {
            mean_e,
            sigma_e,
            noise,
            lut,
            row_len: width * 3,
            inv_full_well: (1.0 / profile.full_well_e) as f32,
        }
    }

    /// One noisy frame, packed 8-bit sRGB.
    pub fn expose(&self, rng: &mut ChaCha8Rng) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.mean_e.len());
        let mask = NOISE_TABLE_LEN - 1;
        let steps = Self::LUT_STEPS as f32;
        for (m_row, s_row) in self
            .mean_e
            .chunks(self.row_len.max(1))
            .zip(self.sigma_e.chunks(self.row_len.max(1)))
        {
            let start = rng.random::<u32>() as usize & mask;
            for (k, (m, s)) in m_row.iter().zip(s_row).enumerate() {
                let n = self.noise[(start + k) & mask];
                let signal = ((m + s * n) * self.inv_full_well).clamp(0.0, 1.0);
                // signal ≥ 0: +0.5 and truncation round half away from zero, as `round`.
                out.push(self.lut[(signal * steps + 0.5) as usize]);
            }
        }
        out
    }
}

/// Packed RGB → YUYV 4:2:2 (BT.601, limited range). `width` must be even.
pub fn rgb_to_yuyv(rgb: &[u8], width: usize, height: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(width * height * 2);
    let yuv = |p: &[u8]| {
        let (r, g, b) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        let y = 16.0 + 0.257 * r + 0.504 * g + 0.098 * b;
        let u = 128.0 - 0.148 * r - 0.291 * g + 0.439 * b;
        let v = 128.0 + 0.439 * r - 0.368 * g - 0.071 * b;
        (y, u, v)
    };
    for row in rgb.chunks_exact(width * 3).take(height) {
        for pair in row.chunks_exact(6) {
            let (y0, u0, v0) = yuv(&pair[..3]);
            let (y1, u1, v1) = yuv(&pair[3..]);
            let q = |x: f64| x.round().clamp(0.0, 255.0) as u8;
            out.extend_from_slice(&[q(y0), q((u0 + u1) / 2.0), q(y1), q((v0 + v1) / 2.0)]);
        }
    }
    out
}

/// Packed RGB → JPEG (MJPEG frame), quality 85.
pub fn rgb_to_jpeg(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, SimError> {
    let mut out = Vec::new();
    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 85);
    enc.encode(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|source| SimError::Frame {
            what: "MJPEG frame",
            source: Box::new(source),
        })?;
    Ok(out)
}
