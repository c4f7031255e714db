//! What observers ask of the world: time, poses and shapes, the terrain below a point, the
//! wheels' and magnets' state.

use std::time::Duration;

use rapier3d::prelude::*;

use crate::device::ShaftLoad;
use crate::robot::WheelPosition;

use super::measure::{joint_rate, ray_down, surface_below, terrain_and_normal_below};
use super::{AdhesionSample, CAMERA_FRAME, PartFrame, PartShape, PartShapeKind, RobotWorld, ServoLink, SlipArea, TerrainMesh, magnet_frame, robot_groups, wheel_frame};

impl RobotWorld {
    /// The robot description the world was built from.
    pub fn robot(&self) -> &crate::robot::RobotDescription {
        &self.robot
    }

    /// The robot's mechanics the world was built from.
    pub fn climber(&self) -> &crate::robot::Climber {
        &self.climber
    }

    pub fn time(&self) -> Duration {
        self.time
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The terrain's surface as an indexed triangle mesh in the world frame, for viewers: a
    /// heightfield every `stride`-th row and column, where `stride` keeps each side to at most
    /// `max_vertices_per_side` vertices (the last row and column always kept); a mesh as it is.
    pub fn terrain_mesh(&self, max_vertices_per_side: usize) -> TerrainMesh {
        let collider = &self.physics.colliders[self.terrain];
        let place = *collider.position();
        if let Some(field) = collider.shape().as_heightfield() {
            let picks = |n: usize| -> Vec<usize> {
                let stride = (n.saturating_sub(1)).div_ceil(max_vertices_per_side.max(2) - 1).max(1);
                let mut picked: Vec<usize> = (0..n).step_by(stride).collect();
                if picked.last() != Some(&(n - 1)) {
                    picked.push(n - 1);
                }
                picked
            };
            // parry's nrows/ncols count cells; the grid of heights has one more of each.
            let heights = field.heights();
            let (rows, cols) = (picks(heights.nrows()), picks(heights.ncols()));
            let scale_y = field.scale().y;
            let vertices = rows.iter().flat_map(|&i| cols.iter().map(move |&j| place * Vector::new(field.x_at(j), heights[(i, j)] * scale_y, field.z_at(i)))).collect();
            let width = cols.len() as u32;
            let mut indices = Vec::with_capacity((rows.len() - 1) * (cols.len() - 1) * 2);
            for i in 0..rows.len() as u32 - 1 {
                for j in 0..width - 1 {
                    let (a, b, c, d) = (i * width + j, i * width + j + 1, (i + 1) * width + j, (i + 1) * width + j + 1);
                    // Counter-clockwise seen from above (+y), as parry's own cells.
                    indices.push([a, c, b]);
                    indices.push([b, c, d]);
                }
            }
            return TerrainMesh { vertices, indices };
        }
        if let Some(mesh) = collider.shape().as_trimesh() {
            return TerrainMesh { vertices: mesh.vertices().iter().map(|&v| place * v).collect(), indices: mesh.indices().to_vec() };
        }
        TerrainMesh { vertices: Vec::new(), indices: Vec::new() }
    }

    pub fn terrain_collider(&self) -> ColliderHandle {
        self.terrain
    }

    /// The rapier world (read-only), for sensors and tests.
    pub fn physics(&self) -> &PhysicsWorld {
        &self.physics
    }

    pub fn adhesion(&self) -> &[AdhesionSample; 4] {
        &self.adhesion
    }

    pub fn set_magnets_on(&mut self, on: bool) {
        self.magnets_on = on;
    }

    /// Fraction of its pull the magnet of `wheel` keeps (1 = healthy, 0 = failed).
    pub fn set_magnet_pull(&mut self, wheel: WheelPosition, fraction: f32) {
        self.magnet_pull[wheel.index()] = fraction;
    }

    pub fn magnet_pull(&self, wheel: WheelPosition) -> f32 {
        self.magnet_pull[wheel.index()]
    }

    /// Start (`Some`) or end (`None`) slip patch `key`: tread friction `friction` over the x and z
    /// ranges. The wheel colliders ask for the contact hook only while a patch exists, so a world
    /// without one steps exactly as before.
    pub fn set_slip_patch(&mut self, key: usize, patch: Option<([f32; 2], [f32; 2], f32)>) {
        self.slip.areas.retain(|a| a.key != key);
        if let Some((x_m, z_m, friction)) = patch {
            self.slip.areas.push(SlipArea { key, x_m, z_m, friction });
        }
        let hooks = if self.slip.areas.is_empty() { ActiveHooks::empty() } else { ActiveHooks::MODIFY_SOLVER_CONTACTS };
        for parts in self.wheels {
            if let Some(collider) = self.physics.colliders.get_mut(parts.collider) {
                collider.set_active_hooks(hooks);
            }
        }
    }

    /// How much faster the tread turns than its centre moves over the ground (m/s): wheel rate
    /// × outer radius − the wheel centre's speed along its section's forward axis. Near 0 when
    /// rolling; large when the wheel spins on a slippery patch.
    pub fn wheel_slip(&self, wheel: WheelPosition) -> f32 {
        let parts = self.wheels[wheel.index()];
        let forward = self.physics.bodies[parts.section].rotation() * Vector::X;
        let ground = self.physics.bodies[parts.wheel].linvel().dot(forward);
        self.wheel_rate(wheel) * self.climber.wheel.outer_radius_m - ground
    }

    /// The middle section's pose (the robot's reference frame).
    pub fn chassis_pose(&self) -> Pose {
        *self.physics.bodies[self.sections[1]].position()
    }

    /// The robot as a tree of named frames, for viewers (a recording's `/tf`): `middle` (which
    /// carries the bolted rear section) in `world`, `front` on the rocker in `middle`, each wheel
    /// (`wheel_front_left`, …) in the section that carries it, and each magnet (`magnet_front_left`,
    /// …) in its wheel, turned about the axle by its shaft's angle (its −y points where it pulls).
    pub fn part_frames(&self) -> Vec<PartFrame> {
        let pose = |handle: RigidBodyHandle| *self.physics.bodies[handle].position();
        let section_name = |handle: RigidBodyHandle| if handle == self.sections[0] { "front" } else { "middle" };
        let (front, middle) = (pose(self.sections[0]), pose(self.sections[1]));
        let mut frames = Vec::with_capacity(10);
        frames.push(PartFrame { name: "middle".to_owned(), parent: "world".to_owned(), pose: middle });
        frames.push(PartFrame { name: "front".to_owned(), parent: "middle".to_owned(), pose: middle.inv_mul(&front) });
        for position in WheelPosition::ALL {
            let parts = self.wheels[position.index()];
            let (section, wheel) = (pose(parts.section), pose(parts.wheel));
            let magnet = Pose::from_parts(wheel.translation, self.magnet_rotation_at(position.index()));
            frames.push(PartFrame { name: wheel_frame(position), parent: section_name(parts.section).to_owned(), pose: section.inv_mul(&wheel) });
            frames.push(PartFrame { name: magnet_frame(position), parent: wheel_frame(position), pose: wheel.inv_mul(&magnet) });
        }
        frames.push(PartFrame { name: CAMERA_FRAME.to_owned(), parent: "middle".to_owned(), pose: self.camera_optical_pose() });
        frames
    }

    /// The camera's optical frame in the middle section's, as image viewers take it: +z where
    /// it looks (the body's down), +x the image's columns (the body's right, +z), +y its rows
    /// (row 0 is the body's forward edge, so +y is the body's back, -x).
    pub fn camera_optical_pose(&self) -> Pose {
        let [x, y, z] = self.climber.camera.position_m;
        let optical = Rotation::from_mat3(&rapier3d::math::Matrix::from_cols(Vector::Z, -Vector::X, -Vector::Y));
        Pose::from_parts(Vector::new(x, y, z), optical)
    }

    /// The obstacles' shapes for viewers, in `world`: boxes, and cylinders about their pose's z.
    pub fn obstacle_shapes(&self) -> Vec<PartShape> {
        let mut shapes = Vec::with_capacity(self.obstacles.len());
        for &handle in &self.obstacles {
            let collider = &self.physics.colliders[handle];
            let pose = *collider.position();
            let kind = if let Some(cuboid) = collider.shape().as_cuboid() {
                (pose, PartShapeKind::Box { half_extents: cuboid.half_extents })
            } else if let Some(cylinder) = collider.shape().as_cylinder() {
                // rapier's cylinder stands along its y axis: a quarter turn about x puts it on z.
                (pose * Pose::from_rotation(Rotation::from_rotation_x(std::f32::consts::FRAC_PI_2)), PartShapeKind::Cylinder { radius_m: cylinder.radius, length_m: 2.0 * cylinder.half_height })
            } else {
                continue;
            };
            shapes.push(PartShape { frame: "world".to_owned(), pose: kind.0, kind: kind.1 });
        }
        shapes
    }

    /// The robot's shapes for viewers, each in the frame of [`RobotWorld::part_frames`] it moves
    /// with: the sections' boxes as their colliders have them, and each wheel as the hollow
    /// cylinder it is (its collider is a ball, which rolls more robustly on heightfields).
    pub fn part_shapes(&self) -> Vec<PartShape> {
        let mut shapes = Vec::with_capacity(7);
        for (frame, section) in [("front", self.sections[0]), ("middle", self.sections[1])] {
            for &collider in self.physics.bodies[section].colliders() {
                if let Some(cuboid) = self.physics.colliders[collider].shape().as_cuboid() {
                    let pose = self.physics.colliders[collider].position_wrt_parent().copied().unwrap_or_default();
                    shapes.push(PartShape { frame: frame.to_owned(), pose, kind: PartShapeKind::Box { half_extents: cuboid.half_extents } });
                }
            }
        }
        let wheel = &self.climber.wheel;
        for position in WheelPosition::ALL {
            // The wheel body's z axis is its axle.
            shapes.push(PartShape { frame: wheel_frame(position), pose: Pose::IDENTITY, kind: PartShapeKind::Cylinder { radius_m: wheel.outer_radius_m, length_m: wheel.width_m } });
        }
        shapes
    }

    /// The downward camera's pose: its mount (`[camera] position_m`) on the middle section,
    /// looking along the section's −y axis.
    pub fn camera_pose(&self) -> Pose {
        let [x, y, z] = self.climber.camera.position_m;
        self.chassis_pose() * Pose::from_translation(Vector::new(x, y, z))
    }

    /// The terrain surface straight below (x, z): point and outward normal, from a ray cast down
    /// from high above (the robot is not in the terrain group, so it never hides the ground).
    pub fn surface_below(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        surface_below(&self.physics, x, z)
    }

    /// The terrain's own surface straight below (x, z) and its normal, obstacles ignored.
    pub fn terrain_surface_below(&self, x: f32, z: f32) -> Option<(Vector, Vector)> {
        terrain_and_normal_below(&self.physics, self.terrain, x, z)
    }

    /// Which obstacle (its index in the scenario's `[[obstacles]]`) stands straight below or
    /// above (x, z), if one does.
    pub fn obstacle_at(&self, x: f32, z: f32) -> Option<usize> {
        let ray = ray_down(x, z);
        self.obstacles.iter().position(|&handle| self.physics.colliders.get(handle).is_some_and(|collider| collider.shape().intersects_ray(collider.position(), &ray, f32::MAX)))
    }

    /// How far along `direction` (unit) from `origin` the nearest surface of the terrain or an
    /// obstacle is, up to `max_m`; the robot's own parts are never hit. For range sensors.
    pub fn cast_ray_at_surroundings(&self, origin: Vector, direction: Vector, max_m: f32) -> Option<f32> {
        let ray = Ray::new(origin, direction);
        let filter = QueryFilter::default().groups(robot_groups());
        self.physics.cast_ray(&ray, max_m, true, filter).map(|(_, toi)| toi)
    }

    /// The chassis' linear velocity.
    pub fn chassis_velocity(&self) -> Vector {
        self.physics.bodies[self.sections[1]].linvel()
    }

    /// Centre of a wheel.
    pub fn wheel_centre(&self, wheel: WheelPosition) -> Vector {
        self.physics.bodies[self.wheels[wheel.index()].wheel].translation()
    }

    /// A wheel's rate about its axle relative to its section (rad/s, positive rolls forward).
    pub fn wheel_rate(&self, wheel: WheelPosition) -> f32 {
        self.links
            .iter()
            .find_map(|link| match link {
                ServoLink::Wheel(joint) if joint.child == self.wheels[wheel.index()].wheel => Some(joint_rate(&self.physics, joint)),
                _ => None,
            })
            .unwrap_or(0.0)
    }

    /// Direction the magnet of a wheel points (world, unit).
    pub fn magnet_direction(&self, wheel: WheelPosition) -> Vector {
        self.magnet_direction_at(wheel.index())
    }

    pub(super) fn magnet_direction_at(&self, index: usize) -> Vector {
        self.magnet_rotation_at(index) * -Vector::Y
    }

    /// The magnet's orientation in the world: its section's, turned about the magnet axis by the
    /// shaft's angle (its −y points where it pulls).
    pub(super) fn magnet_rotation_at(&self, index: usize) -> Rotation {
        let parts = self.wheels[index];
        let angle = self.magnets[index].load.state().position_rad as f32;
        self.physics.bodies[parts.section].rotation() * Rotation::from_axis_angle(parts.magnet_axis, angle)
    }

    /// Gap between a wheel's tread and the nearest terrain (m; 0 when touching), `None` when no
    /// terrain is within the magnet's range of it.
    pub fn tread_gap_m(&self, wheel: WheelPosition) -> Option<f32> {
        let centre = self.physics.bodies[self.wheels[wheel.index()].wheel].translation();
        let filter = QueryFilter::default().groups(robot_groups());
        let outer = self.climber.wheel.outer_radius_m;
        let (_, projection) = self.physics.project_point(centre, outer + self.climber.magnet.range_m, true, filter)?;
        Some(((projection.point - centre).length() - outer).max(0.0))
    }

    /// The geometric contact angle of a wheel: the direction from its centre to the closest
    /// terrain point, as an angle in the wheel's plane from straight down (positive toward the
    /// front), in its section's frame. What a perfectly aligned passive magnet would read.
    pub fn contact_angle(&self, wheel: WheelPosition) -> Option<f32> {
        self.contact_angles(wheel).map(|(in_plane, _)| in_plane)
    }

    /// Both angles of a wheel's contact direction (centre to the closest terrain point), in its
    /// section's frame: in the wheel's plane from straight down, positive toward the front (the
    /// seed's β: what a magnet turning about the axle can follow), and out of that plane,
    /// positive toward the section's +z (the seed's α: the contact off the tread's middle).
    pub fn contact_angles(&self, wheel: WheelPosition) -> Option<(f32, f32)> {
        let parts = self.wheels[wheel.index()];
        let centre = self.physics.bodies[parts.wheel].translation();
        let filter = QueryFilter::default().groups(robot_groups());
        let reach = self.climber.wheel.outer_radius_m + self.climber.magnet.range_m;
        let (_, projection) = self.physics.project_point(centre, reach, true, filter)?;
        let local = self.physics.bodies[parts.section].rotation().inverse() * (projection.point - centre);
        let in_plane = local.x.hypot(local.y);
        Some((local.x.atan2(-local.y), local.z.atan2(in_plane)))
    }

    /// The magnet's angle from straight down in its section's frame (positive toward the front).
    pub fn magnet_angle(&self, wheel: WheelPosition) -> f32 {
        let parts = self.wheels[wheel.index()];
        let local = self.physics.bodies[parts.section].rotation().inverse() * self.magnet_direction(wheel);
        local.x.atan2(-local.y)
    }
}
