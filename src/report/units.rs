//! Plots speak the units scenarios are written in: speeds in mm/min (`target_mm_min = 250`),
//! distance errors in mm. The data files stay SI (`timeseries.csv`, `summary.json`); only what a
//! person reads is converted. Sweep legends read as words (`normal compensation: on`), not as
//! the override that made them (`controller.normal_compensation=true`).

/// Millimetres per metre.
pub const MM_PER_M: f64 = 1_000.0;
/// mm/min per m/s.
pub const MM_MIN_PER_M_S: f64 = 60_000.0;

/// Unit suffixes of keys, longest first (`_m_s` before `_s` and `_m`): the factor from the SI
/// value to the unit shown, and that unit.
const SUFFIXES: &[(&str, f64, &str)] = &[
    ("_mm_min", 1.0, "mm/min"),
    ("_m_s2", 1.0, "m/s²"),
    ("_rad_s", 1.0, "rad/s"),
    ("_m_s", MM_MIN_PER_M_S, "mm/min"),
    ("_pct", 1.0, "%"),
    ("_deg", 1.0, "°"),
    ("_rad", 1.0, "rad"),
    ("_kg", 1.0, "kg"),
    ("_hz", 1.0, "Hz"),
    ("_ms", 1.0, "ms"),
    ("_mm", 1.0, "mm"),
    ("_m", MM_PER_M, "mm"),
    ("_s", 1.0, "s"),
    ("_n", 1.0, "N"),
];

/// Names with a symbol of their own.
const SYMBOLS: &[(&str, &str)] = &[("zeta", "ζ"), ("omega_n", "ωn"), ("psi", "ψ"), ("kp", "Kp"), ("ki", "Ki"), ("kd", "Kd")];

/// A key's unit suffix: (name without it, factor from SI to the shown unit, the unit).
fn split_unit(name: &str) -> (&str, f64, &'static str) {
    SUFFIXES.iter().find_map(|&(suffix, factor, unit)| name.strip_suffix(suffix).filter(|stem| !stem.is_empty()).map(|stem| (stem, factor, unit))).unwrap_or((name, 1.0, ""))
}

/// The factor from a value's SI unit to the unit a plot shows it in, and that unit, from the
/// suffix of its key (`speed.steady_state_error_m_s` → 60000, "mm/min").
pub fn shown_unit(key: &str) -> (f64, &'static str) {
    let (_, factor, unit) = split_unit(key.rsplit('.').next().unwrap_or(key));
    (factor, unit)
}

/// For a signal kept in SI whose plots use another unit: the signal's name in that unit and the
/// factor to it (`speed_m_s` → `speed_mm_min`, 60000; `d_m` → `d_mm`, 1000); `None` when plots
/// show it as it is.
pub fn in_shown_unit(name: &str) -> Option<(String, f64)> {
    let (stem, factor, unit) = split_unit(name);
    (factor != 1.0).then(|| (format!("{stem}_{}", unit.replace('/', "_")), factor))
}

/// A parameter's name as words, without its section or unit: `controller.normal_compensation`
/// → `normal compensation`, `controller.zeta` → `ζ`, `speed.target_mm_min` → `target`.
pub fn parameter_name(key: &str) -> String {
    let last = key.rsplit('.').next().unwrap_or(key);
    let (stem, _, _) = split_unit(last);
    SYMBOLS.iter().find(|(name, _)| *name == stem).map_or_else(|| stem.replace('_', " "), |(_, symbol)| (*symbol).to_owned())
}

/// An axis label for a swept parameter: its name and unit (`target (mm/min)`).
pub fn parameter_axis(key: &str) -> String {
    let last = key.rsplit('.').next().unwrap_or(key);
    match split_unit(last) {
        (_, _, "") => parameter_name(key),
        (_, _, unit) => format!("{} ({unit})", parameter_name(key)),
    }
}

/// A legend entry for one swept value: `normal compensation: on`, `target: 250 mm/min`,
/// `ζ: 0.7`. Numbers are shown in the unit of [`shown_unit`] (a distance in mm).
pub fn parameter_label(key: &str, value: &str) -> String {
    let name = parameter_name(key);
    let value = value.trim();
    match value {
        "true" => return format!("{name}: on"),
        "false" => return format!("{name}: off"),
        _ => {}
    }
    let (factor, unit) = shown_unit(key);
    match value.parse::<f64>() {
        Ok(number) if !unit.is_empty() => format!("{name}: {} {unit}", super::plot::significant(number * factor)),
        _ => format!("{name}: {value}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legends_read_as_words_with_units() {
        assert_eq!(parameter_label("controller.normal_compensation", "true"), "normal compensation: on");
        assert_eq!(parameter_label("controller.normal_compensation", "false"), "normal compensation: off");
        assert_eq!(parameter_label("controller.zeta", "0.7"), "ζ: 0.7");
        assert_eq!(parameter_label("speed.target_mm_min", "250"), "target: 250 mm/min");
        assert_eq!(parameter_label("start.line_offset_m", "0.05"), "line offset: 50 mm");
        assert_eq!(parameter_label("controller.integral_pole_rad_s", "0.1"), "integral pole: 0.1 rad/s");
        assert_eq!(parameter_label("controller.kp", "2"), "Kp: 2");
        assert_eq!(parameter_label("terrain.kind", "perlin"), "kind: perlin");
    }

    #[test]
    fn axes_and_metrics_take_the_scenarios_units() {
        assert_eq!(parameter_axis("speed.target_mm_min"), "target (mm/min)");
        assert_eq!(parameter_axis("controller.zeta"), "ζ");
        assert_eq!(shown_unit("speed.steady_state_error_m_s"), (MM_MIN_PER_M_S, "mm/min"));
        assert_eq!(shown_unit("rms_distance_m"), (MM_PER_M, "mm"));
        assert_eq!(shown_unit("distance.rise_time_s"), (1.0, "s"));
        assert_eq!(shown_unit("distance.overshoot_pct"), (1.0, "%"));
        // A bare suffix is a name, not a unit.
        assert_eq!(parameter_name("x.m"), "m");
        assert_eq!(in_shown_unit("speed_m_s"), Some(("speed_mm_min".to_owned(), MM_MIN_PER_M_S)));
        assert_eq!(in_shown_unit("d_true_m"), Some(("d_true_mm".to_owned(), MM_PER_M)));
        assert_eq!(in_shown_unit("psi_rad"), None);
    }
}
