//! Fault injection: what can go wrong on the bus, in a servo and in the world,
//! as plain data. A scenario schedules faults as `[[events]]` with a `fault` table; `climbsim
//! serve --fault KIND:key=value,...` builds the same table from a compact spec and deserializes it
//! with the same code, so both accept exactly the same keys.
//!
//! The bus ([`crate::bus`]) keeps the schedule and applies each fault where it acts: bit errors,
//! dropped, late and missing replies in the bus itself; overload, overheating, voltage sag and
//! encoder noise in the servo; magnet failure and slip patches in the plant (the rapier world).

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::parts::WheelPosition;

fn one() -> f64 {
    1.0
}
fn default_ambient_c() -> f64 {
    75.0
}
fn default_slip_friction() -> f32 {
    0.05
}
fn everywhere() -> [f32; 2] {
    [f32::NEG_INFINITY, f32::INFINITY]
}

/// One fault. `kind` names it; the other keys are its parameters.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Fault {
    /// Every bit on the wire (instructions and replies) flips with probability `rate`. A corrupted
    /// instruction fails every servo's CRC check and is dropped; a corrupted reply reaches the
    /// controller as it is, and fails its CRC there.
    BitErrors { rate: f64 },
    /// Servo `id` executes instructions but its replies are lost with `probability`.
    DropReplies {
        id: u8,
        #[serde(default = "one")]
        probability: f64,
    },
    /// Servo `id`'s replies start `delay_ms` later than its Return Delay Time says (and every
    /// reply queued behind it on the wire waits too).
    LateReplies { id: u8, delay_ms: f64 },
    /// Servo `id` stops answering: it hears nothing (its line is cut, or its firmware hangs in
    /// the receiver) and so neither executes nor replies. Its control loop keeps running the last
    /// command, so a Bus Watchdog, if set, trips.
    Silent { id: u8 },
    /// Servo `id` detects an overload: Hardware Error Status bit 5 latches, the alert bit is set
    /// in every status packet, and (with bit 5 in Shutdown, the default) torque goes off. Only a
    /// Reboot clears it, so it takes no `until_s`.
    Overload { id: u8 },
    /// Servo `id` sits in hot air at `ambient_c` (the weld pool's heat). Its winding temperature
    /// follows the thermal model of its current from there, so a loaded servo passes the
    /// Temperature Limit and latches the overheating bit while an idle one may not.
    Overheating {
        id: u8,
        #[serde(default = "default_ambient_c")]
        ambient_c: f64,
    },
    /// The supply at servo `id` (every servo without `id`) sags to `volts`: the torque–speed line
    /// scales with it, and outside [Min, Max Voltage Limit] the input-voltage bit latches.
    VoltageSag {
        #[serde(default)]
        id: Option<u8>,
        volts: f64,
    },
    /// Gaussian noise on what servo `id`'s encoder reads: on the position (pulses, standard
    /// deviation) and on the speed estimate (Present Velocity units of 0.229 rev/min). Present
    /// Position/Velocity and the firmware's own loops all see it.
    EncoderNoise {
        id: u8,
        #[serde(default)]
        position_std_pulses: f64,
        #[serde(default)]
        velocity_std: f64,
    },
    /// The magnet of `wheel` (front_left/fl, …) keeps only `pull` of its force (0 = failed).
    MagnetFailure {
        wheel: WheelPosition,
        #[serde(default)]
        pull: f32,
    },
    /// A patch of the terrain (x and z ranges, metres, world frame; the whole surface without
    /// them) where tread-on-steel friction drops to `friction` (oil, scale, a wet plate).
    SlipPatch {
        #[serde(default = "everywhere")]
        x_m: [f32; 2],
        #[serde(default = "everywhere")]
        z_m: [f32; 2],
        #[serde(default = "default_slip_friction")]
        friction: f32,
    },
}

#[derive(Debug, Error, PartialEq)]
pub enum FaultError {
    #[error("fault `{spec}`: {message}")]
    Spec { spec: String, message: String },
    #[error("fault {kind}: {message}")]
    Invalid { kind: &'static str, message: String },
}

impl Fault {
    /// The `kind` key.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::BitErrors { .. } => "bit_errors",
            Self::DropReplies { .. } => "drop_replies",
            Self::LateReplies { .. } => "late_replies",
            Self::Silent { .. } => "silent",
            Self::Overload { .. } => "overload",
            Self::Overheating { .. } => "overheating",
            Self::VoltageSag { .. } => "voltage_sag",
            Self::EncoderNoise { .. } => "encoder_noise",
            Self::MagnetFailure { .. } => "magnet_failure",
            Self::SlipPatch { .. } => "slip_patch",
        }
    }

    /// The servo it acts on, for the faults that name one.
    pub fn servo_id(&self) -> Option<u8> {
        match *self {
            Self::DropReplies { id, .. } | Self::LateReplies { id, .. } | Self::Silent { id } | Self::Overload { id } | Self::Overheating { id, .. } | Self::EncoderNoise { id, .. } => Some(id),
            Self::VoltageSag { id, .. } => id,
            Self::BitErrors { .. } | Self::MagnetFailure { .. } | Self::SlipPatch { .. } => None,
        }
    }

    /// Whether it ends by itself at `until_s`. An overload latches until a Reboot.
    pub fn can_end(&self) -> bool {
        !matches!(self, Self::Overload { .. })
    }

    /// Range checks serde cannot express.
    pub fn validate(&self) -> Result<(), FaultError> {
        let invalid = |message: String| Err(FaultError::Invalid { kind: self.kind(), message });
        let probability = |p: f64| (0.0..=1.0).contains(&p);
        match *self {
            Self::BitErrors { rate } if !probability(rate) => invalid(format!("rate {rate} is not a probability in [0, 1]")),
            Self::DropReplies { probability: p, .. } if !probability(p) => invalid(format!("probability {p} is not in [0, 1]")),
            Self::LateReplies { delay_ms, .. } if !(delay_ms.is_finite() && delay_ms >= 0.0) => invalid(format!("delay_ms {delay_ms} must be >= 0")),
            Self::Overheating { ambient_c, .. } if !ambient_c.is_finite() => invalid("ambient_c must be finite".into()),
            Self::VoltageSag { volts, .. } if !(volts.is_finite() && volts >= 0.0) => invalid(format!("volts {volts} must be >= 0")),
            Self::EncoderNoise { position_std_pulses: p, velocity_std: v, .. } if !(p >= 0.0 && v >= 0.0 && p.is_finite() && v.is_finite()) => invalid("standard deviations must be >= 0".into()),
            Self::MagnetFailure { pull, .. } if !(0.0..=1.0).contains(&pull) => invalid(format!("pull {pull} is not a fraction in [0, 1]")),
            Self::SlipPatch { x_m, z_m, friction } => {
                if !(friction.is_finite() && friction >= 0.0) {
                    return invalid(format!("friction {friction} must be >= 0"));
                }
                if x_m[0] > x_m[1] || z_m[0] > z_m[1] {
                    return invalid("x_m and z_m are [min, max]".into());
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }
}

/// Latest `at`/`until` (s): a million seconds (11.6 days) is beyond any run or serve session,
/// and keeps the time a [`std::time::Duration`] can hold.
pub const MAX_FAULT_TIME_S: f64 = 1e6;

/// The first fault in `faults` on a servo ID that is not in `ids` (the robot's bus).
pub fn check_ids(faults: &[ScheduledFault], ids: &[u8]) -> Result<(), FaultError> {
    for scheduled in faults {
        if let Some(id) = scheduled.fault.servo_id().filter(|id| !ids.contains(id)) {
            let known = ids.iter().map(u8::to_string).collect::<Vec<_>>().join(", ");
            return Err(FaultError::Invalid { kind: scheduled.fault.kind(), message: format!("servo ID {id} is not on the robot's bus (IDs: {known})") });
        }
    }
    Ok(())
}

/// A fault and when it acts: from `at_s` until `until_s` (for good without it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScheduledFault {
    pub at_s: f64,
    pub until_s: Option<f64>,
    pub fault: Fault,
}

impl ScheduledFault {
    pub fn validate(&self) -> Result<(), FaultError> {
        self.fault.validate()?;
        let invalid = |message: String| Err(FaultError::Invalid { kind: self.fault.kind(), message });
        if !(self.at_s.is_finite() && (0.0..=MAX_FAULT_TIME_S).contains(&self.at_s)) {
            return invalid(format!("at {} s is outside [0, {MAX_FAULT_TIME_S}] s", self.at_s));
        }
        if let Some(until) = self.until_s.filter(|u| !(u.is_finite() && *u <= MAX_FAULT_TIME_S)) {
            return invalid(format!("until {until} s is outside [at, {MAX_FAULT_TIME_S}] s"));
        }
        match self.until_s {
            Some(_) if !self.fault.can_end() => invalid("it latches until a Reboot; `until` is not allowed".into()),
            Some(until) if until.is_nan() || until < self.at_s => invalid(format!("until {until} is before at {}", self.at_s)),
            _ => Ok(()),
        }
    }

    /// Parse the compact form of `serve --fault`: `KIND[:key=value,...]`, where `at` and `until`
    /// (seconds) give the window and every other key is the fault table's. Values are TOML
    /// values (`0.5`, `[0.2, 0.4]`, `"fl"`); a bare word is a string (`wheel=fl`).
    ///
    /// `overload:id=2,at=5` · `late_replies:id=3,delay_ms=4,at=1,until=9` ·
    /// `slip_patch:x_m=[0.2,0.6],friction=0.05`
    pub fn parse(spec: &str) -> Result<Self, FaultError> {
        let fail = |message: String| FaultError::Spec { spec: spec.to_owned(), message };
        let (kind, rest) = spec.split_once(':').unwrap_or((spec, ""));
        let kind = kind.trim();
        if kind.is_empty() {
            return Err(fail("no kind (e.g. `overload:id=2,at=5`)".into()));
        }
        let mut table = toml::Table::new();
        table.insert("kind".into(), toml::Value::String(kind.to_owned()));
        let (mut at_s, mut until_s) = (0.0, None);
        for pair in split_top_level(rest) {
            let (key, text) = pair.split_once('=').ok_or_else(|| fail(format!("`{pair}` is not key=value")))?;
            let (key, text) = (key.trim(), text.trim());
            let value = parse_value(text);
            let seconds = || value.as_float().or_else(|| value.as_integer().map(|i| i as f64)).ok_or_else(|| fail(format!("{key}: `{text}` is not a number of seconds")));
            match key {
                "at" | "at_s" => at_s = seconds()?,
                "until" | "until_s" => until_s = Some(seconds()?),
                "kind" => return Err(fail("the kind goes before the colon".into())),
                _ => {
                    if table.insert(key.to_owned(), value).is_some() {
                        return Err(fail(format!("{key} given twice")));
                    }
                }
            }
        }
        let fault = Fault::deserialize(table).map_err(|e| fail(e.to_string()))?;
        let scheduled = Self { at_s, until_s, fault };
        scheduled.validate().map_err(|e| fail(e.to_string()))?;
        Ok(scheduled)
    }
}

/// A TOML value from its text; a bare word that is no TOML value is a string.
fn parse_value(text: &str) -> toml::Value {
    format!("v = {text}").parse::<toml::Table>().ok().and_then(|mut t| t.remove("v")).unwrap_or_else(|| toml::Value::String(text.to_owned()))
}

/// Split at commas that are not inside brackets or quotes.
fn split_top_level(text: &str) -> Vec<&str> {
    let (mut parts, mut depth, mut quoted, mut start) = (Vec::new(), 0i32, false, 0);
    for (i, c) in text.char_indices() {
        match c {
            '"' => quoted = !quoted,
            '[' if !quoted => depth += 1,
            ']' if !quoted => depth -= 1,
            ',' if !quoted && depth == 0 => {
                parts.push(&text[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&text[start..]);
    parts.into_iter().map(str::trim).filter(|p| !p.is_empty()).collect()
}

pub use crate::rng::SplitMix64;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compact_spec_parses_like_the_table() {
        let s = ScheduledFault::parse("overload:id=2,at=5").unwrap();
        assert_eq!(s, ScheduledFault { at_s: 5.0, until_s: None, fault: Fault::Overload { id: 2 } });
        let s = ScheduledFault::parse("slip_patch:x_m=[0.2, 0.6],friction=0.1,until=9").unwrap();
        assert_eq!(s.fault, Fault::SlipPatch { x_m: [0.2, 0.6], z_m: everywhere(), friction: 0.1 });
        assert_eq!(s.until_s, Some(9.0));
        let s = ScheduledFault::parse("magnet_failure:wheel=fl").unwrap();
        assert_eq!(s.fault, Fault::MagnetFailure { wheel: WheelPosition::FrontLeft, pull: 0.0 });
        assert_eq!(ScheduledFault::parse("voltage_sag:volts=9").unwrap().fault, Fault::VoltageSag { id: None, volts: 9.0 });
    }

    #[test]
    fn bad_specs_say_what_is_wrong() {
        let message = |spec: &str| ScheduledFault::parse(spec).unwrap_err().to_string();
        assert!(message("overlaod:id=2").contains("unknown variant `overlaod`"), "{}", message("overlaod:id=2"));
        assert!(message("overload:id=2,colour=red").contains("unknown field `colour`"));
        assert!(message("overload").contains("missing field `id`"));
        assert!(message("overload:id=2,until=3").contains("Reboot"));
        assert!(message("bit_errors:rate=2").contains("probability"));
        assert!(message("late_replies:id=1,delay_ms=3,at=5,until=2").contains("before"));
        assert!(message("silent:id").contains("key=value"));
    }

    #[test]
    fn splitmix_is_deterministic_and_roughly_normal() {
        let (mut a, mut b) = (SplitMix64::new(7), SplitMix64::new(7));
        assert_eq!(a.next_u64(), b.next_u64());
        let n = 20_000;
        let samples: Vec<f64> = (0..n).map(|_| a.next_gaussian()).collect();
        let mean = samples.iter().sum::<f64>() / n as f64;
        let var = samples.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.03 && (var - 1.0).abs() < 0.05, "mean {mean} var {var}");
    }
}
