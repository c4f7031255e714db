//! Ball wheels on a heightfield terrain: parry's own contacts, without the work on triangles the
//! ball cannot reach.
//!
//! parry's heightfield-against-shape contact visits every triangle under the ball's bounding box
//! (8 to 18 for a wheel on a 6 cm grid) and computes each one's pseudo-normals (the heightfield's
//! `FIX_INTERNAL_EDGES`) before it asks whether the ball is in reach; the pseudo-normals alone
//! were 41 % of the narrow phase (callgrind, `examples/world_steps`). Here each triangle's
//! distance from the ball's centre is checked first, and only the one to three triangles in reach
//! go through parry's own pseudo-normals and ball-against-convex contact: the same contact points,
//! normals and feature ids, in the same order. A triangle out of reach gets no manifold, where
//! parry keeps an empty one; either way its contacts start without warm-start impulses when it
//! comes back into reach.
//!
//! Every other pair (obstacles, trimesh terrains) goes to parry's default dispatcher.

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use rapier3d::geometry::{ContactData, ContactManifoldData};
use rapier3d::parry::bounding_volume::BoundingVolume;
use rapier3d::parry::math::{Pose, Real, Vector};
use rapier3d::parry::query::details::NormalConstraints;
use rapier3d::parry::query::details::contact_manifold_convex_ball;
use rapier3d::parry::query::{
    ClosestPoints, Contact, ContactManifold, ContactManifoldsWorkspace, DefaultQueryDispatcher, NonlinearRigidMotion, PersistentQueryDispatcher, PointQuery, QueryDispatcher, QueryDispatcherChain,
    ShapeCastHit, ShapeCastOptions, ShapeDistance, ShapeIntersection, TypedWorkspaceData, Unsupported, WorkspaceData,
};
use rapier3d::parry::shape::{Ball, HeightField, Shape, TrianglePseudoNormals};

/// The dispatcher the world's narrow phase uses: ball on heightfield here, the rest by parry.
pub fn dispatcher() -> QueryDispatcherChain<BallOnHeightField, DefaultQueryDispatcher> {
    BallOnHeightField.chain(DefaultQueryDispatcher)
}

/// Contact manifolds between a ball and a heightfield; every other query is left to the next
/// dispatcher of the chain.
#[derive(Debug, Clone, Copy, Default)]
pub struct BallOnHeightField;

/// Which manifold each triangle in reach had at the last update (as parry's own workspace).
#[derive(Debug, Clone, Default)]
struct Workspace {
    timestamp: bool,
    triangles: HashMap<u32, Slot>,
}

#[derive(Debug, Clone)]
struct Slot {
    manifold: usize,
    timestamp: bool,
    /// The triangle's pseudo-normals: the heightfield never changes, and a wheel rolling at
    /// welding speed stays on a triangle for seconds, so they are computed once per contact
    /// (they were 5 % of a tick, computed every step).
    normals: Option<TrianglePseudoNormals>,
}

impl WorkspaceData for Workspace {
    fn as_typed_workspace_data(&self) -> TypedWorkspaceData<'_> {
        TypedWorkspaceData::Custom
    }

    fn clone_dyn(&self) -> Box<dyn WorkspaceData> {
        Box::new(self.clone())
    }
}

type Manifold = ContactManifold<ContactManifoldData, ContactData>;

/// `pos12` places the ball in the heightfield's frame; `flipped` when the ball is the pair's
/// first shape (the manifolds then name the ball first, as parry's do).
fn ball_on_heightfield(pos12: &Pose, field: &HeightField, ball: &Ball, prediction: Real, manifolds: &mut Vec<Manifold>, workspace: &mut Option<ContactManifoldsWorkspace>, flipped: bool) {
    if workspace.as_ref().is_none_or(|w| w.0.downcast_ref::<Workspace>().is_none()) {
        *workspace = Some(ContactManifoldsWorkspace(Box::new(Workspace::default())));
    }
    let Some(workspace) = workspace.as_mut().and_then(|w| w.0.downcast_mut::<Workspace>()) else { return };
    let timestamp = !workspace.timestamp;
    workspace.timestamp = timestamp;

    let centre: Vector = pos12.translation;
    let reach = ball.radius + prediction;
    let bounds = ball.compute_aabb(pos12).loosened(prediction);
    let mut old_manifolds = std::mem::take(manifolds);
    field.map_elements_in_local_aabb(&bounds, &mut |id, triangle| {
        // Out of reach of the triangle's bounding box, out of reach of the triangle: a few
        // comparisons instead of the projection for the cell corners the ball's box takes in.
        let (low, high) = (triangle.a.min(triangle.b).min(triangle.c), triangle.a.max(triangle.b).max(triangle.c));
        let outside = (low - centre).max(centre - high).max(Vector::ZERO);
        if outside.length_squared() > reach * reach {
            return;
        }
        let closest = triangle.project_local_point(centre, true).point;
        if closest.distance_squared(centre) > reach * reach {
            return;
        }
        let (manifold, slot) = match workspace.triangles.entry(id) {
            Entry::Occupied(entry) => {
                let slot = entry.into_mut();
                let manifold = old_manifolds[slot.manifold].take();
                slot.manifold = manifolds.len();
                slot.timestamp = timestamp;
                (manifold, slot)
            }
            Entry::Vacant(entry) => {
                let slot = entry.insert(Slot { manifold: manifolds.len(), timestamp, normals: field.triangle_normal_constraints(id) });
                let (id1, id2) = if flipped { (0, id) } else { (id, 0) };
                (ContactManifold::with_data(id1, id2, ContactManifoldData::default()), slot)
            }
        };
        manifolds.push(manifold);
        let Some(manifold) = manifolds.last_mut() else { return };
        let constraints = slot.normals.as_ref().map(|n| n as &dyn NormalConstraints);
        // parry's ball-against-convex contact, as its dispatcher calls it for a heightfield's
        // triangle and a ball in either order: the triangle's pseudo-normals go with it.
        contact_manifold_convex_ball(pos12, triangle, ball, constraints, None, prediction, manifold, flipped);
    });
    workspace.triangles.retain(|_, slot| slot.timestamp == timestamp);
}

impl PersistentQueryDispatcher<ContactManifoldData, ContactData> for BallOnHeightField {
    fn contact_manifolds(
        &self,
        pos12: &Pose,
        g1: &dyn Shape,
        g2: &dyn Shape,
        prediction: Real,
        manifolds: &mut Vec<Manifold>,
        workspace: &mut Option<ContactManifoldsWorkspace>,
    ) -> Result<(), Unsupported> {
        if let (Some(field), Some(ball)) = (g1.as_heightfield(), g2.as_ball()) {
            ball_on_heightfield(pos12, field, ball, prediction, manifolds, workspace, false);
            Ok(())
        } else if let (Some(ball), Some(field)) = (g1.as_ball(), g2.as_heightfield()) {
            ball_on_heightfield(&pos12.inverse(), field, ball, prediction, manifolds, workspace, true);
            Ok(())
        } else {
            Err(Unsupported)
        }
    }

    fn contact_manifold_convex_convex(
        &self,
        _pos12: &Pose,
        _g1: &dyn Shape,
        _g2: &dyn Shape,
        _normal_constraints1: Option<&dyn NormalConstraints>,
        _normal_constraints2: Option<&dyn NormalConstraints>,
        _prediction: Real,
        _manifold: &mut Manifold,
    ) -> Result<(), Unsupported> {
        Err(Unsupported)
    }
}

/// Only contact manifolds are this dispatcher's: every other query goes down the chain.
impl QueryDispatcher for BallOnHeightField {
    fn intersection_test(&self, _pos12: &Pose, _g1: &dyn Shape, _g2: &dyn Shape) -> Result<ShapeIntersection, Unsupported> {
        Err(Unsupported)
    }

    fn distance(&self, _pos12: &Pose, _g1: &dyn Shape, _g2: &dyn Shape) -> Result<ShapeDistance, Unsupported> {
        Err(Unsupported)
    }

    fn contact(&self, _pos12: &Pose, _g1: &dyn Shape, _g2: &dyn Shape, _prediction: Real) -> Result<Option<Contact>, Unsupported> {
        Err(Unsupported)
    }

    fn closest_points(&self, _pos12: &Pose, _g1: &dyn Shape, _g2: &dyn Shape, _max_dist: Real) -> Result<ClosestPoints, Unsupported> {
        Err(Unsupported)
    }

    fn cast_shapes(&self, _pos12: &Pose, _local_vel12: Vector, _g1: &dyn Shape, _g2: &dyn Shape, _options: ShapeCastOptions) -> Result<Option<ShapeCastHit>, Unsupported> {
        Err(Unsupported)
    }

    fn cast_shapes_nonlinear(
        &self,
        _motion1: &NonlinearRigidMotion,
        _g1: &dyn Shape,
        _motion2: &NonlinearRigidMotion,
        _g2: &dyn Shape,
        _start_time: Real,
        _end_time: Real,
        _stop_at_penetration: bool,
    ) -> Result<Option<ShapeCastHit>, Unsupported> {
        Err(Unsupported)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rapier3d::parry::query::{Ray, RayCast};
    use rapier3d::parry::shape::HeightFieldFlags;
    use rapier3d::prelude::Array2;

    /// A bumpy 6.25 cm grid, like the Perlin terrains', with FIX_INTERNAL_EDGES.
    fn field() -> HeightField {
        let heights = Array2::from_fn(33, 33, |i, j| 0.02 * ((i as f32) * 0.7).sin() * ((j as f32) * 0.45).cos() + 0.004 * ((i * j) % 5) as f32);
        HeightField::with_flags(heights, Vector::new(2.0, 1.0, 2.0), HeightFieldFlags::FIX_INTERNAL_EDGES)
    }

    fn non_empty(manifolds: &[Manifold]) -> Vec<&Manifold> {
        manifolds.iter().filter(|m| !m.points.is_empty()).collect()
    }

    /// Both orders of the pair, at balls resting on, sinking into and hovering just above the
    /// surface all over the field, each pose updated twice (the second time from the first's
    /// manifolds and workspace): every contact parry's dispatcher finds, this one finds too,
    /// bit for bit and in the same order, and it finds nothing else.
    #[test]
    fn the_contacts_are_parrys_own() {
        let field = field();
        let ball = Ball::new(0.05);
        let prediction = 0.002;
        let mut compared = 0;
        for step in 0..400 {
            let (x, z) = (-0.9 + 0.0451 * (step % 40) as f32, -0.9 + 0.173 * (step / 40) as f32);
            let surface = field.cast_local_ray(&Ray::new(Vector::new(x, 10.0, z), -Vector::Y), 20.0, true).map(|t| 10.0 - t);
            let Some(y) = surface else { continue };
            let sink = [-0.003, 0.0, 0.0005, 0.0015, 0.01][step % 5];
            for flipped in [false, true] {
                let (mut ours, mut theirs) = (Vec::new(), Vec::new());
                let (mut our_space, mut their_space) = (None, None);
                for nudge in [0.0, 0.0007] {
                    let ball_in_field = Pose::from_translation(Vector::new(x + nudge, y + ball.radius - sink, z));
                    let (pos12, g1, g2): (Pose, &dyn Shape, &dyn Shape) = if flipped { (ball_in_field.inverse(), &ball, &field) } else { (ball_in_field, &field, &ball) };
                    BallOnHeightField.contact_manifolds(&pos12, g1, g2, prediction, &mut ours, &mut our_space).expect("ball on heightfield is ours");
                    DefaultQueryDispatcher.contact_manifolds(&pos12, g1, g2, prediction, &mut theirs, &mut their_space).expect("parry handles it");
                    let (ours, theirs) = (non_empty(&ours), non_empty(&theirs));
                    assert_eq!(ours.len(), theirs.len(), "manifolds at ({x}, {z}) sunk {sink}, flipped {flipped}");
                    for (a, b) in ours.iter().zip(&theirs) {
                        assert_eq!((a.subshape1, a.subshape2, a.local_n1, a.local_n2), (b.subshape1, b.subshape2, b.local_n1, b.local_n2));
                        assert_eq!(a.points.len(), b.points.len());
                        for (p, q) in a.points.iter().zip(&b.points) {
                            assert_eq!((p.local_p1, p.local_p2, p.dist, p.fid1, p.fid2), (q.local_p1, q.local_p2, q.dist, q.fid1, q.fid2));
                        }
                    }
                    compared += theirs.len();
                }
            }
        }
        // Most poses touch the surface: the comparison covered real contacts.
        assert!(compared > 1000, "only {compared} manifolds compared");
    }

    #[test]
    fn other_pairs_are_left_to_the_next_dispatcher() {
        let (ball, cuboid) = (Ball::new(0.05), rapier3d::parry::shape::Cuboid::new(Vector::splat(0.1)));
        let (mut manifolds, mut workspace) = (Vec::new(), None);
        let result = BallOnHeightField.contact_manifolds(&Pose::IDENTITY, &ball, &cuboid, 0.0, &mut manifolds, &mut workspace);
        assert_eq!(result, Err(Unsupported));
        let chained = dispatcher().contact_manifolds(&Pose::IDENTITY, &ball, &cuboid, 0.0, &mut manifolds, &mut workspace);
        assert_eq!(chained, Ok(()));
        assert!(!manifolds.is_empty() && !manifolds[0].points.is_empty(), "parry's dispatcher found the ball inside the box");
    }
}
