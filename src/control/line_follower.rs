//! The seed's linear line follower (§4.1): a yaw-rate command ω = K·e with e = [d_err, ψ_err].

use serde::{Deserialize, Serialize};

/// Damping ratio and natural frequency of the closed distance loop.
///
/// Linearised about the line (small ψ), the robot's lateral distance obeys ḋ_err = V·ψ_err and
/// its heading ψ̇_err = ω. With ω = K_d·d_err + K_ψ·ψ_err the loop's characteristic equation is
/// s² − K_ψ·s − V·K_d = 0; matching it to s² + 2ζω_n·s + ω_n² gives
/// K_ψ = −2ζω_n and K_d = −ω_n²/V.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LineFollowerGains {
    pub zeta: f64,
    pub omega_n: f64,
}

impl LineFollowerGains {
    /// (K_d in rad/s per metre, K_ψ in 1/s) at forward speed `speed_m_s` (> 0).
    pub fn gains(&self, speed_m_s: f64) -> (f64, f64) {
        (-self.omega_n * self.omega_n / speed_m_s, -2.0 * self.zeta * self.omega_n)
    }

    /// Yaw-rate command (rad/s, positive turns left) for the robot's signed distance from the
    /// line `d_err_m` (positive: the robot is left of the line) and heading relative to the line
    /// `psi_err_rad` (positive: the robot points left of the line).
    pub fn yaw_rate(&self, speed_m_s: f64, d_err_m: f64, psi_err_rad: f64) -> f64 {
        let (k_d, k_psi) = self.gains(speed_m_s);
        k_d * d_err_m + k_psi * psi_err_rad
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed loop the gains make, integrated exactly for the linear model, has the poles
    /// asked for: the characteristic polynomial's coefficients come back as 2ζω_n and ω_n².
    #[test]
    fn gains_place_the_poles_of_the_linearised_loop() {
        let gains = LineFollowerGains { zeta: 0.7, omega_n: 0.4 };
        let v = 0.004;
        let (k_d, k_psi) = gains.gains(v);
        // s² − K_ψ s − V K_d
        assert!((-k_psi - 2.0 * 0.7 * 0.4).abs() < 1e-12);
        assert!((-v * k_d - 0.16).abs() < 1e-12);
    }

    /// Left of the line and parallel to it: turn right (negative yaw rate).
    #[test]
    fn a_robot_left_of_the_line_turns_right() {
        let gains = LineFollowerGains { zeta: 0.7, omega_n: 0.4 };
        assert!(gains.yaw_rate(0.004, 0.02, 0.0) < 0.0);
        assert!(gains.yaw_rate(0.004, 0.0, 0.1) < 0.0);
    }
}
