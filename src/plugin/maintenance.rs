//! A layer's maintenance each frame: the repair of churned leaves, and a
//! rebuild that keeps the tiling as good as fresh in long sessions.
//!
//! When the changes that wear the tiling reach a quarter of the entries
//! ([`RTree::is_worn`](crate::RTree::is_worn)), a rebuild starts. Its work
//! (tiling a snapshot of the entries, filling the new nodes) runs on
//! Bevy's `AsyncComputeTaskPool` or in slices on the thread that runs the
//! system, as [`RebuildMode`] says; the swap runs on that thread.

use std::time::Duration;

use bevy_ecs::prelude::*;

use super::SpatialIndexConfig;
use super::diagnostics::DiagnosticsSink;
use super::index::SpatialIndex;
use crate::tree::RTree;

/// How the plugin rebuilds a layer's tree when it is worn
/// ([`SpatialIndexPlugin::rebuild`](super::SpatialIndexPlugin::rebuild)).
///
/// A tree kept current move by move slowly loses the quality of a fresh
/// one (on the standard scene's steps, its queries visit 30 % more nodes
/// after 2,000 frames; with teleports, 74 %); a rebuild from the live
/// entries brings most of it back, and answers and handles never change.
///
/// On Bevy's async task pool by default, where the app has one (feature
/// `parallel`; `DefaultPlugins` and `MinimalPlugins` add the pools), and
/// off where it has none: the work runs there, and the thread that runs
/// the plugin pays the snapshot at the start and the changes made
/// meanwhile, applied to the new structure before the swap. Through the
/// plugin (`town` example at 60 Hz, 1,200 frames, three runs each) the
/// mean frame's index and queries took 1.91, 1.91, 1.89 ms with it
/// against 1.99, 1.95, 1.90 ms without: the fresher tree repays its
/// upkeep. In a scene of 100,000 entities (`cargo bench --bench decay`,
/// 2,000 frames at 60 Hz) every motion pattern then stays within 1.25 ×
/// a fresh tree's nodes visited, against up to 1.74 × without; the worst
/// frame's maintenance is a millisecond or so more (steady movers 4.0 →
/// 4.9 ms). In slices on the main thread instead, a rebuild cost the
/// frame 40 % more (3,000 frames back to back): turn slices on only
/// where there is no pool and long sessions matter more than that.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::plugin::{RebuildMode, SpatialIndexPlugin};
/// use std::time::Duration;
///
/// App::new().add_plugins(SpatialIndexPlugin {
///     // No task pool in this app: 0.3 ms a layer a frame on the main thread.
///     rebuild: RebuildMode::InSlices(Duration::from_micros(300)),
///     ..SpatialIndexPlugin::default()
/// });
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RebuildMode {
    /// Never: repair alone.
    Off,
    /// On Bevy's `AsyncComputeTaskPool` where the app has one (feature
    /// `parallel`; `DefaultPlugins` and `MinimalPlugins` add the pools),
    /// costing the frame only the snapshot and the catch-up; off
    /// otherwise. The default.
    #[default]
    OnTaskPool,
    /// On the task pool where there is one, otherwise in slices of this
    /// much time a layer a frame on the thread that runs the plugin.
    OnTaskPoolOrInSlices(Duration),
    /// Always in slices of this much time a layer a frame on the thread
    /// that runs the plugin.
    InSlices(Duration),
}

impl RebuildMode {
    /// Where this app rebuilds: on the pool, or in slices of a budget;
    /// `None` if it does not.
    fn here(self) -> Option<Where> {
        let pool = task_pool_available();
        match self {
            RebuildMode::Off => None,
            RebuildMode::OnTaskPool => pool.then_some(Where::TaskPool),
            RebuildMode::OnTaskPoolOrInSlices(budget) if !pool => Some(Where::Slices(budget)),
            RebuildMode::OnTaskPoolOrInSlices(_) => Some(Where::TaskPool),
            RebuildMode::InSlices(budget) => Some(Where::Slices(budget)),
        }
    }
}

#[derive(Clone, Copy)]
enum Where {
    TaskPool,
    Slices(Duration),
}

fn task_pool_available() -> bool {
    #[cfg(feature = "parallel")]
    return bevy_tasks::AsyncComputeTaskPool::try_get().is_some();
    #[cfg(not(feature = "parallel"))]
    false
}

/// A rebuild's work running on the task pool, per layer.
#[derive(Default)]
pub(crate) struct WorkAway {
    #[cfg(feature = "parallel")]
    task: Option<bevy_tasks::Task<crate::tree::RebuildWork<Entity>>>,
    /// Whether the rebuild under way came back from the pool: only then
    /// is what is left of it a catch-up, done a step a frame.
    back: bool,
}

/// Repairs the layer's churned leaves within the plugin's budget, and
/// keeps its tiling fresh.
pub(crate) fn maintain_layer<L: Component>(
    mut index: ResMut<SpatialIndex<L>>,
    settings: Res<SpatialIndexConfig>,
    mut away: Local<WorkAway>,
    sink: Res<DiagnosticsSink>,
) {
    let tree = &mut index.tree;
    let repacked = tree.optimize(settings.optimize_budget);
    let swapped = match settings.rebuild.here() {
        Some(place) => keep_fresh(tree, place, &mut away),
        None => {
            tree.cancel_rebuild();
            #[cfg(feature = "parallel")]
            {
                away.task = None;
            }
            false
        }
    };
    #[cfg(feature = "parallel")]
    {
        index.rebuild_away = away.task.is_some();
    }
    sink.add(|d| {
        d.maintenance.runs += 1;
        d.maintenance.nodes_repacked += repacked as u64;
        d.maintenance.rebuilds += u32::from(swapped);
    });
}

/// Run condition: the layer has degraded leaves waiting for repair (and a
/// budget to repair them: 0 turns repair off), a rebuild to start or to
/// advance, or a rebuild's work out on the pool.
pub(crate) fn needs_maintenance<L: Component>(
    index: Res<SpatialIndex<L>>,
    settings: Res<SpatialIndexConfig>,
) -> bool {
    let tree = &index.tree;
    (tree.pending_repairs() > 0 && settings.optimize_budget > 0)
        || index.rebuild_away
        || (settings.rebuild.here().is_some() && (tree.rebuild_pending() || tree.is_worn()))
}

/// One frame of the rebuild: started when the tree is worn, its work sent
/// to the task pool or advanced in a slice, swapped in when complete.
/// Returns whether a rebuild was swapped in.
fn keep_fresh(tree: &mut RTree<Entity>, place: Where, away: &mut WorkAway) -> bool {
    #[cfg(feature = "parallel")]
    if !tree.rebuild_pending() {
        // The rebuild was dropped meanwhile (a bulk insert of a spawn wave
        // retiles the tree itself): its work is let go, finished or not
        // (dropping the task cancels what has not started).
        away.task = None;
    }
    #[cfg(feature = "parallel")]
    if let Some(task) = &mut away.task {
        if !task.is_finished() {
            // The step only counts the frame: the catch-up after the work
            // spreads what changed over about as many steps.
            return tree.step_rebuild(Duration::ZERO);
        }
        let work = bevy_tasks::block_on(away.task.take().unwrap());
        // Taken back, its rebuild being the one under way (a dropped one
        // let its work go above).
        away.back = tree.finish_rebuild_work(work);
    }
    #[cfg(not(feature = "parallel"))]
    let _ = away;
    if !tree.rebuild_pending() {
        if !tree.is_worn() {
            return false;
        }
        tree.start_rebuild();
        away.back = false;
        #[cfg(feature = "parallel")]
        if let Where::TaskPool = place
            && let Some(pool) = bevy_tasks::AsyncComputeTaskPool::try_get()
            && let Some(mut work) = tree.take_rebuild_work()
        {
            away.task = Some(pool.spawn(async move {
                work.run();
                work
            }));
            return false;
        }
    }
    match place {
        // Back from the pool: complete, so the steps catch up and swap it in.
        Where::TaskPool if away.back => tree.step_rebuild(Duration::ZERO),
        // Started in slices before the app had a pool: a step without a
        // budget would go one unit a frame. Dropped; the worn tree's next
        // rebuild goes to the pool.
        Where::TaskPool => {
            tree.cancel_rebuild();
            false
        }
        Where::Slices(budget) => tree.step_rebuild(budget),
    }
}

#[cfg(all(test, feature = "parallel"))]
mod tests {
    use bevy_ecs::entity::Entity;

    use super::*;
    use crate::geometry::Aabb;

    /// A rebuild started in slices before the app had a task pool is not
    /// left to go one unit a frame once the pool is there: it is dropped,
    /// and the worn tree's next rebuild runs on the pool and is swapped in
    /// within a few frames.
    #[test]
    fn a_rebuild_begun_in_slices_does_not_crawl_once_a_pool_appears() {
        let mut tree = RTree::<Entity>::new();
        let ids: Vec<_> = (0..20_000u32)
            .map(|i| {
                let at = glam::Vec3::new((i % 150) as f32, 0.0, (i / 150) as f32) * 3.0;
                let entity = Entity::from_raw_u32(i + 1).unwrap();
                tree.insert(entity, Aabb::new(at, at + glam::Vec3::ONE).unwrap())
                    .unwrap()
            })
            .collect();
        for &id in &ids[..6_000] {
            tree.remove(id).unwrap();
        }
        assert!(tree.is_worn());
        let mut away = WorkAway::default();
        keep_fresh(&mut tree, Where::Slices(Duration::ZERO), &mut away);
        assert!(tree.rebuild_pending(), "begun in slices");
        bevy_tasks::AsyncComputeTaskPool::get_or_init(bevy_tasks::TaskPool::default);
        // The first frame with the pool drops it.
        assert!(!keep_fresh(&mut tree, Where::TaskPool, &mut away));
        assert!(!tree.rebuild_pending());
        let mut frames = 0;
        while !keep_fresh(&mut tree, Where::TaskPool, &mut away) {
            frames += 1;
            assert!(frames < 10_000, "not swapped in");
            std::thread::sleep(Duration::from_millis(1));
        }
        tree.validate().unwrap();
        assert!(!tree.is_worn());
    }
}
