//! The emissivity-coated checkerboard (TGA-GS §3.2) and its heat model.
//!
//! # Geometry (board frame)
//! Origin at the first inner corner, x along a row of corners (columns), y down the columns,
//! z into the board; every board point has z = 0. Inner corner (i, j) sits at
//! (i·s, j·s, 0) for i < cols, j < rows (OpenCV's object-point order, row-major).
//! Square (i, j) for i ∈ [−1, cols−1], j ∈ [−1, rows−1] has its top-left corner at (i·s, j·s);
//! it is *black* (printed black, carrying the low-ε coating) when i + j is even, so the
//! top-left pattern square is black. With an even number of squares along one side and an
//! odd number along the other (the default 8×5 inner corners = 9×6 squares) the pattern has no
//! 180° symmetry. A white, uncoated margin of `margin_squares` squares surrounds the pattern.
//!
//! # Heat model
//! The board is a thin plate (default 2 mm FR-4) discretised into `nodes_per_square²` lumped
//! nodes per square. Each node exchanges heat with
//! - the surroundings at `T_env` by radiation from its front (emissivity of its coating) and
//!   back (uncoated, ε = 0.9): `ε σ A (T_env⁴ − T⁴)`,
//! - the air at `T_env` by natural convection on both faces: `2 h A (T_env − T)`,
//! - its four neighbours by lateral conduction through the plate: `k t (T_n − T)` (for square
//!   nodes the edge length equals the centre distance, so the conductance is `k·t`).
//!
//! Explicit Euler at 0.5 s steps (stable: the step is ~100× below the smallest node time
//! constant). Because radiative exchange scales with ε, a coated (low-ε) node changes
//! temperature more slowly: after a step of `T_env` the coated squares lag, the temperature
//! contrast between coated and uncoated squares rises from zero, peaks after a few minutes and
//! decays as the whole board reaches `T_env`; conduction rounds the step at square edges.
//! When the surroundings are *hotter* than the board (the heated case) the coated squares lag
//! behind on the way up, so the contrast has the opposite sign.
//!
//! The surroundings are also what the board reflects: the simulator takes the reflected
//! temperature equal to `T_env` (a board in a chamber or in front of a heater panel at the
//! setpoint). The apparent (camera) contrast therefore also includes the (1−ε) reflection
//! term, which is largest right after the step and decays as the board approaches `T_env`;
//! its sign flips with the heated case too (coated squares look colder than uncoated ones on
//! a board warmer than its surroundings, warmer on a board colder than its surroundings).

use serde::{Deserialize, Serialize};

use crate::physics::{Radiometry, SIGMA_SB, ZERO_CELSIUS_K};

/// Board layout and materials.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoardSpec {
    /// Inner corners along a row (columns).
    pub inner_cols: u32,
    /// Inner corners along a column (rows).
    pub inner_rows: u32,
    pub square_m: f64,
    /// Uncoated white margin around the pattern, in squares.
    pub margin_squares: u32,
    /// Emissivity of the coated (black) squares (AgNW/PVB coating: ≈ 0.3).
    pub emissivity_coated: f64,
    /// Emissivity of the uncoated (white, printed paper/paint) squares and margin.
    pub emissivity_uncoated: f64,
    /// Visible reflectance of black and white squares (for the RGB camera).
    pub reflectance_black: f64,
    pub reflectance_white: f64,
}

impl Default for BoardSpec {
    fn default() -> Self {
        Self {
            inner_cols: 8,
            inner_rows: 5,
            square_m: 0.06,
            margin_squares: 1,
            emissivity_coated: 0.30,
            emissivity_uncoated: 0.95,
            reflectance_black: 0.06,
            reflectance_white: 0.85,
        }
    }
}

/// What lies at a board point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoardMaterial {
    /// A black, coated (low-ε) square.
    Coated,
    /// A white square or the margin (high ε).
    Uncoated,
}

impl BoardSpec {
    /// Board extent in board coordinates: (x_min, y_min, x_max, y_max), metres.
    pub fn extent_m(&self) -> (f64, f64, f64, f64) {
        let m = f64::from(self.margin_squares + 1) * self.square_m;
        (
            -m,
            -m,
            f64::from(self.inner_cols - 1) * self.square_m + m,
            f64::from(self.inner_rows - 1) * self.square_m + m,
        )
    }

    /// Inner corners in board coordinates, row-major (OpenCV object-point order).
    pub fn inner_corners_m(&self) -> Vec<glam::DVec3> {
        let mut v = Vec::with_capacity((self.inner_cols * self.inner_rows) as usize);
        for j in 0..self.inner_rows {
            for i in 0..self.inner_cols {
                v.push(glam::DVec3::new(
                    f64::from(i) * self.square_m,
                    f64::from(j) * self.square_m,
                    0.0,
                ));
            }
        }
        v
    }

    /// Material at board point (x, y); `None` off the board.
    pub fn material_at(&self, x_m: f64, y_m: f64) -> Option<BoardMaterial> {
        let (x0, y0, x1, y1) = self.extent_m();
        if x_m < x0 || y_m < y0 || x_m >= x1 || y_m >= y1 {
            return None;
        }
        let i = (x_m / self.square_m).floor() as i64;
        let j = (y_m / self.square_m).floor() as i64;
        let in_pattern =
            i >= -1 && j >= -1 && i < i64::from(self.inner_cols) && j < i64::from(self.inner_rows);
        if in_pattern && (i + j).rem_euclid(2) == 0 {
            Some(BoardMaterial::Coated)
        } else {
            Some(BoardMaterial::Uncoated)
        }
    }

    pub fn emissivity(&self, m: BoardMaterial) -> f64 {
        match m {
            BoardMaterial::Coated => self.emissivity_coated,
            BoardMaterial::Uncoated => self.emissivity_uncoated,
        }
    }

    pub fn reflectance(&self, m: BoardMaterial) -> f64 {
        match m {
            BoardMaterial::Coated => self.reflectance_black,
            BoardMaterial::Uncoated => self.reflectance_white,
        }
    }
}

/// Plate material and environment coupling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlateSpec {
    pub thickness_m: f64,
    /// Thermal conductivity, W/(m·K). FR-4 in plane ≈ 0.8.
    pub conductivity_w_per_m_k: f64,
    /// Volumetric heat capacity ρ·c_p, J/(m³·K). FR-4 ≈ 1850 kg/m³ · 1100 J/(kg·K).
    pub volumetric_heat_capacity: f64,
    /// Natural-convection coefficient per face, W/(m²·K).
    pub convection_w_per_m2_k: f64,
    /// Emissivity of the (uncoated) back face.
    pub emissivity_back: f64,
    /// Lumped nodes per square edge.
    pub nodes_per_square: u32,
}

impl Default for PlateSpec {
    fn default() -> Self {
        Self {
            thickness_m: 0.002,
            conductivity_w_per_m_k: 0.8,
            volumetric_heat_capacity: 1850.0 * 1100.0,
            convection_w_per_m2_k: 3.0,
            emissivity_back: 0.9,
            nodes_per_square: 6,
        }
    }
}

/// Time step of the heat model, seconds.
pub const HEAT_STEP_S: f64 = 0.5;

/// Temperature field of the board plate.
#[derive(Debug, Clone)]
pub struct BoardThermal {
    pub board: BoardSpec,
    pub plate: PlateSpec,
    /// Node grid size.
    nx: usize,
    ny: usize,
    /// Node edge length, metres.
    node_m: f64,
    /// Board-frame coordinates of node (0, 0)'s lower corner (x_min, y_min).
    origin_m: (f64, f64),
    /// Node temperatures, kelvin, row-major.
    temps_k: Vec<f64>,
    /// Front emissivity per node.
    emissivity: Vec<f64>,
    /// Surroundings (air, walls, reflected) temperature, kelvin.
    pub env_k: f64,
    /// Simulated time since the start, seconds.
    pub time_s: f64,
}

impl BoardThermal {
    /// A board in equilibrium at `start_k` with surroundings at `env_k`.
    pub fn new(board: BoardSpec, plate: PlateSpec, start_k: f64, env_k: f64) -> Self {
        let (x0, y0, x1, y1) = board.extent_m();
        let node_m = board.square_m / f64::from(plate.nodes_per_square.max(1));
        let nx = ((x1 - x0) / node_m).round() as usize;
        let ny = ((y1 - y0) / node_m).round() as usize;
        let mut emissivity = Vec::with_capacity(nx * ny);
        for iy in 0..ny {
            for ix in 0..nx {
                let x = x0 + (ix as f64 + 0.5) * node_m;
                let y = y0 + (iy as f64 + 0.5) * node_m;
                let m = board.material_at(x, y).unwrap_or(BoardMaterial::Uncoated);
                emissivity.push(board.emissivity(m));
            }
        }
        Self {
            board,
            plate,
            nx,
            ny,
            node_m,
            origin_m: (x0, y0),
            temps_k: vec![start_k; nx * ny],
            emissivity,
            env_k,
            time_s: 0.0,
        }
    }

    /// The TGA-GS induction: equilibrium at 25 °C, surroundings stepped to −20 °C.
    pub fn cooled(board: BoardSpec) -> Self {
        Self::new(
            board,
            PlateSpec::default(),
            ZERO_CELSIUS_K + 25.0,
            ZERO_CELSIUS_K - 20.0,
        )
    }

    /// The opposite case: equilibrium at 25 °C, surroundings (heater panel/chamber) at 70 °C.
    pub fn heated(board: BoardSpec) -> Self {
        Self::new(
            board,
            PlateSpec::default(),
            ZERO_CELSIUS_K + 25.0,
            ZERO_CELSIUS_K + 70.0,
        )
    }

    /// Advances the model by `duration_s` (in [`HEAT_STEP_S`] steps; a remainder is one short step).
    pub fn advance(&mut self, duration_s: f64) {
        let mut left = duration_s;
        while left > 1e-12 {
            let dt = left.min(HEAT_STEP_S);
            self.step(dt);
            left -= dt;
        }
    }

    fn step(&mut self, dt: f64) {
        let p = &self.plate;
        let area = self.node_m * self.node_m;
        let cap = p.volumetric_heat_capacity * p.thickness_m * area;
        let g_lat = p.conductivity_w_per_m_k * p.thickness_m;
        let env4 = self.env_k.powi(4);
        let (nx, ny) = (self.nx, self.ny);
        let old = &self.temps_k;
        let mut new = old.clone();
        for iy in 0..ny {
            for ix in 0..nx {
                let k = iy * nx + ix;
                let t = old[k];
                let rad =
                    (self.emissivity[k] + p.emissivity_back) * SIGMA_SB * area * (env4 - t.powi(4));
                let conv = 2.0 * p.convection_w_per_m2_k * area * (self.env_k - t);
                let mut lat = 0.0;
                if ix > 0 {
                    lat += old[k - 1] - t;
                }
                if ix + 1 < nx {
                    lat += old[k + 1] - t;
                }
                if iy > 0 {
                    lat += old[k - nx] - t;
                }
                if iy + 1 < ny {
                    lat += old[k + nx] - t;
                }
                new[k] = t + dt * (rad + conv + g_lat * lat) / cap;
            }
        }
        self.temps_k = new;
        self.time_s += dt;
    }

    /// Plate temperature at a board point, bilinear between node centres, kelvin.
    pub fn temperature_at(&self, x_m: f64, y_m: f64) -> f64 {
        let fx = ((x_m - self.origin_m.0) / self.node_m - 0.5).clamp(0.0, (self.nx - 1) as f64);
        let fy = ((y_m - self.origin_m.1) / self.node_m - 0.5).clamp(0.0, (self.ny - 1) as f64);
        let ix = (fx.floor() as usize).min(self.nx.saturating_sub(2));
        let iy = (fy.floor() as usize).min(self.ny.saturating_sub(2));
        let (ax, ay) = (fx - ix as f64, fy - iy as f64);
        let at = |x: usize, y: usize| {
            let x = x.min(self.nx - 1);
            let y = y.min(self.ny - 1);
            self.temps_k[y * self.nx + x]
        };
        let top = at(ix, iy) * (1.0 - ax) + at(ix + 1, iy) * ax;
        let bottom = at(ix, iy + 1) * (1.0 - ax) + at(ix + 1, iy + 1) * ax;
        top * (1.0 - ay) + bottom * ay
    }

    /// Apparent in-band radiance of a board point (emitted + reflected surroundings).
    pub fn apparent_radiance_at(&self, radiometry: &Radiometry, x_m: f64, y_m: f64) -> Option<f64> {
        let m = self.board.material_at(x_m, y_m)?;
        let eps = self.board.emissivity(m);
        Some(radiometry.apparent_radiance(eps, self.temperature_at(x_m, y_m), self.env_k))
    }

    /// Centres of the pattern squares with their material.
    fn square_centres(&self) -> Vec<(f64, f64, BoardMaterial)> {
        let s = self.board.square_m;
        let mut v = Vec::new();
        for j in -1..i64::from(self.board.inner_rows) {
            for i in -1..i64::from(self.board.inner_cols) {
                let (x, y) = ((i as f64 + 0.5) * s, (j as f64 + 0.5) * s);
                if let Some(m) = self.board.material_at(x, y) {
                    v.push((x, y, m));
                }
            }
        }
        v
    }

    /// Physical contrast: mean temperature at coated square centres minus uncoated ones, K.
    pub fn physical_contrast_k(&self) -> f64 {
        self.contrast(|x, y, _| self.temperature_at(x, y))
    }

    /// Apparent (TLinear) contrast a camera sees: coated minus uncoated square centres, K.
    pub fn apparent_contrast_k(&self, radiometry: &Radiometry) -> f64 {
        self.contrast(|x, y, m| {
            let eps = self.board.emissivity(m);
            radiometry.temperature_k(radiometry.apparent_radiance(
                eps,
                self.temperature_at(x, y),
                self.env_k,
            ))
        })
    }

    fn contrast(&self, value: impl Fn(f64, f64, BoardMaterial) -> f64) -> f64 {
        let (mut sc, mut nc, mut su, mut nu) = (0.0, 0usize, 0.0, 0usize);
        for (x, y, m) in self.square_centres() {
            let v = value(x, y, m);
            match m {
                BoardMaterial::Coated => {
                    sc += v;
                    nc += 1;
                }
                BoardMaterial::Uncoated => {
                    su += v;
                    nu += 1;
                }
            }
        }
        sc / nc.max(1) as f64 - su / nu.max(1) as f64
    }

    /// Mean plate temperature over uncoated nodes (what a thermistor on a white square reads).
    pub fn mean_uncoated_temp_k(&self) -> f64 {
        let hi = self.board.emissivity_uncoated;
        let (s, n) = self
            .temps_k
            .iter()
            .zip(&self.emissivity)
            .filter(|(_, e)| (**e - hi).abs() < 1e-12)
            .fold((0.0, 0usize), |(s, n), (t, _)| (s + t, n + 1));
        s / n.max(1) as f64
    }
}
