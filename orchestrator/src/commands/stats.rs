//! Summary statistics of evaluation and batch runs: success intervals, quantiles, means.

/// The 95% Wilson score interval [low, high] of a success rate of `successes` out of
/// `trials` (both bounds within 0..=1; [0, 1] for no trials). Unlike the normal
/// approximation it stays inside 0..=1 and keeps a width at 50 of 50.
pub(crate) fn wilson_interval_95(successes: usize, trials: usize) -> [f64; 2] {
    if trials == 0 {
        return [0.0, 1.0];
    }
    const Z: f64 = 1.959_964;
    let n = trials as f64;
    let p = successes as f64 / n;
    let centre = p + Z * Z / (2.0 * n);
    let spread = Z * (p * (1.0 - p) / n + Z * Z / (4.0 * n * n)).sqrt();
    let scale = 1.0 + Z * Z / n;
    [((centre - spread) / scale).max(0.0), ((centre + spread) / scale).min(1.0)]
}

/// The q-quantile (0..=1) of `values` by linear interpolation; NaN when empty.
pub(crate) fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let position = q * (sorted.len() - 1) as f64;
    let (low, high) = (position.floor() as usize, position.ceil() as usize);
    sorted[low] + (sorted[high] - sorted[low]) * (position - low as f64)
}

/// Mean of the finite values (an episode the segmenter could not ground has no MED); NaN
/// when there are none.
pub(crate) fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, count) = values.filter(|v| v.is_finite()).fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if count == 0 {
        f64::NAN
    } else {
        sum / count as f64
    }
}

#[cfg(test)]
mod tests {
    use super::{quantile, wilson_interval_95};

    #[test]
    fn success_intervals_bracket_the_rate_and_narrow_with_more_scenes() {
        let at_the_line = wilson_interval_95(45, 50);
        assert!((at_the_line[0] - 0.786).abs() < 1e-3 && (at_the_line[1] - 0.957).abs() < 1e-3, "{at_the_line:?}");
        let same_rate_more_scenes = wilson_interval_95(270, 300);
        assert!(same_rate_more_scenes[0] > at_the_line[0] && same_rate_more_scenes[1] < at_the_line[1]);
        // Every success: the upper bound is 1, the lower one is not.
        let all = wilson_interval_95(50, 50);
        assert!((all[1] - 1.0).abs() < 1e-9 && (all[0] - 0.929).abs() < 1e-3, "{all:?}");
        assert_eq!(wilson_interval_95(0, 0), [0.0, 1.0]);
    }

    #[test]
    fn quantiles_interpolate() {
        let values = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(quantile(&values, 0.0), 1.0);
        assert_eq!(quantile(&values, 1.0), 4.0);
        assert!((quantile(&values, 0.5) - 2.5).abs() < 1e-12);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
