//! Image and G-buffers (planar, row-major, one `Vec` per channel): the renderer's outputs and, with
//! the same layout, the upstream gradients `dL/d(buffer)` given to the backward pass.

use crate::real::Real;

/// Rendered buffers (or their upstream gradients). `rgb` holds three planes (R, G, B) or is empty
/// when the primitives carry no colour.
#[derive(Debug, Clone, PartialEq)]
pub struct GBuffers<T> {
    pub width: usize,
    pub height: usize,
    pub thermal: Vec<T>,
    pub rgb: Vec<T>,
    pub psi_low: Vec<T>,
    pub psi_high: Vec<T>,
    pub psi_beta: Vec<T>,
    /// Alpha-weighted camera depth `Σ w t*` (metres); `depth / alpha` is the expected depth.
    pub depth: Vec<T>,
    pub alpha: Vec<T>,
}

impl<T: Real> GBuffers<T> {
    /// Zero buffers (`rgb`: whether the three colour planes exist).
    pub fn zeros(width: usize, height: usize, rgb: bool) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            thermal: vec![T::ZERO; n],
            rgb: if rgb {
                vec![T::ZERO; 3 * n]
            } else {
                Vec::new()
            },
            psi_low: vec![T::ZERO; n],
            psi_high: vec![T::ZERO; n],
            psi_beta: vec![T::ZERO; n],
            depth: vec![T::ZERO; n],
            alpha: vec![T::ZERO; n],
        }
    }

    /// Every buffer by name.
    pub fn planes(&self) -> [(&'static str, &Vec<T>); 7] {
        [
            ("thermal", &self.thermal),
            ("rgb", &self.rgb),
            ("psi_low", &self.psi_low),
            ("psi_high", &self.psi_high),
            ("psi_beta", &self.psi_beta),
            ("depth", &self.depth),
            ("alpha", &self.alpha),
        ]
    }

    /// Mutable access to every buffer by name.
    pub fn planes_mut(&mut self) -> [(&'static str, &mut Vec<T>); 7] {
        [
            ("thermal", &mut self.thermal),
            ("rgb", &mut self.rgb),
            ("psi_low", &mut self.psi_low),
            ("psi_high", &mut self.psi_high),
            ("psi_beta", &mut self.psi_beta),
            ("depth", &mut self.depth),
            ("alpha", &mut self.alpha),
        ]
    }

    /// Whether every value is finite.
    pub fn all_finite(&self) -> bool {
        self.planes()
            .iter()
            .all(|(_, v)| v.iter().all(|x| x.is_finite()))
    }

    /// Expected depth at pixel `p` (`depth / alpha`), `None` where `alpha < min_alpha`.
    pub fn expected_depth(&self, p: usize, min_alpha: T) -> Option<T> {
        let a = self.alpha[p];
        if a >= min_alpha && a > T::ZERO {
            Some(self.depth[p] / a)
        } else {
            None
        }
    }
}
