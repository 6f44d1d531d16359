//! A layer's maintenance each frame: the repair of churned leaves, and a
//! rebuild that keeps the tiling as good as fresh in long sessions.
//!
//! When the changes that wear the tiling reach a quarter of the entries
//! ([`RTree::is_worn`](crate::RTree::is_worn)), a rebuild starts. Its work
//! (tiling a snapshot of the entries, filling the new nodes) runs on
//! Bevy's `AsyncComputeTaskPool` where the app has one (feature
//! `parallel`), and the swap on the thread that runs the system; without
//! such a pool all of it goes in slices of the plugin's `rebuild_budget` a
//! frame on that thread.

use std::time::Duration;

use bevy_ecs::prelude::*;

use super::SpatialIndexConfig;
use super::diagnostics::DiagnosticsSink;
use super::index::SpatialIndex;
use crate::tree::RTree;

/// A rebuild's work running on the task pool, per layer.
#[derive(Default)]
pub(crate) struct WorkAway {
    #[cfg(feature = "parallel")]
    task: Option<bevy_tasks::Task<crate::tree::RebuildWork<Entity>>>,
}

impl WorkAway {
    fn is_away(&self) -> bool {
        #[cfg(feature = "parallel")]
        return self.task.is_some();
        #[cfg(not(feature = "parallel"))]
        false
    }
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
    let swapped = match settings.rebuild_budget {
        Some(budget) => keep_fresh(tree, budget, &mut away),
        None => {
            tree.cancel_rebuild();
            false
        }
    };
    sink.add(|d| {
        d.maintenance.runs += 1;
        d.maintenance.nodes_repacked += repacked as u64;
        d.maintenance.rebuilds += u32::from(swapped);
    });
}

/// Run condition: the layer has degraded leaves waiting for repair, or a
/// rebuild to start or to advance.
pub(crate) fn needs_maintenance<L: Component>(
    index: Res<SpatialIndex<L>>,
    settings: Res<SpatialIndexConfig>,
) -> bool {
    let tree = &index.tree;
    tree.pending_repairs() > 0
        || (settings.rebuild_budget.is_some() && (tree.rebuild_pending() || tree.is_worn()))
}

/// One frame of the rebuild: started when the tree is worn, its work sent
/// to the task pool where there is one, then advanced for `budget`.
/// Returns whether a rebuild was swapped in.
fn keep_fresh(tree: &mut RTree<Entity>, budget: Duration, away: &mut WorkAway) -> bool {
    #[cfg(feature = "parallel")]
    if let Some(task) = &mut away.task {
        if !task.is_finished() {
            return false;
        }
        let work = bevy_tasks::block_on(away.task.take().unwrap());
        // Refused only if the rebuild was cancelled meanwhile; a worn
        // tree starts another.
        tree.finish_rebuild_work(work);
    }
    if !tree.rebuild_pending() {
        if !tree.is_worn() {
            return false;
        }
        tree.start_rebuild();
        #[cfg(feature = "parallel")]
        if let Some(pool) = bevy_tasks::AsyncComputeTaskPool::try_get()
            && pool.thread_num() > 0
            && let Some(mut work) = tree.take_rebuild_work()
        {
            away.task = Some(pool.spawn(async move {
                work.run();
                work
            }));
            return false;
        }
    }
    debug_assert!(!away.is_away());
    tree.step_rebuild(budget)
}
