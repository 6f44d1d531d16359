//! The plugin's rebuild (`SpatialIndexPlugin::rebuild`): in a scene where
//! entities teleport every frame, rebuilds are started and swapped in, and
//! after every frame the index is valid and answers as the brute-force
//! oracle does; on Bevy's `AsyncComputeTaskPool` (feature `parallel`) and
//! in slices on the calling thread.
#![cfg(feature = "plugin")]

use std::time::Duration;

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, Ray};
use glam::Vec3;

fn random_box(rng: &mut SceneRng) -> Aabb {
    let at = Vec3::new(
        rng.range(0.0, 500.0),
        rng.range(0.0, 20.0),
        rng.range(0.0, 500.0),
    );
    let half = Vec3::splat(rng.range(0.2, 2.0));
    Aabb::new(at - half, at + half).unwrap()
}

/// An App with `plugin` and `count` entities at random boxes, not yet
/// updated.
fn app_with_boxes(
    plugin: SpatialIndexPlugin,
    count: usize,
    rng: &mut SceneRng,
) -> (App, Vec<Entity>) {
    let mut app = App::new();
    app.add_plugins(plugin);
    let entities = (0..count)
        .map(|_| app.world_mut().spawn(SpatialBounds(random_box(rng))).id())
        .collect();
    (app, entities)
}

/// Runs `frames` frames of 3 % teleports and 20 % steps over `count`
/// entities, checking the index after every frame, and then more (up to
/// four times as many in all) until `wanted` rebuilds have been swapped
/// in; returns the rebuilds swapped in. How many frames a rebuild spans
/// depends on the machine's speed (a slice's time budget, a task's
/// thread), which the answers must not, nor whether the test passes.
fn teleporting_scene(plugin: SpatialIndexPlugin, count: usize, frames: usize, wanted: u32) -> u32 {
    let mut rng = SceneRng::new(21);
    let (mut app, entities) = app_with_boxes(plugin, count, &mut rng);
    let mut rebuilds = 0;
    for frame in 0.. {
        if frame >= frames && (rebuilds >= wanted || frame >= 4 * frames) {
            break;
        }
        for &entity in &entities {
            let roll = rng.below(100);
            let mut bounds = app.world_mut().get_mut::<SpatialBounds>(entity).unwrap();
            if roll < 3 {
                bounds.0 = random_box(&mut rng);
            } else if roll < 23 {
                let step = Vec3::new(rng.range(-0.5, 0.5), 0.0, rng.range(-0.5, 0.5));
                bounds.0 = Aabb::new(bounds.0.min + step, bounds.0.max + step).unwrap();
            }
        }
        app.update();
        rebuilds += app
            .world()
            .resource::<SpatialDiagnostics>()
            .maintenance
            .rebuilds;
        let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
        let index = app.world().resource::<SpatialIndex>();
        index.validate().unwrap();
        assert_eq!(index.len(), oracle.len());
        let query = random_box(&mut rng).grown(Vec3::splat(20.0));
        assert_eq!(
            index.tree().overlapping(&query),
            oracle.overlapping(&query),
            "frame {frame}"
        );
        let from = random_box(&mut rng).min;
        let ray = Ray::new(from, rng.direction(), 300.0).unwrap();
        let mut ws = bevy_rtree::QueryWorkspace::default();
        assert_eq!(
            index.tree().cast_ray(&ray, &mut ws),
            oracle.ray_first(&ray),
            "frame {frame}"
        );
    }
    rebuilds
}

/// On the task pool where the app has one (with feature `parallel`; the
/// test gives it one), off otherwise.
#[test]
fn rebuilds_on_the_task_pool_keep_the_answers_exact() {
    #[cfg(feature = "parallel")]
    bevy_tasks::AsyncComputeTaskPool::get_or_init(|| {
        bevy_tasks::TaskPoolBuilder::new().num_threads(2).build()
    });
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::OnTaskPool,
        ..SpatialIndexPlugin::default()
    };
    let wanted = if cfg!(feature = "parallel") { 2 } else { 0 };
    let rebuilds = teleporting_scene(plugin, 4_000, 120, wanted);
    if cfg!(feature = "parallel") {
        assert!(rebuilds >= 2, "{rebuilds} rebuilds in 480 frames");
    } else {
        assert_eq!(rebuilds, 0, "no task pool without feature `parallel`");
    }
}

#[test]
fn rebuilds_in_slices_keep_the_answers_exact() {
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::InSlices(Duration::from_micros(200)),
        ..SpatialIndexPlugin::default()
    };
    let rebuilds = teleporting_scene(plugin, 4_000, 120, 2);
    assert!(rebuilds >= 2, "{rebuilds} rebuilds in 480 frames");
}

/// Off: nothing is rebuilt.
#[test]
fn rebuild_off_rebuilds_nothing() {
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::Off,
        ..SpatialIndexPlugin::default()
    };
    assert_eq!(teleporting_scene(plugin, 4_000, 40, 0), 0);
}

/// A repair budget of 0 turns repair off: with rebuilds off too, the
/// maintenance never runs, though teleports leave leaves to repair.
#[test]
fn a_repair_budget_of_zero_runs_no_maintenance() {
    let plugin = SpatialIndexPlugin {
        optimize_budget: 0,
        rebuild: RebuildMode::Off,
        ..SpatialIndexPlugin::default()
    };
    let mut rng = SceneRng::new(9);
    let (mut app, entities) = app_with_boxes(plugin, 3_000, &mut rng);
    app.update();
    for &entity in entities.iter().step_by(2) {
        app.world_mut().get_mut::<SpatialBounds>(entity).unwrap().0 = random_box(&mut rng);
    }
    for _ in 0..3 {
        app.update();
        let diagnostics = app.world().resource::<SpatialDiagnostics>();
        assert_eq!(diagnostics.maintenance.runs, 0);
    }
    let index = app.world().resource::<SpatialIndex>();
    assert!(index.tree().pending_repairs() > 0, "leaves left to repair");
    index.validate().unwrap();
}

/// The default rebuilds on the task pool where the app has one.
#[test]
fn the_default_rebuilds_on_the_task_pool() {
    assert_eq!(
        SpatialIndexPlugin::default().rebuild,
        RebuildMode::OnTaskPool
    );
}

#[test]
fn a_tiny_budget_still_finishes_rebuilds() {
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::InSlices(Duration::from_nanos(1)),
        ..SpatialIndexPlugin::default()
    };
    // One unit of work a frame (a median cut or a node): a rebuild of 600
    // entries takes about a hundred frames.
    assert!(teleporting_scene(plugin, 600, 250, 1) >= 1);
}

/// A rebuild's work out on the task pool when a spawn wave arrives (more
/// new entities than indexed ones: loaded in bulk, which retiles the tree
/// and drops the rebuild) is let go by that frame's maintenance, in a
/// scene that then stands still: the maintenance runs once for it, then
/// no more. It used to stop at once, the finished work (a whole second
/// structure) left waiting in it.
#[cfg(feature = "parallel")]
#[test]
fn work_away_dropped_by_a_spawn_wave_is_let_go() {
    bevy_tasks::AsyncComputeTaskPool::get_or_init(|| {
        bevy_tasks::TaskPoolBuilder::new().num_threads(2).build()
    });
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::OnTaskPool,
        ..SpatialIndexPlugin::default()
    };
    let mut rng = SceneRng::new(5);
    let (mut app, entities) = app_with_boxes(plugin, 2_000, &mut rng);
    app.update();
    // Teleports until a rebuild starts: its work goes out that frame.
    let mut frames = 0;
    while !app
        .world()
        .resource::<SpatialIndex>()
        .tree()
        .rebuild_pending()
    {
        for &entity in &entities {
            if rng.below(10) == 0 {
                app.world_mut().get_mut::<SpatialBounds>(entity).unwrap().0 = random_box(&mut rng);
            }
        }
        app.update();
        frames += 1;
        assert!(frames < 200, "no rebuild started");
    }
    // The wave, loaded in bulk: the rebuild is dropped by the sync, and the
    // maintenance of that frame runs for the work still out and lets it go;
    // after it, a still scene needs none.
    for _ in 0..2_500 {
        app.world_mut().spawn(SpatialBounds(random_box(&mut rng)));
    }
    let runs: Vec<u32> = (0..4)
        .map(|_| {
            app.update();
            let diagnostics = app.world().resource::<SpatialDiagnostics>();
            diagnostics.maintenance.runs
        })
        .collect();
    let index = app.world().resource::<SpatialIndex>();
    assert!(!index.tree().rebuild_pending());
    assert_eq!(runs, [1, 0, 0, 0], "once to let the work go, then still");
    let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
    let index = app.world().resource::<SpatialIndex>();
    index.validate().unwrap();
    assert_eq!(index.len(), 4_500);
    let query = random_box(&mut rng).grown(Vec3::splat(50.0));
    assert_eq!(index.tree().overlapping(&query), oracle.overlapping(&query));
}

/// The plugin loads the first entities it meets with room for two more in
/// every leaf (`RTree::insert_bulk_with_room`), so that the first entities
/// to move out of their leaves land in that room instead of splitting
/// leaves packed full.
#[test]
fn the_first_load_leaves_room_in_every_leaf() {
    let mut rng = SceneRng::new(11);
    let (mut app, entities) = app_with_boxes(SpatialIndexPlugin::default(), 2_000, &mut rng);
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    index.validate().unwrap();
    assert_eq!(index.len(), entities.len());
    assert_eq!(index.tree().nodes_at_level(0), 2_000usize.div_ceil(14));
}
