//! Named scenes through the plugin: bad input on the ECS path (reported
//! once, counted), what runs or not each frame, pair messages and the
//! diagnostics' counts.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::{Aabb, CullMode, Frustum, JoinMode, Ray, RayMode, SpatialError};
use glam::{Quat, Vec3};

mod common;
use common::plugin_scene::*;

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

/// An app with `count` boxes spawned first, so that the next entity's id
/// is one no other test of this binary reaches: the tests of warnings
/// share one captured log, and each looks for its own entity's lines.
fn app_whose_next_id_is(count: u32) -> App {
    let mut app = app();
    for i in 0..count {
        app.world_mut().spawn(unit_at(i as f32));
    }
    app
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
    let mut app = app_whose_next_id_is(5_000);
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
    let mut app = app_whose_next_id_is(6_000);
    let bad = app.world_mut().spawn(SpatialBounds(nan_box())).id();
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
        .insert(SpatialBounds(nan_box()));
    app.update();
    assert_eq!(warnings_about(bad), 2);
}

/// A box with NaN corners.
fn nan_box() -> Aabb {
    Aabb {
        min: Vec3::NAN,
        max: Vec3::NAN,
    }
}

/// The default box is a placeholder, "no box yet": the entity is left out
/// until it gets a valid box, as with any invalid box, but it is neither
/// warned about nor counted; an invalid box set later still is.
#[test]
fn a_placeholder_box_is_left_out_without_a_warning_or_a_count() {
    capture_warnings();
    let mut app = app_whose_next_id_is(7_000);
    let placeholder = app.world_mut().spawn(SpatialBounds::default()).id();
    let left_out = |app: &App| {
        let index = app.world().resource::<SpatialIndex>();
        index.validate().unwrap();
        !index.contains(placeholder) && index.unindexed().any(|e| e == placeholder)
    };
    app.update();
    assert!(left_out(&app));
    assert_eq!(diagnostics(&app).invalid_total, 0);
    // Given a box, indexed; the placeholder again, left out again.
    app.world_mut()
        .get_mut::<SpatialBounds>(placeholder)
        .unwrap()
        .0 = unit_at(-3.0).0;
    app.update();
    assert!(indexed(&app).contains(&placeholder));
    app.world_mut()
        .entity_mut(placeholder)
        .insert(SpatialBounds::default());
    app.update();
    assert!(left_out(&app));
    assert_eq!(diagnostics(&app).sync.invalid_skipped, 0);
    assert_eq!(warnings_about(placeholder), 0);
    // A box that is wrong rather than missing is reported, as ever.
    app.world_mut()
        .get_mut::<SpatialBounds>(placeholder)
        .unwrap()
        .0 = nan_box();
    app.update();
    assert!(left_out(&app));
    assert_eq!(diagnostics(&app).sync.invalid_skipped, 1);
    assert_eq!(diagnostics(&app).invalid_total, 1);
    assert_eq!(warnings_about(placeholder), 1);
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
