//! Fitting the world to the robot: the parameter values (any `--set` key, each in a range)
//! that make `compare`'s error smallest, and how well the session determines each.
//!
//! The optimizer is Nelder–Mead on the unit box (each parameter scaled to its range, points
//! clamped into it). It is derivative-free, deterministic for a deterministic error (the
//! world's re-enactment is), and needs few evaluations for the handful of parameters a session
//! excites. The crates that offer it or CMA-ES (`argmin`, `cmaes`) bring a second `nalgebra`
//! and a random-number stack into the build for some hundred lines, so it is written here.
//! Reflection and expansion are evaluated as one batch when evaluations run in parallel.

use serde::Serialize;

/// A parameter to fit: a `--set` key and the range to search.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FitParam {
    pub key: String,
    pub lo: f64,
    pub hi: f64,
    /// The range was given in whole numbers: the key takes integers (an encoder offset).
    pub integer: bool,
}

impl FitParam {
    /// `KEY=LO..HI`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let (key, range) = text.split_once('=').ok_or_else(|| format!("`{text}` is not KEY=LO..HI"))?;
        let (lo, hi) = range.split_once("..").ok_or_else(|| format!("`{text}`: the range `{range}` is not LO..HI"))?;
        let number = |s: &str| s.trim().parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("`{text}`: `{s}` is not a finite number"));
        let integer = [lo, hi].iter().all(|s| s.trim().parse::<i64>().is_ok());
        let (lo, hi) = (number(lo)?, number(hi)?);
        if lo >= hi {
            return Err(format!("`{text}`: LO must be below HI"));
        }
        let key = key.trim();
        if key.is_empty() {
            return Err(format!("`{text}` has no key"));
        }
        Ok(Self { key: key.to_owned(), lo, hi, integer })
    }

    /// The value at `unit` (0: LO, 1: HI).
    pub fn value(&self, unit: f64) -> f64 {
        self.lo + unit.clamp(0.0, 1.0) * (self.hi - self.lo)
    }
}

/// When the search stops.
#[derive(Debug, Clone, Copy)]
pub struct Stop {
    pub max_evaluations: usize,
    /// The simplex's spread of errors, relative to the best one.
    pub relative_error_spread: f64,
    /// The simplex's size in the unit box.
    pub unit_size: f64,
}

impl Default for Stop {
    fn default() -> Self {
        Self { max_evaluations: 200, relative_error_spread: 1e-4, unit_size: 1e-3 }
    }
}

/// Evaluates a batch of points of the unit box (possibly in parallel): their errors, in order.
pub type Evaluate<'a> = dyn FnMut(&[Vec<f64>]) -> Vec<f64> + 'a;

/// The search's result.
#[derive(Debug, Clone, PartialEq)]
pub struct Minimum {
    pub unit: Vec<f64>,
    pub error: f64,
    pub evaluations: usize,
}

fn clamp_unit(point: Vec<f64>) -> Vec<f64> {
    point.into_iter().map(|v| v.clamp(0.0, 1.0)).collect()
}

/// `a + t (b - a)` for points.
fn along(a: &[f64], b: &[f64], t: f64) -> Vec<f64> {
    clamp_unit(a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect())
}

/// Nelder–Mead from `start` (unit box), the first simplex a quarter of the box along each axis,
/// restarted from its best point with a fresh simplex each time it converges, for as long as a
/// restart improves on it and the budget lasts: a simplex can collapse in a valley that runs at
/// a slant to the axes, or stall on an integer parameter's steps, short of the minimum (a
/// 4-parameter fit of tread friction, magnet pull, gearbox friction and encoder offset stopped at
/// 10 times the true point's error without restarts). `speculate`: evaluate the expansion with
/// the reflection, as one batch.
pub fn minimise(start: &[f64], spent: usize, stop: Stop, speculate: bool, evaluate: &mut Evaluate<'_>) -> Minimum {
    let mut best = nelder_mead(start, spent, stop, speculate, evaluate);
    while best.evaluations < stop.max_evaluations {
        let restart = nelder_mead(&best.unit, best.evaluations, stop, speculate, evaluate);
        let improved = restart.error < best.error - stop.relative_error_spread * best.error.abs().max(1e-12);
        let evaluations = restart.evaluations;
        best = if restart.error < best.error { restart } else { Minimum { evaluations, ..best } };
        if !improved {
            break;
        }
    }
    best
}

/// The most points of the coarse grid [`grid_start`] evaluates.
pub const GRID_POINTS: usize = 32;

/// The levels per axis of the coarse grid for `n` parameters: the most, up to 5, whose grid
/// has at most [`GRID_POINTS`] points (5 for one or two parameters, 3 for three, 2 for four or
/// five); 1 (no grid) beyond.
pub fn grid_levels(n: usize) -> usize {
    (1..=5usize).rev().find(|levels| u32::try_from(n).ok().and_then(|n| levels.checked_pow(n)).is_some_and(|points| points <= GRID_POINTS)).unwrap_or(1)
}

/// Where the search starts: the best of a coarse grid over the unit box (the cells' centres,
/// [`grid_levels`] per axis, one batch), or its centre when there are too many parameters for
/// one. The error of a re-enactment is not a smooth bowl: contact and slip make it rugged, and
/// a search from the box's centre can slide down a narrow valley to a range's end, far from the
/// minimum (a floor and a wall session's friction and magnet pull did, at three times the
/// hidden values' error). Returns the start and the evaluations spent.
pub fn grid_start(n: usize, evaluate: &mut Evaluate<'_>) -> (Vec<f64>, usize) {
    let levels = grid_levels(n);
    if levels < 2 || n == 0 {
        return (vec![0.5; n], 0);
    }
    let cell = |index: usize| (index as f64 + 0.5) / levels as f64;
    let count = levels.pow(n as u32);
    let points: Vec<Vec<f64>> = (0..count)
        .map(|mut k| {
            (0..n)
                .map(|_| {
                    let index = k % levels;
                    k /= levels;
                    cell(index)
                })
                .collect()
        })
        .collect();
    let errors = evaluate(&points);
    let best = lowest(&errors).map_or(0, |(index, _)| index);
    (points[best].clone(), count)
}

/// The lowest of `errors`: its index and value (None when empty).
fn lowest(errors: &[f64]) -> Option<(usize, f64)> {
    errors.iter().copied().enumerate().min_by(|a, b| a.1.total_cmp(&b.1))
}

/// How many times [`search`] goes on from a probe lower than its minimum.
const POLISH_ROUNDS: usize = 2;
/// Each such search's budget, per parameter.
const POLISH_EVALUATIONS_PER_PARAM: usize = 12;

/// The whole search for `params`: from the best point of a coarse grid ([`grid_start`]),
/// Nelder–Mead with restarts ([`minimise`]), then the probes around the fit that judge each
/// parameter ([`determine`]). A probe lower than the fit means the search stopped short on a
/// rugged error: it goes on from that probe with a small budget of its own and probes again,
/// at most [`POLISH_ROUNDS`] times. The minimum's evaluations count every point evaluated.
pub fn search(params: &[FitParam], stop: Stop, speculate: bool, evaluate: &mut Evaluate<'_>) -> (Minimum, Vec<Determination>) {
    let (start, spent) = grid_start(params.len(), evaluate);
    let mut minimum = minimise(&start, spent, stop, speculate, evaluate);
    let mut polished = 0;
    loop {
        let probes = probe_points(&minimum);
        let errors = evaluate(&probes);
        minimum.evaluations += probes.len();
        match lowest(&errors) {
            Some((index, error)) if polished < POLISH_ROUNDS && error < minimum.error * (1.0 - stop.relative_error_spread) => {
                polished += 1;
                let polish = Stop { max_evaluations: minimum.evaluations + POLISH_EVALUATIONS_PER_PARAM * params.len(), ..stop };
                minimum = minimise(&probes[index], minimum.evaluations, polish, speculate, evaluate);
            }
            _ => {
                let determinations = determine_from(params, &minimum, &errors);
                return (minimum, determinations);
            }
        }
    }
}

/// One Nelder–Mead run from `start`, `spent` evaluations already made of the budget.
fn nelder_mead(start: &[f64], spent: usize, stop: Stop, speculate: bool, evaluate: &mut Evaluate<'_>) -> Minimum {
    let n = start.len();
    let mut simplex: Vec<Vec<f64>> = vec![clamp_unit(start.to_vec())];
    for axis in 0..n {
        let mut point = start.to_vec();
        point[axis] += if point[axis] <= 0.75 { 0.25 } else { -0.25 };
        simplex.push(clamp_unit(point));
    }
    let mut errors = evaluate(&simplex);
    let mut evaluations = spent + simplex.len();
    loop {
        let mut order: Vec<usize> = (0..simplex.len()).collect();
        order.sort_by(|a, b| errors[*a].total_cmp(&errors[*b]));
        simplex = order.iter().map(|i| simplex[*i].clone()).collect();
        errors = order.iter().map(|i| errors[*i]).collect();
        let (best, worst) = (errors[0], errors[n]);
        let size = simplex.iter().skip(1).map(|p| p.iter().zip(&simplex[0]).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max)).fold(0.0, f64::max);
        if evaluations >= stop.max_evaluations || worst - best <= stop.relative_error_spread * best.abs().max(1e-12) || size <= stop.unit_size {
            return Minimum { unit: simplex[0].clone(), error: best, evaluations };
        }
        let centroid: Vec<f64> = (0..n).map(|d| simplex[..n].iter().map(|p| p[d]).sum::<f64>() / n as f64).collect();
        let reflected = along(&centroid, &simplex[n], -1.0);
        let expanded = along(&centroid, &simplex[n], -2.0);
        let (reflected_error, expanded_error) = if speculate {
            let both = evaluate(&[reflected.clone(), expanded.clone()]);
            evaluations += 2;
            (both[0], Some(both[1]))
        } else {
            evaluations += 1;
            (evaluate(std::slice::from_ref(&reflected))[0], None)
        };
        if reflected_error < best {
            let expanded_error = expanded_error.unwrap_or_else(|| {
                evaluations += 1;
                evaluate(std::slice::from_ref(&expanded))[0]
            });
            (simplex[n], errors[n]) = if expanded_error < reflected_error { (expanded, expanded_error) } else { (reflected, reflected_error) };
            continue;
        }
        if reflected_error < errors[n - 1] {
            (simplex[n], errors[n]) = (reflected, reflected_error);
            continue;
        }
        // Contract towards the better of the worst point and its reflection.
        let (toward, toward_error) = if reflected_error < worst { (reflected, reflected_error) } else { (simplex[n].clone(), worst) };
        let contracted = along(&centroid, &toward, 0.5);
        let contracted_error = evaluate(std::slice::from_ref(&contracted))[0];
        evaluations += 1;
        if contracted_error < toward_error {
            (simplex[n], errors[n]) = (contracted, contracted_error);
            continue;
        }
        // Shrink towards the best point.
        let shrunk: Vec<Vec<f64>> = simplex[1..].iter().map(|p| along(&simplex[0], p, 0.5)).collect();
        let shrunk_errors = evaluate(&shrunk);
        evaluations += shrunk.len();
        for (i, (point, error)) in shrunk.into_iter().zip(shrunk_errors).enumerate() {
            (simplex[i + 1], errors[i + 1]) = (point, error);
        }
    }
}

/// How well the session determines one fitted parameter, from the error's curvature around
/// the fit (its Hessian, by central differences a step of [`PROBE_UNIT`] of each range): how
/// far the parameter can move, the others following to keep the error low, before the error
/// has risen by [`RISE`]. Two parameters the session sees only as a product (tread friction
/// and magnet pull, both grip) lie along a flat valley: each is then not identifiable, though
/// either alone would change the error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Determination {
    /// The error's second derivative along this parameter alone, per (parameter unit)².
    pub curvature: f64,
    /// The half-width of the region where the error stays within [`RISE`] of its value at the
    /// fit, the other parameters free (parameter units; None: unbounded).
    pub resolution: Option<f64>,
    /// The region is narrower than [`IDENTIFIABLE_WITHIN`] of the search range.
    pub identifiable: bool,
}

/// The step of the finite differences, as a fraction of each parameter's range.
pub const PROBE_UNIT: f64 = 0.05;
/// The rise of the error (a fraction of its value at the fit, or [`RISE_FLOOR`] if more) that
/// bounds the region a parameter is determined within.
pub const RISE: f64 = 0.1;
pub const RISE_FLOOR: f64 = 1e-3;
/// A parameter is identifiable when its region is narrower than this fraction of its range.
pub const IDENTIFIABLE_WITHIN: f64 = 0.25;

/// The probes around `minimum`: the stencil's centre (a step inside the box, so that every
/// probe is where it says), a step either way along each axis, and the four diagonal steps of
/// each pair of axes: 1 + 2n + 2n(n-1) = 1 + 2n² points.
fn probe_points(minimum: &Minimum) -> Vec<Vec<f64>> {
    let n = minimum.unit.len();
    let h = PROBE_UNIT;
    let centre: Vec<f64> = minimum.unit.iter().map(|u| u.clamp(h, 1.0 - h)).collect();
    let at = |steps: &[(usize, f64)]| {
        let mut point = centre.clone();
        for (axis, sign) in steps {
            point[*axis] += sign * h;
        }
        point
    };
    let mut probes = vec![centre.clone()];
    for i in 0..n {
        probes.push(at(&[(i, -1.0)]));
        probes.push(at(&[(i, 1.0)]));
    }
    for i in 0..n {
        for j in i + 1..n {
            for (si, sj) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                probes.push(at(&[(i, si), (j, sj)]));
            }
        }
    }
    probes
}

/// Probe the error around `minimum` (all probes in one batch, [`probe_points`]) and judge each
/// parameter from the curvature.
pub fn determine(params: &[FitParam], minimum: &Minimum, evaluate: &mut Evaluate<'_>) -> Vec<Determination> {
    let errors = evaluate(&probe_points(minimum));
    determine_from(params, minimum, &errors)
}

/// [`determine`] from the errors at [`probe_points`], in their order.
fn determine_from(params: &[FitParam], minimum: &Minimum, errors: &[f64]) -> Vec<Determination> {
    let n = params.len();
    let h = PROBE_UNIT;
    let pairs: Vec<(usize, usize)> = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).collect();
    let f0 = errors[0];
    let mut hessian = nalgebra::DMatrix::<f64>::zeros(n, n);
    for i in 0..n {
        hessian[(i, i)] = (errors[1 + 2 * i] + errors[2 + 2 * i] - 2.0 * f0) / (h * h);
    }
    for (k, (i, j)) in pairs.iter().enumerate() {
        let e = &errors[1 + 2 * n + 4 * k..1 + 2 * n + 4 * k + 4];
        let mixed = (e[0] - e[1] - e[2] + e[3]) / (4.0 * h * h);
        hessian[(*i, *j)] = mixed;
        hessian[(*j, *i)] = mixed;
    }
    let rise = (RISE * minimum.error.min(f0)).max(RISE_FLOOR);
    let widths = region_half_widths(hessian.clone(), rise);
    params
        .iter()
        .enumerate()
        .map(|(i, param)| {
            let range = param.hi - param.lo;
            let curvature = hessian[(i, i)] / (range * range);
            let resolution = widths[i].filter(|w| w.is_finite()).map(|w| w * range);
            let identifiable = widths[i].is_some_and(|w| w < IDENTIFIABLE_WITHIN);
            Determination { curvature, resolution, identifiable }
        })
        .collect()
}

/// For the quadratic error ½ δᵀ H δ, each axis's half-width of the region where it stays below
/// `rise` with the other axes free: √(2 rise (H⁻¹)ᵢᵢ). A flat or falling direction (an
/// eigenvalue below a millionth of the largest) makes every axis it involves unbounded.
fn region_half_widths(hessian: nalgebra::DMatrix<f64>, rise: f64) -> Vec<Option<f64>> {
    let n = hessian.nrows();
    if hessian.iter().any(|v| !v.is_finite()) {
        return vec![None; n];
    }
    let eigen = nalgebra::SymmetricEigen::new(hessian);
    let largest = eigen.eigenvalues.iter().fold(0.0f64, |m, v| m.max(*v));
    let flat = |value: f64| value <= largest * 1e-6 || value <= 0.0;
    (0..n)
        .map(|i| {
            let mut inverse_ii = 0.0;
            for (k, value) in eigen.eigenvalues.iter().enumerate() {
                let weight = eigen.eigenvectors[(i, k)].powi(2);
                if flat(*value) {
                    if weight > 1e-6 {
                        return None;
                    }
                    continue;
                }
                inverse_ii += weight / value;
            }
            Some((2.0 * rise * inverse_ii).sqrt())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parameter_is_key_and_range() {
        assert_eq!(FitParam::parse("robot.wheel.friction=0.2..0.9"), Ok(FitParam { key: "robot.wheel.friction".into(), lo: 0.2, hi: 0.9, integer: false }));
        assert!(FitParam::parse("robot.magnet.encoder_at_down_pulses=2000..2100").is_ok_and(|p| p.integer));
        for bad in ["robot.wheel.friction", "k=1", "k=2..1", "k=a..1", "=0..1", "k=0..inf"] {
            assert!(FitParam::parse(bad).is_err(), "{bad}");
        }
        assert_eq!(FitParam::parse("k=10..20").expect("parses").value(0.25), 12.5);
    }

    /// A bowl with its floor at (0.3, 0.7) in the unit box; the third coordinate changes nothing.
    fn bowl(points: &[Vec<f64>]) -> Vec<f64> {
        points.iter().map(|p| (p[0] - 0.3).powi(2) + 4.0 * (p[1] - 0.7).powi(2) + 0.01).collect()
    }

    #[test]
    fn nelder_mead_finds_the_floor_with_or_without_speculation_and_the_flat_axis_is_not_identifiable() {
        for speculate in [false, true] {
            let mut evaluate = |points: &[Vec<f64>]| bowl(points);
            let minimum = minimise(&[0.5, 0.5, 0.5], 0, Stop { max_evaluations: 400, relative_error_spread: 1e-9, unit_size: 1e-6 }, speculate, &mut evaluate);
            assert!((minimum.unit[0] - 0.3).abs() < 1e-3 && (minimum.unit[1] - 0.7).abs() < 1e-3, "{minimum:?}");
            assert!(minimum.evaluations <= 400);
            let params: Vec<FitParam> = ["a", "b", "c"].iter().map(|k| FitParam { key: (*k).into(), lo: 0.0, hi: 10.0, integer: false }).collect();
            let determined = determine(&params, &minimum, &mut evaluate);
            assert!(determined[0].identifiable && determined[1].identifiable && !determined[2].identifiable, "{determined:?}");
            // Curvature per (parameter unit)²: 2 / 10² and 8 / 10².
            assert!((determined[0].curvature - 0.02).abs() < 1e-3 && (determined[1].curvature - 0.08).abs() < 1e-3, "{determined:?}");
            assert!(determined[2].resolution.is_none());
            // The error rises by its floor (1e-3) within √(2e-3 / 2) of the first (in unit
            // coordinates, ×10 in its own).
            let expected = (2.0f64 * 1e-3 / 2.0).sqrt() * 10.0;
            assert!((determined[0].resolution.expect("bounded") - expected).abs() < 1e-3, "{determined:?}");
        }
    }

    #[test]
    fn two_parameters_seen_only_as_their_product_are_neither_identifiable_but_a_third_is() {
        // The error depends on a × b (grip: friction × pull) and on c alone.
        let mut evaluate = |points: &[Vec<f64>]| points.iter().map(|p| (p[0] * p[1] - 0.2).powi(2) + (p[2] - 0.6).powi(2) + 1e-4).collect::<Vec<f64>>();
        let minimum = minimise(&[0.5, 0.5, 0.5], 0, Stop { max_evaluations: 400, relative_error_spread: 1e-9, unit_size: 1e-6 }, false, &mut evaluate);
        assert!((minimum.unit[0] * minimum.unit[1] - 0.2).abs() < 1e-2 && (minimum.unit[2] - 0.6).abs() < 1e-2, "{minimum:?}");
        let params: Vec<FitParam> = ["friction", "pull", "offset"].iter().map(|k| FitParam { key: (*k).into(), lo: 0.0, hi: 1.0, integer: false }).collect();
        let determined = determine(&params, &minimum, &mut evaluate);
        assert!(!determined[0].identifiable && !determined[1].identifiable, "a flat valley: {determined:?}");
        assert!(determined[2].identifiable, "{determined:?}");
        assert!(determined[0].curvature > 0.0, "either alone does change the error: {determined:?}");
    }

    #[test]
    fn the_grid_is_at_most_thirty_two_points_and_its_best_cell_is_the_start() {
        assert_eq!((1..=7).map(grid_levels).collect::<Vec<_>>(), vec![5, 5, 3, 2, 2, 1, 1]);
        // A narrow valley from (0, 1) to (1, 0) that falls gently towards (0.3, 0.7), where a
        // search from the centre (on the valley already) can stop short.
        let mut evaluate = |points: &[Vec<f64>]| points.iter().map(|p| 100.0 * (p[0] + p[1] - 1.0).powi(2) + 0.1 * (p[0] - 0.3).powi(2)).collect::<Vec<f64>>();
        let (start, spent) = grid_start(2, &mut evaluate);
        assert_eq!((start, spent), (vec![0.3, 0.7], 25), "the cell on the valley nearest its lowest point");
        let (start, spent) = grid_start(6, &mut evaluate);
        assert_eq!((start, spent), (vec![0.5; 6], 0), "too many parameters for a grid");
    }

    #[test]
    fn points_stay_in_the_box() {
        let mut seen = Vec::new();
        let mut evaluate = |points: &[Vec<f64>]| {
            seen.extend(points.iter().cloned());
            points.iter().map(|p| -p[0] - p[1]).collect()
        };
        let minimum = minimise(&[0.9, 0.1], 0, Stop::default(), true, &mut evaluate);
        assert!(seen.iter().flatten().all(|v| (0.0..=1.0).contains(v)));
        assert!(minimum.unit[0] > 0.99 && minimum.unit[1] > 0.99, "the corner: {minimum:?}");
    }
}
