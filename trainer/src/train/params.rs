//! Row-wise operations on [`Primitives`] (and on Adam moments, which share its layout): gather
//! rows (prune, clone), zero rows, compact bands.

use crate::primitive::Primitives;

/// A new set holding rows `idx` of `p` (indices may repeat: clones).
pub fn gather(p: &Primitives<f32>, idx: &[usize]) -> Primitives<f32> {
    let mut out = Primitives::<f32>::new(p.bands, p.sh_degree);
    let (m, k) = (p.bands, p.sh_k());
    for ((name, src), (_, dst)) in p.groups().into_iter().zip(out.groups_mut()) {
        let s = name.stride(m, k);
        dst.reserve(s * idx.len());
        for &i in idx {
            dst.extend_from_slice(&src[s * i..s * (i + 1)]);
        }
    }
    out.band_count = idx
        .iter()
        .map(|&i| u32::try_from(p.live_bands(i)).unwrap_or(u32::MAX))
        .collect();
    out
}

/// Sets every value of rows `from..` to zero.
pub fn zero_rows_from(p: &mut Primitives<f32>, from: usize) {
    let (m, k) = (p.bands, p.sh_k());
    for (name, v) in p.groups_mut() {
        let s = name.stride(m, k);
        for x in v.iter_mut().skip(s * from) {
            *x = 0.0;
        }
    }
}

/// Re-lays the bands: row i keeps its bands `keep[i]` (in that order, at most `new_m`), the
/// remaining slots are zero and dropped (`band_count[i]` = the number kept). Non-band groups are
/// unchanged.
pub fn compact_bands(p: &Primitives<f32>, keep: &[Vec<usize>], new_m: usize) -> Primitives<f32> {
    let m = p.bands;
    let n = p.len();
    let mut out = p.clone();
    out.bands = new_m;
    out.band_amp = vec![0.0; n * new_m];
    out.band_phase = vec![0.0; n * new_m];
    out.band_freq = vec![0.0; 3 * n * new_m];
    out.band_count = vec![0; n];
    for (i, live) in keep.iter().enumerate().take(n) {
        out.band_count[i] = u32::try_from(live.len().min(new_m)).unwrap_or(u32::MAX);
        for (slot, &j) in live.iter().take(new_m).enumerate() {
            let (src, dst) = (m * i + j, new_m * i + slot);
            out.band_amp[dst] = p.band_amp[src];
            out.band_phase[dst] = p.band_phase[src];
            out.band_freq[3 * dst..3 * dst + 3].copy_from_slice(&p.band_freq[3 * src..3 * src + 3]);
        }
    }
    out
}

/// Number of f32 values of a set (parameters only; the `band_count` mask is extra).
pub fn value_count(p: &Primitives<f32>) -> usize {
    p.groups().iter().map(|(_, v)| v.len()).sum()
}
