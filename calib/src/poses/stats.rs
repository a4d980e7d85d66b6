//! Order statistics of the poses stage's figures and robust thresholds, in one place: the
//! session stage (blur and scene depth, the tags' scale) and the folder stage (reprojection
//! errors, mismatch bounds, the reports) use these.

/// The median of `v`: the upper one for an even count, 0 for an empty slice.
pub fn median(v: &[f64]) -> f64 {
    percentile(v, 0.5)
}

/// The value at fraction `q` (0 = smallest, 1 = largest) of `v`, the nearest rank rounded
/// up at halves; 0 for an empty slice.
pub fn percentile(v: &[f64], q: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let last = v.len().saturating_sub(1);
    // (n − 1)·q rounded half up: the upper median at q = ½, as the stage has always used.
    let at = ((last as f64) * q.clamp(0.0, 1.0) + 0.5).floor() as usize;
    v.get(at.min(last)).copied().unwrap_or(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn medians_and_percentiles() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(
            median(&[4.0, 1.0, 3.0, 2.0]),
            3.0,
            "the upper median of an even count"
        );
        assert_eq!(median(&[]), 0.0);
        assert_eq!(percentile(&[5.0, 1.0, 4.0, 2.0, 3.0], 0.0), 1.0);
        assert_eq!(percentile(&[5.0, 1.0, 4.0, 2.0, 3.0], 1.0), 5.0);
        assert_eq!(
            percentile(&(1..=11).map(f64::from).collect::<Vec<_>>(), 0.9),
            10.0
        );
    }
}
