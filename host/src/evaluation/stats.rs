//! Summary statistics of measured samples: one quantile definition for
//! every printed, plotted and serialised figure, so the median a command
//! prints is the median its plot draws.

/// The `q`-quantile (0..=1) of a sample by linear interpolation between
/// order statistics (Hyndman and Fan's type 7, numpy's default); `None`
/// for an empty sample. NaNs sort last.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    quantile_sorted(&v, q)
}

/// [`quantile`] of an already sorted sample.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> Option<f64> {
    let last = sorted.len().checked_sub(1)?;
    let pos = last as f64 * q.clamp(0.0, 1.0);
    let i = pos.floor() as usize;
    let lo = *sorted.get(i)?;
    let hi = sorted.get(i + 1).copied().unwrap_or(lo);
    Some(lo + (pos - i as f64) * (hi - lo))
}

/// The median ([`quantile`] at 0.5).
pub fn median(values: &[f64]) -> Option<f64> {
    quantile(values, 0.5)
}

/// The mean; `None` for an empty sample.
pub fn mean(values: &[f64]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// Median, mean, 95th percentile and maximum of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Spread {
    /// Median.
    pub median: Option<f64>,
    /// Mean.
    pub mean: Option<f64>,
    /// 95th percentile.
    pub p95: Option<f64>,
    /// Largest value.
    pub max: Option<f64>,
}

impl Spread {
    /// The spread of `values`.
    pub fn of(values: &[f64]) -> Self {
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        Spread {
            median: quantile_sorted(&v, 0.5),
            mean: mean(&v),
            p95: quantile_sorted(&v, 0.95),
            max: quantile_sorted(&v, 1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_and_empty_is_none() {
        assert_eq!(median(&[]), None);
        assert_eq!(median(&[3.0]), Some(3.0));
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(quantile(&[0.0, 10.0], 0.95), Some(9.5));
        assert_eq!(quantile(&[5.0, 1.0, 3.0], 1.0), Some(5.0));
        let s = Spread::of(&[1.0, 2.0, 3.0]);
        assert_eq!((s.median, s.mean, s.max), (Some(2.0), Some(2.0), Some(3.0)));
    }
}
