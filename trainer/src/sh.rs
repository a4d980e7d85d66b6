//! Real spherical harmonics (degree 0–3, the 3DGS basis and constants) for the optional RGB
//! colour of a primitive, with the gradient w.r.t. the coefficients and the view direction.
//!
//! Colour `c = max(0, Σ_k Y_k(d) sh_k + ½)` with `d = (μ − camera centre)/‖μ − camera centre‖`
//! (3DGS's convention: degree-0 coefficients are offsets from grey). Degrees above 3 are read as 3.

use crate::real::Real;

const C0: f64 = 0.282_094_791_773_878_14;
const C1: f64 = 0.488_602_511_902_919_9;
const C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
const C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// Highest supported degree.
pub const SH_MAX_DEGREE: usize = 3;

/// Basis values `Y_k(d)` and their gradients `∂Y_k/∂d` for a unit direction (16 entries; only
/// the first `(degree+1)²` are meaningful).
pub fn basis<T: Real>(d: [T; 3]) -> ([T; 16], [[T; 3]; 16]) {
    let f = T::from_f64;
    let [x, y, z] = d;
    let z0 = T::ZERO;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    let three = f(3.0);
    let y_val = [
        f(C0),
        -f(C1) * y,
        f(C1) * z,
        -f(C1) * x,
        f(C2[0]) * x * y,
        f(C2[1]) * y * z,
        f(C2[2]) * (T::TWO * zz - xx - yy),
        f(C2[3]) * x * z,
        f(C2[4]) * (xx - yy),
        f(C3[0]) * y * (three * xx - yy),
        f(C3[1]) * x * y * z,
        f(C3[2]) * y * (f(4.0) * zz - xx - yy),
        f(C3[3]) * z * (T::TWO * zz - three * xx - three * yy),
        f(C3[4]) * x * (f(4.0) * zz - xx - yy),
        f(C3[5]) * z * (xx - yy),
        f(C3[6]) * x * (xx - three * yy),
    ];
    let s = |c: f64, g: [T; 3]| [f(c) * g[0], f(c) * g[1], f(c) * g[2]];
    let grad = [
        [z0; 3],
        s(C1, [z0, -T::ONE, z0]),
        s(C1, [z0, z0, T::ONE]),
        s(C1, [-T::ONE, z0, z0]),
        s(C2[0], [y, x, z0]),
        s(C2[1], [z0, z, y]),
        s(C2[2], [-T::TWO * x, -T::TWO * y, f(4.0) * z]),
        s(C2[3], [z, z0, x]),
        s(C2[4], [T::TWO * x, -T::TWO * y, z0]),
        s(C3[0], [f(6.0) * x * y, three * xx - three * yy, z0]),
        s(C3[1], [y * z, x * z, x * y]),
        s(
            C3[2],
            [
                -T::TWO * x * y,
                f(4.0) * zz - xx - three * yy,
                f(8.0) * y * z,
            ],
        ),
        s(
            C3[3],
            [
                -f(6.0) * x * z,
                -f(6.0) * y * z,
                f(6.0) * zz - three * xx - three * yy,
            ],
        ),
        s(
            C3[4],
            [
                f(4.0) * zz - three * xx - yy,
                -T::TWO * x * y,
                f(8.0) * x * z,
            ],
        ),
        s(C3[5], [T::TWO * x * z, -T::TWO * y * z, xx - yy]),
        s(C3[6], [three * xx - three * yy, -f(6.0) * x * y, z0]),
    ];
    (y_val, grad)
}

/// Unit direction of `v` and its norm (direction +z for a zero vector).
pub fn normalize<T: Real>(v: [T; 3]) -> ([T; 3], T) {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > T::ZERO {
        ([v[0] / n, v[1] / n, v[2] / n], n)
    } else {
        ([T::ZERO, T::ZERO, T::ONE], T::ZERO)
    }
}

/// Colour of one primitive: `coeffs[k*3 + c]`, `k < K`. Returns the colour and the pre-ReLU value.
pub fn eval<T: Real>(coeffs: &[T], k: usize, dir: [T; 3]) -> ([T; 3], [T; 3]) {
    let (y, _) = basis(dir);
    let mut pre = [T::HALF; 3];
    for (kk, yk) in y.iter().enumerate().take(k.min(16)) {
        for (c, p) in pre.iter_mut().enumerate() {
            *p += *yk * coeffs[kk * 3 + c];
        }
    }
    (pre.map(|p| p.max(T::ZERO)), pre)
}

/// Backward of [`eval`]: adds `dL/dcoeffs` to `g_coeffs` and returns `dL/dv` where
/// `dir = v/‖v‖` (`norm = ‖v‖`).
pub fn backward<T: Real>(
    coeffs: &[T],
    k: usize,
    dir: [T; 3],
    norm: T,
    g_colour: [T; 3],
    g_coeffs: &mut [T],
) -> [T; 3] {
    let (y, dy) = basis(dir);
    let (_, pre) = eval(coeffs, k, dir);
    let g_pre: [T; 3] = std::array::from_fn(|c| {
        if pre[c] > T::ZERO {
            g_colour[c]
        } else {
            T::ZERO
        }
    });
    let mut g_dir = [T::ZERO; 3];
    for kk in 0..k.min(16) {
        let mut gy = T::ZERO;
        for c in 0..3 {
            g_coeffs[kk * 3 + c] += y[kk] * g_pre[c];
            gy += coeffs[kk * 3 + c] * g_pre[c];
        }
        for (a, g) in g_dir.iter_mut().enumerate() {
            *g += gy * dy[kk][a];
        }
    }
    if norm == T::ZERO {
        return [T::ZERO; 3];
    }
    let dd = g_dir[0] * dir[0] + g_dir[1] * dir[1] + g_dir[2] * dir[2];
    std::array::from_fn(|a| (g_dir[a] - dd * dir[a]) / norm)
}
