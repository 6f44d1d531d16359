//! Named scenes through the plugin: the lifecycle of an indexed entity,
//! layers, bad input on the ECS path, and what runs (or not) each frame.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::{Aabb, CullMode, Frustum, JoinMode, Ray, RayMode, SpatialError};
use glam::{Quat, Vec3};

#[derive(Component)]
struct Enemy;

#[derive(Component)]
struct Barrel;

fn app() -> App {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    app
}

fn unit_at(x: f32) -> SpatialBounds {
    SpatialBounds(Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0)).unwrap())
}

/// The entities the main index holds, sorted, after checking its invariants.
fn indexed(app: &App) -> Vec<Entity> {
    indexed_in::<SpatialBounds>(app)
}

/// The same for the index of layer `L`.
fn indexed_in<L: Component>(app: &App) -> Vec<Entity> {
    let index = app.world().resource::<SpatialIndex<L>>();
    index.validate().expect("index invariants");
    let mut all: Vec<Entity> = index.tree().iter().map(|(_, e, _)| e).collect();
    all.sort_unstable();
    all
}

fn sorted<const N: usize>(mut entities: [Entity; N]) -> [Entity; N] {
    entities.sort_unstable();
    entities
}

fn diagnostics(app: &App) -> SpatialDiagnostics {
    *app.world().resource::<SpatialDiagnostics>()
}

/// Looking down -Z from z = 10 at the unit boxes along x.
fn camera() -> CullingCamera {
    CullingCamera::new(
        Frustum::perspective(
            Vec3::new(0.0, 0.0, 10.0),
            Quat::IDENTITY,
            1.2,
            1.0,
            0.1,
            100.0,
        )
        .unwrap(),
    )
}

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

#[test]
fn invalid_boxes_are_skipped_counted_and_recovered() {
    let mut app = app();
    let good = app.world_mut().spawn(unit_at(0.0)).id();
    let bad = app.world_mut().spawn(unit_at(2.0)).id();
    app.update();
    let nan = Aabb {
        min: Vec3::new(f32::NAN, 0.0, 0.0),
        max: Vec3::ONE,
    };
    let inverted = Aabb {
        min: Vec3::ONE,
        max: Vec3::ZERO,
    };
    for (frame, broken) in [nan, inverted].into_iter().enumerate() {
        app.world_mut().get_mut::<SpatialBounds>(bad).unwrap().0 = broken;
        app.update();
        assert_eq!(
            indexed(&app),
            [good],
            "an entity with an unknown box is found by nothing"
        );
        let d = diagnostics(&app);
        assert_eq!(d.sync.invalid_skipped, 1);
        assert_eq!(d.invalid_total, frame as u64 + 1);
    }
    // A spawn with a bad box never enters.
    let infinite = SpatialBounds(Aabb {
        min: Vec3::ZERO,
        max: Vec3::new(f32::INFINITY, 1.0, 1.0),
    });
    app.world_mut().spawn(infinite);
    app.update();
    assert_eq!(indexed(&app), [good]);
    assert_eq!(diagnostics(&app).invalid_total, 3);

    app.world_mut().get_mut::<SpatialBounds>(bad).unwrap().0 = unit_at(4.0).0;
    app.update();
    assert_eq!(indexed(&app), sorted([good, bad]));
}

#[test]
fn a_scene_without_cameras_casters_or_joins_does_none_of_that_work() {
    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
    for i in 0..100 {
        app.world_mut().spawn((unit_at(i as f32 * 2.0), Enemy));
    }
    for _ in 0..3 {
        app.update();
        let d = diagnostics(&app);
        assert_eq!(d.culling, QueryWork::default());
        assert_eq!(d.rays, QueryWork::default());
        // No barrels: the join has nothing to pair.
        assert_eq!(d.joins, QueryWork::default());
    }
    // A static scene has nothing to maintain either.
    let d = diagnostics(&app);
    assert_eq!(d.maintenance.runs, 0);
    assert_eq!((d.sync.inserted, d.sync.updated), (0, 0));
}

#[test]
fn work_starts_and_stops_with_cameras_casters_and_join_members() {
    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean);
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    app.update();

    let cam = app.world_mut().spawn(camera()).id();
    app.update();
    let d = diagnostics(&app);
    assert_eq!(d.culling.runs, 1);
    assert!(d.culling.nodes_visited > 0);
    assert_eq!(
        app.world()
            .get::<VisibleEntityList>(cam)
            .unwrap()
            .entities(),
        [enemy]
    );
    app.world_mut().despawn(cam);
    app.update();
    assert_eq!(diagnostics(&app).culling.runs, 0);

    let ray = Ray::new(Vec3::new(-5.0, 0.5, 0.5), Vec3::X, 100.0).unwrap();
    let caster = app
        .world_mut()
        .spawn(RayCaster::new(ray, RayMode::Any))
        .id();
    app.update();
    assert_eq!(diagnostics(&app).rays.runs, 1);
    assert!(app.world().get::<RayCasterHits>(caster).unwrap().any());
    app.world_mut().despawn(caster);
    app.update();
    assert_eq!(diagnostics(&app).rays.runs, 0);

    let barrel = app.world_mut().spawn((unit_at(3.0), Barrel)).id();
    app.update();
    assert_eq!(diagnostics(&app).joins.runs, 1);
    assert_eq!(
        app.world().resource::<SpatialJoin<Enemy, Barrel>>().pairs(),
        [(enemy, barrel)]
    );
    // Nothing moved: the pairs stand without recomputing.
    app.update();
    assert_eq!(diagnostics(&app).joins.runs, 0);
    assert_eq!(
        app.world()
            .resource::<SpatialJoin<Enemy, Barrel>>()
            .pairs()
            .len(),
        1
    );
    // The last barrel leaves: one more run clears the pairs, then none.
    app.world_mut().despawn(barrel);
    app.update();
    assert_eq!(diagnostics(&app).joins.runs, 1);
    assert!(
        app.world()
            .resource::<SpatialJoin<Enemy, Barrel>>()
            .pairs()
            .is_empty()
    );
    app.update();
    assert_eq!(diagnostics(&app).joins.runs, 0);
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

#[test]
fn pair_messages_report_starts_and_ends() {
    #[derive(Resource, Default)]
    struct Log(Vec<(bool, Entity, Entity)>);

    fn record(
        mut started: MessageReader<PairStarted<Enemy, Barrel>>,
        mut ended: MessageReader<PairEnded<Enemy, Barrel>>,
        mut log: ResMut<Log>,
    ) {
        log.0.extend(started.read().map(|m| (true, m.a, m.b)));
        log.0.extend(ended.read().map(|m| (false, m.a, m.b)));
    }

    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(1.0, JoinMode::Euclidean)
        .init_resource::<Log>()
        .add_systems(Last, record);
    let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
    let barrel = app.world_mut().spawn((unit_at(10.0), Barrel)).id();
    app.update();
    assert!(app.world().resource::<Log>().0.is_empty());

    app.world_mut().get_mut::<SpatialBounds>(barrel).unwrap().0 = unit_at(2.0).0;
    app.update();
    assert_eq!(
        app.world_mut()
            .resource_mut::<Log>()
            .0
            .drain(..)
            .collect::<Vec<_>>(),
        [(true, enemy, barrel)]
    );

    // Exactly at the distance still pairs (closed); just beyond ends it.
    app.world_mut().get_mut::<SpatialBounds>(barrel).unwrap().0 = unit_at(2.0).0;
    app.update();
    assert!(app.world().resource::<Log>().0.is_empty());
    app.world_mut().get_mut::<SpatialBounds>(barrel).unwrap().0 = unit_at(2.5).0;
    app.update();
    assert_eq!(
        app.world_mut()
            .resource_mut::<Log>()
            .0
            .drain(..)
            .collect::<Vec<_>>(),
        [(false, enemy, barrel)]
    );
}

#[test]
fn culling_modes_and_camera_lists_match_the_oracle() {
    let mut app = app();
    let mut oracle = bevy_rtree::oracle::BruteForce::default();
    for i in 0..50 {
        let b = unit_at(i as f32 * 1.5 - 30.0);
        let e = app.world_mut().spawn(b).id();
        oracle.insert(e, b.0);
    }
    let conservative = app.world_mut().spawn(camera()).id();
    let exact = app
        .world_mut()
        .spawn(camera().with_mode(CullMode::Exact))
        .id();
    app.update();
    let frustum = app
        .world()
        .get::<CullingCamera>(conservative)
        .unwrap()
        .frustum;
    for (cam, mode) in [
        (conservative, CullMode::Conservative),
        (exact, CullMode::Exact),
    ] {
        let list = app.world().get::<VisibleEntityList>(cam).unwrap();
        let expected = oracle.visible(&frustum, mode);
        assert!(!expected.is_empty());
        assert_eq!(list.entities(), expected);
    }
    // Two modes, two traversals, in one run of the layer's culling.
    let culling = diagnostics(&app).culling;
    assert_eq!((culling.runs, culling.queries), (1, 2));
}

#[test]
fn spatial_query_answers_like_the_oracle_from_any_system() {
    #[derive(Resource, Default)]
    struct Answers {
        first: Option<Entity>,
        nearest: Vec<Entity>,
        within: Vec<Entity>,
        sphere: Vec<Entity>,
        overlap: Vec<Entity>,
        enemies_near: Vec<Entity>,
    }

    fn ask(mut all: SpatialQuery, mut enemies: SpatialQuery<Enemy>, mut answers: ResMut<Answers>) {
        let origin = Vec3::new(-5.0, 0.5, 0.5);
        let ray = Ray::new(origin, Vec3::X, 100.0).unwrap();
        let any = &SpatialQueryFilter::default();
        answers.first = all.cast_ray(&ray, any).unwrap().map(|h| h.key);
        let mut neighbours = Vec::new();
        all.nearest(Vec3::new(10.2, 0.5, 0.5), 3, None, any, &mut neighbours)
            .unwrap();
        answers.nearest = neighbours.iter().map(|n| n.key).collect();
        all.within_radius(Vec3::new(10.2, 0.5, 0.5), 2.0, any, &mut neighbours)
            .unwrap();
        answers.within = neighbours.iter().map(|n| n.key).collect();
        let mut found = Vec::new();
        all.overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 1.0, any, &mut found)
            .unwrap();
        found.sort_unstable();
        answers.sphere = std::mem::take(&mut found);
        all.overlapping(
            &Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap(),
            any,
            &mut found,
        );
        found.sort_unstable();
        answers.overlap = std::mem::take(&mut found);
        enemies
            .nearest(Vec3::new(10.2, 0.5, 0.5), 2, None, any, &mut neighbours)
            .unwrap();
        answers.enemies_near = neighbours.iter().map(|n| n.key).collect();
    }

    let mut app = app();
    app.add_spatial_layer::<Enemy>()
        .init_resource::<Answers>()
        .add_systems(PostUpdate, ask.after(SpatialIndexSystems::Sync));
    let mut all = bevy_rtree::oracle::BruteForce::default();
    let mut enemies = bevy_rtree::oracle::BruteForce::default();
    for i in 0..40 {
        let b = unit_at(i as f32 * 1.25);
        let mut entity = app.world_mut().spawn(b);
        if i % 3 == 0 {
            entity.insert(Enemy);
        }
        let e = entity.id();
        all.insert(e, b.0);
        if i % 3 == 0 {
            enemies.insert(e, b.0);
        }
    }
    app.update();
    let answers = app.world().resource::<Answers>();
    let origin = Vec3::new(-5.0, 0.5, 0.5);
    let ray = Ray::new(origin, Vec3::X, 100.0).unwrap();
    assert_eq!(answers.first, all.ray_first(&ray).unwrap().map(|h| h.key));
    let p = Vec3::new(10.2, 0.5, 0.5);
    let keys =
        |v: Vec<bevy_rtree::Neighbor<Entity>>| v.into_iter().map(|n| n.key).collect::<Vec<_>>();
    assert_eq!(answers.nearest, keys(all.nearest(p, 3, None).unwrap()));
    assert_eq!(answers.within, keys(all.within_radius(p, 2.0).unwrap()));
    assert_eq!(
        answers.enemies_near,
        keys(enemies.nearest(p, 2, None).unwrap())
    );
    assert_eq!(
        answers.sphere,
        all.overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 1.0)
            .unwrap()
    );
    let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
    assert_eq!(answers.overlap, all.overlapping(&query));
    assert_eq!(answers.nearest.len(), 3);
    assert!(!answers.within.is_empty() && !answers.sphere.is_empty());
}

/// Collects warnings so a test can count them (one logger per test binary).
struct CapturedLog(std::sync::Mutex<Vec<String>>);

impl log::Log for CapturedLog {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        metadata.level() <= log::Level::Warn
    }
    fn log(&self, record: &log::Record) {
        self.0.lock().unwrap().push(record.args().to_string());
    }
    fn flush(&self) {}
}

static CAPTURED: CapturedLog = CapturedLog(std::sync::Mutex::new(Vec::new()));

/// Starts capturing warnings (once per test binary; later calls do nothing).
fn capture_warnings() {
    let _ = log::set_logger(&CAPTURED);
    log::set_max_level(log::LevelFilter::Warn);
}

/// The captured warnings that name `entity`.
fn warnings_about(entity: Entity) -> usize {
    let name = format!("{entity} ");
    let lines = CAPTURED.0.lock().unwrap();
    lines.iter().filter(|line| line.starts_with(&name)).count()
}

#[test]
fn an_invalid_box_is_reported_once_per_entity_however_often_it_is_set() {
    capture_warnings();
    let mut app = app();
    // Other tests in this binary log too: give this entity an id none of
    // them reaches.
    for i in 0..5_000 {
        app.world_mut().spawn(unit_at(i as f32));
    }
    let bad = app.world_mut().spawn(unit_at(0.0)).id();
    app.update();
    for x in [f32::NAN, f32::INFINITY, f32::NAN] {
        app.world_mut()
            .get_mut::<SpatialBounds>(bad)
            .unwrap()
            .0
            .min
            .x = x;
        app.update();
        assert_eq!(
            diagnostics(&app).sync.invalid_skipped,
            1,
            "counted every time"
        );
    }
    assert_eq!(warnings_about(bad), 1, "logged once");
    assert_eq!(diagnostics(&app).invalid_total, 3);
}

/// Disabling an entity whose box is invalid, or opting it out, and taking
/// it back reads the same box again: it stays out of the index and is not
/// warned about again. A box taken away and set invalid again is a new one.
#[test]
fn an_invalid_box_read_again_after_disabling_is_not_warned_about_again() {
    use bevy_ecs::entity_disabling::Disabled;
    capture_warnings();
    let mut app = app();
    // An id no other test of this binary reaches.
    for i in 0..6_000 {
        app.world_mut().spawn(unit_at(i as f32));
    }
    let bad = app.world_mut().spawn(SpatialBounds(Aabb::INVERTED)).id();
    app.update();
    assert_eq!(warnings_about(bad), 1);
    for _ in 0..2 {
        app.world_mut().entity_mut(bad).insert(Disabled);
        app.update();
        app.world_mut().entity_mut(bad).remove::<Disabled>();
        app.update();
        app.world_mut().entity_mut(bad).insert(NoSpatialIndex);
        app.update();
        app.world_mut().entity_mut(bad).remove::<NoSpatialIndex>();
        app.update();
        assert!(!indexed(&app).contains(&bad));
        let index = app.world().resource::<SpatialIndex>();
        assert!(index.unindexed().any(|e| e == bad), "left out for its box");
    }
    assert_eq!(warnings_about(bad), 1, "warned once");
    // A new box, invalid again: a new warning.
    app.world_mut().entity_mut(bad).remove::<SpatialBounds>();
    app.update();
    app.world_mut()
        .entity_mut(bad)
        .insert(SpatialBounds(Aabb::INVERTED));
    app.update();
    assert_eq!(warnings_about(bad), 2);
}

#[test]
fn a_join_with_an_invalid_distance_has_no_pairs_and_recovers() {
    capture_warnings();
    for distance in [f32::NAN, -7.25] {
        let mut app = app();
        app.add_spatial_join::<Enemy, Barrel>(distance, JoinMode::Euclidean);
        let enemy = app.world_mut().spawn((unit_at(0.0), Enemy)).id();
        let barrel = app.world_mut().spawn((unit_at(1.5), Barrel)).id();
        app.update();
        let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
        assert!(join.pairs().is_empty());
        assert_eq!(join.error(), Some(SpatialError::InvalidDistance));
        // Refused, so not computed: not counted as a join that ran.
        let counted = diagnostics(&app).joins;
        assert_eq!((counted.runs, counted.queries), (0, 0));
        // Nothing changed, or only the layers: not run (and not reported)
        // again.
        app.update();
        assert_eq!(diagnostics(&app).joins.runs, 0);
        for x in [0.5, 1.0] {
            app.world_mut().get_mut::<SpatialBounds>(enemy).unwrap().0 = unit_at(x).0;
            app.update();
            assert_eq!(diagnostics(&app).joins.runs, 0);
        }
        app.world_mut()
            .resource_mut::<SpatialJoin<Enemy, Barrel>>()
            .distance = 1.0;
        app.update();
        let join = app.world().resource::<SpatialJoin<Enemy, Barrel>>();
        assert_eq!(join.pairs(), [(enemy, barrel)]);
        assert_eq!(join.error(), None);
        assert_eq!(diagnostics(&app).joins.runs, 1);
    }
    // A join that has nothing to pair never runs; its error is still the
    // distance's, as it is now.
    let mut app = app();
    app.add_spatial_join::<Enemy, Barrel>(-1.0, JoinMode::Euclidean);
    app.world_mut().spawn((unit_at(0.0), Enemy));
    app.update();
    let error = |app: &App| app.world().resource::<SpatialJoin<Enemy, Barrel>>().error();
    assert_eq!(error(&app), Some(SpatialError::InvalidDistance));
    app.world_mut()
        .resource_mut::<SpatialJoin<Enemy, Barrel>>()
        .distance = 1.0;
    assert_eq!(error(&app), None);
    // Only this test uses the distance -7.25: warned about once.
    let lines = CAPTURED.0.lock().unwrap();
    let warned = lines
        .iter()
        .filter(|l| l.contains("distance -7.25"))
        .count();
    assert_eq!(warned, 1);
}

/// Every query of `SpatialQuery` with a filter answers as the oracle does
/// with the filtered-out entities left out: the first allowed hit, the k
/// nearest allowed entities, and so on; and a line of sight from inside
/// the asking entity's own box finds the target, not itself.
#[test]
fn filtered_queries_answer_as_if_the_excluded_entities_were_not_there() {
    #[derive(Resource, Default)]
    struct Asked {
        filter: SpatialQueryFilter,
        first: Option<Entity>,
        all: Vec<Entity>,
        any: bool,
        nearest: Vec<Entity>,
        within: Vec<Entity>,
        sphere: Vec<Entity>,
        overlap: Vec<Entity>,
    }

    fn ask(mut spatial: SpatialQuery, mut asked: ResMut<Asked>) {
        let asked = &mut *asked;
        let filter = &asked.filter;
        let ray = Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::X, 100.0).unwrap();
        asked.first = spatial.cast_ray(&ray, filter).unwrap().map(|h| h.key);
        let mut hits = Vec::new();
        spatial
            .cast_ray_all(&ray, Some(5), filter, &mut hits)
            .unwrap();
        asked.all = hits.iter().map(|h| h.key).collect();
        asked.any = spatial.ray_hits_any(&ray, filter).unwrap();
        let mut near = Vec::new();
        spatial
            .nearest(Vec3::new(10.2, 0.5, 0.5), 4, None, filter, &mut near)
            .unwrap();
        asked.nearest = near.iter().map(|n| n.key).collect();
        spatial
            .within_radius(Vec3::new(10.2, 0.5, 0.5), 3.0, filter, &mut near)
            .unwrap();
        asked.within = near.iter().map(|n| n.key).collect();
        let mut found = Vec::new();
        spatial
            .overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 2.0, filter, &mut found)
            .unwrap();
        found.sort_unstable();
        asked.sphere = std::mem::take(&mut found);
        let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
        spatial.overlapping(&query, filter, &mut found);
        found.sort_unstable();
        asked.overlap = found;
    }

    let mut app = app();
    app.init_resource::<Asked>()
        .add_systems(PostUpdate, ask.after(SpatialIndexSystems::Sync));
    let entities: Vec<Entity> = (0..40)
        .map(|i| app.world_mut().spawn(unit_at(i as f32 * 0.75)).id())
        .collect();
    // The ray starts inside entity 0 (its own box, as a line of sight from
    // an enemy does); exclude it, every third one, and by predicate those
    // from 20 on.
    let shooter = entities[0];
    let excluded: Vec<Entity> = entities.iter().copied().step_by(3).collect();
    let late: Vec<Entity> = entities[20..].to_vec();
    let filter =
        SpatialQueryFilter::excluding(excluded.clone()).with_predicate(move |e| !late.contains(&e));
    app.world_mut().resource_mut::<Asked>().filter = filter.clone();
    app.update();
    let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
    let allowed = |list: Vec<Entity>| -> Vec<Entity> {
        list.into_iter().filter(|e| filter.allows(*e)).collect()
    };
    let ray = Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::X, 100.0).unwrap();
    let hits: Vec<Entity> = allowed(
        oracle
            .ray_hits(&ray)
            .unwrap()
            .iter()
            .map(|h| h.key)
            .collect(),
    );
    let asked = app.world().resource::<Asked>();
    assert_eq!(asked.first, hits.first().copied());
    assert_ne!(
        asked.first,
        Some(shooter),
        "the shooter does not see itself"
    );
    assert_eq!(asked.all, hits[..5.min(hits.len())]);
    assert_eq!(asked.any, !hits.is_empty());
    assert!(!hits.is_empty(), "the ray has allowed hits to find");
    let all = entities.len();
    let near = oracle
        .nearest(Vec3::new(10.2, 0.5, 0.5), all, None)
        .unwrap();
    let near: Vec<Entity> = allowed(near.iter().map(|n| n.key).collect());
    assert_eq!(asked.nearest, near[..4]);
    let within = oracle
        .within_radius(Vec3::new(10.2, 0.5, 0.5), 3.0)
        .unwrap();
    assert_eq!(
        asked.within,
        allowed(within.iter().map(|n| n.key).collect())
    );
    let sphere = oracle
        .overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 2.0)
        .unwrap();
    assert_eq!(asked.sphere, allowed(sphere));
    let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
    assert_eq!(asked.overlap, allowed(oracle.overlapping(&query)));
    assert!(!asked.overlap.is_empty() && asked.overlap.len() < oracle.overlapping(&query).len());
}

/// A caster ignores its own entity by default (its ray starts inside its
/// own box, as a line of sight from an enemy does), hits it when told to,
/// and hits only what its filter allows, in every mode.
#[test]
fn casters_ignore_themselves_and_obey_their_filter() {
    let mut app = app();
    // Five walls 20 m tall along +X; each shooter stands at its own height,
    // in its own unit box, looking down +X.
    let walls: Vec<Entity> = (1..6)
        .map(|i| {
            let x = i as f32 * 3.0;
            let wall = Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 20.0, 1.0)).unwrap();
            app.world_mut().spawn(SpatialBounds(wall)).id()
        })
        .collect();
    let mut height = 0.0;
    let mut shooter = |app: &mut App, mode: RayMode, setup: fn(RayCaster) -> RayCaster| {
        let body = Aabb::new(
            Vec3::new(0.0, height, 0.0),
            Vec3::new(1.0, height + 1.0, 1.0),
        )
        .unwrap();
        let ray = Ray::new(Vec3::new(0.5, height + 0.5, 0.5), Vec3::X, 100.0).unwrap();
        height += 1.5;
        app.world_mut()
            .spawn((SpatialBounds(body), setup(RayCaster::new(ray, mode))))
            .id()
    };
    let plain = shooter(&mut app, RayMode::First, |c| c);
    let selfish = shooter(&mut app, RayMode::First, |c| c.hitting_self(true));
    let all = shooter(&mut app, RayMode::All { limit: Some(2) }, |c| c);
    let any = shooter(&mut app, RayMode::Any, |c| c);
    let filtered: Vec<Entity> = [
        RayMode::First,
        RayMode::All { limit: Some(2) },
        RayMode::Any,
    ]
    .into_iter()
    .map(|mode| shooter(&mut app, mode, |c| c))
    .collect();
    let filter = SpatialQueryFilter::excluding([walls[0]]).with_predicate({
        let skip = walls[1];
        move |e| e != skip
    });
    for &e in &filtered {
        app.world_mut().get_mut::<RayCaster>(e).unwrap().filter = filter.clone();
    }
    let blind = shooter(&mut app, RayMode::Any, |c| c);
    // All hits with a limit of none report only whether there was one.
    let counter = shooter(&mut app, RayMode::All { limit: Some(0) }, |c| c);
    let blind_counter = shooter(&mut app, RayMode::All { limit: Some(0) }, |c| c);
    for e in [blind, blind_counter] {
        app.world_mut().get_mut::<RayCaster>(e).unwrap().filter =
            SpatialQueryFilter::excluding(walls.clone());
    }
    app.update();
    let hits = |app: &App, e: Entity| app.world().get::<RayCasterHits>(e).unwrap().clone();
    let keys = |app: &App, e: Entity| -> Vec<Entity> {
        hits(app, e).hits().iter().map(|h| h.key).collect()
    };
    assert_eq!(keys(&app, plain), [walls[0]]);
    assert_eq!(
        hits(&app, selfish).first().map(|h| (h.key, h.t)),
        Some((selfish, 0.0))
    );
    assert_eq!(keys(&app, all), walls[..2]);
    assert!(hits(&app, any).any());
    assert_eq!(keys(&app, filtered[0]), [walls[2]]);
    assert_eq!(keys(&app, filtered[1]), walls[2..4]);
    assert!(hits(&app, filtered[2]).any());
    assert!(!hits(&app, blind).any(), "only walls and itself on its ray");
    assert!(hits(&app, counter).any() && keys(&app, counter).is_empty());
    assert!(!hits(&app, blind_counter).any(), "only walls and itself");
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

/// The diagnostics count one run of a family's system per layer, whatever
/// modes its cameras and casters use, and all of its work: a caster whose
/// own box turned the batch's first hit down casts again through its
/// filter, and that walk's nodes are counted too.
#[test]
fn diagnostics_count_one_run_and_every_walk() {
    let mut app = app();
    let mut targets = Vec::new();
    for i in 0..400 {
        targets.push(app.world_mut().spawn(unit_at(2.0 * i as f32)).id());
    }
    let view = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.0, 0.1, 100.0).unwrap();
    let world = app.world_mut();
    world.spawn(CullingCamera::new(view));
    world.spawn(CullingCamera::new(view).with_mode(CullMode::Exact));
    // A caster inside the first target's box, looking down the row.
    let ray = Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::X, 1_000.0).unwrap();
    world
        .entity_mut(targets[0])
        .insert(RayCaster::new(ray, RayMode::First));
    // A second mode, from an entity without a box: it ignores itself too,
    // so its any-hit is walked again through its filter as well.
    let any = world.spawn(RayCaster::new(ray, RayMode::Any)).id();
    app.update();
    let d = *app.world().resource::<SpatialDiagnostics>();
    assert_eq!((d.culling.runs, d.culling.queries), (1, 2));
    assert_eq!((d.rays.runs, d.rays.queries), (1, 2));
    let hits = app.world().get::<RayCasterHits>(targets[0]).unwrap();
    assert_eq!(hits.first().map(|h| h.key), Some(targets[1]));
    // The walks the recasts make, alone.
    let index = app.world().resource::<SpatialIndex>();
    let mut ws = bevy_rtree::QueryWorkspace::default();
    let first = index
        .tree()
        .cast_ray_where(&ray, &mut ws, |e| e != targets[0]);
    assert_eq!(first.unwrap().map(|h| h.key), Some(targets[1]));
    let hit = index.tree().ray_hits_any_where(&ray, &mut ws, |e| e != any);
    assert_eq!(hit, Ok(true));
    let recast = ws.take_stats().nodes_visited;
    // And the batches of each mode, as the plugin casts them.
    let mut batches = 0;
    for mode in [RayMode::First, RayMode::Any] {
        let mut results = bevy_rtree::RayResults::default();
        index.tree().cast_rays(&[ray], mode, &mut ws, &mut results);
        batches += ws.take_stats().nodes_visited;
    }
    assert_eq!(d.rays.nodes_visited, batches + recast);
}

/// `SpatialQuery`'s box and sphere overlaps clear their output before they
/// answer (as its other queries do), and a refused query leaves it as it
/// was (the error is found before the output is touched, as everywhere in
/// the crate).
#[test]
fn spatial_query_outputs_hold_this_answer_only() {
    #[derive(Resource, Default)]
    struct Outputs {
        overlap: Vec<Entity>,
        sphere: Vec<Entity>,
        refused_nearest: Vec<usize>,
        refused_sphere: usize,
    }
    let mut app = app();
    for i in 0..5 {
        app.world_mut().spawn(unit_at(2.0 * i as f32));
    }
    app.init_resource::<Outputs>().add_systems(
        PostUpdate,
        (|mut spatial: SpatialQuery, mut outputs: ResMut<Outputs>| {
            let all = SpatialQueryFilter::default();
            let around = Aabb::new(Vec3::splat(-1.0), Vec3::splat(2.5)).unwrap();
            let mut found = vec![Entity::PLACEHOLDER];
            spatial.overlapping(&around, &all, &mut found);
            outputs.overlap = found.clone();
            spatial
                .overlapping_sphere(Vec3::ZERO, 0.5, &all, &mut found)
                .unwrap();
            outputs.sphere = found.clone();
            let refused = spatial.overlapping_sphere(Vec3::ZERO, f32::NAN, &all, &mut found);
            assert!(refused.is_err());
            outputs.refused_sphere = found.len();
            let mut near = Vec::new();
            spatial
                .nearest(Vec3::ZERO, 3, None, &all, &mut near)
                .unwrap();
            outputs.refused_nearest.push(near.len());
            assert!(
                spatial
                    .nearest(Vec3::ZERO, 0, None, &all, &mut near)
                    .is_err()
            );
            outputs.refused_nearest.push(near.len());
        })
        .after(SpatialIndexSystems::Sync),
    );
    app.update();
    let outputs = app.world().resource::<Outputs>();
    assert_eq!(outputs.overlap.len(), 2, "{:?}", outputs.overlap);
    assert!(!outputs.overlap.contains(&Entity::PLACEHOLDER));
    assert_eq!(outputs.sphere.len(), 1);
    assert_eq!(outputs.refused_sphere, 1);
    assert_eq!(outputs.refused_nearest, [3, 3]);
}
