//! AlexNet's feature layers as LPIPS uses them: five convolutions with ReLU, max-pooling after
//! the first two (torchvision's `alexnet().features`, cut after the fifth ReLU).
//!
//! A convolution is an im2col product: the input's patches for a block of output pixels are laid
//! out as a `K × block` matrix (`K = c_in·k·k`, ordered channel, row, column) and multiplied by
//! the `c_out × K` weight matrix with `matrixmultiply`'s SGEMM (the kernel `ndarray` uses, with
//! AVX/FMA dispatch at run time). Blocks of output pixels run on rayon; each writes its own
//! columns, so the result does not depend on the thread count.

use rayon::prelude::*;

/// A CHW float image (or feature map).
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    pub channels: usize,
    pub height: usize,
    pub width: usize,
    pub data: Vec<f32>,
}

impl Tensor {
    pub fn zeros(channels: usize, height: usize, width: usize) -> Self {
        Self {
            channels,
            height,
            width,
            data: vec![0.0; channels * height * width],
        }
    }
}

/// One convolution: weights as a `c_out × (c_in·k·k)` row-major matrix, bias, kernel size,
/// stride and zero padding.
#[derive(Debug, Clone)]
pub struct Conv {
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
    pub stride: usize,
    pub pad: usize,
    pub weights: Vec<f32>,
    pub bias: Vec<f32>,
}

/// Output pixels per im2col block: large enough to keep SGEMM efficient, small enough that a
/// block's patch matrix (`K × BLOCK`, at most 3 456 × 512 floats = 7 MB) stays modest.
const BLOCK: usize = 512;

impl Conv {
    /// The weight matrix from a flax/TensorFlow `HWIO` kernel (`[k][k][c_in][c_out]`).
    pub fn from_hwio(
        hwio: &[f32],
        bias: Vec<f32>,
        (kernel, c_in, c_out): (usize, usize, usize),
        (stride, pad): (usize, usize),
    ) -> Self {
        let kk = kernel * kernel;
        let mut weights = vec![0.0; c_out * c_in * kk];
        for ky in 0..kernel {
            for kx in 0..kernel {
                for ci in 0..c_in {
                    for o in 0..c_out {
                        weights[o * c_in * kk + ci * kk + ky * kernel + kx] =
                            hwio[((ky * kernel + kx) * c_in + ci) * c_out + o];
                    }
                }
            }
        }
        Self {
            c_in,
            c_out,
            kernel,
            stride,
            pad,
            weights,
            bias,
        }
    }

    /// Output size along one axis of `n` input pixels (`None` when the kernel does not fit).
    fn out_len(&self, n: usize) -> Option<usize> {
        (n + 2 * self.pad)
            .checked_sub(self.kernel)
            .map(|d| d / self.stride + 1)
    }

    /// The convolution followed by ReLU; `None` when the input is smaller than the kernel.
    pub fn forward_relu(&self, x: &Tensor) -> Option<Tensor> {
        debug_assert_eq!(x.channels, self.c_in);
        let (oh, ow) = (self.out_len(x.height)?, self.out_len(x.width)?);
        let p = oh * ow;
        let k = self.c_in * self.kernel * self.kernel;
        let blocks: Vec<(usize, Vec<f32>)> = (0..p)
            .step_by(BLOCK)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|p0| {
                let n = BLOCK.min(p - p0);
                let cols = self.patches(x, (oh, ow), p0, n);
                let mut out = vec![0.0f32; self.c_out * n];
                sgemm(&self.weights, &cols, &mut out, (self.c_out, k, n));
                (p0, out)
            })
            .collect();
        let mut y = Tensor::zeros(self.c_out, oh, ow);
        for (p0, out) in blocks {
            let n = out.len() / self.c_out;
            for o in 0..self.c_out {
                let b = self.bias[o];
                let dst = &mut y.data[o * p + p0..o * p + p0 + n];
                for (d, s) in dst.iter_mut().zip(&out[o * n..(o + 1) * n]) {
                    *d = (s + b).max(0.0);
                }
            }
        }
        Some(y)
    }

    /// The `K × n` patch matrix of output pixels `p0 .. p0 + n` (zeros where the window overhangs
    /// the padded border).
    fn patches(&self, x: &Tensor, (_oh, ow): (usize, usize), p0: usize, n: usize) -> Vec<f32> {
        let kk = self.kernel * self.kernel;
        let mut cols = vec![0.0f32; self.c_in * kk * n];
        for j in 0..n {
            let (oy, ox) = ((p0 + j) / ow, (p0 + j) % ow);
            let y0 = (oy * self.stride) as isize - self.pad as isize;
            let x0 = (ox * self.stride) as isize - self.pad as isize;
            for ky in 0..self.kernel {
                let iy = y0 + ky as isize;
                if iy < 0 || iy >= x.height as isize {
                    continue;
                }
                for kx in 0..self.kernel {
                    let ix = x0 + kx as isize;
                    if ix < 0 || ix >= x.width as isize {
                        continue;
                    }
                    let src = iy as usize * x.width + ix as usize;
                    let row = ky * self.kernel + kx;
                    for ci in 0..self.c_in {
                        cols[(ci * kk + row) * n + j] = x.data[ci * x.height * x.width + src];
                    }
                }
            }
        }
        cols
    }
}

/// `c = a·b` for row-major `a` (`m × k`), `b` (`k × n`) and `c` (`m × n`).
fn sgemm(a: &[f32], b: &[f32], c: &mut [f32], (m, k, n): (usize, usize, usize)) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && c.len() >= m * n,
        "sgemm: buffers smaller than {m}×{k} · {k}×{n}"
    );
    // SAFETY: the three slices hold at least m·k, k·n and m·n floats (asserted above), the
    // strides below address exactly those row-major matrices, and `c` does not alias `a` or `b`
    // (it is borrowed mutably).
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}

/// 3×3 max-pooling with stride 2 and no padding (PyTorch's `MaxPool2d(3, 2)`, floor mode);
/// `None` when the input is smaller than the window.
pub fn max_pool_3x3_s2(x: &Tensor) -> Option<Tensor> {
    let oh = x.height.checked_sub(3)? / 2 + 1;
    let ow = x.width.checked_sub(3)? / 2 + 1;
    let mut y = Tensor::zeros(x.channels, oh, ow);
    y.data
        .par_chunks_mut(oh * ow)
        .enumerate()
        .for_each(|(c, out)| {
            let plane = &x.data[c * x.height * x.width..(c + 1) * x.height * x.width];
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut m = f32::NEG_INFINITY;
                    for dy in 0..3 {
                        let row = &plane[(2 * oy + dy) * x.width + 2 * ox..][..3];
                        m = row.iter().fold(m, |a, &b| a.max(b));
                    }
                    out[oy * ow + ox] = m;
                }
            }
        });
    Some(y)
}

/// AlexNet's five convolutions (LPIPS's `alexnet` backbone).
#[derive(Debug, Clone)]
pub struct AlexNet {
    pub convs: [Conv; 5],
}

impl AlexNet {
    /// The five ReLU outputs (`relu1` … `relu5`), or `None` when the image is too small for the
    /// network (under [`super::MIN_SIDE`] pixels on a side).
    pub fn features(&self, x: &Tensor) -> Option<Vec<Tensor>> {
        let r1 = self.convs[0].forward_relu(x)?;
        let r2 = self.convs[1].forward_relu(&max_pool_3x3_s2(&r1)?)?;
        let r3 = self.convs[2].forward_relu(&max_pool_3x3_s2(&r2)?)?;
        let r4 = self.convs[3].forward_relu(&r3)?;
        let r5 = self.convs[4].forward_relu(&r4)?;
        Some(vec![r1, r2, r3, r4, r5])
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    /// A direct (six-loop) convolution + ReLU: the reference the im2col product must match.
    fn direct(conv: &Conv, x: &Tensor) -> Tensor {
        let oh = (x.height + 2 * conv.pad - conv.kernel) / conv.stride + 1;
        let ow = (x.width + 2 * conv.pad - conv.kernel) / conv.stride + 1;
        let kk = conv.kernel * conv.kernel;
        let mut y = Tensor::zeros(conv.c_out, oh, ow);
        for o in 0..conv.c_out {
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut s = f64::from(conv.bias[o]);
                    for ci in 0..conv.c_in {
                        for ky in 0..conv.kernel {
                            for kx in 0..conv.kernel {
                                let iy = (oy * conv.stride + ky) as isize - conv.pad as isize;
                                let ix = (ox * conv.stride + kx) as isize - conv.pad as isize;
                                if iy < 0
                                    || ix < 0
                                    || iy >= x.height as isize
                                    || ix >= x.width as isize
                                {
                                    continue;
                                }
                                let w = conv.weights
                                    [o * conv.c_in * kk + ci * kk + ky * conv.kernel + kx];
                                let v =
                                    x.data[(ci * x.height + iy as usize) * x.width + ix as usize];
                                s += f64::from(w) * f64::from(v);
                            }
                        }
                    }
                    y.data[(o * oh + oy) * ow + ox] = s.max(0.0) as f32;
                }
            }
        }
        y
    }

    fn pseudo(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s as f32 / u32::MAX as f32) - 0.5
            })
            .collect()
    }

    /// The im2col product equals the direct convolution for strided, padded kernels across
    /// several blocks (an image of more than BLOCK output pixels), and the HWIO transpose puts
    /// every weight where the direct loop reads it.
    #[test]
    fn im2col_convolution_matches_the_direct_one() {
        for &(k, stride, pad, c_in, c_out, h, w) in &[
            (11, 4, 2, 3, 5, 97, 131),
            (5, 1, 2, 4, 6, 30, 25),
            (3, 1, 1, 7, 3, 40, 33),
        ] {
            let hwio = pseudo(k * k * c_in * c_out, 1);
            let conv = Conv::from_hwio(&hwio, pseudo(c_out, 2), (k, c_in, c_out), (stride, pad));
            // HWIO element (ky, kx, ci, o) lands at weights[o][ci][ky][kx].
            let (ky, kx, ci, o) = (k - 1, 0, c_in - 1, c_out - 1);
            assert_eq!(
                conv.weights[o * c_in * k * k + ci * k * k + ky * k + kx],
                hwio[((ky * k + kx) * c_in + ci) * c_out + o],
                "HWIO transpose"
            );
            let x = Tensor {
                channels: c_in,
                height: h,
                width: w,
                data: pseudo(c_in * h * w, 3),
            };
            let fast = conv.forward_relu(&x).unwrap();
            let slow = direct(&conv, &x);
            assert_eq!((fast.height, fast.width), (slow.height, slow.width));
            let worst = fast
                .data
                .iter()
                .zip(&slow.data)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst < 1e-4,
                "kernel {k} stride {stride}: im2col differs from the direct convolution by {worst}"
            );
        }
    }

    #[test]
    fn max_pool_takes_the_window_maximum_in_floor_mode() {
        let x = Tensor {
            channels: 1,
            height: 6,
            width: 7,
            data: (0..42).map(|v| ((v * 17) % 23) as f32).collect(),
        };
        let y = max_pool_3x3_s2(&x).unwrap();
        assert_eq!(
            (y.height, y.width),
            (2, 3),
            "floor((6-3)/2)+1, floor((7-3)/2)+1"
        );
        for oy in 0..2 {
            for ox in 0..3 {
                let mut m = f32::MIN;
                for dy in 0..3 {
                    for dx in 0..3 {
                        m = m.max(x.data[(2 * oy + dy) * 7 + 2 * ox + dx]);
                    }
                }
                assert_eq!(y.data[oy * 3 + ox], m, "window ({oy}, {ox})");
            }
        }
        assert!(
            max_pool_3x3_s2(&Tensor::zeros(1, 2, 9)).is_none(),
            "a 2-row input has no 3×3 window"
        );
    }
}
