//! The seed's wall transition (§6), as the built-in controller's option
//! `[controller.wall_transition]`: the front LIDAR sees a surface ahead (a wall from the floor,
//! the floor from a wall); the robot turns until it faces it square; as the front wheels reach
//! it, the front magnet shafts (position mode) turn their magnets toward it; after the wheels
//! have rolled on a set distance the magnets are let go to follow the surface again, and line
//! following goes on. One transition per run: after it the LIDAR is not watched again.
//!
//! The phases are pure decisions on what the controller can know: the LIDAR's range straight
//! ahead, its fitted wall angle, and the wheels' odometry.

use serde::{Deserialize, Serialize};

fn default_detect_m() -> f64 {
    0.45
}
fn default_magnets_at_m() -> f64 {
    0.21
}
fn default_front_magnet_deg() -> f64 {
    30.0
}
fn default_release_after_m() -> f64 {
    0.15
}
fn default_square_gain() -> f64 {
    1.0
}
fn default_square_window_deg() -> f64 {
    20.0
}

/// `[controller.wall_transition]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallTransitionConfig {
    /// LIDAR range straight ahead (m) at which a surface ahead counts as seen: from there the
    /// robot squares up to it instead of following the line.
    #[serde(default = "default_detect_m")]
    pub detect_m: f64,
    /// Range ahead (m) at which the front magnets turn toward the surface: where the front
    /// wheels meet it (0.21 m for this robot's LIDAR and a 150 mm fillet).
    #[serde(default = "default_magnets_at_m")]
    pub magnets_at_m: f64,
    /// How far forward of straight down the front magnets are turned (deg).
    #[serde(default = "default_front_magnet_deg")]
    pub front_magnet_deg: f64,
    /// Wheel travel (m) after the magnets turned at which they are let go (torque off) to follow
    /// the new surface.
    #[serde(default = "default_release_after_m")]
    pub release_after_m: f64,
    /// Squaring turn: yaw rate (rad/s) per radian of the wall's angle.
    #[serde(default = "default_square_gain")]
    pub square_gain: f64,
    /// The LIDAR's returns within this of straight ahead (deg) are fitted as the wall.
    #[serde(default = "default_square_window_deg")]
    pub square_window_deg: f64,
}

impl Default for WallTransitionConfig {
    fn default() -> Self {
        Self {
            detect_m: default_detect_m(),
            magnets_at_m: default_magnets_at_m(),
            front_magnet_deg: default_front_magnet_deg(),
            release_after_m: default_release_after_m(),
            square_gain: default_square_gain(),
            square_window_deg: default_square_window_deg(),
        }
    }
}

/// What the LIDAR says about the surface ahead.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallSighting {
    /// Range straight ahead (m; infinity without a return).
    pub ahead_m: f64,
    /// The turn that would face the surface square (rad, + = left), if it could be fitted.
    pub angle_rad: Option<f64>,
}

/// Where the transition is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Phase {
    /// Following the line; watching the LIDAR.
    Following,
    /// A surface ahead: turning to face it square while driving on.
    Squaring,
    /// The front magnets turned toward the surface at this odometry (m).
    Climbing { since_m: f64 },
    /// The magnets let go; following the line on the new surface.
    Done,
}

impl Phase {
    /// A number for the time series: 0 following, 1 squaring, 2 climbing, 3 done.
    pub fn code(self) -> f64 {
        match self {
            Phase::Following => 0.0,
            Phase::Squaring => 1.0,
            Phase::Climbing { .. } => 2.0,
            Phase::Done => 3.0,
        }
    }
}

/// What the transition wants this period.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Decision {
    /// A yaw rate that replaces the line follower's (rad/s, before the controller's limit).
    pub yaw_rate_rad_s: Option<f64>,
    /// Turn the front magnets to this angle forward of straight down (rad) and hold it.
    pub hold_front_magnets_rad: Option<f64>,
    /// Let the front magnets go (torque off).
    pub release_front_magnets: bool,
}

/// The transition's state machine.
#[derive(Debug, Clone)]
pub struct WallTransition {
    config: WallTransitionConfig,
    phase: Phase,
}

impl WallTransition {
    pub fn new(config: WallTransitionConfig) -> Self {
        Self { config, phase: Phase::Following }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// One control period: what the LIDAR sees and how far the wheels have rolled (m).
    pub fn update(&mut self, wall: Option<WallSighting>, odometry_m: f64) -> Decision {
        let ahead = wall.map_or(f64::INFINITY, |w| w.ahead_m);
        let squaring_turn = |config: &WallTransitionConfig| wall.and_then(|w| w.angle_rad).map(|angle| config.square_gain * angle);
        match self.phase {
            Phase::Following if ahead <= self.config.detect_m => {
                tracing::info!(ahead_m = ahead, "wall transition: a surface ahead, squaring up");
                self.phase = Phase::Squaring;
                Decision { yaw_rate_rad_s: squaring_turn(&self.config), ..Decision::default() }
            }
            Phase::Following | Phase::Done => Decision::default(),
            Phase::Squaring if ahead <= self.config.magnets_at_m => {
                tracing::info!(ahead_m = ahead, odometry_m, "wall transition: front magnets toward the surface");
                self.phase = Phase::Climbing { since_m: odometry_m };
                Decision { yaw_rate_rad_s: Some(0.0), hold_front_magnets_rad: Some(self.config.front_magnet_deg.to_radians()), release_front_magnets: false }
            }
            // Keep squaring; without a fit (a noisy scan) keep straight rather than follow a line
            // the camera may be losing at the foot of the wall.
            Phase::Squaring => Decision { yaw_rate_rad_s: Some(squaring_turn(&self.config).unwrap_or(0.0)), ..Decision::default() },
            Phase::Climbing { since_m } if odometry_m - since_m >= self.config.release_after_m => {
                tracing::info!(odometry_m, "wall transition: front magnets let go, following the line");
                self.phase = Phase::Done;
                Decision { release_front_magnets: true, ..Decision::default() }
            }
            // Straight up the fillet: the line is foreshortened to nothing in the camera there.
            Phase::Climbing { .. } => Decision { yaw_rate_rad_s: Some(0.0), ..Decision::default() },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(ahead_m: f64, angle_deg: f64) -> Option<WallSighting> {
        Some(WallSighting { ahead_m, angle_rad: Some(angle_deg.to_radians()) })
    }

    #[test]
    fn the_phases_follow_the_lidar_and_the_odometry() {
        let mut t = WallTransition::new(WallTransitionConfig::default());
        assert_eq!(t.update(None, 0.0), Decision::default());
        assert_eq!(t.update(seen(0.8, 10.0), 0.1), Decision::default());
        assert_eq!(t.phase(), Phase::Following);
        // Seen at 0.45 m, 10° to the left: turn left at 1 rad/s per rad.
        let d = t.update(seen(0.45, 10.0), 0.2);
        assert_eq!(t.phase(), Phase::Squaring);
        assert!((d.yaw_rate_rad_s.unwrap_or(f64::NAN) - 10f64.to_radians()).abs() < 1e-12);
        // A scan without a fit: straight on.
        assert_eq!(t.update(Some(WallSighting { ahead_m: 0.3, angle_rad: None }), 0.3).yaw_rate_rad_s, Some(0.0));
        // At the foot of the wall the front magnets turn 30° forward.
        let d = t.update(seen(0.21, 0.0), 0.4);
        assert_eq!(t.phase(), Phase::Climbing { since_m: 0.4 });
        assert!((d.hold_front_magnets_rad.unwrap_or(f64::NAN) - 30f64.to_radians()).abs() < 1e-12);
        // Let go after 0.15 m more, once.
        assert!(!t.update(None, 0.54).release_front_magnets);
        assert!(t.update(None, 0.55).release_front_magnets);
        assert_eq!(t.phase(), Phase::Done);
        assert_eq!(t.update(seen(0.1, 30.0), 0.6), Decision::default(), "one transition per run");
    }

    #[test]
    fn unknown_keys_are_refused() {
        assert!(toml::from_str::<WallTransitionConfig>("detect = 0.3").is_err());
        assert_eq!(toml::from_str::<WallTransitionConfig>("").ok(), Some(WallTransitionConfig::default()));
    }
}
