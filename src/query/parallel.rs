//! Parallel batched rays, culling and joins (feature `parallel`).
//!
//! The work runs on bevy_tasks' [`ComputeTaskPool`], the pool a Bevy app
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
//! Tasks are as many as the pool has threads, and the calling thread works
//! as one of them: on the 2-core machine the benches ran on, a pool thread
//! took 34 to 100 µs to start on a task when calls came back to back (up
//! to 320 µs after a few milliseconds of idle), so more, smaller tasks
//! lost more than they balanced. Work is claimed in pieces instead, so the calling
//! thread does more of it while a pool thread is starting. When the calling
//! thread runs out of work while a pool task still finishes its last piece,
//! it spins for a short while (see `SPIN_WAIT`) rather than park: waking a
//! parked thread costs as much as starting one.
//!
//! Small work runs on the calling thread: splitting costs a few
//! microseconds per task, more than a few dozen rays or a small tree take.

use std::ops::{ControlFlow, Range};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use bevy_tasks::{ComputeTaskPool, TaskPool};

use super::frustum::{PreparedView, fully_inside};
use super::join::{JoinItem, JoinTest, four_lane_masks};
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

/// How long the calling thread, out of work, spins while a pool task
/// finishes its last item, before it leaves the wait to the pool's scope.
/// The scope parks the thread, and a parked thread took about 40 µs to wake
/// on the 2-core machine the benches ran on: longer than most last items
/// take (a run of rays: about 20 µs). 1,000 incoherent rays on 2 threads
/// went from 1.47–1.51 × to 1.66–1.97 × the single-threaded speed with the
/// spin in a probe (medians of single calls), from 1.50–1.55 × to
/// 1.61–1.79 × in the bench; the joins did not move.
const SPIN_WAIT: Duration = Duration::from_micros(100);

/// The pool the queries run on.
fn pool() -> &'static TaskPool {
    ComputeTaskPool::get_or_init(TaskPool::default)
}

/// How many tasks to split `units` of work into, at least `min_per_task`
/// each; `1` means "run on the calling thread".
pub(super) fn task_count(units: usize, min_per_task: usize) -> usize {
    let threads = pool().thread_num();
    if threads < 2 {
        return 1;
    }
    // One task per thread: measured on 2 threads, more and smaller batches
    // of rays cost more per ray than the better balance saves.
    threads.min(units / min_per_task.max(1)).max(1)
}

/// Runs `body(item, task)` for every item on the pool: each task claims the
/// next unclaimed item until none is left, so a thread that starts late or
/// draws cheap items simply takes more of them. Each task notes the indices
/// it took, in order, in its `taken`.
fn run_claimed<T: Sync, K: Send>(
    items: &[T],
    tasks: &mut [TaskScratch<K>],
    body: impl Fn(&T, &mut TaskScratch<K>) + Sync,
) {
    let next = AtomicUsize::new(0);
    let (next, body) = (&next, &body);
    let take = move |task: &mut TaskScratch<K>| {
        task.taken.clear();
        loop {
            let index = next.fetch_add(1, Ordering::Relaxed);
            let Some(item) = items.get(index) else { break };
            task.taken.push(index as u32);
            body(item, task);
        }
    };
    let (first, rest) = tasks.split_first_mut().expect("at least one task");
    if rest.is_empty() {
        // One task: no scope to enter, no thread to wake.
        take(first);
        return;
    }
    let working = AtomicUsize::new(0);
    let working = &working;
    pool().scope(|scope| {
        for task in rest.iter_mut() {
            // Counted while it works, so that the calling thread knows
            // whether a pool task is still busy when it runs out of work.
            scope.spawn(async move {
                working.fetch_add(1, Ordering::AcqRel);
                take(task);
                working.fetch_sub(1, Ordering::Release);
            });
        }
        // The calling thread works too rather than wait.
        take(first);
        spin_while_working(working);
    });
}

/// Spins while `working` pool tasks are still running, for at most
/// [`SPIN_WAIT`]. A task that has not started yet is not waited for: the
/// scope runs it on the calling thread if the pool has not, and it finds
/// nothing left to claim.
fn spin_while_working(working: &AtomicUsize) {
    let start = Instant::now();
    while working.load(Ordering::Acquire) > 0 && start.elapsed() < SPIN_WAIT {
        std::hint::spin_loop();
    }
}

/// For every item, the task that took it and its rank among that task's
/// items, from each task's `taken` list.
fn owners<'a>(taken: impl Iterator<Item = &'a [u32]>, items: usize, owner: &mut Vec<(u32, u32)>) {
    owner.clear();
    owner.resize(items, (0, 0));
    for (task, indices) in taken.enumerate() {
        for (rank, &index) in indices.iter().enumerate() {
            owner[index as usize] = (task as u32, rank as u32);
        }
    }
}

/// Where answer list `list` of a task's `rank`-th item sits in that task's
/// list, when the task records after each item the length of each of its
/// `lists` answer lists (`ends[rank * lists + list]`).
fn segment(ends: &[usize], rank: usize, lists: usize, list: usize) -> Range<usize> {
    let start = if rank == 0 {
        0
    } else {
        ends[(rank - 1) * lists + list]
    };
    start..ends[rank * lists + list]
}

/// Replaces the pending items of a depth-first traversal by the items they
/// push, one level at a time, until there are at least `target` or the next
/// step could report an answer. With `step` pushing in the traversal's own
/// order, running the stack from the new frontier reaches every answer in
/// the same order as from the old one: each item's pushes take its place.
fn expand_frontier<T: Copy>(
    frontier: &mut Vec<T>,
    next: &mut Vec<T>,
    target: usize,
    may_report: impl Fn(T) -> bool,
    mut step: impl FnMut(T, &mut Vec<T>),
) {
    while !frontier.is_empty()
        && frontier.len() < target
        && !frontier.iter().any(|&item| may_report(item))
    {
        next.clear();
        for &item in frontier.iter() {
            step(item, next);
        }
        std::mem::swap(frontier, next);
    }
}

/// A visitor for steps that must not report (debug builds check it).
fn reports_nothing<T>(_: T) -> ControlFlow<()> {
    debug_assert!(false, "a frontier step reported an answer");
    ControlFlow::Continue(())
}

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
            .min(rays.len() / pws.min_rays_per_task)
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
        let [frontier, next] = &mut pws.cull_frontier;
        frontier.clear();
        frontier.extend(self.cull_start(views));
        let ws = &mut pws.tasks[0].ws;
        expand_frontier(
            frontier,
            next,
            count * ITEMS_PER_TASK,
            // A subtree inside every plane is not cut further. (It is
            // walked level by level like any other, so it could be: a view
            // over the whole scene then goes to as many tasks as the root
            // has children. Whether cutting it pays on 8 or 16 threads is
            // still to be measured.)
            |(node, mask)| self.node(node).is_leaf() || fully_inside(mask),
            |item, pushed| {
                ws.stats.nodes_visited += 1;
                self.push_visible_children::<false>(views, item, true, pushed);
            },
        );
        let frontier = &pws.cull_frontier[0];
        let count = count.min(frontier.len()).max(1);
        pws.last_split = count;
        let tasks = &mut pws.tasks[..count];
        for task in tasks.iter_mut() {
            task.keys.resize_with(views.len(), Vec::new);
            task.keys.iter_mut().for_each(Vec::clear);
            task.ends.clear();
        }
        run_claimed(frontier, tasks, |&item, task| {
            let keys = &mut task.keys;
            let _ =
                self.cull_subtree::<false, _>(views, item, &mut task.ws, &mut |view, key, _| {
                    keys[view].push(key);
                    ControlFlow::Continue(())
                });
            task.ends.extend(keys.iter().map(Vec::len));
        });
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
        let ws = &mut pws.tasks[0].ws;
        let [frontier, next] = &mut pws.join_frontier;
        frontier.clear();
        frontier.push(start);
        expand_frontier(
            frontier,
            next,
            count * ITEMS_PER_TASK,
            may_report,
            |pair, pushed| {
                ws.join_stack.clear();
                let _ = step(pair, ws, &mut |_, _| reports_nothing(()));
                pushed.extend_from_slice(&ws.join_stack);
            },
        );
        let count = count.min(frontier.len()).max(1);
        let tasks = &mut pws.tasks[..count];
        pws.last_split = count;
        let frontier = &pws.join_frontier[0];
        for task in tasks.iter_mut() {
            task.pairs.clear();
            task.ends.clear();
        }
        run_claimed(frontier, tasks, |&item, task| {
            task.ws.join_stack.clear();
            task.ws.join_stack.push(item);
            let _ = drain(&mut task.ws, &mut task.pairs);
            task.ends.push(task.pairs.len());
        });
        let owner = &mut pws.owner;
        owners(tasks.iter().map(|t| &t.taken[..]), frontier.len(), owner);
        // A stack runs its last items first: the last item's pairs come first.
        for &(task, rank) in owner.iter().rev() {
            let task = &tasks[task as usize];
            out.extend_from_slice(&task.pairs[segment(&task.ends, rank as usize, 1, 0)]);
        }
    }
}
