//! Names of the robot's parts that several layers share: which wheel, which job a servo does.
//! They sit at the bottom of the crate so that the fault descriptions (read by the bus) can name
//! a wheel without importing the robot description, which builds the bus.

use serde::Deserialize;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ServoRole {
    WheelDrive,
    MagnetShaft,
}

/// Which wheel a servo belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WheelPosition {
    #[serde(alias = "fl")]
    FrontLeft,
    #[serde(alias = "fr")]
    FrontRight,
    #[serde(alias = "rl")]
    RearLeft,
    #[serde(alias = "rr")]
    RearRight,
}

impl WheelPosition {
    pub const ALL: [Self; 4] = [Self::FrontLeft, Self::FrontRight, Self::RearLeft, Self::RearRight];

    pub fn is_front(self) -> bool {
        matches!(self, Self::FrontLeft | Self::FrontRight)
    }

    pub fn is_left(self) -> bool {
        matches!(self, Self::FrontLeft | Self::RearLeft)
    }

    pub fn index(self) -> usize {
        self as usize
    }

    /// The wheel's name as scenarios and robot descriptions write it (`front_left`, …).
    pub fn name(self) -> &'static str {
        match self {
            Self::FrontLeft => "front_left",
            Self::FrontRight => "front_right",
            Self::RearLeft => "rear_left",
            Self::RearRight => "rear_right",
        }
    }
}
