//! The seed's linear line follower (§4.1): a yaw-rate command ω = K·e with e = [d_err, ψ_err],
//! optionally with integral action on d_err.

use serde::{Deserialize, Serialize};

/// Damping ratio and natural frequency of the closed distance loop, and an optional third pole
/// for integral action.
///
/// Linearised about the line (small ψ), the robot's lateral distance obeys ḋ_err = V·ψ_err and
/// its heading ψ̇_err = ω. With ω = K_d·d_err + K_ψ·ψ_err the loop's characteristic equation is
/// s² − K_ψ·s − V·K_d = 0; matching it to s² + 2ζω_n·s + ω_n² gives
/// K_ψ = −2ζω_n and K_d = −ω_n²/V (the seed's law).
///
/// With integral action, ω = K_d·d + K_ψ·ψ + K_i·∫d, the loop is third order,
/// s³ − K_ψ·s² − V·K_d·s − V·K_i = 0; matching it to (s² + 2ζω_n·s + ω_n²)(s + p) keeps the
/// seed's pair of poles and adds one at −p: K_ψ = −(2ζω_n + p), K_d = −(ω_n² + 2ζω_n·p)/V,
/// K_i = −ω_n²·p/V. p = 0 is the seed's law. Why: a skid-steered robot under magnet pull does not
/// turn at all for the smallest yaw commands (its wheels stick in yaw), so the proportional law
/// leaves a standing distance error or a slow limit cycle; the integral grows the command until
/// the robot turns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LineFollowerGains {
    pub zeta: f64,
    pub omega_n: f64,
    /// p (rad/s): the integral pole; 0 = no integral action.
    #[serde(default)]
    pub integral_pole_rad_s: f64,
}

impl LineFollowerGains {
    /// (K_d in rad/s per metre, K_ψ in 1/s, K_i in rad/s per metre-second) at forward speed
    /// `speed_m_s` (> 0).
    pub fn gains(&self, speed_m_s: f64) -> (f64, f64, f64) {
        let (w, p) = (self.omega_n, self.integral_pole_rad_s);
        let damping = 2.0 * self.zeta * w;
        (-(w * w + damping * p) / speed_m_s, -(damping + p), -w * w * p / speed_m_s)
    }
}

/// The line follower with its integral state.
#[derive(Debug, Clone)]
pub struct LineFollower {
    gains: LineFollowerGains,
    /// ∫ d_err dt (m·s).
    integral_m_s: f64,
}

impl LineFollower {
    pub fn new(gains: LineFollowerGains) -> Self {
        Self { gains, integral_m_s: 0.0 }
    }

    /// Yaw-rate command (rad/s, positive turns left, within ±`limit_rad_s`) for the robot's signed
    /// distance from the line `d_err_m` (positive: the robot is left of the line) and heading
    /// relative to the line `psi_err_rad` (positive: the robot points left of the line), `dt_s`
    /// after the previous call. The integral only grows while the command is inside the limit
    /// (conditional integration), so a long saturated turn does not wind it up.
    pub fn yaw_rate(&mut self, speed_m_s: f64, d_err_m: f64, psi_err_rad: f64, dt_s: f64, limit_rad_s: f64) -> f64 {
        let (k_d, k_psi, k_i) = self.gains.gains(speed_m_s);
        let proportional = k_d * d_err_m + k_psi * psi_err_rad;
        let candidate = self.integral_m_s + d_err_m * dt_s.max(0.0);
        let command = proportional + k_i * candidate;
        if command.abs() <= limit_rad_s {
            self.integral_m_s = candidate;
        }
        (proportional + k_i * self.integral_m_s).clamp(-limit_rad_s, limit_rad_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed loop the gains make, integrated exactly for the linear model, has the poles
    /// asked for: the characteristic polynomial's coefficients come back as 2ζω_n and ω_n².
    #[test]
    fn gains_place_the_poles_of_the_linearised_loop() {
        let gains = LineFollowerGains { zeta: 0.7, omega_n: 0.4, integral_pole_rad_s: 0.0 };
        let v = 0.004;
        let (k_d, k_psi, k_i) = gains.gains(v);
        // s² − K_ψ s − V K_d
        assert!((-k_psi - 2.0 * 0.7 * 0.4).abs() < 1e-12);
        assert!((-v * k_d - 0.16).abs() < 1e-12);
        assert_eq!(k_i, 0.0);
    }

    /// With an integral pole p the characteristic polynomial s³ − K_ψ s² − V K_d s − V K_i is
    /// (s² + 2ζω_n s + ω_n²)(s + p), expanded.
    #[test]
    fn the_integral_pole_adds_a_third_pole_and_keeps_the_pair() {
        let (zeta, w, p, v) = (0.7, 0.4, 0.1, 0.004);
        let gains = LineFollowerGains { zeta, omega_n: w, integral_pole_rad_s: p };
        let (k_d, k_psi, k_i) = gains.gains(v);
        assert!((-k_psi - (2.0 * zeta * w + p)).abs() < 1e-12);
        assert!((-v * k_d - (w * w + 2.0 * zeta * w * p)).abs() < 1e-12);
        assert!((-v * k_i - w * w * p).abs() < 1e-12);
    }

    /// A constant distance error that the proportional part alone leaves standing is integrated
    /// away: the command grows; and a command pinned at the limit stops the integral growing.
    #[test]
    fn the_integral_grows_the_command_and_does_not_wind_up_at_the_limit() {
        let gains = LineFollowerGains { zeta: 1.0, omega_n: 0.3, integral_pole_rad_s: 0.1 };
        let mut follower = LineFollower::new(gains);
        let first = follower.yaw_rate(0.004, 0.001, 0.0, 0.02, 0.5);
        let later = (0..500).map(|_| follower.yaw_rate(0.004, 0.001, 0.0, 0.02, 0.5)).last().unwrap_or(0.0);
        assert!(first < 0.0 && later < first, "turns right harder as the error persists: {first} then {later}");
        let mut pinned = LineFollower::new(gains);
        for _ in 0..1000 {
            assert_eq!(pinned.yaw_rate(0.004, 0.05, 0.0, 0.02, 0.5), -0.5);
        }
        // Back on the line, the command leaves the limit at once: nothing was wound up.
        assert!(pinned.yaw_rate(0.004, 0.0, 0.0, 0.02, 0.5).abs() < 0.5);
    }

    /// Left of the line and parallel to it: turn right (negative yaw rate).
    #[test]
    fn a_robot_left_of_the_line_turns_right() {
        let mut follower = LineFollower::new(LineFollowerGains { zeta: 0.7, omega_n: 0.4, integral_pole_rad_s: 0.0 });
        assert!(follower.yaw_rate(0.004, 0.02, 0.0, 0.02, 1.0) < 0.0);
        assert!(follower.yaw_rate(0.004, 0.0, 0.1, 0.02, 1.0) < 0.0);
    }
}
