//! Parallel batched rays, culling and joins (feature `parallel`).
//!
//! The work runs on bevy_tasks' [`ComputeTaskPool`](bevy_tasks::ComputeTaskPool), the pool a Bevy app
//! already runs its systems and `par_iter`s on: a second pool (rayon's, say)
//! would start its own threads and compete with the schedule for the same
//! cores. In an app with `TaskPoolPlugin` the pool has the app's thread
//! count; elsewhere it is created on first use with one thread per core.
//!
//! Every answer equals the single-threaded call's, in the same order:
//! - a batch of rays is cut into runs of consecutive rays, a few per task;
//!   the tasks claim runs one at a time, and the slots are concatenated in
//!   ray order;
//! - culling and joins first run their depth-first traversal breadth first
//!   for a few levels, only over nodes (or node pairs) that report nothing,
//!   until there are enough pending items to share; the tasks then claim
//!   items one at a time and run the ordinary traversal from each, and the
//!   answers are concatenated in the order the single-threaded stack would
//!   have reached them.
//!
//! How the work is shared among the pool's threads: `parallel_claim.rs`.
//!
//! Small work runs on the calling thread: splitting costs a few
//! microseconds per task, more than a few dozen rays or a small tree take.

use std::ops::ControlFlow;
use std::sync::Mutex;

use super::frustum::{PreparedView, fully_inside};
use super::join::{JoinItem, JoinTest, four_lane_masks};
use super::parallel_claim::{
    cut_frontier, owners, reports_nothing, run_claimed, run_prepared, segment, task_count,
};
pub use super::parallel_workspace::ParallelWorkspace;
use super::parallel_workspace::{RayRun, TaskScratch};
use super::{CullMode, FRUSTUMS_PER_PASS, JoinMode, QueryWorkspace, RayMode, RayResults};
use crate::geometry::{Frustum, Ray, SpatialError};
use crate::tree::RTree;

/// Pending items per task to aim for before splitting a traversal. Items
/// differ in cost by orders of magnitude (a subtree in view or not), so
/// tasks claim them one by one from many.
const ITEMS_PER_TASK: usize = 16;

/// Runs of a ray batch per task, claimed one at a time. A pool thread starts
/// on its first run 34 to 100 µs after the call; with several runs each, the
/// calling thread casts more of them meanwhile instead of waiting for the
/// pool thread to finish a fixed half. 1,000 incoherent rays on 2 threads,
/// against about 0.65 ms on one: 0.48 ms with one run per task, 0.42 ms
/// with 4, 0.37 ms with 8, 0.40 ms with 16 (runs are also kept to at least
/// `min_rays_per_task` rays). Measured again once the calling thread spun
/// at the end (against about 0.29 ms on one thread): 4 runs gained 1.83 to
/// 2.0 × on incoherent rays but 1.40 to 1.52 × on the clear-eye camera rays,
/// 8 runs 1.66 to 1.91 × and 1.52 to 1.61 ×, 16 runs 1.58 to 1.86 × and
/// 1.58 to 1.62 ×.
const RAY_RUNS_PER_TASK: usize = 8;

/// The fewest rays in a run. Runs were first kept to `min_rays_per_task`
/// rays (64 by default), which cut 1,000 rays into only 15 runs: on 16
/// threads that is one run a task, with no runs left to even out the pool
/// threads' late starts. A run's own cost (a batch's setup) is a few
/// hundred nanoseconds, small against 16 rays' walks.
const MIN_RAYS_PER_RUN: usize = 16;

impl<K: Copy + Ord + Send + Sync, const W: usize> RTree<K, W> {
    /// [`RTree::cast_rays`] on the task pool: the batch is cut into runs of
    /// consecutive rays (keep coherent rays next to each other), a few per
    /// thread, each cast as its own batch by whichever task claims it next.
    /// `out` is identical to the single-threaded call's.
    ///
    /// Rays that need no walk because they share an origin inside an entry
    /// (see [`RTree::cast_rays`]) do not count towards splitting: camera
    /// rays from an eye inside a box are answered on the calling thread.
    pub fn par_cast_rays(
        &self,
        rays: &[Ray],
        mode: RayMode,
        pws: &mut ParallelWorkspace<K>,
        out: &mut RayResults<K>,
    ) {
        // Split runs would each ask the shared-origin query again, for
        // rays that leave no walk to share.
        let mut count = task_count(rays.len(), pws.min_rays_per_task);
        if count > 1 {
            let ws = &mut pws.tasks(1)[0].ws;
            // The estimate is not part of the answer: its point queries stay
            // out of the stats, which then count what one thread counts.
            let before = ws.stats;
            let walking = rays.len() - self.rays_answered_at_shared_origins(rays, mode, ws);
            ws.stats = before;
            count = task_count(walking, pws.min_rays_per_task);
        }
        if count == 1 {
            self.cast_rays(rays, mode, &mut pws.tasks(1)[0].ws, out);
            return;
        }
        let runs = (count * RAY_RUNS_PER_TASK)
            .min(rays.len() / pws.min_rays_per_task.min(MIN_RAYS_PER_RUN))
            .max(count);
        if pws.ray_runs.len() < runs {
            pws.ray_runs.resize_with(runs, || RayRun {
                rays: 0..0,
                out: Mutex::default(),
            });
        }
        for (i, run) in pws.ray_runs[..runs].iter_mut().enumerate() {
            run.rays = i * rays.len() / runs..(i + 1) * rays.len() / runs;
        }
        pws.tasks(count);
        let ParallelWorkspace {
            tasks, ray_runs, ..
        } = pws;
        run_claimed(&ray_runs[..runs], &mut tasks[..count], |run, task| {
            let mut run_out = run.out.lock().unwrap_or_else(|e| e.into_inner());
            self.cast_rays(&rays[run.rays.clone()], mode, &mut task.ws, &mut run_out);
        });
        out.clear();
        for run in ray_runs[..runs].iter_mut() {
            out.append(run.out.get_mut().unwrap_or_else(|e| e.into_inner()));
        }
    }

    /// [`RTree::visible_into`] on the task pool. Each list of `out` gets the
    /// same keys in the same order as from the single-threaded call (`out`
    /// is made one list per frustum first, as there). Small
    /// culls run on the calling thread (see
    /// [`ParallelWorkspace::with_min_view_entries_to_split`]).
    pub fn par_visible_into(
        &self,
        frustums: &[Frustum],
        mode: CullMode,
        pws: &mut ParallelWorkspace<K>,
        out: &mut Vec<Vec<K>>,
    ) {
        out.resize_with(frustums.len(), Vec::new);
        let view_entries = self.len().saturating_mul(frustums.len());
        let count = if view_entries < pws.min_view_entries_to_split {
            1
        } else {
            pws.tree_split(self.len())
        };
        if count == 1 {
            let ws = &mut pws.tasks(1)[0].ws;
            self.visible_into(frustums, mode, ws, out);
            return;
        }
        for (chunk, views) in frustums.chunks(FRUSTUMS_PER_PASS).enumerate() {
            let out = &mut out[chunk * FRUSTUMS_PER_PASS..][..views.len()];
            let views: Vec<PreparedView> =
                views.iter().map(|f| PreparedView::new(f, mode)).collect();
            self.par_cull_pass(&views, count, pws, out);
        }
    }

    fn par_cull_pass(
        &self,
        views: &[PreparedView],
        count: usize,
        pws: &mut ParallelWorkspace<K>,
        out: &mut [Vec<K>],
    ) {
        pws.tasks(count);
        let tasks = &mut pws.tasks[..count];
        for task in tasks.iter_mut() {
            task.keys.resize_with(views.len(), Vec::new);
            task.keys.iter_mut().for_each(Vec::clear);
            task.ends.clear();
        }
        let [frontier, next] = &mut pws.cull_frontier;
        let prepare = move |first: &mut TaskScratch<K>| {
            // Moved into the closure's body (so that it runs once), the
            // borrow the items come from can outlive the call.
            let frontier = { frontier };
            let ws = &mut first.ws;
            cut_frontier(
                frontier,
                next,
                self.cull_start(views),
                count * ITEMS_PER_TASK,
                // A subtree inside every plane is not cut further: cutting
                // it too (it is walked level by level and reports nothing
                // above its leaves) measured worse on the 16-core machine,
                // four views 2.30 → 2.11 × at 8 threads and 2.15 → 1.53 × at
                // 16 (docs/performance.md, "Sixteen cores").
                |(node, mask)| self.node(node).is_leaf() || fully_inside(mask),
                |item, pushed| {
                    ws.stats.nodes_visited += 1;
                    self.push_visible_children::<false>(views, item, true, pushed);
                },
            )
        };
        let frontier = run_prepared(tasks, prepare, |&item, task| {
            let keys = &mut task.keys;
            let _ =
                self.cull_subtree::<false, _>(views, item, &mut task.ws, &mut |view, key, _| {
                    keys[view].push(key);
                    ControlFlow::Continue(())
                });
            task.ends.extend(keys.iter().map(Vec::len));
        });
        pws.last_split = count.min(frontier.len()).max(1);
        let owner = &mut pws.owner;
        owners(tasks.iter().map(|t| &t.taken[..]), frontier.len(), owner);
        // A stack runs its last items first: the last item's answers come first.
        for &(task, rank) in owner.iter().rev() {
            let task = &tasks[task as usize];
            for (view, list) in out.iter_mut().enumerate() {
                let range = segment(&task.ends, rank as usize, views.len(), view);
                list.extend_from_slice(&task.keys[view][range]);
            }
        }
    }

    /// [`RTree::self_join_into`] on the task pool: appends the same pairs in
    /// the same order as the single-threaded call.
    pub fn par_self_join_into(
        &self,
        distance: f32,
        mode: JoinMode,
        pws: &mut ParallelWorkspace<K>,
        out: &mut Vec<(K, K)>,
    ) -> Result<(), SpatialError> {
        let test = JoinTest::new(distance, mode)?;
        let count = pws.tree_split(self.len());
        if count == 1 {
            let ws = &mut pws.tasks(1)[0].ws;
            return self.self_join_into(distance, mode, ws, out);
        }
        let root = self.root();
        self.par_join(
            JoinItem::roots(root, root),
            count,
            pws,
            out,
            |item| self.node(item.a).is_leaf(),
            |pair, ws, mut visit| self.self_join_step(pair, test, ws, four_lane_masks, &mut visit),
            |ws, pairs| {
                self.drain_self_join(test, ws, &mut |a, b| {
                    pairs.push((a, b));
                    ControlFlow::Continue(())
                })
            },
        );
        Ok(())
    }

    /// [`RTree::cross_join_into`] on the task pool: appends the same pairs
    /// in the same order as the single-threaded call.
    pub fn par_cross_join_into(
        &self,
        other: &RTree<K, W>,
        distance: f32,
        mode: JoinMode,
        pws: &mut ParallelWorkspace<K>,
        out: &mut Vec<(K, K)>,
    ) -> Result<(), SpatialError> {
        let test = JoinTest::new(distance, mode)?;
        let count = pws.tree_split(self.len().max(other.len()));
        if count == 1 || self.is_empty() || other.is_empty() {
            let ws = &mut pws.tasks(1)[0].ws;
            return self.cross_join_into(other, distance, mode, ws, out);
        }
        self.par_join(
            self.cross_join_roots(other, test),
            count,
            pws,
            out,
            |item| self.node(item.a).is_leaf() && other.node(item.b).is_leaf(),
            |pair, ws, mut visit| {
                self.cross_join_step(other, pair, test, ws, four_lane_masks, &mut visit)
            },
            |ws, pairs| {
                self.drain_cross_join(other, test, ws, &mut |a, b| {
                    pairs.push((a, b));
                    ControlFlow::Continue(())
                })
            },
        );
        Ok(())
    }

    /// The split shared by both joins, from the root pair `start`: `step`
    /// expands one pair while the split runs breadth first (on the
    /// four-lane test: a few dozen pairs, which every lane test expands
    /// alike), `drain` runs a task's stack of pairs to the end and appends
    /// the entry pairs it finds to the task's list. `step` takes its
    /// visitor as `dyn` (it runs on a few dozen pairs and reports none);
    /// `drain` calls its own, concrete one once per reported pair.
    #[allow(clippy::too_many_arguments)]
    fn par_join<Step, Drain>(
        &self,
        start: JoinItem,
        count: usize,
        pws: &mut ParallelWorkspace<K>,
        out: &mut Vec<(K, K)>,
        may_report: impl Fn(JoinItem) -> bool,
        step: Step,
        drain: Drain,
    ) where
        Step: Fn(
            JoinItem,
            &mut QueryWorkspace,
            &mut dyn FnMut(K, K) -> ControlFlow<()>,
        ) -> ControlFlow<()>,
        Drain: Fn(&mut QueryWorkspace, &mut Vec<(K, K)>) -> ControlFlow<()> + Sync,
    {
        pws.tasks(count);
        let tasks = &mut pws.tasks[..count];
        for task in tasks.iter_mut() {
            task.pairs.clear();
            task.ends.clear();
        }
        let [frontier, next] = &mut pws.join_frontier;
        let prepare = move |first: &mut TaskScratch<K>| {
            // As in `par_cull_pass`: moved in, the borrow outlives the call.
            let frontier = { frontier };
            let ws = &mut first.ws;
            cut_frontier(
                frontier,
                next,
                [start],
                count * ITEMS_PER_TASK,
                may_report,
                |pair, pushed| {
                    ws.join_stack.clear();
                    let _ = step(pair, ws, &mut |_, _| reports_nothing(()));
                    pushed.extend_from_slice(&ws.join_stack);
                },
            )
        };
        let frontier = run_prepared(tasks, prepare, |&item, task| {
            task.ws.join_stack.clear();
            task.ws.join_stack.push(item);
            let _ = drain(&mut task.ws, &mut task.pairs);
            task.ends.push(task.pairs.len());
        });
        pws.last_split = count.min(frontier.len()).max(1);
        let owner = &mut pws.owner;
        owners(tasks.iter().map(|t| &t.taken[..]), frontier.len(), owner);
        // A stack runs its last items first: the last item's pairs come first.
        for &(task, rank) in owner.iter().rev() {
            let task = &tasks[task as usize];
            out.extend_from_slice(&task.pairs[segment(&task.ends, rank as usize, 1, 0)]);
        }
    }
}
