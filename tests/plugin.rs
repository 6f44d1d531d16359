//! Named scenes through the plugin: the lifecycle of an indexed entity
//! (spawn, move, despawn, handles, opting out, disabling) and its layers.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::{Aabb, JoinMode, Ray, RayMode};
use glam::Vec3;

mod common;
use common::plugin_scene::*;

/// A handle copied onto another entity (by hand, or by cloning the
/// entity) names the first entity's entry: the second entity's moves must
/// not move that entry, and the second entity gets an entry of its own.
#[test]
fn a_handle_copied_to_another_entity_moves_only_its_own_entity() {
    let mut app = app();
    let a = app.world_mut().spawn(unit_at(0.0)).id();
    app.update();
    let handle = *app.world().get::<SpatialHandle>(a).unwrap();
    assert!(handle.id().is_some());
    let b = app.world_mut().spawn((unit_at(40.0), handle)).id();
    app.update();
    assert_eq!(indexed(&app), sorted([a, b]));
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.get(a), Some(unit_at(0.0).0));
    assert_eq!(index.get(b), Some(unit_at(40.0).0));
    // B's own handle now, and each entity moves its own entry.
    let b_handle = *app.world().get::<SpatialHandle>(b).unwrap();
    assert_ne!(b_handle, handle);
    app.world_mut().entity_mut(b).insert(handle);
    app.world_mut().get_mut::<SpatialBounds>(b).unwrap().0 = unit_at(80.0).0;
    app.update();
    assert_eq!(indexed(&app), sorted([a, b]));
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.get(a), Some(unit_at(0.0).0));
    assert_eq!(index.get(b), Some(unit_at(80.0).0));
    assert_eq!(diagnostics(&app).sync.updated, 1);
}

#[test]
fn spawn_move_despawn_and_respawn_follow_the_entity() {
    let mut app = app();
    let a = app.world_mut().spawn(unit_at(0.0)).id();
    app.update();
    assert_eq!(indexed(&app), [a]);
    assert_eq!(diagnostics(&app).sync.inserted, 1);

    app.world_mut().get_mut::<SpatialBounds>(a).unwrap().0 =
        Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0)).unwrap();
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(
        index.get(a),
        Some(Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0)).unwrap())
    );
    assert_eq!(diagnostics(&app).sync.updated, 1);

    // Unchanged entities do not touch the index.
    app.update();
    let d = diagnostics(&app);
    assert_eq!((d.sync.inserted, d.sync.updated, d.sync.removed), (0, 0, 0));

    // Despawn enough entities that their slots come back (the allocator
    // frees in blocks), then respawn: new generations, same slots.
    let mut old: Vec<Entity> = (0..600)
        .map(|i| app.world_mut().spawn(unit_at(i as f32)).id())
        .collect();
    old.push(a);
    app.update();
    for &e in &old {
        app.world_mut().despawn(e);
    }
    app.update();
    assert_eq!(indexed(&app), []);
    let mut new: Vec<Entity> = (0..600)
        .map(|i| app.world_mut().spawn(unit_at(i as f32)).id())
        .collect();
    let reused = new
        .iter()
        .filter(|n| old.iter().any(|o| o.index() == n.index()))
        .count();
    assert!(reused > 0, "some slots are reused");
    app.update();
    new.sort_unstable();
    assert_eq!(indexed(&app), new);
    let index = app.world().resource::<SpatialIndex>();
    assert!(old.iter().all(|&o| !index.contains(o)));
    assert!(!app.world().resource::<SpatialIndex>().contains(a));
}

#[test]
fn removing_the_component_takes_the_entity_out_before_the_next_query() {
    let mut app = app();
    let a = app.world_mut().spawn(unit_at(0.0)).id();
    app.update();
    app.world_mut().entity_mut(a).remove::<SpatialBounds>();
    // Out at once, not at the next sync.
    assert!(!app.world().resource::<SpatialIndex>().contains(a));
    app.update();
    assert_eq!(indexed(&app), []);
}

#[test]
fn opting_out_and_back_in() {
    let mut app = app();
    let a = app.world_mut().spawn(unit_at(0.0)).id();
    app.update();
    app.world_mut().entity_mut(a).insert(NoSpatialIndex);
    app.update();
    assert_eq!(indexed(&app), []);
    app.world_mut().entity_mut(a).remove::<NoSpatialIndex>();
    app.update();
    assert_eq!(indexed(&app), [a]);
    // Spawned opted out: never indexed.
    let b = app.world_mut().spawn((unit_at(3.0), NoSpatialIndex)).id();
    app.update();
    assert_eq!(indexed(&app), [a]);
    app.world_mut().entity_mut(b).remove::<NoSpatialIndex>();
    app.update();
    assert_eq!(indexed(&app), sorted([a, b]));
}

/// Bevy's `Disabled` takes an entity out of every index at once, as it
/// takes it out of every query, and enabling it puts it back on the next
/// update; an entity spawned disabled is indexed once enabled.
#[test]
fn disabled_entities_leave_every_index_and_come_back_enabled() {
    use bevy_ecs::entity_disabling::Disabled;
    let mut app = app();
    app.add_spatial_layer::<Enemy>();
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let other = app.world_mut().spawn(unit_at(2.0)).id();
    app.update();
    assert_eq!(indexed(&app), sorted([enemy, other]));
    app.world_mut().entity_mut(enemy).insert(Disabled);
    assert_eq!(indexed(&app), [other], "leaving is immediate");
    assert_eq!(indexed_in::<Enemy>(&app), []);
    app.update();
    assert_eq!(indexed(&app), [other], "a sync does not bring it back");
    app.world_mut().entity_mut(enemy).remove::<Disabled>();
    app.update();
    assert_eq!(indexed(&app), sorted([enemy, other]));
    assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
    let asleep = app.world_mut().spawn((unit_at(4.0), Enemy, Disabled)).id();
    app.update();
    assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
    app.world_mut().entity_mut(asleep).remove::<Disabled>();
    app.update();
    assert_eq!(indexed_in::<Enemy>(&app), sorted([enemy, asleep]));
}

/// An app that takes `Disabled` out of Bevy's query filters
/// (`DefaultQueryFilters::empty()`, before its first update) sees disabled
/// entities in every query: so do the indexes, whose answers stay those of
/// a query over the entities' boxes, whether or not a box changed while
/// disabled.
#[test]
fn disabled_entities_stay_where_the_app_s_queries_see_them() {
    use bevy_ecs::entity_disabling::{DefaultQueryFilters, Disabled};
    let mut app = app();
    app.add_spatial_layer::<Enemy>()
        .insert_resource(DefaultQueryFilters::empty());
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let other = app.world_mut().spawn(unit_at(2.0)).id();
    app.update();
    // What Bevy's queries see, to compare the indexes with.
    let seen = |app: &mut App| {
        let world = app.world_mut();
        let mut boxes = world.query::<(Entity, &SpatialBounds)>();
        let mut seen: Vec<(Entity, Aabb)> = boxes.iter(world).map(|(e, b)| (e, b.0)).collect();
        seen.sort_unstable_by_key(|s| s.0);
        seen
    };
    let in_index = |app: &App| {
        let index = app.world().resource::<SpatialIndex<SpatialBounds>>();
        let mut held: Vec<(Entity, Aabb)> = index.tree().iter().map(|(_, e, b)| (e, b)).collect();
        held.sort_unstable_by_key(|s| s.0);
        held
    };
    app.world_mut().entity_mut(enemy).insert(Disabled);
    app.update();
    assert_eq!(seen(&mut app).len(), 2, "Bevy's queries still see it");
    assert_eq!(in_index(&app), seen(&mut app));
    assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
    app.world_mut().entity_mut(enemy).insert(unit_at(5.0));
    app.update();
    assert_eq!(in_index(&app), seen(&mut app));
    app.world_mut().entity_mut(enemy).remove::<Disabled>();
    app.update();
    assert_eq!(in_index(&app), seen(&mut app));
    assert_eq!(indexed(&app), sorted([enemy, other]));
}

/// Disabling components of the app's own, registered in the first frame's
/// `Update`, after the startup sync indexed the entities (Bevy's queries
/// leave them out where the query is first used after that, as the
/// plugin's `PostUpdate` ones are): an entity that already carried one
/// leaves the indexes before that frame's sync and queries, one that gains
/// one leaves at once, and losing it puts the entity back with the box it
/// has then. With a table-stored component alone the syncs read table by
/// table; a sparse one registered too makes every query row by row.
#[test]
fn an_apps_own_disabling_components_take_entities_out_and_back() {
    #[derive(Component)]
    struct Frozen;
    #[derive(Component)]
    #[component(storage = "SparseSet")]
    struct Asleep;
    for sparse_too in [false, true] {
        let mut app = app();
        app.add_spatial_layer::<Enemy>();
        let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
        let other = app.world_mut().spawn(unit_at(2.0)).id();
        let frozen_early = app.world_mut().spawn((unit_at(4.0), Enemy, Frozen)).id();
        let eye = app.world_mut().spawn(camera()).id();
        app.add_systems(Update, move |world: &mut World, mut done: Local<bool>| {
            if !*done {
                assert!(world.resource::<SpatialIndex>().contains(frozen_early));
                world.register_disabling_component::<Frozen>();
                if sparse_too {
                    world.register_disabling_component::<Asleep>();
                }
                *done = true;
            }
        });
        app.update();
        assert_eq!(indexed(&app), sorted([enemy, other]), "already frozen");
        assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
        let mut seen = app
            .world()
            .get::<VisibleEntityList>(eye)
            .unwrap()
            .entities()
            .to_vec();
        seen.sort_unstable();
        assert_eq!(
            seen,
            sorted([enemy, other]),
            "not seen in the frame it froze"
        );

        for (i, sleeper) in [enemy, other].into_iter().enumerate() {
            let sparse = sparse_too && i == 1;
            let in_layer = sleeper == enemy;
            if sparse {
                app.world_mut().entity_mut(sleeper).insert(Asleep);
            } else {
                app.world_mut().entity_mut(sleeper).insert(Frozen);
            }
            let awake = if in_layer { other } else { enemy };
            assert_eq!(indexed(&app), [awake], "leaving is immediate");
            if in_layer {
                assert_eq!(indexed_in::<Enemy>(&app), []);
            }
            // It moves while disabled; no sync sees it.
            let moved = unit_at(10.0 + i as f32);
            *app.world_mut().get_mut::<SpatialBounds>(sleeper).unwrap() = moved;
            app.update();
            assert_eq!(indexed(&app), [awake], "a sync does not bring it back");
            if sparse {
                app.world_mut().entity_mut(sleeper).remove::<Asleep>();
            } else {
                app.world_mut().entity_mut(sleeper).remove::<Frozen>();
            }
            app.update();
            assert_eq!(indexed(&app), sorted([enemy, other]));
            let index = app.world().resource::<SpatialIndex>();
            assert_eq!(index.get(sleeper), Some(moved.0), "back with its box now");
            assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
        }
        if sparse_too {
            // Both at once: back only when neither is left.
            app.world_mut().entity_mut(enemy).insert((Frozen, Asleep));
            app.world_mut().entity_mut(enemy).remove::<Frozen>();
            app.update();
            assert_eq!(indexed(&app), [other]);
            app.world_mut().entity_mut(enemy).remove::<Asleep>();
            app.update();
            assert_eq!(indexed(&app), sorted([enemy, other]));
            assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
        }
    }
}

#[test]
fn layers_hold_only_their_marked_entities() {
    let mut app = app();
    app.add_spatial_layer::<Enemy>();
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let other = app.world_mut().spawn(unit_at(2.0)).id();
    app.update();
    assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
    assert_eq!(indexed(&app), sorted([enemy, other]));

    app.world_mut().entity_mut(other).insert(Enemy);
    app.update();
    assert_eq!(indexed_in::<Enemy>(&app), sorted([enemy, other]));

    app.world_mut().entity_mut(enemy).remove::<Enemy>();
    assert_eq!(
        indexed_in::<Enemy>(&app),
        [other],
        "leaving a layer is immediate"
    );
    app.update();
    assert_eq!(indexed(&app), sorted([enemy, other]));

    // A layer-limited caster sees only its layer.
    let ray = Ray::new(Vec3::new(-5.0, 0.5, 0.5), Vec3::X, 100.0).unwrap();
    let caster = app
        .world_mut()
        .spawn(RayCaster::<Enemy>::for_layer(ray, RayMode::First))
        .id();
    app.update();
    let hits = app.world().get::<RayCasterHits<Enemy>>(caster).unwrap();
    assert_eq!(hits.first().map(|h| h.key), Some(other));
}

/// Contract S9 through the plugin: the join's pairs and a caster's hits
/// are the frame's, kept until their next run, while the index forgets a
/// despawned entity at once.
#[test]
fn a_despawned_entity_leaves_the_index_at_once_and_the_kept_answers_at_the_next_run() {
    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let barrel = app.world_mut().spawn((unit_at(2.0), Barrel)).id();
    let ray = Ray::new(Vec3::new(10.0, 0.5, 0.5), Vec3::NEG_X, 100.0).unwrap();
    let caster = app
        .world_mut()
        .spawn(RayCaster::new(ray, RayMode::First))
        .id();
    app.update();
    let first = |app: &App| app.world().get::<RayCasterHits>(caster).unwrap().first();
    assert_eq!(first(&app).map(|h| h.key), Some(barrel));
    app.world_mut().despawn(barrel);
    let barrels = app.world().resource::<SpatialIndex<Barrel>>();
    assert_eq!(barrels.get(barrel), None);
    assert!(barrels.is_empty());
    assert_eq!(app.world().resource::<SpatialIndex>().get(barrel), None);
    let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
    assert_eq!(join.pairs(), [(enemy, barrel)], "the frame's answer");
    assert_eq!(first(&app).map(|h| h.key), Some(barrel), "the frame's hit");
    app.update();
    let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
    assert!(join.pairs().is_empty());
    assert_eq!(first(&app).map(|h| h.key), Some(enemy));
}

/// `SpatialHandle` is a component like any other: an app can remove it
/// while the entity keeps its box. The entity must go on following its box
/// in the main index (and leave it when despawned), disabled or not when
/// the handle went.
#[test]
fn an_entity_that_loses_its_handle_still_follows_its_box() {
    use bevy_ecs::entity_disabling::Disabled;
    let mut app = app();
    let mover = app.world_mut().spawn(unit_at(0.0)).id();
    let sleeper = app.world_mut().spawn(unit_at(10.0)).id();
    app.update();
    app.world_mut().entity_mut(mover).remove::<SpatialHandle>();
    app.world_mut().entity_mut(sleeper).insert(Disabled);
    app.world_mut()
        .entity_mut(sleeper)
        .remove::<SpatialHandle>();
    app.world_mut().get_mut::<SpatialBounds>(mover).unwrap().0 = unit_at(50.0).0;
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.get(mover), Some(unit_at(50.0).0));
    assert_eq!(indexed(&app), vec![mover]);
    let handle = app.world().get::<SpatialHandle>(mover).and_then(|h| h.id());
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.tree().get(handle.unwrap()).unwrap().0, mover);

    app.world_mut().entity_mut(sleeper).remove::<Disabled>();
    app.world_mut().get_mut::<SpatialBounds>(sleeper).unwrap().0 = unit_at(70.0).0;
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.get(sleeper), Some(unit_at(70.0).0));
    app.world_mut().get_mut::<SpatialBounds>(sleeper).unwrap().0 = unit_at(80.0).0;
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    assert_eq!(index.get(sleeper), Some(unit_at(80.0).0));

    app.world_mut().despawn(mover);
    app.update();
    assert_eq!(indexed(&app), vec![sleeper]);
}

/// A removal that takes the box and the handle together (`clear`) leaves
/// the entity without either: the handle is put back only on an entity
/// that keeps its box.
#[test]
fn a_cleared_entity_gets_no_handle_back() {
    let mut app = app();
    let cleared = app.world_mut().spawn(unit_at(0.0)).id();
    let kept = app.world_mut().spawn(unit_at(5.0)).id();
    app.update();
    app.world_mut().entity_mut(cleared).clear();
    app.world_mut().entity_mut(kept).remove::<SpatialHandle>();
    app.update();
    assert!(app.world().get::<SpatialHandle>(cleared).is_none());
    assert!(app.world().get::<SpatialHandle>(kept).is_some());
    assert_eq!(indexed(&app), vec![kept]);
}

/// What changes while an entity is disabled (a layer's marker added, its
/// opt-out removed) holds once it is enabled again, and nothing of it is
/// indexed before.
#[test]
fn changes_made_while_disabled_hold_once_enabled() {
    use bevy_ecs::entity_disabling::Disabled;
    let mut app = app();
    app.add_spatial_layer::<Enemy>();
    let marked = app.world_mut().spawn(unit_at(0.0)).id();
    let opted_out = app.world_mut().spawn((unit_at(3.0), NoSpatialIndex)).id();
    app.update();
    assert_eq!(indexed(&app), [marked]);
    for entity in [marked, opted_out] {
        app.world_mut().entity_mut(entity).insert(Disabled);
    }
    app.update();
    app.world_mut().entity_mut(marked).insert(Enemy);
    app.world_mut()
        .entity_mut(opted_out)
        .remove::<NoSpatialIndex>();
    app.update();
    assert_eq!(indexed(&app), []);
    assert_eq!(indexed_in::<Enemy>(&app), []);
    for entity in [marked, opted_out] {
        app.world_mut().entity_mut(entity).remove::<Disabled>();
    }
    app.update();
    assert_eq!(indexed(&app), sorted([marked, opted_out]));
    assert_eq!(indexed_in::<Enemy>(&app), [marked]);
}

/// An entity moved from one layer to another by a system's commands
/// leaves the first layer's index and joins the second's in that frame,
/// and the join between the layers pairs it by its new layer.
#[test]
fn an_entity_moved_between_layers_by_commands_is_paired_by_its_new_layer() {
    #[derive(Resource)]
    struct Moving(Entity);
    fn to_barrels(moving: Res<Moving>, mut commands: Commands) {
        commands.entity(moving.0).remove::<Enemy>().insert(Barrel);
    }
    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(1.0, JoinMode::Euclidean);
    let moving = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let barrel = app.world_mut().spawn((unit_at(0.5), Barrel)).id();
    let enemy = app.world_mut().spawn((unit_at(1.0), Enemy)).id();
    app.update();
    let pairs = |app: &App| {
        app.world()
            .resource::<SpatialJoin<Enemy, Barrel>>()
            .pairs()
            .to_vec()
    };
    let mut expected = vec![(moving, barrel), (enemy, barrel)];
    expected.sort_unstable();
    assert_eq!(pairs(&app), expected);
    app.insert_resource(Moving(moving));
    app.add_systems(Update, to_barrels.run_if(run_once));
    app.update();
    assert_eq!(indexed_in::<Enemy>(&app), [enemy]);
    assert_eq!(indexed_in::<Barrel>(&app), sorted([moving, barrel]));
    let mut expected = vec![(enemy, barrel), (enemy, moving)];
    expected.sort_unstable();
    assert_eq!(pairs(&app), expected);
}

/// A culling camera removed and inserted again in one flush of commands
/// keeps its list, and answers in that frame.
#[test]
fn a_camera_removed_and_inserted_again_in_one_flush_keeps_its_list() {
    #[derive(Resource)]
    struct Again(Entity);
    fn insert_again(again: Res<Again>, mut commands: Commands) {
        commands
            .entity(again.0)
            .remove::<CullingCamera>()
            .insert(camera());
    }
    let mut app = app();
    let seen = app.world_mut().spawn(unit_at(0.0)).id();
    let cam = app.world_mut().spawn(camera()).id();
    app.update();
    let listed = |app: &App| {
        let list = app.world().get::<VisibleEntityList>(cam);
        list.map(|l| l.entities().to_vec())
    };
    assert_eq!(listed(&app), Some(vec![seen]));
    app.insert_resource(Again(cam));
    app.add_systems(Update, insert_again.run_if(run_once));
    app.update();
    assert_eq!(listed(&app), Some(vec![seen]));
}

/// A disabled caster casts no ray and a disabled camera culls nothing:
/// no run of either is counted.
#[test]
fn disabled_casters_and_cameras_count_no_run() {
    use bevy_ecs::entity_disabling::Disabled;
    let mut app = app();
    app.world_mut().spawn(unit_at(3.0));
    let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0).unwrap();
    let caster = RayCaster::new(ray, RayMode::First);
    app.world_mut().spawn((caster.clone(), Disabled));
    app.world_mut().spawn((camera(), Disabled));
    app.update();
    app.update();
    let counted = diagnostics(&app);
    assert_eq!((counted.culling.runs, counted.culling.queries), (0, 0));
    assert_eq!((counted.rays.runs, counted.rays.queries), (0, 0));
    // Enabled, both run.
    app.world_mut().spawn(caster);
    app.world_mut().spawn(camera());
    app.update();
    let counted = diagnostics(&app);
    assert!(counted.culling.runs > 0 && counted.rays.runs > 0);
}
