//! The plugin in the schedule and in the App: no ambiguous pairs of
//! systems, and misuse of layers is a clear error, never silence.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{LogLevel, ScheduleBuildSettings};
use bevy_rtree::prelude::*;

#[derive(Component)]
struct Enemy;
#[derive(Component)]
struct Barrel;

#[test]
fn the_plugin_s_systems_have_no_ambiguities_among_themselves() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_spatial_layer::<Enemy>()
        .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean)
        .add_spatial_join::<Enemy, Enemy>(1.0, JoinMode::Euclidean);
    app.edit_schedule(PostUpdate, |schedule| {
        schedule.set_build_settings(ScheduleBuildSettings {
            ambiguity_detection: LogLevel::Error,
            ..Default::default()
        });
    });
    app.world_mut().spawn((
        SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap()),
        Enemy,
    ));
    app.update();
}

/// With Bevy's transforms and cameras and the index serving Bevy's
/// visibility: no pair of systems in `PostUpdate` (or `First`) is
/// ambiguous.
#[cfg(feature = "bevy_camera")]
#[test]
fn with_bevy_s_cameras_no_system_pair_in_post_update_is_ambiguous() {
    use bevy_asset::Assets;
    use bevy_camera::CameraPlugin;
    use bevy_mesh::Mesh;
    use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
    let mut app = App::new();
    app.add_plugins((bevy_transform::TransformPlugin, CameraPlugin))
        .insert_resource(Assets::<Mesh>::default())
        .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
        .add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin))
        .add_spatial_layer::<Enemy>()
        .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
    ambiguities_are_errors(&mut app);
    app.update();
}

/// Ambiguity detection as an error in `PostUpdate`, where the plugin's
/// systems run, and in `First`, where Bevy's culling is taken out.
#[cfg(feature = "bevy_camera")]
fn ambiguities_are_errors(app: &mut App) {
    use bevy_ecs::schedule::ScheduleLabel;
    for label in [First.intern(), PostUpdate.intern()] {
        app.edit_schedule(label, |schedule| {
            schedule.set_build_settings(ScheduleBuildSettings {
                ambiguity_detection: LogLevel::Error,
                ..Default::default()
            });
        });
    }
}

/// The same with Bevy's lights, whose shadow visibility the index serves
/// too (feature `bevy_light`).
#[cfg(feature = "bevy_light")]
#[test]
fn with_bevy_s_lights_no_system_pair_in_post_update_is_ambiguous() {
    use bevy_asset::{AssetApp, AssetPlugin, Assets};
    use bevy_camera::CameraPlugin;
    use bevy_light::LightPlugin;
    use bevy_mesh::Mesh;
    use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
    let mut app = App::new();
    app.add_plugins((
        TaskPoolPlugin::default(),
        AssetPlugin::default(),
        bevy_transform::TransformPlugin,
        CameraPlugin,
        LightPlugin,
    ))
    .insert_resource(Assets::<Mesh>::default())
    .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
    .init_asset::<bevy_image::Image>()
    .add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    ambiguities_are_errors(&mut app);
    app.finish();
    app.cleanup();
    app.update();
}

#[derive(Component)]
struct Unregistered;

/// A layer registered before the plugin used to add the default plugin
/// silently, and the configured one added next panicked as a duplicate:
/// now the misuse itself is the clear error.
#[test]
#[should_panic(expected = "before SpatialIndexPlugin")]
fn a_layer_before_the_plugin_is_a_clear_error() {
    App::new().add_spatial_layer::<Enemy>();
}

/// A caster or camera of a layer nobody registered used to answer nothing,
/// forever and silently.
#[test]
#[should_panic(expected = "which is not registered")]
fn a_caster_of_an_unregistered_layer_is_a_clear_error() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let ray = Ray::new(Vec3::ZERO, Vec3::X, 10.0).unwrap();
    app.world_mut()
        .spawn(RayCaster::<Unregistered>::for_layer(ray, RayMode::First));
}

#[test]
#[should_panic(expected = "which is not registered")]
fn a_camera_of_an_unregistered_layer_is_a_clear_error() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let view = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.0, 0.1, 10.0).unwrap();
    app.world_mut()
        .spawn(CullingCamera::<Unregistered>::for_layer(view));
}

/// What a system in `Update` counted through `SpatialQuery`.
#[derive(Resource, Default)]
struct SeenInUpdate(Vec<usize>);

/// The first frame's `Update` used to query an empty index: the boxes of
/// entities spawned at startup were only indexed in that frame's
/// `PostUpdate`. Now they are indexed in `PostStartup` (after Bevy's
/// startup transform propagation, with the feature `bevy`).
#[test]
fn a_query_in_the_first_update_sees_the_entities_spawned_at_startup() {
    let mut app = App::new();
    #[cfg(feature = "bevy")]
    app.add_plugins(bevy_transform::TransformPlugin);
    app.add_plugins(SpatialIndexPlugin::default())
        .add_spatial_layer::<Enemy>()
        .init_resource::<SeenInUpdate>()
        .add_systems(Startup, |mut commands: Commands| {
            let unit = Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap();
            commands.spawn(SpatialBounds(unit));
            commands.spawn((SpatialBounds(unit), Enemy));
            #[cfg(feature = "bevy")]
            commands.spawn((
                LocalBounds(unit),
                bevy_transform::prelude::Transform::from_xyz(0.5, 0.0, 0.0),
            ));
        })
        .add_systems(
            Update,
            |mut all: SpatialQuery,
             mut enemies: SpatialQuery<Enemy>,
             mut seen: ResMut<SeenInUpdate>| {
                let around = Aabb::new(Vec3::splat(-1.0), Vec3::splat(2.0)).unwrap();
                let none = SpatialQueryFilter::default();
                let mut found = Vec::new();
                all.overlapping(&around, &none, &mut found);
                seen.0.push(found.len());
                found.clear();
                enemies.overlapping(&around, &none, &mut found);
                seen.0.push(found.len());
            },
        );
    app.update();
    let expected_all = if cfg!(feature = "bevy") { 3 } else { 2 };
    assert_eq!(app.world().resource::<SeenInUpdate>().0, [expected_all, 1]);
    // Later frames see them too, and nothing twice.
    app.update();
    assert_eq!(
        app.world().resource::<SeenInUpdate>().0[2..],
        [expected_all, 1]
    );
    app.world().resource::<SpatialIndex>().validate().unwrap();
}

/// The sync in `PostStartup` and the one in `PostUpdate` are two systems
/// of one index: the first frame's starts where the startup one ended, so
/// the startup boxes are neither applied again as moves nor an invalid one
/// counted twice; a box changed in the first frame's `Update` is still seen.
#[test]
fn the_first_frame_does_not_sync_the_startup_boxes_again() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_spatial_layer::<Enemy>()
        .add_systems(Startup, |mut commands: Commands| {
            let unit = Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap();
            for i in 0..50 {
                let at = Vec3::X * i as f32;
                commands.spawn(SpatialBounds(Aabb::new(at, at + Vec3::ONE).unwrap()));
            }
            commands.spawn((SpatialBounds(unit), Enemy));
            // A box that is wrong (not the default placeholder): counted.
            commands.spawn(SpatialBounds(Aabb {
                min: Vec3::NAN,
                max: Vec3::NAN,
            }));
        });
    #[derive(Resource)]
    struct Moved(Option<Entity>);
    app.insert_resource(Moved(None)).add_systems(
        Update,
        |mut moved: ResMut<Moved>,
         mut enemies: Query<(Entity, &mut SpatialBounds), With<Enemy>>| {
            if moved.0.is_none() {
                for (entity, mut bounds) in &mut enemies {
                    bounds.0 =
                        Aabb::new(Vec3::Y * 10.0, Vec3::splat(1.0) + Vec3::Y * 10.0).unwrap();
                    moved.0 = Some(entity);
                }
            }
        },
    );
    app.update();
    let diagnostics = *app.world().resource::<SpatialDiagnostics>();
    assert_eq!(diagnostics.invalid_total, 1, "{diagnostics:?}");
    // The enemy alone, in the main index and in its layer's.
    assert_eq!(
        diagnostics.sync.updated, 2,
        "only the enemy moved: {diagnostics:?}"
    );
    let enemy = app.world().resource::<Moved>().0.unwrap();
    for boxes in [
        app.world().resource::<SpatialIndex>().get(enemy),
        app.world().resource::<SpatialIndex<Enemy>>().get(enemy),
    ] {
        assert_eq!(boxes.unwrap().min.y, 10.0);
    }
    app.world().resource::<SpatialIndex>().validate().unwrap();
    assert_eq!(app.world().resource::<SpatialIndex>().len(), 51);
    app.update();
    let diagnostics = *app.world().resource::<SpatialDiagnostics>();
    assert_eq!(
        (diagnostics.sync.updated, diagnostics.invalid_total),
        (0, 1)
    );
}
