//! The parallel queries' scratch memory and thresholds (feature
//! `parallel`): one workspace and answer buffers per task, kept from call
//! to call.

use std::ops::Range;
use std::sync::Mutex;

use super::frustum::CullItem;
use super::join::JoinItem;
use super::{QueryWorkspace, RayResults};
use crate::tree::QueryStats;

/// Scratch memory of the parallel queries: one [`QueryWorkspace`] and answer
/// buffers per task, reused from call to call, and the thresholds below
/// which a query runs on the calling thread.
///
/// ```
/// use bevy_rtree::{Aabb, ParallelWorkspace, RTree, Ray, RayMode, RayResults};
/// use bevy_rtree::glam::Vec3;
///
/// let mut tree = RTree::new();
/// for i in 0..100u32 {
///     let x = i as f32 * 2.0;
///     tree.insert(i, Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))?)?;
/// }
/// let rays: Vec<Ray> = (0..100)
///     .map(|i| Ray::new(Vec3::new(i as f32 * 2.0 + 0.5, 0.5, 10.0), Vec3::NEG_Z, 20.0))
///     .collect::<Result<_, _>>()?;
/// // Split even this small batch, to show it: by default it would run on one thread.
/// let mut pws = ParallelWorkspace::default().with_min_rays_per_task(1);
/// let mut out = RayResults::default();
/// tree.par_cast_rays(&rays, RayMode::First, &mut pws, &mut out);
/// assert_eq!(out.first(42)?.map(|hit| (hit.key, hit.t)), Some((42, 9.0)));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Debug)]
pub struct ParallelWorkspace<K> {
    pub(super) tasks: Vec<TaskScratch<K>>,
    pub(super) cull_frontier: [Vec<CullItem>; 2],
    pub(super) join_frontier: [Vec<JoinItem>; 2],
    /// Per frontier item: the task that took it and its rank there.
    pub(super) owner: Vec<(u32, u32)>,
    /// The runs of a ray batch, each with its answers.
    pub(super) ray_runs: Vec<RayRun<K>>,
    pub(super) min_rays_per_task: usize,
    pub(super) min_entries_to_split: usize,
    pub(super) min_view_entries_to_split: usize,
    pub(super) last_split: usize,
}

/// A run of consecutive rays of a batch and its answers. The lock is never
/// contended: a run is claimed by one task, and read after all have ended.
#[derive(Debug)]
pub(super) struct RayRun<K> {
    pub(super) rays: Range<usize>,
    pub(super) out: Mutex<RayResults<K>>,
}

/// What one task owns while it runs.
#[derive(Debug)]
pub(super) struct TaskScratch<K> {
    pub(super) ws: QueryWorkspace,
    pub(super) keys: Vec<Vec<K>>,
    pub(super) pairs: Vec<(K, K)>,
    /// Per item taken (per view, for culling): the answer count after it.
    pub(super) ends: Vec<usize>,
    /// The indices of the items taken, in order.
    pub(super) taken: Vec<u32>,
}

impl<K> Default for TaskScratch<K> {
    fn default() -> Self {
        TaskScratch {
            ws: QueryWorkspace::default(),
            keys: Vec::new(),
            pairs: Vec::new(),
            ends: Vec::new(),
            taken: Vec::new(),
        }
    }
}

// Not derived: an empty workspace needs no default key.
impl<K> Default for ParallelWorkspace<K> {
    fn default() -> Self {
        ParallelWorkspace {
            tasks: Vec::new(),
            cull_frontier: [Vec::new(), Vec::new()],
            join_frontier: [Vec::new(), Vec::new()],
            owner: Vec::new(),
            ray_runs: Vec::new(),
            min_rays_per_task: 64,
            min_entries_to_split: 4096,
            min_view_entries_to_split: 200_000,
            last_split: 0,
        }
    }
}

impl<K> ParallelWorkspace<K> {
    /// A batch is split only into runs of at least this many rays (default
    /// 64; at least 1), not counting rays answered at a shared origin.
    ///
    /// Splitting pays only when the batch takes several times longer than a
    /// pool thread takes to start, and a thread that slept between frames
    /// can be slow to start. On the 2-core virtual machine the benches ran
    /// on, 1,000 incoherent rays gained 1.51–1.65 × back to back, but lost
    /// (0.80–0.82 ×) when each call came after 2 ms of idle, while 4,000
    /// rays gained 1.71–1.73 × back to back. If your pool idles between
    /// frames, raise this so that batches of a few thousand rays stay on
    /// the calling thread.
    pub fn with_min_rays_per_task(mut self, rays: usize) -> Self {
        self.min_rays_per_task = rays.max(1);
        self
    }

    /// Culling and joins are split only over trees of at least this many
    /// entries (default 4096; a join counts the larger tree).
    pub fn with_min_entries_to_split(mut self, entries: usize) -> Self {
        self.min_entries_to_split = entries;
        self
    }

    /// A cull is split only when its views times the tree's entries reach
    /// this (default 200,000: two views of the standard 100,000-entity
    /// scene), besides the tree reaching `min_entries_to_split`.
    ///
    /// One view of a tree that size is culled in about 50 µs on the 2-core
    /// machine the benches ran on, less than a pool thread takes to start
    /// (70 to 100 µs): split, it took 10 to 20 % longer; two views broke
    /// even or gained up to 16 %, four gained 28 to 53 %.
    pub fn with_min_view_entries_to_split(mut self, view_entries: usize) -> Self {
        self.min_view_entries_to_split = view_entries;
        self
    }

    /// How many tasks the last query ran as (`1`: on the calling thread).
    pub fn last_split(&self) -> usize {
        self.last_split
    }

    /// The counters of every task, summed.
    pub fn stats(&self) -> QueryStats {
        self.tasks.iter().fold(QueryStats::default(), |sum, task| {
            let s = task.ws.stats();
            QueryStats {
                nodes_visited: sum.nodes_visited + s.nodes_visited,
                entries_tested: sum.entries_tested + s.entries_tested,
            }
        })
    }

    /// Returns the summed counters and resets them to zero.
    pub fn take_stats(&mut self) -> QueryStats {
        let stats = self.stats();
        for task in &mut self.tasks {
            task.ws.take_stats();
        }
        stats
    }

    /// How many tasks a cull or join over a tree of `entries` entries is
    /// split into; `1` means "run on the calling thread".
    pub(super) fn tree_split(&self, entries: usize) -> usize {
        if entries < self.min_entries_to_split {
            1
        } else {
            super::parallel_claim::task_count(usize::MAX, 1)
        }
    }

    /// The scratch of `count` tasks (at least one), noted as the last split.
    pub(super) fn tasks(&mut self, count: usize) -> &mut [TaskScratch<K>] {
        let count = count.max(1);
        self.last_split = count;
        if self.tasks.len() < count {
            self.tasks.resize_with(count, TaskScratch::default);
        }
        &mut self.tasks[..count]
    }
}
