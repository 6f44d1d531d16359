//! Boxes at a camera's planes and transforms at the ends of `f32`:
//! decided as Bevy decides them.

use super::*;

/// Boxes placed across, on and just outside a camera's planes, closer than
/// the rounding of either test can tell: the tree must keep every box
/// Bevy's test accepts, and prove inside only boxes Bevy's test accepts.
#[test]
fn boxes_at_a_camera_plane_are_decided_as_bevy_decides() {
    let mut twins = Twins::new(7);
    twins.spawn_camera(0);
    twins.update();
    let camera = twins.cameras[0][0];
    let frustum = *twins
        .bevy
        .world()
        .get::<bevy_camera::primitives::Frustum>(camera)
        .unwrap();
    let eye = twins
        .bevy
        .world()
        .get::<GlobalTransform>(camera)
        .unwrap()
        .translation();
    let forward = twins
        .bevy
        .world()
        .get::<GlobalTransform>(camera)
        .unwrap()
        .forward();
    for _ in 0..4_000 {
        let pair = twins.both(|world, rng, _| {
            let plane = frustum.half_spaces[rng.below(5)];
            let n = Vec3::from(plane.normal());
            let q = eye
                + forward * rng.range(2.0, 60.0)
                + Vec3::new(
                    rng.range(-20.0, 20.0),
                    rng.range(-10.0, 10.0),
                    rng.range(-20.0, 20.0),
                );
            let on_plane = q - n * (n.dot(q) + plane.d());
            // Points and slivers too, which lie wholly within rounding of a plane.
            let half = Vec3::new(
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
            ) * [0.0, 1e-3, 1.0, 1.0][rng.below(4)];
            let reach = n.abs().dot(half);
            let delta =
                [1e-6, 1e-5, 3e-5, 1e-4, 1e-3, 5e-3, 2e-2][rng.below(7)] * rng.range(-1.0, 1.0);
            let center = on_plane - n * (reach + delta);
            world
                .spawn((
                    Mesh3d::default(),
                    Aabb {
                        center: Vec3A::ZERO,
                        half_extents: half.into(),
                    },
                    Transform::from_translation(center),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    twins.update();
    let seen = twins.check(0);
    assert!(
        seen > 1_000 && seen < 3_500,
        "both sides of the planes: {seen} seen"
    );
}

/// A transform with a column near `f32::MAX` over a box flat along it:
/// Bevy's box test then computes NaN for a plane, which culls nothing, so
/// Bevy keeps an entity whose (small, valid) world box lies outside that
/// plane. Such entities are decided by Bevy's test alone, as Bevy decides.
#[test]
fn entities_on_huge_columns_are_decided_as_bevy_decides() {
    use glam::Affine3A;
    let mut twins = Twins::new(17);
    // At the origin, looking down -Z: the left plane's normal is about
    // (0.92, 0, -0.38).
    let camera =
        twins.both(|world, _, _| world.spawn((Camera3d::default(), Transform::IDENTITY)).id());
    twins.cameras.push(camera);
    for i in 0..40 {
        let pair = twins.both(|world, rng, _| {
            // Left of the view, from just outside its plane (within the
            // box's bounding sphere) to well outside; the first column is
            // huge and meets a half extent of 0.
            let at = Vec3::new(-5.2 - rng.range(0.0, 0.5), 0.0, -10.0);
            let huge = f32::MAX * if i % 2 == 0 { 1.0 } else { 0.6 };
            let columns =
                Affine3A::from_cols(Vec3A::new(huge, 0.0, -huge), Vec3A::Y, Vec3A::Z, at.into());
            world
                .spawn((
                    GlobalTransform::from(columns),
                    Aabb {
                        center: Vec3A::ZERO,
                        half_extents: Vec3A::new(0.0, 1.0, 1.0),
                    },
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    for frame in 0..3 {
        twins.update();
        // Half of them overflow Bevy's test: it keeps most of those.
        let kept = twins.check(frame);
        assert!((1..=20).contains(&kept), "frame {frame}: {kept}");
    }
    let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
}

/// A tiny scale (1e-16 on every axis, whose determinant underflows `f32`)
/// collapses no axis: such entities are indexed like any other, and seen
/// as Bevy sees them.
#[test]
fn entities_of_a_tiny_scale_are_indexed_and_seen_as_bevy_sees_them() {
    let mut twins = Twins::new(13);
    twins.spawn_camera(0);
    for i in 0..200 {
        let pair = twins.both(|world, rng, _| {
            let mut transform = random_transform(rng, 40.0, (-5.0, 30.0));
            if i % 2 == 0 {
                transform.scale = Vec3::splat(1e-16);
            }
            world
                .spawn((
                    transform,
                    random_aabb(rng),
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    for frame in 0..3 {
        twins.update();
        twins.check(frame);
    }
    let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
    assert_eq!(index.unindexed().count(), 0);
    assert_eq!(index.len(), 200);
}

/// A camera is itself culled by Bevy (a `Camera` requires `Visibility`),
/// and Bevy's layer test answers yes for the same `RenderLayers`
/// component before it compares layers: a camera with no layers at all
/// still sees itself, and so must the index's culling.
#[test]
fn a_camera_with_no_layers_sees_itself_as_bevy_does() {
    let mut apps = [app(false), app(true)];
    let cameras = apps.each_mut().map(|app| {
        let world = app.world_mut();
        let camera = (Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0));
        world.spawn((camera, RenderLayers::none())).id()
    });
    for frame in 0..3 {
        apps.iter_mut().for_each(App::update);
        let [bevy, ours] = [0, 1].map(|side| {
            let camera = apps[side].world().entity(cameras[side]);
            let listed = camera.get::<VisibleEntities>().unwrap();
            let mut listed: Vec<usize> = listed.entities.values().map(Vec::len).collect();
            listed.sort_unstable();
            (camera.get::<ViewVisibility>().unwrap().get(), listed)
        });
        assert!(bevy.0, "frame {frame}: Bevy's own answer");
        assert_eq!(bevy, ours, "frame {frame}");
    }
}

/// Two tables split over the pool's threads (with the `multi_threaded`
/// executor, as in a game's development build): Bevy's parallel queries by
/// table assert in a debug build that a batch holds its whole table, so
/// the passes must not hand them runs smaller than a table there. Bevy's
/// own culling, the oracle, runs the frame too.
#[test]
fn tables_split_over_threads_in_a_debug_build() {
    let [mut bevy, mut ours] = [app(false), app(true)];
    let meshes = [&mut bevy, &mut ours].map(|app| {
        let world = app.world_mut();
        world.spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)));
        (0..200)
            .map(|i| {
                let mut mesh = world.spawn((
                    Mesh3d::default(),
                    Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                    Transform::from_xyz(i as f32 * 0.05 - 5.0, 0.0, 0.0),
                ));
                if i % 2 == 0 {
                    // A second table.
                    mesh.insert(RenderLayers::layer(0));
                }
                mesh.id()
            })
            .collect::<Vec<_>>()
    });
    for _ in 0..3 {
        bevy.update();
        ours.update();
        let seen = |app: &App, list: &[Entity]| -> Vec<bool> {
            let visible = |&e: &Entity| app.world().get::<ViewVisibility>(e).unwrap().get();
            list.iter().map(visible).collect()
        };
        let expected = seen(&bevy, &meshes[0]);
        assert!(expected.iter().any(|&v| v) && expected.iter().any(|&v| !v));
        assert_eq!(seen(&ours, &meshes[1]), expected);
    }
}
