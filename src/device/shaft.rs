//! The seam between a servo and what its output shaft drives.
//!
//! Each firmware tick the servo hands out a [`ShaftDrive`]: the motor's torque-speed line at the
//! horn for the PWM it chose, plus gearbox friction and reflected rotor inertia. Whatever owns the
//! shaft integrates it and reports a [`ShaftState`] back. On the bench that is a [`BenchLoad`]; the
//! rapier world swaps in a revolute joint behind the same types without touching protocol or bus.

/// Shaft position and speed at the horn, in the motor's own positive direction.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ShaftState {
    pub position_rad: f64,
    /// The rate the encoder sees: what Present Velocity reports and the velocity loop closes on.
    pub velocity_rad_s: f64,
    /// The rate at which the load actually took the motor's torque, when the owner of the shaft
    /// knows it differs from the encoder's (None: they are the same). A physics engine that
    /// corrects positions in a separate pass moves the shaft by more than its solved velocity;
    /// the torque it applied, and so the current the motor drew, follow the solved velocity.
    pub back_emf_velocity_rad_s: Option<f64>,
}

impl ShaftState {
    /// The speed that sets the motor's back-EMF, and with it torque and current.
    pub fn back_emf_velocity(&self) -> f64 {
        self.back_emf_velocity_rad_s.unwrap_or(self.velocity_rad_s)
    }
}

/// What the motor does to the shaft during one tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ShaftDrive {
    /// Electrical torque at standstill for the applied PWM (N·m at the horn).
    pub torque_at_standstill_nm: f64,
    /// Slope of the torque-speed line from back-EMF (N·m per rad/s): torque = standstill − slope·ω.
    pub back_emf_damping: f64,
    /// Gearbox Coulomb friction (N·m).
    pub coulomb_friction_nm: f64,
    /// Gearbox viscous friction (N·m per rad/s).
    pub viscous_friction: f64,
    /// Rotor inertia reflected through the gearbox (kg·m²), to add to whatever the shaft drives.
    pub rotor_inertia_kgm2: f64,
}

impl ShaftDrive {
    /// Electrical torque at shaft speed `omega`.
    pub fn electrical_torque(&self, omega: f64) -> f64 {
        self.torque_at_standstill_nm - self.back_emf_damping * omega
    }
}

/// Something a servo shaft drives.
pub trait ShaftLoad: Send {
    /// Advance `dt` seconds under `drive` and return the new state.
    fn step(&mut self, drive: &ShaftDrive, dt: f64) -> ShaftState;
    fn state(&self) -> ShaftState;
}

/// A servo on the bench: its own rotor inertia plus an optional extra inertia and external torque.
#[derive(Debug, Clone, Default)]
pub struct BenchLoad {
    pub extra_inertia_kgm2: f64,
    /// A constant external torque on the horn (N·m), e.g. a weight on a lever.
    pub external_torque_nm: f64,
    state: ShaftState,
}

impl BenchLoad {
    pub fn new(extra_inertia_kgm2: f64) -> Self {
        Self { extra_inertia_kgm2, ..Self::default() }
    }
}

impl ShaftLoad for BenchLoad {
    fn step(&mut self, drive: &ShaftDrive, dt: f64) -> ShaftState {
        let inertia = (drive.rotor_inertia_kgm2 + self.extra_inertia_kgm2).max(1e-9);
        let damping = drive.back_emf_damping + drive.viscous_friction;
        let driving = drive.torque_at_standstill_nm + self.external_torque_nm;
        let omega = self.state.velocity_rad_s;
        // Damping is integrated implicitly: the back-EMF pole (~2 ms) is close to the 1 ms tick.
        let implicit = |torque: f64| (inertia * omega + dt * torque) / (inertia + dt * damping);
        let friction = drive.coulomb_friction_nm;
        let next = if omega == 0.0 && driving.abs() <= friction {
            0.0 // stiction holds
        } else {
            let direction = if omega != 0.0 { omega.signum() } else { driving.signum() };
            let moving = implicit(driving - friction * direction);
            // Friction can stop the shaft but never reverse it within one tick.
            if omega != 0.0 && moving.signum() != direction { 0.0 } else { moving }
        };
        self.state.position_rad += 0.5 * (omega + next) * dt;
        self.state.velocity_rad_s = next;
        self.state
    }

    fn state(&self) -> ShaftState {
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(standstill: f64) -> ShaftDrive {
        ShaftDrive { torque_at_standstill_nm: standstill, back_emf_damping: 10.6 / std::f64::consts::PI, coulomb_friction_nm: 0.1, viscous_friction: 0.0, rotor_inertia_kgm2: 7.4e-3 }
    }

    #[test]
    fn full_torque_reaches_line_speed() {
        let mut load = BenchLoad::new(0.0);
        for _ in 0..200 {
            load.step(&drive(10.6), 1e-3);
        }
        let expected = (10.6 - 0.1) / (10.6 / std::f64::consts::PI);
        assert!((load.state().velocity_rad_s - expected).abs() < 1e-3, "{:?}", load.state());
    }

    #[test]
    fn stiction_holds_below_friction() {
        let mut load = BenchLoad::new(0.0);
        load.step(&drive(0.05), 1e-3);
        assert_eq!(load.state(), ShaftState::default());
    }

    #[test]
    fn friction_stops_without_reversing() {
        let mut load = BenchLoad::new(0.0);
        for _ in 0..50 {
            load.step(&drive(10.6), 1e-3);
        }
        for _ in 0..500 {
            load.step(&drive(0.0), 1e-3);
        }
        assert_eq!(load.state().velocity_rad_s, 0.0);
    }
}
