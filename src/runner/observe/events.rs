//! The scenario's scripted events (`[[events]]`): target-speed steps, magnets on and off, the
//! line moving; and the target speed in force. Faults are scheduled on the bus instead
//! ([`crate::bus::BusFaults`]).

use std::path::Path;

use tracing::info_span;

use crate::runner::RunError;
use crate::scenario::{Event, Scenario, mm_min_to_m_s};
use crate::sim::RobotWorld;

use super::welds::Welds;

/// What an applied event did that others should hear of.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// A line for the run's log.
    Note(String),
    /// The welds moved: whatever shows them must show them again.
    WeldsMoved,
}

/// The events still to come, in time order, and the target speed they leave in force.
pub struct Events {
    events: Vec<Event>,
    next: usize,
    target_speed_m_s: f64,
    speed_step_at_s: f64,
}

impl Events {
    pub fn new(scenario: &Scenario) -> Self {
        let mut events = scenario.events.clone();
        events.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        Self { events, next: 0, target_speed_m_s: mm_min_to_m_s(scenario.speed.target_mm_min), speed_step_at_s: scenario.speed.step_at_s }
    }

    /// The target speed in force at `t_s` (zero before the speed step).
    pub fn target_speed_m_s(&self, t_s: f64) -> f64 {
        if t_s >= self.speed_step_at_s { self.target_speed_m_s } else { 0.0 }
    }

    /// When the speed step comes (s).
    pub fn speed_step_at_s(&self) -> f64 {
        self.speed_step_at_s
    }

    /// Apply the events due by `t_s` to the world and the welds; what they did, in order.
    pub fn apply_due(&mut self, t_s: f64, world: &mut RobotWorld, welds: &mut Welds, scenario_path: &Path) -> Result<Vec<Effect>, RunError> {
        let mut effects = Vec::new();
        while let Some(event) = self.events.get(self.next).filter(|e| e.at_s <= t_s).cloned() {
            self.next += 1;
            let _span = info_span!("event", at_s = event.at_s).entered();
            if let Some(speed) = event.set_speed_mm_min {
                self.target_speed_m_s = mm_min_to_m_s(speed);
                effects.push(Effect::Note(format!("event at {} s: target speed {speed} mm/min", event.at_s)));
            }
            if let Some(on) = event.magnets {
                world.set_magnets_on(on);
                effects.push(Effect::Note(format!("event at {} s: magnets {}", event.at_s, if on { "on" } else { "off" })));
            }
            if let Some(offset) = event.line_offset_m {
                // Validation refuses a line offset without a line; every weld moves.
                welds.offset(offset, world, scenario_path)?;
                effects.push(Effect::Note(format!("event at {} s: the line moves {} mm to the left", event.at_s, offset * 1000.0)));
                effects.push(Effect::WeldsMoved);
            }
        }
        Ok(effects)
    }
}
