//! The candidates and proofs of [`frustum_candidates`](super::frustum_candidates)
//! against Bevy's own tests, run as Bevy's camera culling runs them: a
//! box the tree proves inside must pass Bevy's sphere and oriented-box
//! tests, and a box it leaves out must fail them. Planes are placed a
//! rounding's width from boxes turned, scaled and placed at magnitudes
//! from 1e-30 to 1e14 m (for the proofs), or past the box (for what is
//! left out).

use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum, Sphere};
use bevy_ecs::entity::Entity;
use bevy_shape::{HalfSpace as BevyHalfSpace, ViewFrustum};
use bevy_transform::prelude::{GlobalTransform, Transform};
use glam::{DVec3, Quat, Vec3, Vec3A, Vec4};

use super::Renderable;
use super::frustum_candidates::{UNTESTED_BY_CAMERAS, candidates, slack};
use super::sync::world_box;
use crate::plugin::index::SpatialIndex;
use crate::query::QueryWorkspace;
use crate::scene::SceneRng;
use crate::tree::TreeSettings;

/// Bevy's decision for one entity and camera, as `check_visibility_cpu_culling`
/// makes it: the sphere test, then the oriented-box test, neither with
/// the far plane.
fn bevy_accepts(frustum: &BevyFrustum, aabb: &BevyAabb, transform: &GlobalTransform) -> bool {
    let world_from_local = transform.affine();
    let sphere = Sphere {
        center: world_from_local.transform_point3a(aabb.center),
        radius: transform.radius_vec3a(aabb.half_extents),
    };
    frustum.intersects_sphere(&sphere, false)
        && frustum.intersects_obb(aabb, &world_from_local, true, false)
}

/// A plane with normal `n` whose `d` puts the corner of `world` farthest
/// against `n` at `gap` (in `f64`) inside it.
fn plane_at(n: Vec3, world: &crate::geometry::Aabb, gap: f64) -> Vec4 {
    let (min, max) = (world.min.as_dvec3(), world.max.as_dvec3());
    let nd = n.as_dvec3();
    let corner = DVec3::select(nd.cmpge(DVec3::ZERO), min, max);
    Vec4::new(n.x, n.y, n.z, (gap - nd.dot(corner)) as f32)
}

#[test]
fn proven_boxes_pass_bevy_s_tests_and_left_out_ones_fail_them() {
    let mut rng = SceneRng::new(0x9A0F);
    let (mut proven_near, mut left_out, mut trials) = (0, 0, 0);
    for magnitude in [1e-30f32, 1e-6, 1.0, 1e3, 1e6, 1e10, 1e14] {
        for _ in 0..400 {
            trials += 1;
            let place = Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            ) * magnitude;
            let turn = Quat::from_euler(
                glam::EulerRot::YXZ,
                rng.range(0.0, 6.3),
                rng.range(-1.5, 1.5),
                rng.range(-1.0, 1.0),
            );
            let scale = Vec3::new(
                rng.range(0.2, 5.0),
                rng.range(0.2, 5.0),
                rng.range(0.2, 5.0),
            );
            let transform = GlobalTransform::from(
                Transform::from_translation(place)
                    .with_rotation(turn)
                    .with_scale(scale),
            );
            let size = magnitude * 1e-2;
            let aabb = BevyAabb {
                center: Vec3A::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                ) * size,
                half_extents: Vec3A::new(
                    rng.range(0.1, 1.0),
                    rng.range(0.1, 1.0),
                    rng.range(0.1, 1.0),
                ) * size
                    // Within Bevy's rounding, points: Bevy's test then has no
                    // extent to spare, and only the slack keeps a proof sound.
                    * if trials % 3 == 1 { 0.0 } else { 1.0 },
            };
            let world = world_box(&aabb, &transform);
            if world.validate().is_err() {
                continue;
            }
            let mut index = SpatialIndex::<Renderable>::new(TreeSettings::default());
            let entity = Entity::from_raw_u32(1).unwrap();
            index.tree.insert(entity, world).unwrap();
            // The eye near the box or far from it (the tree's test runs at
            // eye-relative coordinates, Bevy's at world ones).
            let away = [rng.range(0.0, 2.0), rng.range(1e3, 1e4)][trials % 2];
            let eye = place + rng.direction() * magnitude * away;
            // One plane a few slacks either side of the box's far corner;
            // the other tested planes far behind it; the far plane (which
            // Bevy's camera culling skips) cutting the box off.
            let reach =
                world.min.abs().max(world.max.abs()).max_element() * 3.0 + eye.abs().max_element();
            let near_plane = rng.direction();
            let s = slack(near_plane, 0.0, reach);
            // A few slacks either side, for the proof; within Bevy's own
            // rounding of the plane (a few 2^-24 of the magnitudes), where
            // only a sound slack keeps the tree from proving what Bevy's
            // test may reject; or past the margin the tree's held boxes
            // add, for what is left out.
            let gap = match trials % 3 {
                0 => s * f64::from(rng.range(-3.0, 3.0)),
                1 => f64::from(reach) * 2f64.powi(-24) * f64::from(rng.range(-8.0, 8.0)),
                _ => -f64::from((world.max - world.min).max_element() * rng.range(1.0, 4.0)),
            };
            let mut planes = [Vec4::ZERO; 6];
            for (i, plane) in planes.iter_mut().enumerate() {
                *plane = match i {
                    0 => plane_at(near_plane, &world, gap),
                    UNTESTED_BY_CAMERAS => {
                        plane_at(rng.direction(), &world, -f64::from(size) * 10.0)
                    }
                    _ => plane_at(rng.direction(), &world, f64::from(magnitude) * 4.0),
                };
            }
            let frustum = BevyFrustum(ViewFrustum {
                half_spaces: planes.map(BevyHalfSpace::new),
            });
            let mut out = Vec::new();
            let mut ws = QueryWorkspace::default();
            candidates(
                &index,
                &frustum,
                UNTESTED_BY_CAMERAS,
                eye,
                &mut ws,
                &mut out,
            );
            let accepted = bevy_accepts(&frustum, &aabb, &transform);
            match out.first() {
                Some(&(_, true)) => {
                    assert!(
                        accepted,
                        "proven but Bevy culls it: {magnitude} m, gap {gap}"
                    );
                    proven_near += usize::from(gap.abs() < 4.0 * s);
                }
                Some(&(_, false)) => {}
                None => {
                    assert!(
                        !accepted,
                        "left out but Bevy sees it: {magnitude} m, gap {gap}"
                    );
                    left_out += 1;
                }
            }
        }
    }
    // Proofs a few roundings from the plane, and boxes left out, were met.
    assert!(
        proven_near > trials / 20,
        "{proven_near} proven of {trials}"
    );
    assert!(left_out > trials / 10, "{left_out} left out of {trials}");
}
