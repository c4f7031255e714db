//! Obstacles on the terrain: boxes (stiffeners, brackets) and cylinders (pipes on a deck,
//! posts), fixed rapier colliders that the wheels and sections hit and the LIDAR sees.
//!
//! Each stands on the terrain: it is placed in plan at `at_m = [x, z]` and rests on the surface
//! found straight below that point (its lowest point on the surface), turned by `yaw_deg` about
//! the vertical. A cylinder stands upright unless `lying = true`, when its axis runs along its
//! yawed x axis (a pipe on the deck). The magnets pull toward the terrain only, not toward
//! obstacles.

use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// The largest obstacle dimension accepted (m): anything larger is a terrain, not an obstacle.
pub const MAX_OBSTACLE_M: f32 = 100.0;

/// Read and written as one flat table ([`ObstacleTable`]), not as an internally tagged enum:
/// serde buffers a tagged enum's fields, and then a mistake in the third `[[obstacles]]` is
/// blamed on the first one's header with no key; a plain table keeps every key's line.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(try_from = "ObstacleTable", into = "ObstacleTable")]
pub enum ObstacleSpec {
    /// A box of `size_m` = [length along x, height, width along z] before its yaw.
    Box {
        at_m: [f32; 2],
        size_m: [f32; 3],
        #[serde(default)]
        yaw_deg: f32,
    },
    Cylinder {
        at_m: [f32; 2],
        radius_m: f32,
        /// Height when upright; length when lying.
        length_m: f32,
        #[serde(default)]
        lying: bool,
        #[serde(default)]
        yaw_deg: f32,
    },
}

/// The kinds of obstacle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleKind {
    Box,
    Cylinder,
}

/// An `[[obstacles]]` table as written: every kind's keys, each kind taking its own.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleTable {
    pub kind: ObstacleKind,
    pub at_m: [f32; 2],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_m: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius_m: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_m: Option<f32>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lying: bool,
    #[serde(default)]
    pub yaw_deg: f32,
}

impl TryFrom<ObstacleTable> for ObstacleSpec {
    type Error = String;

    fn try_from(table: ObstacleTable) -> Result<Self, String> {
        let ObstacleTable { kind, at_m, size_m, radius_m, length_m, lying, yaw_deg } = table;
        let not_for = |key: &str, kind: &str| Err(format!("`{key}` is not a key of a {kind} obstacle"));
        match kind {
            ObstacleKind::Box => {
                if radius_m.is_some() {
                    return not_for("radius_m", "box");
                }
                if length_m.is_some() {
                    return not_for("length_m", "box");
                }
                if lying {
                    return not_for("lying", "box");
                }
                let size_m = size_m.ok_or("a box obstacle needs `size_m` = [length, height, width]")?;
                Ok(Self::Box { at_m, size_m, yaw_deg })
            }
            ObstacleKind::Cylinder => {
                if size_m.is_some() {
                    return not_for("size_m", "cylinder");
                }
                let (Some(radius_m), Some(length_m)) = (radius_m, length_m) else {
                    return Err("a cylinder obstacle needs `radius_m` and `length_m`".to_owned());
                };
                Ok(Self::Cylinder { at_m, radius_m, length_m, lying, yaw_deg })
            }
        }
    }
}

impl From<ObstacleSpec> for ObstacleTable {
    fn from(spec: ObstacleSpec) -> Self {
        match spec {
            ObstacleSpec::Box { at_m, size_m, yaw_deg } => Self { kind: ObstacleKind::Box, at_m, size_m: Some(size_m), radius_m: None, length_m: None, lying: false, yaw_deg },
            ObstacleSpec::Cylinder { at_m, radius_m, length_m, lying, yaw_deg } => {
                Self { kind: ObstacleKind::Cylinder, at_m, size_m: None, radius_m: Some(radius_m), length_m: Some(length_m), lying, yaw_deg }
            }
        }
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum ObstacleError {
    #[error("{field} = {value} m must be positive, finite and at most {MAX_OBSTACLE_M} m")]
    Size { field: &'static str, value: f32 },
    #[error("{field} = {value} must be finite")]
    NotFinite { field: &'static str, value: f32 },
    #[error("no terrain below its position ({x} m, {z} m): an obstacle must stand on the terrain")]
    OffTerrain { x: f32, z: f32 },
}

impl ObstacleSpec {
    /// Where it stands in plan (x, z).
    pub fn at_m(&self) -> [f32; 2] {
        match self {
            Self::Box { at_m, .. } | Self::Cylinder { at_m, .. } => *at_m,
        }
    }

    fn yaw_deg(&self) -> f32 {
        match self {
            Self::Box { yaw_deg, .. } | Self::Cylinder { yaw_deg, .. } => *yaw_deg,
        }
    }

    /// Every number in range (sizes positive and bounded, positions and angles finite).
    pub fn validate(&self) -> Result<(), ObstacleError> {
        let size = |field: &'static str, value: f32| if value > 0.0 && value <= MAX_OBSTACLE_M { Ok(()) } else { Err(ObstacleError::Size { field, value }) };
        let finite = |field: &'static str, value: f32| if value.is_finite() { Ok(()) } else { Err(ObstacleError::NotFinite { field, value }) };
        let [x, z] = self.at_m();
        finite("at_m[0]", x)?;
        finite("at_m[1]", z)?;
        finite("yaw_deg", self.yaw_deg())?;
        match self {
            Self::Box { size_m: [length, height, width], .. } => {
                size("size_m[0]", *length)?;
                size("size_m[1]", *height)?;
                size("size_m[2]", *width)
            }
            Self::Cylinder { radius_m, length_m, .. } => {
                size("radius_m", *radius_m)?;
                size("length_m", *length_m)
            }
        }
    }

    /// Its shape, and where its centre sits above the surface point below it.
    fn shape_and_lift(&self) -> (SharedShape, Rotation, f32) {
        let yaw = Rotation::from_rotation_y(self.yaw_deg().to_radians());
        match *self {
            Self::Box { size_m: [length, height, width], .. } => (SharedShape::cuboid(length / 2.0, height / 2.0, width / 2.0), yaw, height / 2.0),
            // rapier's cylinder stands along its y axis.
            Self::Cylinder { radius_m, length_m, lying: false, .. } => (SharedShape::cylinder(length_m / 2.0, radius_m), yaw, length_m / 2.0),
            Self::Cylinder { radius_m, length_m, lying: true, .. } => (SharedShape::cylinder(length_m / 2.0, radius_m), yaw * Rotation::from_rotation_z(std::f32::consts::FRAC_PI_2), radius_m),
        }
    }

    /// A fixed collider standing on the surface point `ground` (from a ray cast down at
    /// [`ObstacleSpec::at_m`]).
    pub fn collider(&self, ground: Vector) -> ColliderBuilder {
        let (shape, rotation, lift) = self.shape_and_lift();
        ColliderBuilder::new(shape).position(Pose::from_parts(ground + Vector::Y * lift, rotation))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ObstacleSpec, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn boxes_and_cylinders_parse_and_unknown_keys_are_refused() {
        let pipe = parse("kind = \"cylinder\"\nat_m = [1.0, 0.5]\nradius_m = 0.05\nlength_m = 1.0\nlying = true").expect("pipe");
        assert!(matches!(pipe, ObstacleSpec::Cylinder { lying: true, .. }));
        assert!(parse("kind = \"box\"\nat_m = [0, 0]\nsize_m = [0.1, 0.1, 0.1]\ncolour = 1").is_err());
        assert!(parse("kind = \"sphere\"\nat_m = [0, 0]").is_err());
        let error = parse("kind = \"box\"\nat_m = [0, 0]\nradius_m = 0.1\nsize_m = [0.1, 0.1, 0.1]").expect_err("a box has no radius");
        assert!(error.to_string().contains("`radius_m` is not a key of a box obstacle"), "{error}");
        assert!(parse("kind = \"cylinder\"\nat_m = [0, 0]\nradius_m = 0.1").expect_err("no length").to_string().contains("needs `radius_m` and `length_m`"));
        // Written back as it was read.
        let text = toml::to_string(&pipe).expect("serialise");
        assert_eq!(parse(&text).expect("again"), pipe);
    }

    #[test]
    fn sizes_out_of_range_are_named() {
        let bad = ObstacleSpec::Box { at_m: [0.0, 0.0], size_m: [0.1, -0.2, 0.1], yaw_deg: 0.0 };
        assert_eq!(bad.validate(), Err(ObstacleError::Size { field: "size_m[1]", value: -0.2 }));
        let nan = ObstacleSpec::Cylinder { at_m: [f32::NAN, 0.0], radius_m: 0.1, length_m: 0.1, lying: false, yaw_deg: 0.0 };
        assert!(matches!(nan.validate(), Err(ObstacleError::NotFinite { field: "at_m[0]", .. })));
    }

    #[test]
    fn an_obstacle_rests_on_the_ground_below_it() {
        let ground = Vector::new(1.0, 0.2, 0.5);
        for (spec, lowest) in [
            (ObstacleSpec::Box { at_m: [1.0, 0.5], size_m: [0.2, 0.1, 0.4], yaw_deg: 30.0 }, 0.2),
            (ObstacleSpec::Cylinder { at_m: [1.0, 0.5], radius_m: 0.05, length_m: 0.3, lying: false, yaw_deg: 0.0 }, 0.2),
            (ObstacleSpec::Cylinder { at_m: [1.0, 0.5], radius_m: 0.05, length_m: 0.3, lying: true, yaw_deg: 90.0 }, 0.2),
        ] {
            let collider = spec.collider(ground).build();
            let aabb = collider.compute_aabb();
            assert!((aabb.mins.y - lowest).abs() < 1e-5, "{spec:?}: lowest point at {}", aabb.mins.y);
        }
    }
}
