//! The step-response characteristics: the rising step and the decaying error, reduced to one
//! normalised response (definitions in the [module documentation](super)).

use serde::Serialize;

use super::{MetricsError, mean, validate_series};

/// Levels and band of the step-response definitions. The defaults are the seed's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StepOptions {
    /// Half-width of the settling band as a fraction of the reference (default 0.02).
    pub band: f64,
    /// Lower level of the rise time, as a fraction of the way from start to end (default 0.1).
    pub rise_low: f64,
    /// Upper level of the rise time (default 0.9).
    pub rise_high: f64,
    /// Time of the step; `None` means the first sample. Samples before it are ignored.
    pub t_step: Option<f64>,
    /// Fraction of the step window, at its end, averaged for the steady-state error of a run
    /// that never settled (default 0.1).
    pub unsettled_tail: f64,
}

impl Default for StepOptions {
    fn default() -> Self {
        Self { band: 0.02, rise_low: 0.1, rise_high: 0.9, t_step: None, unsettled_tail: 0.1 }
    }
}

/// The step-response characteristics of one run. See the [module documentation](super) for the
/// definitions. Fields that may not exist in a run are `Option`s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StepCharacteristics {
    /// Time of the step (the first sample unless [`StepOptions::t_step`] says otherwise).
    pub t_step: f64,
    /// The initial error `e0` (decaying error) or the target (rising step).
    pub reference: f64,
    /// `None` if the response never reached the lower or the upper rise level.
    pub rise_time: Option<f64>,
    /// Measured from `t_step`; `None` if the run ended outside the band.
    pub settling_time: Option<f64>,
    /// Whether the run ended inside the band (`settling_time.is_some()`).
    pub settled: bool,
    /// Overshoot past the final value in percent of `|reference|`; 0 without overshoot.
    pub overshoot_pct: f64,
    /// Signed, in the units of the signal: mean error after settling (decaying error), or target
    /// minus mean speed after settling (rising step); over the run's tail if it never settled.
    pub steady_state_error: f64,
}

/// Step characteristics of an error that starts at `e0 = error(t_step)` (interpolated if
/// `t_step` falls between samples) and should decay to zero.
pub fn decaying_error_step(t: &[f64], error: &[f64], options: &StepOptions) -> Result<StepCharacteristics, MetricsError> {
    validate_series(t, error)?;
    validate_options(options)?;
    let (window_t, window_error) = step_window(t, error, options)?;
    let initial_error = window_error[0];
    if initial_error == 0.0 {
        return Err(MetricsError::DegenerateReference { what: "initial error", value: initial_error });
    }
    let response: Vec<f64> = window_error.iter().map(|e| 1.0 - e / initial_error).collect();
    let step = characterise(&window_t, &response, options);
    let steady_state_error = mean(&window_error[step.steady_state_from..]);
    Ok(step.into_characteristics(window_t[0], initial_error, steady_state_error))
}

/// Step characteristics of a signal commanded at `t_step` from zero to `target` (the speed step).
pub fn rising_step(t: &[f64], value: &[f64], target: f64, options: &StepOptions) -> Result<StepCharacteristics, MetricsError> {
    validate_series(t, value)?;
    validate_options(options)?;
    if target == 0.0 || !target.is_finite() {
        return Err(MetricsError::DegenerateReference { what: "target", value: target });
    }
    let (window_t, window_value) = step_window(t, value, options)?;
    let response: Vec<f64> = window_value.iter().map(|v| v / target).collect();
    let step = characterise(&window_t, &response, options);
    let steady_state_error = target - mean(&window_value[step.steady_state_from..]);
    Ok(step.into_characteristics(window_t[0], target, steady_state_error))
}

fn validate_options(options: &StepOptions) -> Result<(), MetricsError> {
    let open_unit = |name, value: f64| {
        if value > 0.0 && value < 1.0 { Ok(()) } else { Err(MetricsError::InvalidOption { name, value, expected: "between 0 and 1" }) }
    };
    open_unit("band", options.band)?;
    open_unit("rise_low", options.rise_low)?;
    open_unit("rise_high", options.rise_high)?;
    open_unit("unsettled_tail", options.unsettled_tail)?;
    if options.rise_low >= options.rise_high {
        return Err(MetricsError::InvalidOption { name: "rise_low", value: options.rise_low, expected: "below rise_high" });
    }
    Ok(())
}

/// The samples of the step: from `t_step` (the first sample unless the options say otherwise) to
/// the end, with a sample interpolated at `t_step` if it falls between two, so that the window
/// starts exactly at the step.
fn step_window(t: &[f64], y: &[f64], options: &StepOptions) -> Result<(Vec<f64>, Vec<f64>), MetricsError> {
    let (t_first, t_last) = (t[0], t[t.len() - 1]);
    let t_step = options.t_step.unwrap_or(t_first);
    // The window must hold at least one interval after the step, hence t_step < t_last.
    if !(t_step >= t_first && t_step < t_last) {
        return Err(MetricsError::StepOutsideRun { t_step, t_first, t_last });
    }
    let first_after = t.partition_point(|&ti| ti < t_step);
    let mut window_t = Vec::with_capacity(t.len() - first_after + 1);
    let mut window_y = Vec::with_capacity(window_t.capacity());
    if t[first_after] != t_step {
        let before = first_after - 1;
        let fraction = (t_step - t[before]) / (t[first_after] - t[before]);
        window_t.push(t_step);
        window_y.push(y[before] + fraction * (y[first_after] - y[before]));
    }
    window_t.extend_from_slice(&t[first_after..]);
    window_y.extend_from_slice(&y[first_after..]);
    Ok((window_t, window_y))
}

struct NormalisedStep {
    rise_time: Option<f64>,
    settling_time: Option<f64>,
    overshoot_pct: f64,
    /// Index of the first sample averaged for the steady-state error.
    steady_state_from: usize,
}

impl NormalisedStep {
    fn into_characteristics(self, t_step: f64, reference: f64, steady_state_error: f64) -> StepCharacteristics {
        StepCharacteristics {
            t_step,
            reference,
            rise_time: self.rise_time,
            settling_time: self.settling_time,
            settled: self.settling_time.is_some(),
            overshoot_pct: self.overshoot_pct,
            steady_state_error,
        }
    }
}

/// The characteristics of a normalised response `r` (0 → 1) sampled at `t`, which starts at the
/// step.
fn characterise(t: &[f64], r: &[f64], options: &StepOptions) -> NormalisedStep {
    let (t_step, t_end) = (t[0], t[t.len() - 1]);
    let rise_time = match (first_reach(t, r, options.rise_low), first_reach(t, r, options.rise_high)) {
        (Some(low), Some(high)) => Some(high - low),
        _ => None,
    };
    let settled_at = settling_instant(t, r, options.band);
    let overshoot = r.iter().fold(0.0_f64, |max, ri| max.max(ri - 1.0));
    let averaged_from = settled_at.unwrap_or(t_end - options.unsettled_tail * (t_end - t_step));
    NormalisedStep {
        rise_time,
        settling_time: settled_at.map(|at| at - t_step),
        overshoot_pct: 100.0 * overshoot,
        // Both instants lie at or before the last sample, so the average is never empty.
        steady_state_from: t.partition_point(|&ti| ti < averaged_from).min(t.len() - 1),
    }
}

/// First time `r` reaches `level`, interpolated between the samples around the crossing.
fn first_reach(t: &[f64], r: &[f64], level: f64) -> Option<f64> {
    match r.iter().position(|&ri| ri >= level)? {
        0 => Some(t[0]),
        index => Some(lerp_crossing(t[index - 1], r[index - 1], t[index], r[index], level)),
    }
}

/// The instant after which `|r − 1| ≤ band` for good; `None` if the last sample is outside.
fn settling_instant(t: &[f64], r: &[f64], band: f64) -> Option<f64> {
    let outside = |ri: f64| (ri - 1.0).abs() > band;
    match r.iter().rposition(|&ri| outside(ri)) {
        None => Some(t[0]),
        Some(last) if last == r.len() - 1 => None,
        Some(last) => {
            let boundary = if r[last] > 1.0 { 1.0 + band } else { 1.0 - band };
            Some(lerp_crossing(t[last], r[last], t[last + 1], r[last + 1], boundary))
        }
    }
}

/// Time at which the line through `(t0, r0)` and `(t1, r1)` reaches `level`, clamped to the
/// segment (it already is when `level` lies between `r0` and `r1`).
fn lerp_crossing(t0: f64, r0: f64, t1: f64, r1: f64, level: f64) -> f64 {
    if r1 == r0 {
        return t1;
    }
    let fraction = ((level - r0) / (r1 - r0)).clamp(0.0, 1.0);
    t0 + fraction * (t1 - t0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit step response of `ω_n² / (s² + 2ζω_n s + ω_n²)` at time `t` (closed form).
    fn second_order_step(zeta: f64, omega_n: f64, t: f64) -> f64 {
        if zeta < 1.0 {
            let root = (1.0 - zeta * zeta).sqrt();
            let omega_d = omega_n * root;
            1.0 - (-zeta * omega_n * t).exp() / root * (omega_d * t + zeta.acos()).sin()
        } else if zeta == 1.0 {
            1.0 - (1.0 + omega_n * t) * (-omega_n * t).exp()
        } else {
            let root = (zeta * zeta - 1.0).sqrt();
            let (s1, s2) = (-omega_n * (zeta - root), -omega_n * (zeta + root));
            1.0 - (s2 * (s1 * t).exp() - s1 * (s2 * t).exp()) / (s2 - s1)
        }
    }

    /// Root of `f` in `[a, b]` (a sign change) by bisection to machine precision.
    fn bisect(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
        let fa_negative = f(a) < 0.0;
        for _ in 0..200 {
            let mid = 0.5 * (a + b);
            if (f(mid) < 0.0) == fa_negative {
                a = mid;
            } else {
                b = mid;
            }
        }
        0.5 * (a + b)
    }

    /// Exact characteristics of the analytic response, by scanning a fine grid for the bracket of
    /// each crossing and bisecting it.
    struct Exact {
        rise_time: f64,
        settling_time: f64,
    }

    fn exact(zeta: f64, omega_n: f64, horizon: f64) -> Exact {
        let y = |t: f64| second_order_step(zeta, omega_n, t);
        let grid_step = 1e-4 / omega_n;
        let grid: Vec<f64> = (0..=(horizon / grid_step) as usize).map(|i| i as f64 * grid_step).collect();
        let first_reach = |level: f64| {
            let i = grid.iter().position(|&t| y(t) >= level).expect("reaches the level");
            bisect(|t| y(t) - level, grid[i - 1], grid[i])
        };
        let outside = |t: f64| (y(t) - 1.0).abs() - 0.02;
        let last_outside = grid.iter().rposition(|&t| outside(t) > 0.0).expect("starts outside");
        assert!(last_outside + 1 < grid.len(), "horizon too short to settle");
        Exact { rise_time: first_reach(0.9) - first_reach(0.1), settling_time: bisect(outside, grid[last_outside], grid[last_outside + 1]) }
    }

    fn sampled(zeta: f64, omega_n: f64, dt: f64, horizon: f64) -> (Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..=(horizon / dt).round() as usize).map(|i| i as f64 * dt).collect();
        let y = t.iter().map(|&ti| second_order_step(zeta, omega_n, ti)).collect();
        (t, y)
    }

    fn assert_within_2_percent(what: &str, measured: f64, expected: f64) {
        let relative = (measured - expected).abs() / expected.abs();
        assert!(relative < 0.02, "{what}: measured {measured}, expected {expected} ({relative:.4} off)");
    }

    const OMEGA_N: f64 = 2.0;
    const DT: f64 = 0.001;
    const HORIZON: f64 = 40.0;

    fn check_against_analytic(zeta: f64, step: &StepCharacteristics) {
        let exact = exact(zeta, OMEGA_N, HORIZON);
        assert_within_2_percent("rise time", step.rise_time.expect("rises"), exact.rise_time);
        assert_within_2_percent("settling time", step.settling_time.expect("settles"), exact.settling_time);
        assert!(step.settled);
        if zeta < 1.0 {
            let overshoot = 100.0 * (-std::f64::consts::PI * zeta / (1.0 - zeta * zeta).sqrt()).exp();
            assert_within_2_percent("overshoot", step.overshoot_pct, overshoot);
        } else {
            assert!(step.overshoot_pct < 1e-9, "no overshoot for ζ = {zeta}: {}", step.overshoot_pct);
        }
        assert!(step.steady_state_error.abs() < 0.02 * step.reference.abs(), "steady-state error {} for reference {}", step.steady_state_error, step.reference);
    }

    const ZETAS: [f64; 5] = [0.2, 0.5, 0.7, 1.0, 1.5];

    #[test]
    fn rising_step_matches_analytic_second_order_responses() {
        for zeta in ZETAS {
            let target = 0.004; // 240 mm/min, the seed's welding speed
            let (t, unit) = sampled(zeta, OMEGA_N, DT, HORIZON);
            let speed: Vec<f64> = unit.iter().map(|u| target * u).collect();
            let step = rising_step(&t, &speed, target, &StepOptions::default()).expect("measurable");
            check_against_analytic(zeta, &step);
        }
    }

    #[test]
    fn decaying_error_matches_analytic_second_order_responses() {
        for zeta in ZETAS {
            for initial_error in [0.3, -0.05] {
                let (t, unit) = sampled(zeta, OMEGA_N, DT, HORIZON);
                let error: Vec<f64> = unit.iter().map(|u| initial_error * (1.0 - u)).collect();
                let step = decaying_error_step(&t, &error, &StepOptions::default()).expect("measurable");
                assert!((step.reference - initial_error).abs() < 1e-12, "e0 = {}", step.reference);
                check_against_analytic(zeta, &step);
            }
        }
    }

    #[test]
    fn a_late_step_is_measured_from_its_own_time() {
        let t_step = 5.0;
        let (t, unit) = sampled(0.5, OMEGA_N, DT, HORIZON);
        let speed: Vec<f64> = t.iter().map(|&ti| if ti < t_step { 0.0 } else { second_order_step(0.5, OMEGA_N, ti - t_step) }).collect();
        let options = StepOptions { t_step: Some(t_step), ..StepOptions::default() };
        let late = rising_step(&t, &speed, 1.0, &options).expect("measurable");
        let immediate = rising_step(&t, &unit, 1.0, &StepOptions::default()).expect("measurable");
        assert_eq!(late.t_step, t_step);
        let close = |a: Option<f64>, b: Option<f64>| (a.unwrap_or(f64::NAN) - b.unwrap_or(f64::NAN)).abs() < 2.0 * DT;
        assert!(close(late.rise_time, immediate.rise_time));
        assert!(close(late.settling_time, immediate.settling_time));
        assert!((late.overshoot_pct - immediate.overshoot_pct).abs() < 1e-6);
    }

    #[test]
    fn a_run_that_never_settles_averages_its_last_tenth_and_says_so() {
        // Rises to 90 % of the target and stays: 10 % short, outside the 2 % band.
        let t: Vec<f64> = (0..=100).map(f64::from).collect();
        let speed: Vec<f64> = t.iter().map(|&ti| 0.9 * (1.0 - (-ti / 10.0).exp())).collect();
        let step = rising_step(&t, &speed, 1.0, &StepOptions::default()).expect("measurable");
        assert!(!step.settled);
        assert_eq!(step.settling_time, None);
        assert_eq!(step.rise_time, None, "never reaches 90 %");
        let tail_mean = speed[90..].iter().sum::<f64>() / 11.0;
        assert!((step.steady_state_error - (1.0 - tail_mean)).abs() < 1e-12);
    }

    #[test]
    fn a_response_that_never_moves_has_no_rise_time() {
        let t = [0.0, 1.0, 2.0];
        let step = rising_step(&t, &[0.0, 0.0, 0.0], 2.0, &StepOptions::default()).expect("measurable");
        assert_eq!(step.rise_time, None);
        assert_eq!(step.settling_time, None);
        assert_eq!(step.overshoot_pct, 0.0);
        assert_eq!(step.steady_state_error, 2.0);
    }

    #[test]
    fn crossings_are_interpolated_between_samples() {
        // Rises 0.3 per 0.3 s sample, then 0.1 to the target: r crosses 0.1 at 0.1 s and 0.9 at
        // 0.9 s.
        let t = [0.0, 0.3, 0.6, 0.9, 1.2, 1.5];
        let v = [0.0, 0.3, 0.6, 0.9, 1.0, 1.0];
        let step = rising_step(&t, &v, 1.0, &StepOptions::default()).expect("measurable");
        assert!((step.rise_time.expect("rises") - 0.8).abs() < 1e-12);
        // The last sample outside is 0.9 at 0.9 s; the band edge 0.98 lies at 0.9 + 0.08·3 s.
        assert!((step.settling_time.expect("settles") - 1.14).abs() < 1e-12);
    }

    #[test]
    fn overshoot_is_the_excursion_past_zero_opposite_the_initial_error() {
        let t = [0.0, 1.0, 2.0, 3.0, 4.0];
        let error = [-0.2, -0.05, 0.03, 0.0, 0.0];
        let step = decaying_error_step(&t, &error, &StepOptions::default()).expect("measurable");
        assert!((step.overshoot_pct - 15.0).abs() < 1e-9);
        assert!(step.settled);
        assert_eq!(step.steady_state_error, 0.0);
    }
}
