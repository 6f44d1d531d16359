//! How the parallel queries (`parallel.rs`) share their work among the
//! pool's threads and put the answers back in order: tasks claim items one
//! at a time, a traversal is first cut into a frontier of items, and each
//! item's answers are found again by the task and rank that took it.
//!
//! Tasks are as many as the pool has threads, and the calling thread works
//! as one of them. Work is claimed in pieces rather than cut into one share
//! per task, so a thread that starts late simply takes less: on the 2-core
//! machine the benches ran on, a pool thread took 34 to 100 µs to start on
//! a task when calls came back to back (up to 320 µs after a few
//! milliseconds of idle); on the 16-core machine of the scaling runs, the
//! first of 15 tasks started after 8 to 11 µs and the last after 15 to
//! 18 µs (`benches/parallel.rs`, "pool start"). The pool tasks are spawned
//! before the calling thread cuts the frontier, so that they wake
//! meanwhile. When the calling thread runs out of work while a pool task
//! still finishes its last piece, it spins for a short while (see
//! `SPIN_WAIT`) rather than park: waking a parked thread costs as much as
//! starting one.

use std::ops::{ControlFlow, Range};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use bevy_tasks::{ComputeTaskPool, TaskPool};

use super::parallel_workspace::TaskScratch;

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
/// draws cheap items simply takes more of them. Items are claimed last
/// first: a frontier expanded in part (`expand_frontier`) keeps its larger,
/// unexpanded items at the end, and starting those first leaves the small
/// ones to even out the finish. Each task notes the indices it took, in
/// order, in its `taken`.
pub(super) fn run_claimed<T: Sync, K: Send>(
    items: &[T],
    tasks: &mut [TaskScratch<K>],
    body: impl Fn(&T, &mut TaskScratch<K>) + Sync,
) {
    run_prepared(tasks, |_| items, body);
}

/// [`run_claimed`] over items that `prepare` makes on the calling thread
/// (with the first task's scratch) once the pool tasks are spawned: a pool
/// thread takes about 10 µs to start on a task (see the module docs), and
/// the threads start while the items are made instead of after. A pool
/// task that starts before the items are made waits for them. Returns the
/// items.
pub(super) fn run_prepared<'a, T: Sync + 'a, K: Send>(
    tasks: &mut [TaskScratch<K>],
    prepare: impl FnOnce(&mut TaskScratch<K>) -> &'a [T],
    body: impl Fn(&T, &mut TaskScratch<K>) + Sync,
) -> &'a [T] {
    let next = AtomicUsize::new(0);
    let (next, body) = (&next, &body);
    let take = move |items: &[T], task: &mut TaskScratch<K>| loop {
        let claimed = next.fetch_add(1, Ordering::Relaxed);
        let Some(index) = items.len().checked_sub(claimed + 1) else {
            break;
        };
        task.taken.push(index as u32);
        body(&items[index], task);
    };
    tasks.iter_mut().for_each(|task| task.taken.clear());
    let (first, rest) = tasks.split_first_mut().expect("at least one task");
    if rest.is_empty() {
        // One task: no scope to enter, no thread to wake.
        let items = prepare(first);
        take(items, first);
        return items;
    }
    let published = Published::default();
    let working = AtomicUsize::new(0);
    let (published, working) = (&published, &working);
    let mut made: &[T] = &[];
    pool().scope(|scope| {
        for task in rest.iter_mut() {
            // Counted while it works, so that the calling thread knows
            // whether a pool task is still busy when it runs out of work.
            scope.spawn(async move {
                working.fetch_add(1, Ordering::AcqRel);
                if let Some(items) = published.wait() {
                    take(items, task);
                }
                working.fetch_sub(1, Ordering::Release);
            });
        }
        let unblock = published.unblock_on_drop();
        made = prepare(first);
        published.publish(made);
        drop(unblock);
        // The calling thread works too rather than wait.
        take(made, first);
        spin_while_working(working);
    });
    made
}

/// The items of [`run_prepared`], handed from the calling thread to the
/// pool tasks; `None` if making them panicked, so that no task waits on.
struct Published<'a, T>(OnceLock<Option<&'a [T]>>);

impl<T> Default for Published<'_, T> {
    fn default() -> Self {
        Self(OnceLock::new())
    }
}

impl<'a, T> Published<'a, T> {
    fn publish(&self, items: &'a [T]) {
        let _ = self.0.set(Some(items));
    }

    /// Spins briefly, then yields (the calling thread may be waiting for
    /// this one's core), until the items are published.
    fn wait(&self) -> Option<&'a [T]> {
        let mut round = 0u32;
        loop {
            if let Some(&items) = self.0.get() {
                return items;
            }
            if round < 256 {
                round += 1;
                std::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
    }

    /// A guard that publishes `None` when dropped before the items were
    /// published (while unwinding from a panic in making them).
    fn unblock_on_drop(&self) -> impl Drop + '_ {
        struct Unblock<'p, 'a, T>(&'p Published<'a, T>);
        impl<T> Drop for Unblock<'_, '_, T> {
            fn drop(&mut self) {
                let _ = self.0.0.set(None);
            }
        }
        Unblock(self)
    }
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
pub(super) fn owners<'a>(
    taken: impl Iterator<Item = &'a [u32]>,
    items: usize,
    owner: &mut Vec<(u32, u32)>,
) {
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
pub(super) fn segment(ends: &[usize], rank: usize, lists: usize, list: usize) -> Range<usize> {
    let start = if rank == 0 {
        0
    } else {
        ends[(rank - 1) * lists + list]
    };
    start..ends[rank * lists + list]
}

/// The frontier a split traversal shares out: the items of `start`,
/// expanded by [`expand_frontier`], in the reused buffers `frontier` and
/// `next`.
pub(super) fn cut_frontier<'a, T: Copy>(
    frontier: &'a mut Vec<T>,
    next: &mut Vec<T>,
    start: impl IntoIterator<Item = T>,
    target: usize,
    may_report: impl Fn(T) -> bool,
    step: impl FnMut(T, &mut Vec<T>),
) -> &'a [T] {
    frontier.clear();
    frontier.extend(start);
    expand_frontier(frontier, next, target, may_report, step);
    frontier
}

/// Replaces the pending items of a depth-first traversal by the items they
/// push, one level at a time and the last level only in part, until there
/// are at least `target` or the next step could report an answer. With
/// `step` pushing in the traversal's own order, running the stack from the
/// new frontier reaches every answer in the same order as from the old
/// one: each item's pushes take its place, whichever items were expanded.
pub(super) fn expand_frontier<T: Copy>(
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
        let mut expanded = 0;
        for &item in frontier.iter() {
            step(item, next);
            expanded += 1;
            // Stop within the level once there are enough: a level can
            // multiply the items by the node width, and the expansion runs
            // on one thread while the others wait (a full level took the
            // 16-thread cross join 2,347 items and as long as the whole
            // join on one thread).
            if next.len() + (frontier.len() - expanded) >= target {
                break;
            }
        }
        next.extend_from_slice(&frontier[expanded..]);
        std::mem::swap(frontier, next);
    }
}

/// A visitor for steps that must not report (debug builds check it).
pub(super) fn reports_nothing<T>(_: T) -> ControlFlow<()> {
    debug_assert!(false, "a frontier step reported an answer");
    ControlFlow::Continue(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The leaves below `frontier` in the order a depth-first stack started
    /// from it reports them, in a tree where node `n` below `depth` has
    /// children `n * width + 1 ..= n * width + width`.
    fn stack_order(frontier: &[(u32, u32)], width: u32, depth: u32) -> Vec<u32> {
        let mut stack = frontier.to_vec();
        let mut leaves = Vec::new();
        while let Some((node, level)) = stack.pop() {
            if level == depth {
                leaves.push(node);
            } else {
                stack.extend((1..=width).map(|c| (node * width + c, level + 1)));
            }
        }
        leaves
    }

    #[test]
    fn a_frontier_cut_within_a_level_keeps_the_stack_order() {
        let (width, depth) = (5, 4);
        let whole = stack_order(&[(0, 0)], width, depth);
        for target in 1..200 {
            let (mut frontier, mut next) = (vec![(0u32, 0u32)], Vec::new());
            expand_frontier(
                &mut frontier,
                &mut next,
                target,
                |(_, level)| level == depth,
                |(node, level), pushed| {
                    pushed.extend((1..=width).map(|c| (node * width + c, level + 1)));
                },
            );
            let reached = frontier.len() >= target || frontier.iter().any(|&(_, l)| l == depth);
            assert!(reached, "target {target}: stopped at {}", frontier.len());
            // Cut within a level: never more than one node's children over.
            let levels = frontier.iter().map(|&(_, l)| l);
            if levels.clone().max() != levels.min() {
                assert!(frontier.len() < target + width as usize, "target {target}");
            }
            assert_eq!(
                stack_order(&frontier, width, depth),
                whole,
                "target {target}"
            );
        }
    }

    #[test]
    fn every_item_is_claimed_once_and_its_owner_found() {
        let items: Vec<u32> = (0..1000).collect();
        let threads = pool().thread_num().max(2);
        let mut tasks: Vec<TaskScratch<u32>> = (0..threads).map(|_| Default::default()).collect();
        run_claimed(&items, &mut tasks, |&item, task| {
            task.pairs.push((item, item))
        });
        let mut owner = Vec::new();
        owners(tasks.iter().map(|t| &t.taken[..]), items.len(), &mut owner);
        for (index, &(task, rank)) in owner.iter().enumerate() {
            let pair = tasks[task as usize].pairs[rank as usize];
            assert_eq!(pair, (index as u32, index as u32));
        }
        let claimed: usize = tasks.iter().map(|t| t.taken.len()).sum();
        assert_eq!(claimed, items.len());
    }

    /// A pool task that started before the items were made must not wait
    /// for them forever when making them panics: the scope waits for it.
    #[test]
    fn a_panic_while_making_the_items_releases_the_waiting_tasks() {
        let threads = pool().thread_num().max(2);
        let mut tasks: Vec<TaskScratch<u32>> = (0..threads).map(|_| Default::default()).collect();
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            run_prepared(
                &mut tasks,
                |_| -> &[u32] {
                    // Long enough for the pool tasks to start and wait.
                    std::thread::sleep(Duration::from_millis(50));
                    panic!("making the items failed");
                },
                |_, _| {},
            );
        }));
        assert!(result.is_err());
    }
}
