//! Parameter sweeps: a grid of `--set` overrides, sliced into shards for CI matrices and job
//! arrays, and the summaries of every run gathered into one table.

use std::collections::BTreeMap;

use thiserror::Error;

use crate::overrides::{Override, OverrideError, parse_value, split_values};

#[derive(Debug, Clone, PartialEq, Error)]
pub enum SweepError {
    #[error("--set {0}: expected KEY=V1,V2,...")]
    NotAssignment(String),
    #[error("--set {0}: no values")]
    NoValues(String),
    #[error(transparent)]
    Override(#[from] OverrideError),
    #[error("--shard {0}: expected K/N with 1 ≤ K ≤ N, or auto/N (K from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX)")]
    Shard(String),
    #[error("--shard {text}: {message}")]
    ShardIndex { text: String, message: String },
    #[error("--set {0} is given twice: one --set per key, its values separated by commas")]
    DuplicateKey(String),
}

/// One swept key and its values.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
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

    /// Every `--set` of a sweep; a key given twice is an error (the grid would be ambiguous).
    pub fn parse_all(texts: &[String]) -> Result<Vec<Self>, SweepError> {
        let mut axes: Vec<Self> = Vec::with_capacity(texts.len());
        for text in texts {
            let axis = Self::parse(text)?;
            if axes.iter().any(|a| a.key == axis.key) {
                return Err(SweepError::DuplicateKey(axis.key));
            }
            axes.push(axis);
        }
        Ok(axes)
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
        Self::parse_with_env(text, |name| std::env::var(name).ok())
    }

    /// [`Self::parse`] with the environment given: `auto/N` takes K from a job array's 0-based
    /// task index, Slurm's `SLURM_ARRAY_TASK_ID` or a Kubernetes Indexed Job's
    /// `JOB_COMPLETION_INDEX`, as it is: a task's id is its shard's, whatever part of the array
    /// runs (failed tasks resubmitted with `--array=5-7` run shards 6 to 8, as they should; the
    /// id less `SLURM_ARRAY_TASK_MIN` would run shards 1 to 3 into those tasks' folders).
    /// An array numbered from 1 (`--array=1-8`) is refused at its last task, naming the cure. N
    /// is always explicit: a shard count read from the scheduler would silently change with the
    /// array's size.
    pub fn parse_with_env(text: &str, env: impl Fn(&str) -> Option<String>) -> Result<Self, SweepError> {
        let bad = || SweepError::Shard(text.to_owned());
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let count = n.trim().parse::<usize>().map_err(|_| bad())?;
        if count == 0 {
            return Err(bad());
        }
        let index = if k.trim() == "auto" {
            let fail = |message: String| SweepError::ShardIndex { text: text.to_owned(), message };
            let number = |name: &str| env(name).map(|v| v.trim().parse::<usize>().map_err(|_| fail(format!("{name}={v} is not a task index"))));
            let zero_based = match (number("SLURM_ARRAY_TASK_ID"), number("JOB_COMPLETION_INDEX")) {
                (Some(slurm), None) => {
                    let id = slurm?;
                    if id >= count {
                        return Err(fail(format!(
                            "SLURM_ARRAY_TASK_ID={id} is not below the shard count {count}: the task ids are the shards' 0-based indices, so number the array 0-{} (--array=0-{}; a part of it, --array=5-7, reruns those shards)",
                            count - 1,
                            count - 1
                        )));
                    }
                    id
                }
                (None, Some(kubernetes)) => kubernetes?,
                (Some(_), Some(_)) => return Err(fail("both SLURM_ARRAY_TASK_ID and JOB_COMPLETION_INDEX are set: give K/N explicitly".to_owned())),
                (None, None) => return Err(fail("auto needs SLURM_ARRAY_TASK_ID (a Slurm job array) or JOB_COMPLETION_INDEX (a Kubernetes Indexed Job)".to_owned())),
            };
            if zero_based >= count {
                return Err(fail(format!("task index {zero_based} (0-based) is not below the shard count {count}")));
            }
            zero_based + 1
        } else {
            k.trim().parse::<usize>().map_err(|_| bad())?
        };
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
        assert!(Shard::parse("0/4").is_err() && Shard::parse("5/4").is_err() && Shard::parse("x").is_err() && Shard::parse("1/0").is_err());
        assert!(Shard::parse_with_env("auto/0", |_| Some("0".to_owned())).is_err(), "no shards, whatever the task");
    }

    #[test]
    fn auto_shards_come_from_the_job_array_index() {
        let env = |vars: &'static [(&'static str, &'static str)]| move |name: &str| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| (*v).to_owned());
        assert_eq!(Shard::parse_with_env("auto/4", env(&[("SLURM_ARRAY_TASK_ID", "0")])), Ok(Shard { index: 1, count: 4 }));
        // A part of the array resubmitted (--array=2-3) runs its own shards, not the first ones.
        assert_eq!(Shard::parse_with_env("auto/4", env(&[("SLURM_ARRAY_TASK_ID", "2"), ("SLURM_ARRAY_TASK_MIN", "2")])), Ok(Shard { index: 3, count: 4 }));
        // An array numbered from 1 is refused at its last task, saying how to number it.
        match Shard::parse_with_env("auto/4", env(&[("SLURM_ARRAY_TASK_ID", "4"), ("SLURM_ARRAY_TASK_MIN", "1")])) {
            Err(SweepError::ShardIndex { message, .. }) => assert!(message.contains("--array=0-3"), "{message}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(Shard::parse_with_env("auto/4", env(&[("JOB_COMPLETION_INDEX", "3")])), Ok(Shard { index: 4, count: 4 }));
        for vars in [&[("JOB_COMPLETION_INDEX", "4")][..], &[][..], &[("SLURM_ARRAY_TASK_ID", "1"), ("JOB_COMPLETION_INDEX", "1")][..], &[("SLURM_ARRAY_TASK_ID", "x")][..]] {
            assert!(matches!(Shard::parse_with_env("auto/4", env(vars)), Err(SweepError::ShardIndex { .. })), "{vars:?}");
        }
    }

    #[test]
    fn a_key_swept_twice_is_an_error() {
        let texts = ["world.duration_s=1,2".to_owned(), "world.duration_s=3".to_owned()];
        assert_eq!(Axis::parse_all(&texts), Err(SweepError::DuplicateKey("world.duration_s".to_owned())));
    }

    #[test]
    fn bad_axes_are_errors() {
        assert!(matches!(Axis::parse("controller.kp"), Err(SweepError::NotAssignment(_))));
        assert!(matches!(Axis::parse("controller.kp="), Err(SweepError::NoValues(_))));
    }
}
