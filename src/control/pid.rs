//! A discrete PID with the integral clamped (anti-windup), for the wheel-speed loop.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PidGains {
    pub kp: f64,
    #[serde(default)]
    pub ki: f64,
    #[serde(default)]
    pub kd: f64,
}

#[derive(Debug, Clone)]
pub struct Pid {
    gains: PidGains,
    /// |integral contribution| never exceeds this (output units), so a stalled robot does not
    /// wind the integral up and overshoot for seconds once free.
    integral_limit: f64,
    integral: f64,
    last_error: Option<f64>,
}

impl Pid {
    pub fn new(gains: PidGains, integral_limit: f64) -> Self {
        Self { gains, integral_limit: integral_limit.abs(), integral: 0.0, last_error: None }
    }

    /// Output for `error` after `dt_s` seconds. The derivative acts on the error's change since
    /// the previous call (zero on the first).
    pub fn update(&mut self, error: f64, dt_s: f64) -> f64 {
        if self.gains.ki != 0.0 && dt_s > 0.0 {
            let limit = self.integral_limit / self.gains.ki.abs();
            self.integral = (self.integral + error * dt_s).clamp(-limit, limit);
        }
        let derivative = match self.last_error {
            Some(last) if dt_s > 0.0 => (error - last) / dt_s,
            _ => 0.0,
        };
        self.last_error = Some(error);
        self.gains.kp * error + self.gains.ki * self.integral + self.gains.kd * derivative
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proportional_only_is_kp_times_error() {
        let mut pid = Pid::new(PidGains { kp: 2.0, ki: 0.0, kd: 0.0 }, 1.0);
        assert_eq!(pid.update(0.5, 0.01), 1.0);
    }

    #[test]
    fn integral_accumulates_and_is_clamped() {
        let mut pid = Pid::new(PidGains { kp: 0.0, ki: 10.0, kd: 0.0 }, 0.3);
        assert!((pid.update(1.0, 0.01) - 0.1).abs() < 1e-12);
        for _ in 0..100 {
            pid.update(1.0, 0.01);
        }
        assert!((pid.update(1.0, 0.01) - 0.3).abs() < 1e-12, "clamped at the limit");
    }

    #[test]
    fn derivative_acts_on_the_change_of_error() {
        let mut pid = Pid::new(PidGains { kp: 0.0, ki: 0.0, kd: 1.0 }, 1.0);
        assert_eq!(pid.update(1.0, 0.1), 0.0);
        assert!((pid.update(1.5, 0.1) - 5.0).abs() < 1e-9);
    }
}
