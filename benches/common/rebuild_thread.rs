//! The plugin's `RebuildMode::OnTaskPool` upkeep, with a plain thread for
//! Bevy's task pool, for the benches and the accuracy report that price
//! it on bare trees.

use std::thread::JoinHandle;
use std::time::Duration;

use bevy_rtree::{RTree, RebuildWork};

/// One frame of a tree's rebuild: started when the tree is worn, its work
/// sent to another thread and taken back when done, the swap (and any
/// work left) advanced for `budget`. Returns whether a rebuild was
/// swapped in.
pub fn keep_fresh_on_a_thread(
    tree: &mut RTree<u32>,
    budget: Duration,
    away: &mut Option<JoinHandle<RebuildWork<u32>>>,
) -> bool {
    if let Some(worker) = away {
        if !worker.is_finished() {
            // A step while the work is away only counts the frame.
            return tree.step_rebuild(budget);
        }
        let work = away.take().expect("checked").join().expect("the work ran");
        tree.finish_rebuild_work(work);
    }
    if !tree.rebuild_pending() {
        if !tree.is_worn() {
            return false;
        }
        tree.start_rebuild();
        if let Some(mut work) = tree.take_rebuild_work() {
            *away = Some(std::thread::spawn(move || {
                work.run();
                work
            }));
            return false;
        }
    }
    tree.step_rebuild(budget)
}
