//! Reusable traversal state.

use crate::tree::QueryStats;

/// Scratch memory and counters for queries.
///
/// Keep one per system or thread and pass it to every query: its buffers grow
/// to the largest query seen and are then reused, and its [`QueryStats`]
/// accumulate the work done until [`QueryWorkspace::take_stats`].
///
/// ```
/// use bevy_rtree::{Aabb, QueryWorkspace, RTree};
/// use bevy_rtree::glam::Vec3;
///
/// let mut tree = RTree::new();
/// tree.insert(1u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
/// let mut ws = QueryWorkspace::default();
/// let mut hits = Vec::new();
/// tree.visit_overlapping(&Aabb::new(Vec3::ZERO, Vec3::ONE)?, &mut ws, |key, _| {
///     hits.push(key);
///     std::ops::ControlFlow::Continue(())
/// });
/// assert_eq!(hits, [1]);
/// assert_eq!(ws.take_stats().nodes_visited, 1);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct QueryWorkspace {
    /// Depth-first traversal stack of node indices; grows, never drops work.
    pub(crate) stack: Vec<u32>,
    /// Frustum traversal: nodes with their per-view plane masks. The cull
    /// (`frustum_levels.rs`) keeps one level of the tree here, in the order
    /// of a depth-first stack; the proving cull uses it as its stack.
    pub(crate) cull_stack: Vec<(u32, u64)>,
    /// The cull's next level, built from `cull_stack`'s.
    pub(crate) cull_level: Vec<(u32, u64)>,
    /// The leaves of a subtree reported whole, in the order they report.
    pub(crate) leaves: Vec<u32>,
    /// Single-ray traversal: a stack of node indices and their entry `t`,
    /// and where the last walked ray started.
    pub(crate) ray_walk: super::ray::RayWalkScratch,
    /// Join traversal stack: pairs of node indices.
    pub(crate) join_stack: Vec<super::join::JoinItem>,
    /// Sorted proxy indices of the moved entries of an incremental join.
    pub(crate) moved: Vec<u32>,
    /// Nearest-neighbour traversal stack: node index and the squared
    /// distance from the query point to its bound.
    pub(crate) nearest: Vec<(u32, f64)>,
    /// Per-ray state of batched raycasts.
    pub(crate) rays: super::ray_batch::RayBatchScratch,
    pub(crate) stats: QueryStats,
}

impl QueryWorkspace {
    /// The counters accumulated so far.
    pub fn stats(&self) -> QueryStats {
        self.stats
    }

    /// Returns the counters and resets them to zero.
    pub fn take_stats(&mut self) -> QueryStats {
        std::mem::take(&mut self.stats)
    }
}
