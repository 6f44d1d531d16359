//! The automatic path from `GlobalTransform` (feature `bevy`).
#![cfg(feature = "bevy")]

#[path = "transform/collapse.rs"]
mod collapse;
mod common;

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::Aabb;
use bevy_rtree::plugin::*;
use bevy_transform::prelude::*;
use glam::{Quat, Vec3};

fn app() -> App {
    let mut app = App::new();
    app.add_plugins((TransformPlugin, SpatialIndexPlugin::default()));
    app
}

fn local() -> Aabb {
    Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0)).unwrap()
}

#[test]
fn world_boxes_follow_propagated_transforms() {
    let mut app = app();
    let parent = app
        .world_mut()
        .spawn(Transform::from_xyz(10.0, 0.0, 0.0))
        .id();
    let child = app
        .world_mut()
        .spawn((
            Transform::from_xyz(0.0, 5.0, 0.0),
            LocalBounds(local()),
            ChildOf(parent),
        ))
        .id();
    app.update();
    let expected = Aabb::new(Vec3::new(9.0, 4.0, -1.0), Vec3::new(11.0, 6.0, 1.0)).unwrap();
    assert_eq!(app.world().get::<SpatialBounds>(child).unwrap().0, expected);
    assert_eq!(
        app.world().resource::<SpatialIndex>().get(child),
        Some(expected)
    );

    // Moving the parent moves the child's box in the same frame.
    app.world_mut()
        .get_mut::<Transform>(parent)
        .unwrap()
        .translation
        .x = 20.0;
    app.update();
    let moved = app.world().resource::<SpatialIndex>().get(child).unwrap();
    assert_eq!(moved.min.x, 19.0);

    // A rotation rounds outward (SEMANTICS S1): the box still contains the
    // exact image of every corner.
    app.world_mut()
        .get_mut::<Transform>(child)
        .unwrap()
        .rotation = Quat::from_rotation_y(0.7);
    app.update();
    let rotated = app.world().resource::<SpatialIndex>().get(child).unwrap();
    let global = *app.world().get::<GlobalTransform>(child).unwrap();
    for corner in common::corners(&local()) {
        assert!(rotated.contains_point(global.transform_point(corner)));
    }
    app.world().resource::<SpatialIndex>().validate().unwrap();
}

/// `LocalBounds` leaves behind the `SpatialBounds` it required, as Bevy
/// leaves required components: the entity stays at its last world box,
/// which no longer follows the transform, until that box goes too.
#[test]
fn removing_local_bounds_leaves_the_last_world_box_in_place() {
    let mut app = app();
    let e = app
        .world_mut()
        .spawn((Transform::from_xyz(10.0, 0.0, 0.0), LocalBounds(local())))
        .id();
    app.update();
    let index = |app: &App| app.world().resource::<SpatialIndex>().get(e);
    let last = index(&app).unwrap();
    assert_eq!(last.min.x, 9.0);
    app.world_mut().entity_mut(e).remove::<LocalBounds>();
    app.world_mut()
        .get_mut::<Transform>(e)
        .unwrap()
        .translation
        .x = 100.0;
    app.update();
    assert_eq!(index(&app), Some(last), "fixed where it was");
    app.world_mut().entity_mut(e).remove::<SpatialBounds>();
    assert_eq!(index(&app), None);
    // Put back, it follows the transform again.
    app.world_mut().entity_mut(e).insert(LocalBounds(local()));
    app.update();
    assert_eq!(index(&app).unwrap().min.x, 99.0);
}

/// Removing `SpatialBounds` takes an entity with `LocalBounds` out of the
/// index; putting it back (whatever value it is given) brings the entity
/// back at its world box, also after it moved meanwhile or when it did
/// not move at all. A box written by hand is replaced by the world box.
/// Read table by table and (a sparse disabling component registered) row
/// by row.
#[test]
fn spatial_bounds_inserted_again_or_written_is_the_world_box() {
    for row_by_row in [false, true] {
        let mut app = app();
        if row_by_row {
            app.world_mut().register_disabling_component::<Asleep>();
        }
        let spawn = |app: &mut App, x: f32| {
            app.world_mut()
                .spawn((Transform::from_xyz(x, 0.0, 0.0), LocalBounds(local())))
                .id()
        };
        let (moved, still) = (spawn(&mut app, 10.0), spawn(&mut app, 20.0));
        app.update();
        let index = |app: &App, e: Entity| app.world().resource::<SpatialIndex>().get(e);
        for e in [moved, still] {
            app.world_mut().entity_mut(e).remove::<SpatialBounds>();
        }
        app.world_mut()
            .get_mut::<Transform>(moved)
            .unwrap()
            .translation
            .x = 100.0;
        app.update();
        assert_eq!(index(&app, moved), None);
        assert_eq!(index(&app, still), None);
        let stale = Aabb::new(Vec3::splat(-9.0), Vec3::splat(-8.0)).unwrap();
        app.world_mut()
            .entity_mut(moved)
            .insert(SpatialBounds::default());
        app.world_mut()
            .entity_mut(still)
            .insert(SpatialBounds(stale));
        app.update();
        assert_eq!(index(&app, moved).map(|b| b.min.x), Some(99.0));
        assert_eq!(index(&app, still).map(|b| b.min.x), Some(19.0));
        // Written by hand: the world box again in the same frame.
        app.world_mut().get_mut::<SpatialBounds>(still).unwrap().0 = stale;
        app.update();
        assert_eq!(index(&app, still).map(|b| b.min.x), Some(19.0));
        app.world().resource::<SpatialIndex>().validate().unwrap();
    }
}

/// A caster on a moving, turning, scaled turret casts from the turret each
/// frame, not from the world origin: its local ray follows the
/// `GlobalTransform` (the scale stretches nothing), `t` is in metres, the
/// hit's point lies on the target's face, and the turret's own box is
/// ignored although the ray starts inside it.
#[test]
fn a_caster_follows_its_turret_and_does_not_see_itself() {
    use bevy_rtree::{Ray, RayMode};
    let mut app = app();
    // Targets on a ring of radius 20 around the origin, every 30 degrees.
    let targets: Vec<Entity> = (0..12)
        .map(|i| {
            let angle = i as f32 * std::f32::consts::TAU / 12.0;
            let at = Vec3::new(angle.cos(), 0.0, -angle.sin()) * 20.0;
            app.world_mut()
                .spawn((Transform::from_translation(at), LocalBounds(local())))
                .id()
        })
        .collect();
    // Looking down its local +X, 100 m long, from inside its own box.
    let ray = Ray::new(Vec3::ZERO, Vec3::X * 3.0, 100.0 / 3.0).unwrap();
    let turret = app
        .world_mut()
        .spawn((
            Transform::from_xyz(0.0, 0.0, 0.0).with_scale(Vec3::splat(2.0)),
            LocalBounds(local()),
            RayCaster::new(ray, RayMode::First),
        ))
        .id();
    for (i, &target) in targets.iter().enumerate() {
        let angle = i as f32 * std::f32::consts::TAU / 12.0;
        app.world_mut()
            .get_mut::<Transform>(turret)
            .unwrap()
            .rotation = Quat::from_rotation_y(angle);
        app.update();
        let hits = app.world().get::<RayCasterHits>(turret).unwrap();
        let hit = hits.first().expect("the target ahead is hit");
        assert_eq!(hit.key, target, "turned {i} times");
        // The ray enters the target's axis-aligned box (half extent 1 m,
        // centre 20 m out) where its dominant axis crosses a face.
        let entry = 20.0 - 1.0 / angle.cos().abs().max(angle.sin().abs());
        assert!(
            (hit.t - entry).abs() < 1e-3,
            "t = {} m, expected {entry}",
            hit.t
        );
        let point = hits.point(&hit).unwrap();
        let centre = Vec3::new(angle.cos(), 0.0, -angle.sin()) * 20.0;
        assert!(
            (point - centre).length() <= 1.0 * 3f32.sqrt() + 1e-3,
            "{point}"
        );
    }
    // Moved away from the ring's centre, up where nothing is: no hit.
    app.world_mut()
        .get_mut::<Transform>(turret)
        .unwrap()
        .translation = Vec3::new(0.0, 50.0, 0.0);
    app.update();
    let hits = app.world().get::<RayCasterHits>(turret).unwrap();
    assert_eq!(hits.first(), None);
    assert_eq!(hits.ray().unwrap().origin, Vec3::new(0.0, 50.0, 0.0));
}

/// A caster on a transform keeps every ray the contract calls valid: a
/// direction far longer or shorter than one (whose squared length leaves
/// `f32`) is turned and normalised like any other, and an invalid one is
/// still reported as invalid. The wall's entry point is known: 5 m ahead.
#[test]
fn a_caster_on_a_transform_keeps_valid_extreme_directions() {
    use bevy_rtree::{Ray, RayMode, SpatialError};
    let mut app = app();
    let wall_box = Aabb::new(Vec3::new(5.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0)).unwrap();
    let wall = app.world_mut().spawn(SpatialBounds(wall_box)).id();
    let lengths = [1e-30f32, 1e-25, 1e-20, 1.0, 1e20, 1e30];
    let casters: Vec<Entity> = lengths
        .iter()
        .map(|&length| {
            let ray = Ray::new(Vec3::ZERO, Vec3::Y * length, f32::INFINITY).unwrap();
            app.world_mut()
                .spawn((
                    RayCaster::new(ray, RayMode::First),
                    // Turned so that local +Y looks down world +X.
                    Transform::from_rotation(Quat::from_rotation_z(-std::f32::consts::FRAC_PI_2)),
                ))
                .id()
        })
        .collect();
    // Only a subnormal direction: invalid (S3), with or without a transform.
    let subnormal = Ray {
        origin: Vec3::ZERO,
        dir: Vec3::X * 1e-40,
        max_t: 1.0,
    };
    let invalid = app
        .world_mut()
        .spawn((
            RayCaster::new(subnormal, RayMode::First),
            Transform::IDENTITY,
        ))
        .id();
    app.update();
    for (&caster, length) in casters.iter().zip(lengths) {
        let hits = app.world().get::<RayCasterHits>(caster).unwrap();
        assert_eq!(hits.error(), None, "direction of length {length}");
        let hit = hits.first().expect("the wall ahead is hit");
        assert_eq!(hit.key, wall, "direction of length {length}");
        assert!(
            (hit.t - 5.0).abs() < 1e-4,
            "t = {} m, length {length}",
            hit.t
        );
    }
    let hits = app.world().get::<RayCasterHits>(invalid).unwrap();
    assert_eq!(hits.error(), Some(SpatialError::InvalidRay));
}

/// A mirroring transform mirrors a caster's ray as it mirrors the entity,
/// origin and direction alike, whichever axis it mirrors; a collapsed axis
/// (scale 0) has no rotation, and the ray is reported invalid.
#[test]
fn a_mirrored_caster_looks_the_mirrored_way() {
    use bevy_rtree::{Ray, RayMode, SpatialError};
    let mut app = app();
    let wall = |x: f32| Aabb::new(Vec3::new(x, -1.0, -1.0), Vec3::new(x + 1.0, 1.0, 1.0)).unwrap();
    let east = app.world_mut().spawn(SpatialBounds(wall(10.0))).id();
    let west = app.world_mut().spawn(SpatialBounds(wall(-11.0))).id();
    // From 2 m out along local +X, looking down local +X.
    let ray = Ray::new(Vec3::new(2.0, 0.0, 0.0), Vec3::X, 100.0).unwrap();
    // (scale, the wall hit, the world origin, the entry t in metres)
    let cases = [
        (Vec3::ONE, east, Vec3::new(2.0, 0.0, 0.0), 8.0),
        (
            Vec3::new(-1.0, 1.0, 1.0),
            west,
            Vec3::new(-2.0, 0.0, 0.0),
            8.0,
        ),
        (
            Vec3::new(1.0, -1.0, 1.0),
            east,
            Vec3::new(2.0, 0.0, 0.0),
            8.0,
        ),
        (
            Vec3::new(1.0, 1.0, -1.0),
            east,
            Vec3::new(2.0, 0.0, 0.0),
            8.0,
        ),
        (Vec3::splat(-1.0), west, Vec3::new(-2.0, 0.0, 0.0), 8.0),
        (
            Vec3::new(-2.0, 3.0, 1.0),
            west,
            Vec3::new(-4.0, 0.0, 0.0),
            6.0,
        ),
        // A determinant that underflows f32 (1e-48) keeps its reflection.
        (
            Vec3::new(-1e-16, 1e-16, 1e-16),
            west,
            Vec3::new(-2e-16, 0.0, 0.0),
            10.0,
        ),
    ];
    let casters: Vec<Entity> = cases
        .iter()
        .map(|&(scale, ..)| {
            app.world_mut()
                .spawn((
                    RayCaster::new(ray, RayMode::First),
                    Transform::from_scale(scale),
                ))
                .id()
        })
        .collect();
    let flat = app
        .world_mut()
        .spawn((
            RayCaster::new(ray, RayMode::First),
            Transform::from_scale(Vec3::new(1.0, 0.0, 1.0)),
        ))
        .id();
    // Turned about x as well: the f32 determinant's terms then underflow
    // to zeros that sum to +0, and a split of the transform into scale and
    // rotation in f32 loses the reflection.
    let tiny_turned = app
        .world_mut()
        .spawn((
            RayCaster::new(ray, RayMode::First),
            Transform::from_scale(Vec3::new(-1e-16, 1e-16, 1e-16))
                .with_rotation(Quat::from_rotation_x(std::f32::consts::FRAC_PI_4)),
        ))
        .id();
    app.update();
    let hits = app.world().get::<RayCasterHits>(tiny_turned).unwrap();
    assert_eq!(hits.first().map(|h| h.key), Some(west), "{:?}", hits.ray());
    assert!((hits.first().unwrap().t - 10.0).abs() < 1e-4);
    for (&caster, &(scale, wall, origin, t)) in casters.iter().zip(&cases) {
        let hits = app.world().get::<RayCasterHits>(caster).unwrap();
        let cast = hits.ray().unwrap();
        assert!(
            (cast.origin - origin).length() < 1e-5,
            "scale {scale}: {cast:?}"
        );
        let hit = hits.first().expect("a wall is hit");
        assert_eq!(hit.key, wall, "scale {scale}");
        assert!((hit.t - t).abs() < 1e-4, "scale {scale}: t = {}", hit.t);
    }
    let hits = app.world().get::<RayCasterHits>(flat).unwrap();
    assert_eq!(hits.error(), Some(SpatialError::InvalidRay));
}

/// The entities whose `SpatialBounds` this frame's world boxes marked
/// changed, recorded right after they are written.
#[derive(Resource, Default)]
struct MarkedChanged(Vec<Entity>);

fn record_marked(mut marked: ResMut<MarkedChanged>, bounds: Query<(Entity, Ref<SpatialBounds>)>) {
    marked.0 = bounds
        .iter()
        .filter(|(_, b)| b.is_changed())
        .map(|(e, _)| e)
        .collect();
    marked.0.sort_unstable();
}

/// A disabling component stored in a sparse set: every query of an app that
/// registers one is read row by row, not table by table.
#[derive(Component)]
#[component(storage = "SparseSet")]
struct Asleep;

/// A world box is marked changed in exactly the frames where its value
/// changes, as `set_if_neq` marks it (so that the index's sync sees only
/// real moves), whether its transform, its local box or neither changed,
/// or either was written with its old value; read table by table and
/// (with a sparse disabling component registered) row by row.
#[test]
fn world_boxes_are_marked_changed_exactly_when_they_change() {
    for row_by_row in [false, true] {
        let mut app = app();
        if row_by_row {
            app.world_mut().register_disabling_component::<Asleep>();
        }
        app.init_resource::<MarkedChanged>()
            .add_systems(PostUpdate, record_marked.after(SpatialIndexSystems::Bounds));
        let entities: Vec<Entity> = (0..40)
            .map(|i| {
                let transform = Transform::from_xyz(i as f32 * 3.0, 0.0, 0.0);
                app.world_mut()
                    .spawn((transform, LocalBounds(local())))
                    .id()
            })
            .collect();
        let mut before: Vec<Option<SpatialBounds>> = vec![None; entities.len()];
        for frame in 0..12u32 {
            for (i, &e) in entities.iter().enumerate() {
                let mut world = app.world_mut().entity_mut(e);
                match (i as u32 + frame) % 6 {
                    // A move.
                    0 => world.get_mut::<Transform>().unwrap().translation.y += 1.0,
                    // The same transform written again.
                    1 => {
                        let same = *world.get::<Transform>().unwrap();
                        *world.get_mut::<Transform>().unwrap() = same;
                    }
                    // The same local box written again.
                    2 => world.get_mut::<LocalBounds>().unwrap().0 = local(),
                    // A new local box.
                    3 => {
                        let grown = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0 + frame as f32));
                        world.get_mut::<LocalBounds>().unwrap().0 = grown.unwrap();
                    }
                    // Nothing.
                    _ => {}
                }
            }
            app.update();
            let now: Vec<Option<SpatialBounds>> = entities
                .iter()
                .map(|&e| app.world().get::<SpatialBounds>(e).copied())
                .collect();
            let mut expected: Vec<Entity> = entities
                .iter()
                .zip(before.iter().zip(&now))
                .filter(|(_, (b, n))| b != n)
                .map(|(&e, _)| e)
                .collect();
            expected.sort_unstable();
            let marked = &app.world().resource::<MarkedChanged>().0;
            assert_eq!(marked, &expected, "frame {frame}, row by row {row_by_row}");
            // Some frames change boxes and some leave boxes unchanged
            // although their inputs were written.
            assert!(frame == 0 || (!expected.is_empty() && expected.len() < entities.len()));
            let index = app.world().resource::<SpatialIndex>();
            for (&e, bounds) in entities.iter().zip(&now) {
                assert_eq!(index.get(e), bounds.map(|b| b.0), "frame {frame}");
            }
            index.validate().unwrap();
            before = now;
        }
    }
}

/// `SpatialBounds` keeps no summary tick: the world boxes are written
/// table by table with their change ticks, which would leave one stale.
#[test]
fn spatial_bounds_keeps_no_summary_tick() {
    let mut world = World::new();
    let id = world.register_component::<SpatialBounds>();
    assert!(!world.components().get_info(id).unwrap().summary_tick());
}

/// A local box changed while the entity was disabled (Bevy's `Disabled`,
/// or a disabling component of the app's own) is the one it comes back
/// with: the world boxes' system skipped it meanwhile, as every query
/// does, and runs on for the other entities.
#[test]
fn a_local_box_changed_while_disabled_is_the_one_it_comes_back_with() {
    use bevy_ecs::entity_disabling::Disabled;
    #[derive(Component)]
    struct Frozen;
    for own in [false, true] {
        let mut app = app();
        if own {
            app.world_mut().register_disabling_component::<Frozen>();
        }
        let sleeper = app
            .world_mut()
            .spawn((Transform::from_xyz(10.0, 0.0, 0.0), LocalBounds(local())))
            .id();
        let awake = app
            .world_mut()
            .spawn((Transform::from_xyz(-10.0, 0.0, 0.0), LocalBounds(local())))
            .id();
        app.update();
        if own {
            app.world_mut().entity_mut(sleeper).insert(Frozen);
        } else {
            app.world_mut().entity_mut(sleeper).insert(Disabled);
        }
        app.update();
        let grown = Aabb::new(Vec3::splat(-5.0), Vec3::splat(5.0)).unwrap();
        app.world_mut().get_mut::<LocalBounds>(sleeper).unwrap().0 = grown;
        // The other entity moves, so that the world boxes' system runs.
        for _ in 0..2 {
            app.world_mut()
                .get_mut::<Transform>(awake)
                .unwrap()
                .translation
                .y += 1.0;
            app.update();
        }
        if own {
            app.world_mut().entity_mut(sleeper).remove::<Frozen>();
        } else {
            app.world_mut().entity_mut(sleeper).remove::<Disabled>();
        }
        app.update();
        let expected = Aabb::new(Vec3::new(5.0, -5.0, -5.0), Vec3::new(15.0, 5.0, 5.0)).unwrap();
        let index = app.world().resource::<SpatialIndex>();
        assert_eq!(index.get(sleeper), Some(expected), "own component {own}");
        assert_eq!(
            app.world().get::<SpatialBounds>(sleeper).unwrap().0,
            expected
        );
        index.validate().unwrap();
    }
}
