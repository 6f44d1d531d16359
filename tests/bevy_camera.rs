//! Culling cameras that follow bevy_camera's `Frustum` (feature
//! `bevy_camera`): the list equals the oracle over the converted frustum,
//! and agrees with Bevy's own box test for this scene.
#![cfg(feature = "bevy_camera")]

use bevy_app::prelude::*;
use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum};
use bevy_camera::{CameraProjection, PerspectiveProjection};
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, CullMode, SpatialError};
use bevy_transform::prelude::*;
use glam::{Quat, Vec3};

/// What Bevy's frustum update computes for a perspective camera (infinite
/// reverse-z projection, far plane at 120 m).
fn bevy_frustum(transform: &Transform) -> BevyFrustum {
    let projection = PerspectiveProjection {
        fov: 1.0,
        aspect_ratio: 16.0 / 9.0,
        near: 0.1,
        far: 120.0,
        ..PerspectiveProjection::default()
    };
    projection.compute_frustum(&GlobalTransform::from(*transform))
}

/// What a camera at `transform` that the main layer follows carries.
fn follower(transform: &Transform) -> impl bevy_ecs::bundle::Bundle {
    (
        bevy_frustum(transform),
        GlobalTransform::from(*transform),
        FollowBevyFrustum::default(),
    )
}

#[test]
fn a_bevy_camera_culls_like_bevy_and_like_the_oracle() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let mut rng = SceneRng::new(21);
    let mut boxes = Vec::new();
    for _ in 0..2_000 {
        let center = Vec3::new(
            rng.range(-100.0, 100.0),
            rng.range(-10.0, 10.0),
            rng.range(-100.0, 100.0),
        );
        let aabb =
            Aabb::from_center_half_extents(center, Vec3::splat(rng.range(0.2, 2.0))).unwrap();
        let e = app.world_mut().spawn(SpatialBounds(aabb)).id();
        boxes.push((e, aabb));
    }
    let mut transform =
        Transform::from_xyz(5.0, 2.0, 3.0).with_rotation(Quat::from_rotation_y(0.4));
    let camera = app.world_mut().spawn(follower(&transform)).id();
    for frame in 0..3 {
        app.update();
        let culling = *app
            .world()
            .get::<CullingCamera>(camera)
            .expect("the plugin adds the culling camera");
        assert_eq!(culling.mode, CullMode::Conservative);
        let visible = app
            .world()
            .get::<VisibleEntityList>(camera)
            .unwrap()
            .entities()
            .to_vec();
        let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
        assert_eq!(
            visible,
            oracle.visible(&culling.frustum, CullMode::Conservative),
            "frame {frame}"
        );
        let bevy = app.world().get::<BevyFrustum>(camera).unwrap();
        let mut by_bevy: Vec<_> = boxes
            .iter()
            .filter(|(_, b)| bevy.intersects_obb_identity(&BevyAabb::from_min_max(b.min, b.max)))
            .map(|(e, _)| *e)
            .collect();
        by_bevy.sort_unstable();
        assert!(visible.len() > 50, "the camera sees part of the field");
        assert_eq!(
            visible, by_bevy,
            "frame {frame}: same answer as Bevy's own test"
        );
        // The camera turns; Bevy would update its Frustum, we do it here.
        transform.rotate_y(0.7);
        let world = app.world_mut();
        *world.get_mut::<BevyFrustum>(camera).unwrap() = bevy_frustum(&transform);
        *world.get_mut::<GlobalTransform>(camera).unwrap() = GlobalTransform::from(transform);
    }
}

#[derive(bevy_ecs::component::Component)]
struct Enemy;

/// A Bevy camera that follows for a layer: its `CullingCamera<Enemy>` and
/// `VisibleEntityList<Enemy>` list the enemies it sees and nothing else;
/// the same camera can follow for the main layer too.
#[test]
fn a_bevy_camera_follows_for_a_layer() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_spatial_layer::<Enemy>();
    let ahead = |x: f32| Aabb::from_center_half_extents(Vec3::new(x, 0.0, -20.0), Vec3::ONE);
    let enemy = app
        .world_mut()
        .spawn((SpatialBounds(ahead(0.0).unwrap()), Enemy))
        .id();
    let crate_box = app
        .world_mut()
        .spawn(SpatialBounds(ahead(3.0).unwrap()))
        .id();
    let transform = Transform::from_xyz(0.0, 0.0, 0.0);
    let camera = app
        .world_mut()
        .spawn((
            bevy_frustum(&transform),
            GlobalTransform::from(transform),
            FollowBevyFrustum::<Enemy>::for_layer().with_mode(CullMode::Exact),
            FollowBevyFrustum::default(),
        ))
        .id();
    app.update();
    let world = app.world();
    let enemies = world.get::<VisibleEntityList<Enemy>>(camera).unwrap();
    assert_eq!(enemies.entities(), &[enemy]);
    let layer_camera = world.get::<CullingCamera<Enemy>>(camera).unwrap();
    assert_eq!(layer_camera.mode, CullMode::Exact);
    let all = world.get::<VisibleEntityList>(camera).unwrap();
    let mut both = vec![enemy, crate_box];
    both.sort_unstable();
    assert_eq!(all.entities(), both.as_slice());
}

/// Following for a layer nobody registered is a clear error.
#[test]
#[should_panic(expected = "not registered")]
fn following_for_an_unregistered_layer_is_a_clear_error() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    app.world_mut()
        .spawn(FollowBevyFrustum::<Enemy>::for_layer());
}

/// The warnings logged while the test runs, kept to be read back.
struct CapturedWarnings;

static WARNINGS: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

impl log::Log for CapturedWarnings {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        metadata.level() <= log::Level::Warn
    }
    fn log(&self, record: &log::Record) {
        if self.enabled(record.metadata()) {
            WARNINGS.lock().unwrap().push(record.args().to_string());
        }
    }
    fn flush(&self) {}
}

/// Installs the capturing logger, once for the whole test binary.
fn capture_warnings() {
    static INSTALL: std::sync::Once = std::sync::Once::new();
    INSTALL.call_once(|| {
        log::set_logger(&CapturedWarnings).expect("no other logger in this test binary");
        log::set_max_level(log::LevelFilter::Warn);
    });
}

/// The warnings so far that name `entity` and speak of `topic` (the log is
/// the whole test binary's, and two tests' Apps may number entities alike).
fn warnings_about(entity: bevy_ecs::entity::Entity, topic: &str) -> usize {
    let name = format!("{entity}:");
    let all = WARNINGS.lock().unwrap();
    all.iter()
        .filter(|w| w.starts_with(&name) && w.contains(topic))
        .count()
}

/// With the index in `Update`, before Bevy's first frustum update, a new
/// camera's Bevy frustum is still the default one: it gets its culling
/// camera once Bevy has computed a frustum, with no warning meanwhile. A
/// frustum that is not finite keeps the last culling frustum, is counted
/// every frame it stays so and warned about each time it becomes so.
#[test]
fn a_camera_waits_for_its_first_bevy_frustum_without_a_warning() {
    use bevy_ecs::schedule::ScheduleLabel;
    capture_warnings();
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin {
        schedule: Update.intern(),
        ..SpatialIndexPlugin::default()
    });
    let transform = Transform::from_xyz(0.0, 2.0, 10.0);
    let camera = app
        .world_mut()
        .spawn((
            BevyFrustum::default(),
            GlobalTransform::from(transform),
            FollowBevyFrustum::default(),
        ))
        .id();
    app.update();
    assert!(app.world().get::<CullingCamera>(camera).is_none());
    assert_eq!(
        warnings_about(camera, "Bevy frustum"),
        0,
        "no warning before Bevy's frustum"
    );
    *app.world_mut().get_mut::<BevyFrustum>(camera).unwrap() = bevy_frustum(&transform);
    app.update();
    let followed = app
        .world()
        .get::<CullingCamera>(camera)
        .expect("following now");
    let expected =
        bevy_rtree::Frustum::from_bevy(&bevy_frustum(&transform), transform.translation).unwrap();
    assert_eq!(followed.frustum, expected);
    assert_eq!(warnings_about(camera, "Bevy frustum"), 0);
    // Not finite: warned about once, counted every frame it stays so
    // (written again or not), the last frustum kept.
    let broken = bevy_frustum(&Transform::from_xyz(f32::NAN, 2.0, 10.0));
    let refused_now = |app: &App| app.world().resource::<SpatialDiagnostics>().culling.refused;
    for frame in 0..5 {
        if frame < 3 {
            *app.world_mut().get_mut::<BevyFrustum>(camera).unwrap() = broken;
        }
        app.update();
        assert_eq!(refused_now(&app), 1, "counted every frame");
    }
    assert_eq!(warnings_about(camera, "Bevy frustum"), 1);
    let kept = app.world().get::<CullingCamera>(camera).unwrap();
    assert_eq!(kept.frustum, expected);
    // Valid again: nothing counted; refused again: warned about again.
    *app.world_mut().get_mut::<BevyFrustum>(camera).unwrap() = bevy_frustum(&transform);
    app.update();
    assert_eq!(refused_now(&app), 0);
    *app.world_mut().get_mut::<BevyFrustum>(camera).unwrap() = broken;
    app.update();
    assert_eq!(refused_now(&app), 1);
    assert_eq!(warnings_about(camera, "Bevy frustum"), 2);
    // A camera that stops following is no longer counted (another one
    // still following keeps the system running); following again while
    // still refused, it is counted and warned about again.
    let other = app.world_mut().spawn(follower(&transform)).id();
    app.world_mut()
        .entity_mut(camera)
        .remove::<FollowBevyFrustum>();
    app.update();
    assert_eq!(refused_now(&app), 0);
    app.world_mut()
        .entity_mut(camera)
        .insert(FollowBevyFrustum::default());
    app.update();
    assert_eq!(refused_now(&app), 1);
    assert_eq!(warnings_about(camera, "Bevy frustum"), 3);
    // Disabled, it is out of every query and not counted; enabled again
    // with the same refused frustum, it is counted again.
    app.world_mut()
        .entity_mut(camera)
        .insert(bevy_ecs::entity_disabling::Disabled);
    app.update();
    assert_eq!(refused_now(&app), 0);
    app.world_mut()
        .entity_mut(camera)
        .remove::<bevy_ecs::entity_disabling::Disabled>();
    app.update();
    assert_eq!(refused_now(&app), 1);
    assert_eq!(warnings_about(camera, "Bevy frustum"), 3);
    assert!(app.world().get::<CullingCamera>(other).is_some());
}

/// A caster whose ray is refused in world space (its entity scaled to
/// nothing on an axis) is counted in the diagnostics every frame and
/// warned about once; the caster beside it is not.
#[test]
fn a_refused_caster_is_counted_every_frame_and_warned_about_once() {
    use bevy_rtree::{Ray, RayMode, SpatialError};
    capture_warnings();
    let mut app = App::new();
    app.add_plugins((
        bevy_transform::TransformPlugin,
        SpatialIndexPlugin::default(),
    ));
    let ray = Ray::new(Vec3::ZERO, Vec3::X, 10.0).unwrap();
    let flat = app
        .world_mut()
        .spawn((
            RayCaster::new(ray, RayMode::First),
            Transform::from_scale(Vec3::new(0.0, 1.0, 1.0)),
        ))
        .id();
    let fine = app
        .world_mut()
        .spawn((RayCaster::new(ray, RayMode::First), Transform::IDENTITY))
        .id();
    for _ in 0..3 {
        app.update();
        let diagnostics = app.world().resource::<SpatialDiagnostics>();
        assert_eq!(diagnostics.rays.refused, 1);
        assert_eq!(diagnostics.rays.queries, 2);
    }
    let hits = app.world().get::<RayCasterHits>(flat).unwrap();
    assert_eq!(hits.error(), Some(SpatialError::InvalidRay));
    assert_eq!(warnings_about(flat, "RayCaster"), 1);
    assert_eq!(warnings_about(fine, "RayCaster"), 0);
}

/// An entity that stops following (`FollowBevyFrustum` or its `Frustum`
/// removed) loses the culling camera the plugin kept for it, and its list,
/// so no frozen view goes on being culled; a new `Frustum` brings it back.
/// A Bevy `Camera` with `is_active: false` is skipped and keeps its list,
/// as Bevy skips it.
#[test]
fn a_camera_that_stops_following_or_is_inactive_is_not_culled() {
    use bevy_camera::Camera;
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let ahead = Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, -10.0), Vec3::ONE).unwrap();
    let seen = app.world_mut().spawn(SpatialBounds(ahead)).id();
    let transform = Transform::default();
    let follow = |world: &mut bevy_ecs::world::World| world.spawn(follower(&transform)).id();
    let culled = |app: &App| app.world().resource::<SpatialDiagnostics>().culling.queries;

    let stops = follow(app.world_mut());
    let loses_frustum = follow(app.world_mut());
    app.update();
    assert_eq!(culled(&app), 2);
    for camera in [stops, loses_frustum] {
        let list = app.world().get::<VisibleEntityList>(camera).unwrap();
        assert_eq!(list.entities(), [seen]);
    }
    app.world_mut()
        .entity_mut(stops)
        .remove::<FollowBevyFrustum>();
    app.world_mut()
        .entity_mut(loses_frustum)
        .remove::<BevyFrustum>();
    app.update();
    for camera in [stops, loses_frustum] {
        let entity = app.world().entity(camera);
        assert!(!entity.contains::<CullingCamera>() && !entity.contains::<VisibleEntityList>());
    }
    assert_eq!(culled(&app), 0);
    app.world_mut()
        .entity_mut(loses_frustum)
        .insert(bevy_frustum(&transform));
    app.update();
    assert_eq!(culled(&app), 1);
    let list = app.world().get::<VisibleEntityList>(loses_frustum).unwrap();
    assert_eq!(list.entities(), [seen]);

    // Inactive: not culled, the last list kept while the scene changes.
    app.world_mut().entity_mut(loses_frustum).insert(Camera {
        is_active: false,
        ..Camera::default()
    });
    app.world_mut().despawn(seen);
    app.update();
    assert_eq!(culled(&app), 0);
    let list = app.world().get::<VisibleEntityList>(loses_frustum).unwrap();
    assert_eq!(list.entities(), [seen]);
    app.world_mut()
        .get_mut::<Camera>(loses_frustum)
        .unwrap()
        .is_active = true;
    app.update();
    assert_eq!(culled(&app), 1);
    let list = app.world().get::<VisibleEntityList>(loses_frustum).unwrap();
    assert!(list.entities().is_empty());
}

/// A Bevy camera with an infinite far plane (`far: f32::INFINITY`, which
/// Bevy stores as a plane of infinite or NaN offset and never culls with)
/// is followed, looking along an axis or turned, and sees a box a
/// thousand kilometres ahead, as the oracle does. A camera at a NaN
/// position is still refused.
#[test]
fn a_bevy_camera_with_an_infinite_far_plane_is_followed() {
    let projection = PerspectiveProjection {
        far: f32::INFINITY,
        ..PerspectiveProjection::default()
    };
    // Bevy's frustum of a camera at a NaN position, its far plane finite
    // or infinite: refused.
    for far in [120.0, f32::INFINITY] {
        let nan_at = Transform::from_xyz(f32::NAN, 2.0, 10.0);
        let broken = PerspectiveProjection {
            far,
            ..PerspectiveProjection::default()
        }
        .compute_frustum(&GlobalTransform::from(nan_at));
        assert!(bevy_rtree::Frustum::from_bevy(&broken, Vec3::ZERO).is_err());
    }
    // A NaN far distance gives a far plane of NaN offset, as an infinite
    // one does along an axis; turned, its normal has no zero and it can be
    // told apart: refused, not taken for no far plane.
    let turned = Transform::from_rotation(Quat::from_euler(glam::EulerRot::YXZ, 0.7, 0.35, 0.0));
    let nan_far = PerspectiveProjection {
        far: f32::NAN,
        ..PerspectiveProjection::default()
    }
    .compute_frustum(&GlobalTransform::from(turned));
    assert!(nan_far.half_spaces[5].d().is_nan());
    assert!(bevy_rtree::Frustum::from_bevy(&nan_far, Vec3::ZERO).is_err());

    for turn in [0.0, 0.7] {
        let mut app = App::new();
        app.add_plugins(SpatialIndexPlugin::default());
        let transform =
            Transform::from_rotation(Quat::from_euler(glam::EulerRot::YXZ, turn, turn * 0.5, 0.0));
        let ahead = transform.rotation * Vec3::NEG_Z * 1e6;
        let far_box = Aabb::from_center_half_extents(ahead, Vec3::splat(10.0)).unwrap();
        let behind = Aabb::from_center_half_extents(-ahead, Vec3::splat(10.0)).unwrap();
        let seen = app.world_mut().spawn(SpatialBounds(far_box)).id();
        app.world_mut().spawn(SpatialBounds(behind));
        let frustum = projection.compute_frustum(&GlobalTransform::from(transform));
        let far = frustum.half_spaces[5];
        assert!(far.d() == f32::INFINITY || far.d().is_nan(), "{far:?}");
        let camera = app
            .world_mut()
            .spawn((
                frustum,
                GlobalTransform::from(transform),
                FollowBevyFrustum::default(),
            ))
            .id();
        app.update();
        let culling = *app.world().get::<CullingCamera>(camera).expect("followed");
        assert!(culling.frustum.planes()[5].is_inactive());
        let list = app.world().get::<VisibleEntityList>(camera).unwrap();
        assert_eq!(list.entities(), [seen], "turn {turn}");
        let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
        assert_eq!(
            oracle.visible(&culling.frustum, CullMode::Conservative),
            [seen]
        );
    }
}

/// Bevy's box converts to one that contains it: its corners are kept only
/// where they are exactly its centre ± half extents. A centre of 1e-17
/// beside a half extent of 1 has `f32` corners ±1, which miss the true
/// upper corner 1 + 1e-17 (a plain `f64` difference rounds that away).
#[test]
fn bevy_boxes_convert_to_boxes_that_contain_them() {
    let exact = BevyAabb::from_min_max(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.0, 4.0, 3.0));
    let ours = Aabb::try_from(&exact).unwrap();
    assert_eq!(
        ours,
        Aabb::new(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.0, 4.0, 3.0)).unwrap()
    );
    let tiny_centre = BevyAabb {
        center: glam::Vec3A::new(1e-17, 0.0, 0.0),
        half_extents: glam::Vec3A::ONE,
    };
    assert_eq!(tiny_centre.max().x, 1.0, "the f32 corner misses 1 + 1e-17");
    let ours = Aabb::try_from(&tiny_centre).unwrap();
    // The true corners are -1 + 1e-17 and 1 + 1e-17: the upper one is
    // above 1, so the box must reach past 1.
    assert!(ours.max.x > 1.0, "{ours:?}");
    assert!(ours.min.x <= -1.0 + 1e-17, "{ours:?}");
    // Exact corners at `MAX_COORD` itself are a valid box; rounded outward
    // they would pass the bound.
    let edge = bevy_rtree::MAX_COORD;
    let widest = BevyAabb {
        center: glam::Vec3A::ZERO,
        half_extents: glam::Vec3A::splat(edge),
    };
    assert_eq!(
        Aabb::try_from(&widest),
        Aabb::new(Vec3::splat(-edge), Vec3::splat(edge))
    );
    // Past it, refused.
    let wider = BevyAabb {
        center: glam::Vec3A::ZERO,
        half_extents: glam::Vec3A::splat(edge * 1.01),
    };
    assert!(Aabb::try_from(&wider).is_err());
    // A negative half extent (exact corners, min above max) or a NaN one:
    // refused.
    for half in [
        glam::Vec3A::new(1.0, -1.0, 1.0),
        glam::Vec3A::new(1.0, f32::NAN, 1.0),
    ] {
        let inverted = BevyAabb {
            center: glam::Vec3A::ONE,
            half_extents: half,
        };
        assert_eq!(Aabb::try_from(&inverted), Err(SpatialError::InvalidBox));
    }
    // A negative zero is a flat box.
    let flat = BevyAabb {
        center: glam::Vec3A::ONE,
        half_extents: glam::Vec3A::new(1.0, -0.0, 1.0),
    };
    assert_eq!(
        Aabb::try_from(&flat),
        Aabb::new(Vec3::new(0.0, 1.0, 0.0), Vec3::new(2.0, 1.0, 2.0))
    );
}
