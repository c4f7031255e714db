//! How closely the distance error kept to the line.

use serde::Serialize;

use super::{MetricsError, mean, validate_series};

/// How closely the distance error kept to the line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LineTracking {
    /// Largest `|d|` over all samples.
    pub max_abs: f64,
    /// Root mean square of `d` over the samples (equal weights: the runner samples at fixed dt).
    pub rms: f64,
    /// The `tolerance` the time on line was measured against.
    pub tolerance: f64,
    /// Time during which `|d| < tolerance`, with `d` interpolated linearly between samples.
    pub time_on_line: f64,
    /// `time_on_line` as a fraction of the run's duration `t_end − t_first`.
    pub fraction_on_line: f64,
}

/// Largest and RMS distance error, and the time spent within `tolerance` of the line (for the
/// painted line, half its width). Measured over the whole series.
pub fn line_tracking(t: &[f64], distance: &[f64], tolerance: f64) -> Result<LineTracking, MetricsError> {
    validate_series(t, distance)?;
    if !(tolerance.is_finite() && tolerance > 0.0) {
        return Err(MetricsError::InvalidOption { name: "tolerance", value: tolerance, expected: "finite and > 0" });
    }
    let max_abs = distance.iter().fold(0.0_f64, |max, d| max.max(d.abs()));
    let squares: Vec<f64> = distance.iter().map(|d| d * d).collect();
    let rms = mean(&squares).sqrt();
    let time_on_line: f64 = t.windows(2).zip(distance.windows(2)).map(|(ts, ds)| (ts[1] - ts[0]) * fraction_within(ds[0], ds[1], tolerance)).sum();
    let duration = t[t.len() - 1] - t[0];
    Ok(LineTracking { max_abs, rms, tolerance, time_on_line, fraction_on_line: time_on_line / duration })
}

/// Fraction of a segment, along which the value goes linearly from `a` to `b`, where
/// `|value| < tolerance`.
fn fraction_within(a: f64, b: f64, tolerance: f64) -> f64 {
    if a == b {
        return if a.abs() < tolerance { 1.0 } else { 0.0 };
    }
    // value(s) = a + s·(b − a) for s in [0, 1]; solve for the s at ±tolerance and clip.
    let s_at = |level: f64| (level - a) / (b - a);
    let (s_low, s_high) = {
        let (s1, s2) = (s_at(-tolerance), s_at(tolerance));
        (s1.min(s2), s1.max(s2))
    };
    (s_high.min(1.0) - s_low.max(0.0)).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_tracking_counts_the_interpolated_time_within_tolerance() {
        // d goes linearly from −1 to 1 over 2 s: |d| < 0.5 for the middle second.
        let t = [0.0, 1.0, 2.0];
        let d = [-1.0, 0.0, 1.0];
        let tracking = line_tracking(&t, &d, 0.5).expect("measurable");
        assert!((tracking.time_on_line - 1.0).abs() < 1e-12);
        assert!((tracking.fraction_on_line - 0.5).abs() < 1e-12);
        assert_eq!(tracking.max_abs, 1.0);
        assert!((tracking.rms - (2.0_f64 / 3.0).sqrt()).abs() < 1e-12);
        let on_line = line_tracking(&t, &[0.1, 0.1, -0.1], 0.5).expect("measurable");
        assert_eq!(on_line.time_on_line, 2.0);
    }
}
