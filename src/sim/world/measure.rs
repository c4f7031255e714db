//! Measurements of the physics state that stepping ([`super::step`]), building
//! ([`super::build`]) and the observers' queries ([`super::queries`]) all take: a servo joint's
//! axis, rate and angle, and casts from a point to the terrain.

use rapier3d::parry::query::ShapeCastOptions;
use rapier3d::prelude::*;

use super::{ServoJoint, robot_groups};

/// Joint axis in world coordinates.
pub(super) fn world_axis(physics: &PhysicsWorld, joint: &ServoJoint) -> Vector {
    physics.bodies[joint.parent].rotation() * joint.axis
}

pub(super) fn joint_rate(physics: &PhysicsWorld, joint: &ServoJoint) -> f32 {
    let axis = world_axis(physics, joint);
    (physics.bodies[joint.child].angvel() - physics.bodies[joint.parent].angvel()).dot(axis)
}

/// Angle of the child about the joint axis relative to the parent, in (−π, π].
pub(super) fn joint_angle(physics: &PhysicsWorld, joint: &ServoJoint) -> f32 {
    let parent = physics.bodies[joint.parent].rotation();
    let child = physics.bodies[joint.child].rotation();
    let relative = parent.inverse() * *child;
    // Twist of the relative rotation about the (parent-frame) axis.
    let v = Vector::new(relative.x, relative.y, relative.z);
    2.0 * v.dot(joint.axis).atan2(relative.w)
}

/// The surface a magnet faces: contact point and outward normal, looking from `centre` along
/// `direction` up to `reach`. A ray gives the exact face normal; a ray that passes exactly
/// through a grid vertex or edge can miss, and then the seed's sphere cast (radius `probe`)
/// finds the surface. The sphere cast is not the first choice because parry's shape cast
/// against a fine heightfield returned normals tilted by up to 20° on flat cells (measured).
///
/// The ray goes straight to the terrain collider's shape: the terrain is the only collider in
/// the magnets' filter, and skipping the query pipeline's tree walk halves the cast's cost
/// (it runs four times a step).
pub(super) fn find_surface(physics: &PhysicsWorld, terrain: ColliderHandle, centre: Vector, direction: Vector, reach: f32, probe: f32, filter: QueryFilter<'_>) -> Option<(Vector, Vector)> {
    let ray = Ray::new(centre, direction);
    let terrain = physics.colliders.get(terrain)?;
    if let Some(hit) = terrain.shape().cast_ray_and_get_normal(terrain.position(), &ray, reach, true) {
        return Some((ray.point_at(hit.time_of_impact), hit.normal));
    }
    let options = ShapeCastOptions { max_time_of_impact: reach, target_distance: 0.0, stop_at_penetration: true, compute_impact_geometry_on_penetration: true };
    let (_, hit) = physics.cast_shape(&Pose::from_translation(centre), direction, &Ball::new(probe), options, filter)?;
    Some((hit.witness1, hit.normal1))
}

/// The terrain straight below (x, z): point and outward normal, from a ray cast down from high
/// above against the terrain group only.
pub(super) fn surface_below(physics: &PhysicsWorld, x: f32, z: f32) -> Option<(Vector, Vector)> {
    let ray = ray_down(x, z);
    let filter = QueryFilter::default().groups(robot_groups());
    let (_, hit) = physics.cast_ray_and_get_normal(&ray, 2.0 * RAY_DOWN_FROM_M, true, filter)?;
    Some((ray.point_at(hit.time_of_impact), hit.normal))
}

/// How high above the origin a ray looking straight down starts (terrains stay far below).
const RAY_DOWN_FROM_M: f32 = 100.0;

/// A ray straight down onto (x, z) from [`RAY_DOWN_FROM_M`] up.
pub(super) fn ray_down(x: f32, z: f32) -> Ray {
    Ray::new(Vector::new(x, RAY_DOWN_FROM_M, z), -Vector::Y)
}

/// The terrain collider's surface straight below (x, z), obstacles ignored.
pub(super) fn terrain_below(physics: &PhysicsWorld, terrain: ColliderHandle, x: f32, z: f32) -> Option<Vector> {
    terrain_and_normal_below(physics, terrain, x, z).map(|(point, _)| point)
}

/// [`terrain_below`] with the surface's outward normal there.
pub(super) fn terrain_and_normal_below(physics: &PhysicsWorld, terrain: ColliderHandle, x: f32, z: f32) -> Option<(Vector, Vector)> {
    let ray = ray_down(x, z);
    let collider = physics.colliders.get(terrain)?;
    let hit = collider.shape().cast_ray_and_get_normal(collider.position(), &ray, 2.0 * RAY_DOWN_FROM_M, true)?;
    Some((ray.point_at(hit.time_of_impact), hit.normal))
}
