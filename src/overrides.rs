//! `--set KEY=VALUE` overrides of a data file's keys (a scenario's, and with a `robot.` or
//! `profile.` prefix the robot description's and the firmware profile's), for runs, sweeps and
//! fits: `controller.zeta=0.5` sets `zeta` in the `[controller]` table. Values are TOML (`0.5`, `true`, `"text"`, `[1, 2]`); anything that
//! does not parse as TOML is taken as a string.

use thiserror::Error;

#[derive(Debug, Clone, PartialEq, Error)]
pub enum OverrideError {
    #[error("`{0}` is not KEY=VALUE")]
    NotAssignment(String),
    #[error("`{key}`: `{part}` is not a table in this file")]
    NotATable { key: String, part: String },
    #[error("`{0}` has an empty key part")]
    EmptyKey(String),
}

/// The prefix of a robot description's keys in `--set`.
pub const ROBOT_PREFIX: &str = "robot.";
/// The prefix of a firmware profile's keys in `--set`.
pub const PROFILE_PREFIX: &str = "profile.";

/// One `KEY=VALUE`.
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    pub key: String,
    pub value: toml::Value,
}

impl std::fmt::Display for Override {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}={}", self.key, self.value)
    }
}

/// Parse a TOML value, or take the text as a string.
pub fn parse_value(text: &str) -> toml::Value {
    let text = text.trim();
    format!("v = {text}").parse::<toml::Table>().ok().and_then(|mut t| t.remove("v")).unwrap_or_else(|| toml::Value::String(text.to_owned()))
}

impl Override {
    pub fn parse(assignment: &str) -> Result<Self, OverrideError> {
        let (key, value) = assignment.split_once('=').ok_or_else(|| OverrideError::NotAssignment(assignment.to_owned()))?;
        let key = key.trim();
        if key.split('.').any(str::is_empty) {
            return Err(OverrideError::EmptyKey(assignment.to_owned()));
        }
        Ok(Self { key: key.to_owned(), value: parse_value(value) })
    }

    /// Set the key in `table`, creating missing tables on the way.
    pub fn apply(&self, table: &mut toml::Table) -> Result<(), OverrideError> {
        self.set(&self.key, table)
    }

    /// Set the key less its `prefix` (`robot.`: which file it names) in that file's `table`.
    pub fn apply_under(&self, prefix: &str, table: &mut toml::Table) -> Result<(), OverrideError> {
        self.set(self.key.strip_prefix(prefix).unwrap_or(&self.key), table)
    }

    fn set(&self, key: &str, table: &mut toml::Table) -> Result<(), OverrideError> {
        let parts: Vec<&str> = key.split('.').collect();
        let (last, path) = parts.split_last().ok_or_else(|| OverrideError::EmptyKey(self.key.clone()))?;
        let mut current = table;
        for part in path {
            let entry = current.entry((*part).to_owned()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
            current = entry.as_table_mut().ok_or_else(|| OverrideError::NotATable { key: self.key.clone(), part: (*part).to_owned() })?;
        }
        current.insert((*last).to_owned(), self.value.clone());
        Ok(())
    }
}

/// Split a sweep's value list `0.3,0.5,[1, 2]` on the commas outside brackets and quotes.
pub fn split_values(list: &str) -> Vec<String> {
    let mut values = Vec::new();
    let (mut depth, mut quoted, mut current) = (0i32, false, String::new());
    for c in list.chars() {
        match c {
            '"' => quoted = !quoted,
            '[' | '{' if !quoted => depth += 1,
            ']' | '}' if !quoted => depth -= 1,
            ',' if depth == 0 && !quoted => {
                values.push(std::mem::take(&mut current).trim().to_owned());
                continue;
            }
            _ => {}
        }
        current.push(c);
    }
    values.push(current.trim().to_owned());
    values.retain(|v| !v.is_empty());
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_parse_as_toml_or_fall_back_to_strings() {
        assert_eq!(parse_value("0.5"), toml::Value::Float(0.5));
        assert_eq!(parse_value("3"), toml::Value::Integer(3));
        assert_eq!(parse_value("true"), toml::Value::Boolean(true));
        assert_eq!(parse_value("builtin"), toml::Value::String("builtin".into()));
        assert_eq!(parse_value("[1, 2]"), toml::Value::Array(vec![toml::Value::Integer(1), toml::Value::Integer(2)]));
    }

    #[test]
    fn apply_sets_nested_keys_and_creates_tables() {
        let mut table: toml::Table = "[controller]\nkind = \"builtin\"\nzeta = 0.7\n".parse().expect("toml");
        Override::parse("controller.zeta=0.3").expect("parse").apply(&mut table).expect("apply");
        Override::parse("speed.target_mm_min = 300").expect("parse").apply(&mut table).expect("apply");
        assert_eq!(table["controller"]["zeta"].as_float(), Some(0.3));
        assert_eq!(table["controller"]["kind"].as_str(), Some("builtin"));
        assert_eq!(table["speed"]["target_mm_min"].as_integer(), Some(300));
    }

    #[test]
    fn bad_overrides_are_errors() {
        assert!(matches!(Override::parse("zeta"), Err(OverrideError::NotAssignment(_))));
        assert!(matches!(Override::parse("controller..zeta=1"), Err(OverrideError::EmptyKey(_))));
        let mut table: toml::Table = "[controller]\nzeta = 0.7\n".parse().expect("toml");
        let error = Override::parse("controller.zeta.x=1").expect("parse").apply(&mut table);
        assert!(matches!(error, Err(OverrideError::NotATable { .. })));
    }

    #[test]
    fn value_lists_split_outside_brackets() {
        assert_eq!(split_values("0.3,0.5, 0.7"), ["0.3", "0.5", "0.7"]);
        assert_eq!(split_values("[1, 2],[3,4]"), ["[1, 2]", "[3,4]"]);
        assert_eq!(split_values("\"a,b\",c"), ["\"a,b\"", "c"]);
    }
}
