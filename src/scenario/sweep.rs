//! Parameter sweeps: a grid of `--set` overrides, sliced into shards for CI matrices and job
//! arrays, and the summaries of every run gathered into one table.

use std::collections::BTreeMap;

use thiserror::Error;

use super::overrides::{Override, OverrideError, parse_value, split_values};

#[derive(Debug, Clone, PartialEq, Error)]
pub enum SweepError {
    #[error("--set {0}: expected KEY=V1,V2,...")]
    NotAssignment(String),
    #[error("--set {0}: no values")]
    NoValues(String),
    #[error(transparent)]
    Override(#[from] OverrideError),
    #[error("--shard {0}: expected K/N with 1 ≤ K ≤ N")]
    Shard(String),
}

/// One swept key and its values.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    pub key: String,
    pub values: Vec<String>,
}

impl Axis {
    /// `controller.zeta=0.3,0.5,0.7`.
    pub fn parse(text: &str) -> Result<Self, SweepError> {
        let (key, list) = text.split_once('=').ok_or_else(|| SweepError::NotAssignment(text.to_owned()))?;
        let values = split_values(list);
        if values.is_empty() {
            return Err(SweepError::NoValues(text.to_owned()));
        }
        Ok(Self { key: key.trim().to_owned(), values })
    }
}

/// One point of the grid: its index in the whole sweep and its overrides (one per axis).
#[derive(Debug, Clone, PartialEq)]
pub struct GridPoint {
    pub index: usize,
    pub overrides: Vec<Override>,
}

impl GridPoint {
    /// A folder name that says what the run was: `007-controller.zeta=0.5`.
    pub fn label(&self) -> String {
        let parameters: Vec<String> = self.overrides.iter().map(|o| format!("{}={}", o.key, o.value)).collect();
        let mut label = format!("{:03}-{}", self.index, parameters.join(","));
        label.retain(|c| c.is_ascii_alphanumeric() || "-_.,=+".contains(c));
        label
    }
}

/// Every combination of the axes' values, the first axis varying slowest.
pub fn grid(axes: &[Axis]) -> Vec<GridPoint> {
    let mut points: Vec<Vec<Override>> = vec![Vec::new()];
    for axis in axes {
        let mut next = Vec::with_capacity(points.len() * axis.values.len());
        for point in &points {
            for value in &axis.values {
                let mut overrides = point.clone();
                overrides.push(Override { key: axis.key.clone(), value: parse_value(value) });
                next.push(overrides);
            }
        }
        points = next;
    }
    points.into_iter().enumerate().map(|(index, overrides)| GridPoint { index, overrides }).collect()
}

/// `K/N`: the K-th of N slices (1-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub const ALL: Self = Self { index: 1, count: 1 };

    pub fn parse(text: &str) -> Result<Self, SweepError> {
        let bad = || SweepError::Shard(text.to_owned());
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let (index, count) = (k.trim().parse::<usize>().map_err(|_| bad())?, n.trim().parse::<usize>().map_err(|_| bad())?);
        if index == 0 || count == 0 || index > count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }

    /// This shard's points: every N-th starting at K−1, so that slow corners of the grid
    /// (e.g. low gains) spread over the shards instead of landing in one.
    pub fn select(&self, points: Vec<GridPoint>) -> Vec<GridPoint> {
        points.into_iter().filter(|p| p.index % self.count == self.index - 1).collect()
    }
}

/// The sweep table: one row per run, its parameters, then every summary metric.
pub fn table_columns(axes: &[Axis], summaries: &[BTreeMap<String, serde_json::Value>]) -> Vec<String> {
    let mut metrics: Vec<String> = summaries.iter().flat_map(|s| s.keys().cloned()).collect();
    metrics.sort();
    metrics.dedup();
    let mut columns = vec!["run".to_owned()];
    columns.extend(axes.iter().map(|a| a.key.clone()));
    columns.extend(metrics);
    columns
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axes() -> Vec<Axis> {
        vec![Axis::parse("controller.kp=1,2,4").expect("axis"), Axis::parse("controller.normal_compensation=true,false").expect("axis")]
    }

    #[test]
    fn grid_is_the_cartesian_product_first_axis_slowest() {
        let points = grid(&axes());
        assert_eq!(points.len(), 6);
        assert_eq!(points[0].overrides[0].value, toml::Value::Integer(1));
        assert_eq!(points[1].overrides[1].value, toml::Value::Boolean(false));
        assert_eq!(points[5].overrides[0].value, toml::Value::Integer(4));
        assert_eq!(points[3].label(), "003-controller.kp=2,controller.normal_compensation=false");
    }

    #[test]
    fn shards_partition_the_grid() {
        let points = grid(&axes());
        let mut seen: Vec<usize> = (1..=4).flat_map(|k| Shard { index: k, count: 4 }.select(points.clone())).map(|p| p.index).collect();
        seen.sort_unstable();
        assert_eq!(seen, (0..6).collect::<Vec<_>>());
        assert_eq!(Shard::parse("2/4"), Ok(Shard { index: 2, count: 4 }));
        assert!(Shard::parse("0/4").is_err() && Shard::parse("5/4").is_err() && Shard::parse("x").is_err());
    }

    #[test]
    fn bad_axes_are_errors() {
        assert!(matches!(Axis::parse("controller.kp"), Err(SweepError::NotAssignment(_))));
        assert!(matches!(Axis::parse("controller.kp="), Err(SweepError::NoValues(_))));
    }
}
