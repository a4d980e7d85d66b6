//! [`Real`]: the small float trait the CPU reference renderer and losses are generic over.
//!
//! Only `f32` and `f64` implement it. f64 is the ground truth (finite-difference tests); f32 is what
//! the Vulkan port computes in, so the stiff-case suite compares the two.

use std::fmt::{Debug, Display};
use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

/// A real scalar (`f32` or `f64`).
pub trait Real:
    Copy
    + Debug
    + Display
    + Default
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
{
    const ZERO: Self;
    const ONE: Self;
    const TWO: Self;
    const HALF: Self;
    /// Machine epsilon.
    const EPSILON: Self;
    /// Smallest positive normal value.
    const MIN_POSITIVE: Self;
    /// Largest finite value.
    const MAX: Self;

    /// Conversion from f64 (rounds for f32).
    fn from_f64(x: f64) -> Self;
    /// Widening conversion to f64.
    fn to_f64(self) -> f64;
    fn exp(self) -> Self;
    /// Natural logarithm.
    fn ln(self) -> Self;
    fn sqrt(self) -> Self;
    fn cos(self) -> Self;
    fn sin(self) -> Self;
    fn abs(self) -> Self;
    /// `self^e` with C `pow` semantics (`0^0 = 1`, `0^e = 0` for `e > 0`).
    fn powf(self, e: Self) -> Self;
    fn is_finite(self) -> bool;
    /// Maximum that ignores NaN in `other` like `f64::max`.
    fn max(self, other: Self) -> Self;
    fn min(self, other: Self) -> Self;

    /// `ln(1 + e^x)` without overflow.
    fn softplus(self) -> Self {
        let twenty = Self::from_f64(20.0);
        if self > twenty {
            self
        } else if self < -twenty {
            self.exp()
        } else {
            (Self::ONE + self.exp()).ln()
        }
    }

    /// `1 / (1 + e^{-x})` without overflow.
    fn sigmoid(self) -> Self {
        if self >= Self::ZERO {
            Self::ONE / (Self::ONE + (-self).exp())
        } else {
            let e = self.exp();
            e / (Self::ONE + e)
        }
    }

    /// Sign with `signum(0) = 0` (the subgradient the L1 terms use).
    fn sign0(self) -> Self {
        if self > Self::ZERO {
            Self::ONE
        } else if self < Self::ZERO {
            -Self::ONE
        } else {
            Self::ZERO
        }
    }
}

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const TWO: Self = 2.0;
            const HALF: Self = 0.5;
            const EPSILON: Self = <$t>::EPSILON;
            const MIN_POSITIVE: Self = <$t>::MIN_POSITIVE;
            const MAX: Self = <$t>::MAX;

            #[inline]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline]
            fn powf(self, e: Self) -> Self {
                <$t>::powf(self, e)
            }
            #[inline]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
        }
    };
}

impl_real!(f32);
impl_real!(f64);

/// 3-vector helpers on plain arrays (flat, GPU-friendly; no glam generic over the scalar).
pub(crate) mod v3 {
    use super::Real;

    #[inline]
    pub fn dot<T: Real>(a: [T; 3], b: [T; 3]) -> T {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }
    #[inline]
    pub fn add<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }
    #[inline]
    pub fn sub<T: Real>(a: [T; 3], b: [T; 3]) -> [T; 3] {
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    }
    #[inline]
    pub fn scale<T: Real>(a: [T; 3], s: T) -> [T; 3] {
        [a[0] * s, a[1] * s, a[2] * s]
    }
    /// `m * v` for a row-major 3×3 `m`.
    #[inline]
    pub fn mat_vec<T: Real>(m: &[T; 9], v: [T; 3]) -> [T; 3] {
        [
            m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
            m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
            m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
        ]
    }
    /// `mᵀ * v` for a row-major 3×3 `m`.
    #[inline]
    pub fn mat_t_vec<T: Real>(m: &[T; 9], v: [T; 3]) -> [T; 3] {
        [
            m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
            m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
            m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
        ]
    }
    /// `a * b` for row-major 3×3 matrices.
    #[inline]
    pub fn mat_mul<T: Real>(a: &[T; 9], b: &[T; 9]) -> [T; 9] {
        let mut out = [T::ZERO; 9];
        for r in 0..3 {
            for c in 0..3 {
                out[3 * r + c] =
                    a[3 * r] * b[c] + a[3 * r + 1] * b[3 + c] + a[3 * r + 2] * b[6 + c];
            }
        }
        out
    }
}
