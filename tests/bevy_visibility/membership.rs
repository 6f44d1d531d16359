//! Entities that join the set Bevy culls late, or not through the handle:
//! spawned before the plugin, given their visibility after their box,
//! asleep under a disabling component.

use super::*;

/// Entities spawned before the plugin is added (so without the component
/// that keeps their index handle) are indexed and decided as Bevy decides.
#[test]
fn entities_spawned_before_the_plugin_are_served_too() {
    let mut apps = [app(false), app(false)];
    let mut entities = [Vec::new(), Vec::new()];
    for (app, spawned) in apps.iter_mut().zip(&mut entities) {
        let mut rng = SceneRng::new(3);
        for _ in 0..500 {
            let entity = app
                .world_mut()
                .spawn((
                    Mesh3d::default(),
                    random_aabb(&mut rng),
                    random_transform(&mut rng, 50.0, (-5.0, 30.0)),
                ))
                .id();
            spawned.push(entity);
        }
        app.world_mut()
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 5.0, 60.0)));
    }
    apps[1].add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    for frame in 0..3 {
        for app in &mut apps {
            app.update();
        }
        let seen = |app: &App, list: &[Entity]| -> Vec<bool> {
            list.iter()
                .map(|&e| app.world().get::<ViewVisibility>(e).unwrap().get())
                .collect()
        };
        let (bevy, ours) = (seen(&apps[0], &entities[0]), seen(&apps[1], &entities[1]));
        assert_eq!(bevy, ours, "frame {frame}");
        assert!(bevy.iter().any(|&v| v) && !bevy.iter().all(|&v| v));
    }
    let index = apps[1].world().resource::<SpatialIndex<Renderable>>();
    assert_eq!(index.len(), 500);
}

/// A disabling component stored in a sparse set, registered in both Apps
/// after their plugins (as a plugin added later would; taking Bevy's
/// culling out when the plugin was built used to initialize `PostUpdate`
/// first, so that none of its queries left such entities out), makes
/// every query sparse, so no query of the plugin can be read table by
/// table: it goes row by row through Bevy's iteration, with the same
/// answers. Entities fall asleep (that component) and wake, and are
/// disabled (Bevy's `Disabled`) and enabled, every frame; neither side sees
/// them meanwhile. The scenes take both ways of deciding candidates (a
/// pass over every entity, and look-ups), on one thread and on several.
#[test]
fn a_sparse_disabling_component_changes_no_answer() {
    #[derive(Component)]
    #[component(storage = "SparseSet")]
    struct Asleep;
    for (seed, spread, parallel) in [(21, 100.0, true), (22, 100.0, false), (23, 2_000.0, true)] {
        let mut twins = Twins::new(seed);
        twins.spread = spread;
        twins.both(|world, _, _| world.register_disabling_component::<Asleep>());
        twins.ours.insert_resource(BevyVisibilitySettings {
            parallel,
            ..Default::default()
        });
        for _ in 0..3_000 {
            twins.spawn_entity();
        }
        for kind in [0, 1, 2] {
            twins.spawn_camera(kind);
        }
        let mut seen = 0;
        for frame in 0..20 {
            for _ in 0..30 {
                let pair = twins.entities[twins.rng.below(twins.entities.len())];
                let action = twins.rng.below(4);
                twins.both(|world, _, side| {
                    let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                        return;
                    };
                    match action {
                        0 => entity.insert(Asleep),
                        1 => entity.remove::<Asleep>(),
                        2 => entity.insert(Disabled),
                        _ => entity.remove::<Disabled>(),
                    };
                });
            }
            twins.update();
            seen += twins.check(frame);
            // Nothing asleep or disabled is left in the index.
            let world = twins.ours.world();
            let index = world.resource::<SpatialIndex<Renderable>>();
            index.validate().unwrap();
            for (_, entity, _) in index.tree().iter() {
                let held = world.entity(entity);
                assert!(
                    !held.contains::<Asleep>() && !held.contains::<Disabled>(),
                    "frame {frame}: {entity} is indexed while disabled"
                );
            }
            twins.mutate();
        }
        assert!(seen > 200, "seed {seed}: {seen} seen in 20 frames");
    }
}

/// An app that takes `Disabled` out of Bevy's query filters
/// (`DefaultQueryFilters::empty()`, before its first update) has Bevy cull
/// disabled entities as any other: so does the index, which keeps them,
/// their boxes moving while disabled.
#[test]
fn disabled_entities_are_culled_where_the_app_s_queries_see_them() {
    use bevy_ecs::entity_disabling::DefaultQueryFilters;
    let mut twins = Twins::new(24);
    twins.both(|world, _, _| world.insert_resource(DefaultQueryFilters::empty()));
    for _ in 0..2_000 {
        twins.spawn_entity();
    }
    for kind in [0, 2] {
        twins.spawn_camera(kind);
    }
    let mut disabled_and_seen = 0;
    for frame in 0..15 {
        for _ in 0..60 {
            let pair = twins.entities[twins.rng.below(twins.entities.len())];
            let disable = twins.rng.below(3) != 0;
            twins.both(|world, _, side| {
                let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                    return;
                };
                if disable {
                    entity.insert(Disabled);
                } else {
                    entity.remove::<Disabled>();
                }
            });
        }
        twins.update();
        twins.check(frame);
        let world = twins.bevy.world_mut();
        let mut disabled = world.query_filtered::<&ViewVisibility, With<Disabled>>();
        disabled_and_seen += disabled.iter(world).filter(|v| v.get()).count();
        twins.mutate();
    }
    assert!(
        disabled_and_seen > 50,
        "{disabled_and_seen} disabled and seen"
    );
}

/// An entity that gets its visibility components after its box is culled
/// from then on, as Bevy culls it: gaining `InheritedVisibility` and
/// `ViewVisibility` puts an entity into the set Bevy's culling tests as
/// much as gaining a box does. Entities spawned with a box and no
/// visibility get it a few frames later, some lose it and get it back.
#[test]
fn entities_that_get_their_visibility_late_are_culled_as_bevy_culls_them() {
    let mut twins = Twins::new(11);
    for kind in [0, 0, 4] {
        twins.spawn_camera(kind);
    }
    let spread = 60.0;
    for _ in 0..600 {
        let pair = twins.both(|world, rng, _| {
            world
                .spawn((
                    random_transform(rng, spread, (-5.0, 30.0)),
                    random_aabb(rng),
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    let mut visible = 0;
    for frame in 0..12 {
        let entities = twins.entities.clone();
        for (i, pair) in entities.iter().enumerate() {
            twins.both(|world, _, side| {
                let mut entity = world.entity_mut(pair[side]);
                match frame {
                    2 if i % 2 == 0 => {
                        entity.insert(Visibility::Visible);
                    }
                    5 => {
                        entity.insert(Visibility::Inherited);
                    }
                    8 if i % 3 == 0 => {
                        entity.remove::<(Visibility, InheritedVisibility, ViewVisibility)>();
                    }
                    10 if i % 3 == 0 => {
                        entity.insert(Visibility::Visible);
                    }
                    _ => {}
                }
            });
        }
        twins.update();
        visible = twins.check(frame);
    }
    assert!(visible > 0, "the cameras see some of the entities");
}

/// Where entities with a box existed before the plugin, Bevy refuses the
/// handle as a required component of `Aabb`, and no entity gets one: an
/// entity given its visibility after its box is still culled as Bevy culls
/// it (observers stand in for the handle's hook).
#[test]
fn late_visibility_is_seen_where_no_entity_gets_the_handle() {
    let mut apps = [app(false), app(false)];
    let mut late = Vec::new();
    for app in &mut apps {
        app.world_mut().spawn((
            Mesh3d::default(),
            Aabb::from_min_max(Vec3::splat(-40.0), Vec3::splat(-39.0)),
            Transform::default(),
        ));
        app.world_mut()
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 20.0)));
    }
    apps[1].add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    for app in &mut apps {
        app.update();
        let entity = app
            .world_mut()
            .spawn((
                Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                Transform::default(),
                VisibilityClass([TypeId::of::<Mesh3d>()].into()),
            ))
            .id();
        app.update();
        app.world_mut()
            .entity_mut(entity)
            .insert(Visibility::Visible);
        app.update();
        app.update();
        late.push(entity);
    }
    assert!(apps[1].world().get::<RenderableHandle>(late[1]).is_none());
    let seen: Vec<Option<bool>> = apps
        .iter()
        .zip(&late)
        .map(|(app, &e)| app.world().get::<ViewVisibility>(e).map(|v| v.get()))
        .collect();
    assert_eq!(seen, vec![Some(true), Some(true)]);
}

/// A disabling component registered by a `Startup` system (Bevy asks for
/// them before the app starts; its own culling, whose queries are set up
/// at their first run, still leaves such entities out): the index's side
/// leaves them out too, on both ways of deciding candidates.
#[test]
fn a_disabling_component_registered_at_startup_is_respected() {
    #[derive(Component)]
    struct Hidden;
    for (seed, spread) in [(51, 100.0), (52, 2_000.0)] {
        let mut twins = Twins::new(seed);
        twins.spread = spread;
        for app in [&mut twins.bevy, &mut twins.ours] {
            app.add_systems(Startup, |world: &mut World| {
                world.register_disabling_component::<Hidden>();
            });
        }
        for _ in 0..2_000 {
            twins.spawn_entity();
        }
        for kind in [0, 2] {
            twins.spawn_camera(kind);
        }
        for pair in twins.entities.clone().iter().step_by(3) {
            twins.both(|world, _, side| {
                world.entity_mut(pair[side]).insert(Hidden);
            });
        }
        let mut seen = 0;
        for frame in 0..5 {
            twins.update();
            seen += twins.check(frame);
            twins.mutate();
        }
        assert!(seen > 100, "seed {seed}: {seen} seen");
    }
}
