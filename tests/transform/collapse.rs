//! Transforms that collapse an axis, or nearly: which leave the index
//! (and make a caster's ray invalid), and which keep a true world box.

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, Ray, RayMode};
use bevy_transform::prelude::*;
use glam::{Quat, Vec3};

use super::{app, common, local};

#[test]
fn unusable_transforms_take_the_entity_out_and_are_counted() {
    let mut app = app();
    let e = app
        .world_mut()
        .spawn((Transform::from_xyz(1.0, 2.0, 3.0), LocalBounds(local())))
        .id();
    app.update();
    assert!(app.world().resource::<SpatialIndex>().contains(e));

    let bad = [
        Transform::from_scale(Vec3::new(1.0, 0.0, 1.0)),
        Transform::from_xyz(f32::NAN, 0.0, 0.0),
        Transform::from_xyz(f32::INFINITY, 0.0, 0.0),
    ];
    for (i, transform) in bad.into_iter().enumerate() {
        *app.world_mut().get_mut::<Transform>(e).unwrap() = transform;
        app.update();
        let index = app.world().resource::<SpatialIndex>();
        assert!(!index.contains(e), "case {i}");
        index.validate().unwrap();
        let diagnostics = app.world().resource::<SpatialDiagnostics>();
        assert_eq!(diagnostics.sync.invalid_skipped, 1, "case {i}");
        // Back to a usable transform: back in the index.
        *app.world_mut().get_mut::<Transform>(e).unwrap() = Transform::from_xyz(0.0, 0.0, 0.0);
        app.update();
        assert!(
            app.world().resource::<SpatialIndex>().contains(e),
            "case {i}"
        );
    }
}

/// A tiny scale whose determinant underflows `f32` (1e-16 on every axis,
/// so 1e-48) collapses no axis: the entity keeps a box around the exact
/// image of its corners (checked in `f64`), and nothing is counted.
#[test]
fn a_tiny_scale_is_not_a_collapsed_axis() {
    let mut app = app();
    let scale = Vec3::splat(1e-16);
    assert_eq!(scale.x * scale.y * scale.z, 0.0, "underflows in f32");
    let e = app
        .world_mut()
        .spawn((
            Transform::from_xyz(5.0, 0.0, 0.0)
                .with_scale(scale)
                .with_rotation(Quat::from_rotation_y(0.3)),
            LocalBounds(local()),
        ))
        .id();
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    let world = index.get(e).expect("indexed");
    index.validate().unwrap();
    let global = app.world().get::<GlobalTransform>(e).unwrap().affine();
    for corner in common::corners(&local()) {
        let m = global.matrix3.as_dmat3();
        let exact = m * corner.as_dvec3() + global.translation.as_dvec3();
        for axis in 0..3 {
            assert!(world.min[axis] as f64 <= exact[axis] && exact[axis] <= world.max[axis] as f64);
        }
    }
    assert!(world.max.x - world.min.x < 1e-6, "{world:?}");
    assert_eq!(
        app.world().resource::<SpatialDiagnostics>().invalid_total,
        0
    );
}

/// A random rotation, each Euler angle in (-3, 3).
fn turn(rng: &mut SceneRng) -> Quat {
    let mut angle = || rng.range(-3.0, 3.0);
    Quat::from_euler(glam::EulerRot::XYZ, angle(), angle(), angle())
}

/// Asserts that `entity`'s world box holds the exact image of its local
/// box's corners under its `GlobalTransform` (in `f64`).
fn holds_the_exact_image(app: &App, entity: Entity, world: &Aabb) {
    let global = app.world().get::<GlobalTransform>(entity).unwrap().affine();
    let m = global.matrix3.as_dmat3();
    for corner in common::corners(&local()) {
        let exact = m * corner.as_dvec3() + global.translation.as_dvec3();
        for axis in 0..3 {
            assert!(world.min[axis] as f64 <= exact[axis], "{world:?} {exact:?}");
            assert!(exact[axis] <= world.max[axis] as f64, "{world:?} {exact:?}");
        }
    }
}

/// Spawns under each of `parents` a child turned by `turn_child`, with a
/// local box, and beside it a caster turned the same way.
fn turned_children(
    app: &mut App,
    parents: &[Transform],
    mut turn_child: impl FnMut() -> Quat,
) -> Vec<(Entity, Entity)> {
    let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0).unwrap();
    parents
        .iter()
        .map(|&parent| {
            let world = app.world_mut();
            let parent = world.spawn(parent).id();
            let turned = Transform::from_rotation(turn_child());
            let boxed = (turned, LocalBounds(local()), ChildOf(parent));
            let caster = (turned, RayCaster::new(ray, RayMode::First), ChildOf(parent));
            (world.spawn(boxed).id(), world.spawn(caster).id())
        })
        .collect()
}

/// A zero scale on a turned parent above a turned child: the child's
/// columns are only nearly in one plane once `f32` has rounded them. Such
/// a child is either taken out and counted (where the rounding left them
/// exactly in one plane) or keeps a box that holds the exact, flat image
/// of its local box; its caster casts or reports an invalid ray. Never a
/// box that misses the image, and every child taken out is counted.
#[test]
fn a_zero_scale_above_a_turned_child_leaves_a_true_box_or_none() {
    let mut app = app();
    let mut rng = SceneRng::new(7);
    let parents: Vec<Transform> = (0..40)
        .map(|_| Transform::from_rotation(turn(&mut rng)).with_scale(Vec3::new(1.0, 0.0, 1.0)))
        .collect();
    let mut child_rng = SceneRng::new(17);
    let children = turned_children(&mut app, &parents, || turn(&mut child_rng));
    app.update();
    let mut left_out = 0;
    for &(child, _) in &children {
        match app.world().resource::<SpatialIndex>().get(child) {
            Some(world) => holds_the_exact_image(&app, child, &world),
            None => left_out += 1,
        }
    }
    let diagnostics = app.world().resource::<SpatialDiagnostics>();
    assert_eq!(diagnostics.sync.invalid_skipped, left_out);
    assert!(left_out < children.len() as u64, "some keep a flat box");
    app.world().resource::<SpatialIndex>().validate().unwrap();
}

/// Parents stretched 10,000 : 1 (100 by 0.01, a 1000 m by 0.1 m by 0.1 m
/// beam, 1000 by 0.001 by 1) above children turned at random and at the
/// turns that bring the columns nearest one plane collapse no axis: every
/// child is indexed with a box that holds the exact image of its corners,
/// its caster casts, and nothing is counted.
#[test]
fn a_stretched_parent_above_a_turned_child_is_no_collapse() {
    let mut app = app();
    let mut rng = SceneRng::new(8);
    let stretches = [
        Vec3::new(100.0, 0.01, 1.0),
        Vec3::new(1000.0, 0.1, 0.1),
        Vec3::new(1000.0, 0.001, 1.0),
    ];
    // The parent's long axis along the child's diagonal, or half way
    // between its x and y axes.
    let worst = [
        Quat::from_rotation_arc(Vec3::ONE / 3f32.sqrt(), Vec3::X),
        Quat::from_rotation_z(std::f32::consts::FRAC_PI_4),
    ];
    let mut parents = Vec::new();
    let mut child_turns = Vec::new();
    for &stretch in &stretches {
        // The worst turns under an unturned parent, then random ones.
        for child_turn in worst {
            parents.push(Transform::from_scale(stretch));
            child_turns.push(child_turn);
        }
        for _ in 0..18 {
            parents.push(Transform::from_rotation(turn(&mut rng)).with_scale(stretch));
            child_turns.push(turn(&mut rng));
        }
    }
    let mut turns = child_turns.into_iter();
    let children = turned_children(&mut app, &parents, || turns.next().unwrap());
    app.update();
    for &(child, caster) in &children {
        let world = app.world().resource::<SpatialIndex>().get(child);
        holds_the_exact_image(&app, child, &world.expect("indexed"));
        let hits = app.world().get::<RayCasterHits>(caster).unwrap();
        assert_eq!(hits.error(), None, "{:?}", hits.ray());
    }
    let diagnostics = app.world().resource::<SpatialDiagnostics>();
    assert_eq!(diagnostics.invalid_total, 0);
}

/// An entity given `LocalBounds` after this frame's world boxes were
/// written (by a system between the plugin's sets) reaches the sync with
/// the default box its `SpatialBounds` came with: a placeholder, left out
/// without being counted as invalid, and indexed at its world box the next
/// frame.
#[test]
fn local_bounds_given_after_the_world_boxes_wait_a_frame_uncounted() {
    let mut app = app();
    let spawned = |mut commands: Commands, mut done: Local<bool>| {
        if !std::mem::replace(&mut *done, true) {
            commands.spawn((Transform::from_xyz(5.0, 0.0, 0.0), LocalBounds(local())));
        }
    };
    app.add_systems(
        PostUpdate,
        spawned
            .after(SpatialIndexSystems::Bounds)
            .before(SpatialIndexSystems::Sync),
    );
    app.update();
    let mut query = app
        .world_mut()
        .query_filtered::<Entity, With<LocalBounds>>();
    let entity = query.single(app.world()).unwrap();
    let index = app.world().resource::<SpatialIndex>();
    assert!(!index.contains(entity), "no world box yet");
    let diagnostics = app.world().resource::<SpatialDiagnostics>();
    assert_eq!(diagnostics.invalid_total, 0);
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    let expected = local().transformed(&Transform::from_xyz(5.0, 0.0, 0.0).compute_affine());
    assert_eq!(index.get(entity), expected.ok());
    assert_eq!(
        app.world().resource::<SpatialDiagnostics>().invalid_total,
        0
    );
}
