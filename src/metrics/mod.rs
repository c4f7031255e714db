//! Step-response characteristics of a sampled run, as the seed report defines them (sections 4.1
//! and 5.1), and line-tracking figures for the distance error.
//!
//! Two kinds of step are measured:
//!
//! - a **decaying error** ([`decaying_error_step`]): the distance error `d(t)` starts at an initial
//!   error `e0 ≠ 0` and the controller drives it to zero (the line-following experiment);
//! - a **rising step** ([`rising_step`]): the speed `v(t)` is commanded from zero to a target
//!   (the velocity-control experiment).
//!
//! Both are reduced to one *normalised response* `r(t)` that goes from 0 towards 1, so that one
//! set of definitions serves both:
//!
//! | step           | reference `ref`      | normalised response `r(t)` |
//! |----------------|----------------------|----------------------------|
//! | decaying error | `e0 = d(t_step)`     | `1 − d(t) / e0`            |
//! | rising         | `target`             | `v(t) / target`            |
//!
//! On `r`, with the options' defaults (10 %, 90 %, band 2 %):
//!
//! - **rise time**: first time `r` reaches 0.9 minus first time it reaches 0.1. For the decaying
//!   error this is the seed's "time for the error to fall from 90 % to 10 % of the initial error".
//!   Each first crossing is interpolated linearly between the two samples around it; a sample
//!   at or after `t_step` that is already past the level counts as crossing at its own time.
//! - **settling time**: time from `t_step` after which `|r − 1| ≤ band` holds for every later
//!   sample (the error stays within 2 % of `|e0|`, or the speed within 2 % of the target). The
//!   instant is interpolated linearly between the last sample outside the band and the next one.
//!   A run whose last sample is outside the band has not settled.
//! - **overshoot %**: `100 · max(r − 1)` over the samples from `t_step`, or 0 if `r` never passes
//!   1: for the decaying error, the largest excursion past zero on the side opposite to `e0`, as a
//!   percentage of `|e0|`; for the rising step, the largest excursion above the target.
//! - **steady-state error**, in the units of the signal: for the decaying error the signed mean of
//!   `d` over the samples from the settling instant on; for the rising step `target − mean(v)`
//!   over the same samples. If the run never settled, the mean is taken over the last 10 % (by
//!   time) of the step window `[t_step, t_end]` and `settled` is `false`.
//!
//! Times are in the units of `t` (seconds in climbsim); samples before `t_step` are ignored.
//!
//! The step-response characteristics are in `step.rs` and the line-tracking figures in `line.rs`;
//! this file holds what both take in: the checks on a sampled series and their error.

mod line;
mod step;

pub use line::{LineTracking, line_tracking};
pub use step::{StepCharacteristics, StepOptions, decaying_error_step, rising_step};

use thiserror::Error;

/// Why a series could not be measured.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MetricsError {
    #[error("the series has {len} samples; at least 2 are needed")]
    TooFewSamples { len: usize },
    #[error("the time series has {t_len} samples but the value series has {y_len}")]
    LengthMismatch { t_len: usize, y_len: usize },
    #[error("{series}[{index}] is not a finite number")]
    NotFinite { series: &'static str, index: usize },
    #[error("time does not increase at sample {index}")]
    TimeNotIncreasing { index: usize },
    #[error("step time {t_step} is outside the run [{t_first}, {t_last})")]
    StepOutsideRun { t_step: f64, t_first: f64, t_last: f64 },
    #[error("the step's reference ({what}) is zero or not finite: {value}")]
    DegenerateReference { what: &'static str, value: f64 },
    #[error("option {name} = {value} is out of range ({expected})")]
    InvalidOption { name: &'static str, value: f64, expected: &'static str },
}

fn validate_series(t: &[f64], y: &[f64]) -> Result<(), MetricsError> {
    if t.len() != y.len() {
        return Err(MetricsError::LengthMismatch { t_len: t.len(), y_len: y.len() });
    }
    if t.len() < 2 {
        return Err(MetricsError::TooFewSamples { len: t.len() });
    }
    for (series, values) in [("t", t), ("y", y)] {
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(MetricsError::NotFinite { series, index });
        }
    }
    if let Some(index) = t.windows(2).position(|w| w[1] <= w[0]) {
        return Err(MetricsError::TimeNotIncreasing { index: index + 1 });
    }
    Ok(())
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let options = StepOptions::default();
        assert_eq!(rising_step(&[], &[], 1.0, &options), Err(MetricsError::TooFewSamples { len: 0 }));
        assert_eq!(decaying_error_step(&[0.0], &[1.0], &options), Err(MetricsError::TooFewSamples { len: 1 }));
        assert_eq!(rising_step(&[0.0, 1.0], &[0.0], 1.0, &options), Err(MetricsError::LengthMismatch { t_len: 2, y_len: 1 }));
        assert_eq!(decaying_error_step(&[0.0, 1.0, 2.0], &[1.0, f64::NAN, 0.0], &options), Err(MetricsError::NotFinite { series: "y", index: 1 }));
        assert_eq!(line_tracking(&[0.0, f64::INFINITY], &[1.0, 0.0], 0.1), Err(MetricsError::NotFinite { series: "t", index: 1 }));
        assert_eq!(rising_step(&[0.0, 1.0, 1.0], &[0.0, 1.0, 1.0], 1.0, &options), Err(MetricsError::TimeNotIncreasing { index: 2 }));
        assert!(matches!(decaying_error_step(&[0.0, 1.0], &[0.0, 1.0], &options), Err(MetricsError::DegenerateReference { .. })));
        assert!(matches!(rising_step(&[0.0, 1.0], &[0.0, 1.0], f64::NAN, &options), Err(MetricsError::DegenerateReference { .. })));
        let late = StepOptions { t_step: Some(1.0), ..options };
        assert!(matches!(rising_step(&[0.0, 1.0], &[0.0, 1.0], 1.0, &late), Err(MetricsError::StepOutsideRun { .. })));
        let wide = StepOptions { band: 1.5, ..options };
        assert!(matches!(rising_step(&[0.0, 1.0], &[0.0, 1.0], 1.0, &wide), Err(MetricsError::InvalidOption { name: "band", .. })));
        assert!(matches!(line_tracking(&[0.0, 1.0], &[0.0, 1.0], -1.0), Err(MetricsError::InvalidOption { name: "tolerance", .. })));
    }
}
