//! DC motor and gearbox, from the datasheet figures in the profile: a linear torque-speed line
//! through (0, stall torque) and (no-load speed, 0) at the rated voltage, scaled by the applied
//! voltage; current proportional to torque.

use std::f64::consts::TAU;

use super::profile::MotorSpec;
use super::shaft::ShaftDrive;

#[derive(Debug, Clone)]
pub struct Motor {
    spec: MotorSpec,
    /// Torque-speed slope at the horn (N·m per rad/s).
    back_emf_damping: f64,
    rotor_inertia_reflected: f64,
    winding_resistance_ohm: f64,
}

impl Motor {
    pub fn new(spec: &MotorSpec) -> Self {
        let no_load_rad_s = spec.no_load_speed_rpm * TAU / 60.0;
        Self {
            back_emf_damping: spec.back_emf_damping_nm_per_rad_s.unwrap_or(spec.stall_torque_nm / no_load_rad_s),
            rotor_inertia_reflected: spec.rotor_inertia_kgm2 * spec.gear_ratio * spec.gear_ratio,
            winding_resistance_ohm: spec.rated_voltage_v / spec.stall_current_a,
            spec: spec.clone(),
        }
    }

    pub fn spec(&self) -> &MotorSpec {
        &self.spec
    }

    /// The drive for `duty` (−1..1 of the supply) at `supply_v`.
    pub fn drive(&self, duty: f64, supply_v: f64) -> ShaftDrive {
        ShaftDrive {
            torque_at_standstill_nm: self.spec.stall_torque_nm * duty * supply_v / self.spec.rated_voltage_v,
            back_emf_damping: self.back_emf_damping,
            coulomb_friction_nm: self.spec.coulomb_friction_nm,
            viscous_friction: self.spec.viscous_friction_nm_per_rad_s,
            rotor_inertia_kgm2: self.rotor_inertia_reflected,
        }
    }

    /// Torque off: the H-bridge is open, so the shaft coasts with gearbox friction only (no
    /// back-EMF braking).
    pub fn coast(&self) -> ShaftDrive {
        ShaftDrive { back_emf_damping: 0.0, ..self.drive(0.0, 0.0) }
    }

    /// Duty that makes the motor produce `torque_nm` at speed `omega` (an ideal current loop).
    pub fn duty_for_torque(&self, torque_nm: f64, omega: f64, supply_v: f64) -> f64 {
        let volts = (torque_nm + self.back_emf_damping * omega) * self.spec.rated_voltage_v / self.spec.stall_torque_nm;
        volts / supply_v
    }

    /// Winding current (A, signed) for an electrical torque.
    pub fn current_for_torque(&self, torque_nm: f64) -> f64 {
        torque_nm / self.spec.stall_torque_nm * self.spec.stall_current_a
    }

    pub fn torque_for_current(&self, current_a: f64) -> f64 {
        current_a / self.spec.stall_current_a * self.spec.stall_torque_nm
    }

    /// Copper loss (W) at `current_a`.
    pub fn copper_loss_w(&self, current_a: f64) -> f64 {
        current_a * current_a * self.winding_resistance_ohm
    }
}
