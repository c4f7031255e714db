//! The 3D scene of a run as Foxglove scene entities, built from plain geometry: the terrain as
//! one triangle mesh coloured by height, the weld line as its painted stripe, the robot's parts
//! as boxes and cylinders in their own frames, and an arrow per magnet for its pull.
//!
//! Everything here is in rapier's frame (y up); the recording's `map` → `world` transform turns
//! it for Foxglove's z-up 3D panel.

use foxglove::messages::{
    ArrowPrimitive, CameraCalibration, Color, CubePrimitive, CylinderPrimitive, Point3, Pose as FoxglovePose, Quaternion, SceneEntity, SceneUpdate, Timestamp, TriangleListPrimitive, Vector3,
};
use rapier3d::prelude::{Pose, Rotation, Vector};

use crate::sim::line::LineSample;
use crate::sim::{PartShape, PartShapeKind, TerrainMesh};

/// Metres of arrow per newton of magnet pull: a magnet at its 80 N contact pull draws a 40 mm
/// arrow, a little less than the wheel's radius.
pub const ARROW_M_PER_N: f64 = 0.0005;

/// How far the painted stripe is drawn above the surface, so that it is not hidden in it.
const STRIPE_LIFT_M: f32 = 0.001;

fn point(v: Vector) -> Point3 {
    Point3 { x: f64::from(v.x), y: f64::from(v.y), z: f64::from(v.z) }
}

pub(super) fn vector3(v: Vector) -> Vector3 {
    Vector3 { x: f64::from(v.x), y: f64::from(v.y), z: f64::from(v.z) }
}

pub(super) fn quaternion(q: Rotation) -> Quaternion {
    Quaternion { x: f64::from(q.x), y: f64::from(q.y), z: f64::from(q.z), w: f64::from(q.w) }
}

pub(super) fn pose(p: &Pose) -> FoxglovePose {
    FoxglovePose { position: Some(vector3(p.translation)), orientation: Some(quaternion(p.rotation)) }
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

fn entity(timestamp: Timestamp, frame_id: &str, id: &str) -> SceneEntity {
    // No lifetime: an entity stays until it is replaced by one with the same id.
    SceneEntity { timestamp: Some(timestamp), frame_id: frame_id.to_owned(), id: id.to_owned(), frame_locked: true, ..SceneEntity::default() }
}

/// Steel grey, darker low and lighter high, so that bumps show under a light from any side.
fn height_colour(height: f32, low: f32, high: f32) -> Color {
    let span = (high - low).max(1e-6);
    let shade = 0.35 + 0.45 * f64::from(((height - low) / span).clamp(0.0, 1.0));
    color(shade, shade, shade * 1.05, 1.0)
}

/// The terrain (`terrain`), the weld line's stripe (`weld_line`) and the obstacles
/// (`obstacles`, rust brown), in `world`.
pub fn terrain_and_line(timestamp: Timestamp, terrain: &TerrainMesh, lines: &[&[LineSample]], obstacles: &[PartShape]) -> SceneUpdate {
    let (low, high) = terrain.vertices.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| (lo.min(v.y), hi.max(v.y)));
    let mut ground = entity(timestamp, "world", "terrain");
    ground.triangles.push(TriangleListPrimitive {
        pose: Some(pose(&Pose::IDENTITY)),
        points: terrain.vertices.iter().copied().map(point).collect(),
        color: None,
        colors: terrain.vertices.iter().map(|v| height_colour(v.y, low, high)).collect(),
        indices: terrain.indices.iter().flatten().copied().collect(),
    });
    let mut stripe = entity(timestamp, "world", "weld_line");
    let lifted = |p: Vector, normal: Vector| point(p + normal * STRIPE_LIFT_M);
    let mut points = Vec::with_capacity(lines.iter().map(|l| l.len().saturating_sub(1) * 6).sum());
    for pair in lines.iter().flat_map(|line| line.windows(2)) {
        let (a, b) = (&pair[0], &pair[1]);
        let (al, ar, bl, br) = (lifted(a.left_edge, a.normal), lifted(a.right_edge, a.normal), lifted(b.left_edge, b.normal), lifted(b.right_edge, b.normal));
        points.extend([al, ar, bl, bl, ar, br]);
    }
    stripe.triangles.push(TriangleListPrimitive { pose: Some(pose(&Pose::IDENTITY)), points, color: Some(color(0.95, 0.75, 0.1, 1.0)), colors: Vec::new(), indices: Vec::new() });
    let mut entities = vec![ground, stripe];
    // No entity for no obstacles: an empty one is a thing in the panel's list with nothing in it.
    if !obstacles.is_empty() {
        let mut things = entity(timestamp, "world", "obstacles");
        for shape in obstacles {
            add_shape(&mut things, shape, color(0.55, 0.3, 0.15, 1.0), color(0.55, 0.3, 0.15, 1.0));
        }
        entities.push(things);
    }
    SceneUpdate { deletions: Vec::new(), entities }
}

/// A box or cylinder into `entity`, in `box_colour` or `cylinder_colour`.
fn add_shape(entity: &mut SceneEntity, shape: &PartShape, box_colour: Color, cylinder_colour: Color) {
    match shape.kind {
        PartShapeKind::Box { half_extents } => entity.cubes.push(CubePrimitive {
            pose: Some(pose(&shape.pose)),
            size: Some(Vector3 { x: 2.0 * f64::from(half_extents.x), y: 2.0 * f64::from(half_extents.y), z: 2.0 * f64::from(half_extents.z) }),
            color: Some(box_colour),
        }),
        // Foxglove's cylinder stands along its z axis, as the wheel's axle does.
        PartShapeKind::Cylinder { radius_m, length_m } => entity.cylinders.push(CylinderPrimitive {
            pose: Some(pose(&shape.pose)),
            size: Some(Vector3 { x: 2.0 * f64::from(radius_m), y: 2.0 * f64::from(radius_m), z: f64::from(length_m) }),
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: Some(cylinder_colour),
        }),
    }
}

/// The robot's parts, one entity per frame (`robot/<frame>`), locked to their frames: sections
/// as blue boxes, wheels as dark cylinders about their axles.
pub fn robot(timestamp: Timestamp, shapes: &[PartShape]) -> SceneUpdate {
    let mut entities: Vec<SceneEntity> = Vec::new();
    for shape in shapes {
        let index = match entities.iter().position(|e| e.frame_id == shape.frame) {
            Some(index) => index,
            None => {
                entities.push(entity(timestamp, &shape.frame, &format!("robot/{}", shape.frame)));
                entities.len() - 1
            }
        };
        add_shape(&mut entities[index], shape, color(0.2, 0.4, 0.75, 0.9), color(0.15, 0.15, 0.15, 0.6));
    }
    SceneUpdate { deletions: Vec::new(), entities }
}

/// One arrow per magnet (`magnet/<frame>`), in the magnet's frame along its −y (where it pulls),
/// as long as its pull ([`ARROW_M_PER_N`]); red when the pull is under `weak_n`. The magnet sits
/// inside its wheel and pulls toward the steel the tyre stands on, so an arrow from the magnet
/// would never leave the tyre: it stands on the wheel's far side instead, pointing the way the
/// magnet pulls and ending on the tyre (`tyre_radius_m` from the axle).
pub fn magnet_arrows(timestamp: Timestamp, magnets: &[(String, f32)], weak_n: f32, tyre_radius_m: f32) -> SceneUpdate {
    // The arrow primitive points along its pose's +x: a −90° turn about z takes +x to −y.
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let entities = magnets
        .iter()
        .map(|(frame, force_n)| {
            let mut arrow = entity(timestamp, frame, &format!("magnet/{frame}"));
            let length = f64::from(force_n.max(0.0)) * ARROW_M_PER_N;
            let above = FoxglovePose { position: Some(Vector3 { x: 0.0, y: f64::from(tyre_radius_m) + length, z: 0.0 }), orientation: Some(Quaternion { x: 0.0, y: 0.0, z: -half, w: half }) };
            let shade = if *force_n < weak_n { color(0.9, 0.1, 0.1, 1.0) } else { color(0.1, 0.8, 0.2, 1.0) };
            arrow.arrows.push(ArrowPrimitive { pose: Some(above), shaft_length: length * 0.75, shaft_diameter: 0.004, head_length: length * 0.25, head_diameter: 0.01, color: Some(shade) });
            arrow
        })
        .collect();
    SceneUpdate { deletions: Vec::new(), entities }
}

/// The calibration of the orthographic downward camera as a pinhole that sees the same ground
/// at `distance_m` below it: `width` × `height` pixels over `2 × half_height_m` forward, square
/// pixels, the principal point at the image's centre. With it Foxglove places the image in 3D.
pub fn camera_calibration(timestamp: Timestamp, (width, height): (u32, u32), half_height_m: f32, distance_m: f32) -> CameraCalibration {
    let focal_px = f64::from(distance_m) * f64::from(height) / (2.0 * f64::from(half_height_m));
    let (cx, cy) = (f64::from(width) / 2.0, f64::from(height) / 2.0);
    CameraCalibration {
        timestamp: Some(timestamp),
        frame_id: crate::sim::CAMERA_FRAME.to_owned(),
        width,
        height,
        distortion_model: "plumb_bob".to_owned(),
        d: vec![0.0; 5],
        k: vec![focal_px, 0.0, cx, 0.0, focal_px, cy, 0.0, 0.0, 1.0],
        r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: vec![focal_px, 0.0, cx, 0.0, 0.0, focal_px, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at_zero() -> Timestamp {
        Timestamp::new(0, 0)
    }

    #[test]
    fn the_terrain_keeps_its_triangles_and_colours_low_dark_high_light() {
        let mesh = TerrainMesh { vertices: vec![Vector::new(0.0, 0.0, 0.0), Vector::new(1.0, 0.1, 0.0), Vector::new(0.0, 0.2, 1.0)], indices: vec![[0, 2, 1]] };
        let update = terrain_and_line(at_zero(), &mesh, &[], &[]);
        let triangles = &update.entities[0].triangles[0];
        assert_eq!(triangles.indices, vec![0, 2, 1]);
        assert_eq!(triangles.points.len(), 3);
        let shade = |i: usize| triangles.colors[i].r;
        assert!(shade(0) < shade(1) && shade(1) < shade(2), "{:?}", triangles.colors);
    }

    #[test]
    fn the_stripe_is_two_triangles_per_segment_lifted_off_the_surface() {
        let sample = |x: f32| LineSample { point: Vector::new(x, 0.0, 0.0), normal: Vector::Y, arc_length_m: x, left_edge: Vector::new(x, 0.0, -0.01), right_edge: Vector::new(x, 0.0, 0.01) };
        let update = terrain_and_line(at_zero(), &TerrainMesh { vertices: Vec::new(), indices: Vec::new() }, &[&[sample(0.0), sample(0.1), sample(0.2)]], &[]);
        let stripe = &update.entities[1].triangles[0];
        assert_eq!(stripe.points.len(), 12);
        assert!(stripe.points.iter().all(|p| (p.y - f64::from(STRIPE_LIFT_M)).abs() < 1e-9));
    }

    #[test]
    fn parts_of_one_frame_share_an_entity_and_wheels_keep_their_size() {
        let shapes = [
            PartShape { frame: "middle".to_owned(), pose: Pose::IDENTITY, kind: PartShapeKind::Box { half_extents: Vector::new(0.06, 0.03, 0.08) } },
            PartShape { frame: "middle".to_owned(), pose: Pose::from_translation(Vector::new(-0.15, 0.0, 0.0)), kind: PartShapeKind::Box { half_extents: Vector::new(0.03, 0.02, 0.1) } },
            PartShape { frame: "wheel_front_left".to_owned(), pose: Pose::IDENTITY, kind: PartShapeKind::Cylinder { radius_m: 0.05, length_m: 0.04 } },
        ];
        let update = robot(at_zero(), &shapes);
        assert_eq!(update.entities.len(), 2);
        assert_eq!(update.entities[0].cubes.len(), 2);
        let size = update.entities[1].cylinders[0].size.unwrap_or_default();
        assert!((size.x - 0.1).abs() < 1e-6 && (size.z - 0.04).abs() < 1e-6);
    }

    #[test]
    fn the_calibration_makes_the_image_the_size_it_sees_on_the_ground() {
        // 256 px over 0.2 m forward, the ground 0.15 m below: a pinhole of 192 px focal length.
        let calibration = camera_calibration(at_zero(), (256, 256), 0.1, 0.15);
        assert!((calibration.k[0] - 192.0).abs() < 1e-3 && calibration.k[0] == calibration.k[4], "{:?}", calibration.k);
        assert_eq!((calibration.k[2], calibration.k[5]), (128.0, 128.0));
        // A point 0.1 m ahead on the ground (image up = -y) projects onto the image's top row.
        let v = calibration.k[4] * (-0.1) / 0.15 + calibration.k[5];
        assert!(v.abs() < 1e-3, "{v}");
    }

    #[test]
    fn an_arrow_is_as_long_as_its_magnet_pulls_and_red_when_weak() {
        let update = magnet_arrows(at_zero(), &[("magnet_front_left".to_owned(), 80.0), ("magnet_rear_left".to_owned(), 5.0)], 20.0, 0.05);
        let arrow = |i: usize| update.entities[i].arrows[0];
        assert!((arrow(0).shaft_length + arrow(0).head_length - 0.04).abs() < 1e-9);
        // Outside the tyre: from 0.05 + 0.04 m on the far side down to the tyre at 0.05 m.
        let start = arrow(0).pose.and_then(|p| p.position).unwrap_or_default();
        assert!((start.y - 0.09).abs() < 1e-6, "{start:?}");
        assert!(arrow(1).color.unwrap_or_default().r > 0.5 && arrow(0).color.unwrap_or_default().r < 0.5);
    }
}
