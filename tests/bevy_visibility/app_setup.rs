//! The plugin among the app's other parts: the renderables' layer shared
//! with a join, each camera's lists per visibility class, and the
//! change ticks it writes.

use super::*;

/// The renderables' layer belongs to `BevyVisibilityPlugin`: a join over
/// it, registered after the plugin, shares its one index, and a mesh the
/// app takes out of its own index (`NoSpatialIndex`) stays in the
/// renderables' and is seen as Bevy sees it.
#[test]
fn a_join_over_the_renderables_shares_their_index() {
    use bevy_rtree::JoinMode;
    use bevy_rtree::plugin::{NoSpatialIndex, SpatialAppExt, SpatialJoin};
    let mut bevy = app(false);
    let mut ours = app(true);
    ours.add_spatial_join::<Renderable, Renderable>(1.0, JoinMode::Euclidean);
    let meshes = [&mut bevy, &mut ours].map(|app| {
        let world = app.world_mut();
        world.spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)));
        let spawn = |world: &mut World, x: f32| {
            world
                .spawn((
                    Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                    Transform::from_xyz(x, 0.0, 0.0),
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        };
        [spawn(world, 0.0), spawn(world, 1.5)]
    });
    for frame in 0..3 {
        if frame == 1 {
            for (app, pair) in [&mut bevy, &mut ours].into_iter().zip(&meshes) {
                app.world_mut().entity_mut(pair[0]).insert(NoSpatialIndex);
            }
        }
        bevy.update();
        ours.update();
        let apps = [&bevy, &ours];
        let [seen_by_bevy, seen_by_ours] = [0, 1].map(|side| {
            meshes[side].map(|e| apps[side].world().get::<ViewVisibility>(e).unwrap().get())
        });
        assert_eq!(seen_by_bevy, [true, true], "frame {frame}");
        assert_eq!(seen_by_ours, seen_by_bevy, "frame {frame}");
        let index = ours.world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
        assert_eq!(index.len(), 2, "frame {frame}");
        let join = ours
            .world()
            .resource::<SpatialJoin<Renderable, Renderable>>();
        let (a, b) = (meshes[1][0], meshes[1][1]);
        assert_eq!(
            join.pairs(),
            [(a.min(b), a.max(b))],
            "frame {frame}: the two meshes 0.5 m apart"
        );
    }
}

/// The other order, a join over the renderables before the plugin that
/// fills them, is refused with a message that names the fix.
#[test]
#[should_panic(expected = "add BevyVisibilityPlugin before")]
fn a_renderables_layer_before_the_plugin_is_refused() {
    use bevy_rtree::JoinMode;
    use bevy_rtree::plugin::SpatialAppExt;
    let mut app = App::new();
    app.add_plugins((TransformPlugin, CameraPlugin, SpatialIndexPlugin::default()))
        .add_spatial_join::<Renderable, Renderable>(1.0, JoinMode::Euclidean)
        .add_plugins(BevyVisibilityPlugin);
}

/// Every active camera has a list for every visibility class seen so far,
/// as Bevy's queues give one, empty or not: a camera that sees only
/// layer 1, beside two that see entities of the app's own class on
/// layer 0, has an empty list for that class from the next frame on
/// (extraction sees only the classes a camera has a list for).
#[test]
fn a_camera_has_a_list_for_every_class_seen_so_far() {
    let mut twins = Twins::new(41);
    for (i, layer) in [0, 1, 0].into_iter().enumerate() {
        let pair = twins.both(|world, _, _| {
            let mut camera = world.spawn((
                Camera3d::default(),
                Transform::from_xyz(i as f32 * 5.0, 0.0, 10.0),
            ));
            if layer == 1 {
                camera.insert(RenderLayers::layer(1));
            }
            camera.id()
        });
        twins.cameras.push(pair);
    }
    let pair = twins.both(|world, _, _| {
        world
            .spawn((
                Transform::from_xyz(5.0, 0.0, 0.0),
                Visibility::default(),
                Sphere {
                    center: Vec3A::ZERO,
                    radius: 1.0,
                },
                VisibilityClass([TypeId::of::<AppClass>()].into()),
            ))
            .id()
    });
    twins.entities.push(pair);
    for frame in 0..3 {
        twins.update();
        twins.check(frame);
    }
    let classes = |app: &App, camera: Entity| {
        let lists = app.world().get::<VisibleEntities>(camera).unwrap();
        lists.entities.contains_key(&TypeId::of::<AppClass>())
    };
    let [_, layer_1, _] = twins.cameras.clone().try_into().unwrap();
    assert!(
        classes(&twins.bevy, layer_1[0]),
        "Bevy's lists have the key"
    );
    assert!(classes(&twins.ours, layer_1[1]));
    let ours = twins
        .ours
        .world()
        .get::<VisibleEntities>(layer_1[1])
        .unwrap();
    assert!(ours.get(TypeId::of::<AppClass>()).is_empty());
}

/// An entity whose `Mesh3d` was removed and inserted again names its
/// visibility class twice (Bevy's hook pushes it again), and Bevy lists it
/// twice in the camera's list: so does the index, on both ways of deciding.
#[test]
fn a_class_named_twice_is_listed_twice_as_bevy_lists_it() {
    for spread in [100.0, 2_000.0] {
        let mut twins = Twins::new(31);
        twins.spread = spread;
        for _ in 0..3_000 {
            twins.spawn_entity();
        }
        twins.spawn_camera(0);
        for pair in twins.entities.clone().iter().step_by(3) {
            twins.both(|world, _, side| {
                let mut entity = world.entity_mut(pair[side]);
                if entity.take::<Mesh3d>().is_some() {
                    entity.insert(Mesh3d::default());
                }
            });
        }
        for frame in 0..5 {
            twins.update();
            twins.check(frame);
            twins.mutate();
        }
        let camera = twins.cameras[0][0];
        let list = twins
            .bevy
            .world()
            .get::<VisibleEntities>(camera)
            .unwrap()
            .get(TypeId::of::<Mesh3d>());
        let twice = list.windows(2).filter(|w| w[0] == w[1]).count();
        assert!(twice > 0, "spread {spread}: Bevy lists some entity twice");
    }
}

/// `CulledColumns::set_visible` writes `ViewVisibility`'s change ticks as Bevy's
/// `set_visible` does, which also updates a column's summary tick where the
/// component keeps one: `ViewVisibility` keeps none.
#[test]
fn view_visibility_keeps_no_summary_tick() {
    let mut world = World::new();
    let id = world.register_component::<ViewVisibility>();
    let info = world.components().get_info(id).unwrap();
    assert!(!info.summary_tick());
}

/// Where the app moves an entity (writes its `GlobalTransform`) after
/// transform propagation: ordered before `RenderableSyncSystems`, as its
/// docs ask, the index sees the move in the same frame as Bevy's culling;
/// ordered after it (but before the culling), the index sees it a frame
/// late, the documented difference: that frame the entity is still seen
/// where it was, and from the next frame on both agree.
#[test]
fn a_move_after_the_sync_is_seen_a_frame_late_and_before_it_at_once() {
    use bevy_camera::visibility::VisibilitySystems;
    use bevy_rtree::plugin::RenderableSyncSystems;
    use bevy_transform::TransformSystems;

    #[derive(Resource, Default)]
    struct Away(bool);

    /// Puts every box behind the camera once `Away` is set.
    fn send_away(away: Res<Away>, mut moved: Query<&mut GlobalTransform, With<Aabb>>) {
        if away.0 {
            for mut at in &mut moved {
                *at = GlobalTransform::from_xyz(0.0, 0.0, 50.0);
            }
        }
    }

    for before_the_sync in [true, false] {
        let [mut bevy, mut ours] = [app(false), app(true)];
        let mesh = [&mut bevy, &mut ours].map(|app| {
            let late = send_away
                .after(TransformSystems::Propagate)
                .before(VisibilitySystems::CheckVisibility);
            if before_the_sync {
                app.add_systems(PostUpdate, late.before(RenderableSyncSystems));
            } else {
                app.add_systems(PostUpdate, late.after(RenderableSyncSystems));
            }
            app.init_resource::<Away>();
            let world = app.world_mut();
            world.spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)));
            world
                .spawn((
                    Mesh3d::default(),
                    Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                    Transform::default(),
                ))
                .id()
        });
        let seen = |app: &App, entity| app.world().get::<ViewVisibility>(entity).unwrap().get();
        bevy.update();
        ours.update();
        assert!(seen(&bevy, mesh[0]) && seen(&ours, mesh[1]), "in view");
        for app in [&mut bevy, &mut ours] {
            app.insert_resource(Away(true));
            app.update();
        }
        assert!(!seen(&bevy, mesh[0]), "Bevy culls it at once");
        assert_eq!(
            seen(&ours, mesh[1]),
            !before_the_sync,
            "ordered before the sync: at once; after it: a frame late"
        );
        bevy.update();
        ours.update();
        assert!(
            !seen(&bevy, mesh[0]) && !seen(&ours, mesh[1]),
            "both, a frame on"
        );
    }
}
