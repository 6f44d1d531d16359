//! Counters that make the cost of queries and maintenance visible without a
//! profiler.

/// Work done by queries: accumulated into a
/// [`QueryWorkspace`](crate::QueryWorkspace) until reset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct QueryStats {
    /// Nodes whose lanes were tested.
    pub nodes_visited: u64,
    /// Leaf lanes (entries) tested: every lane of each leaf a query visits
    /// (once per ray of a batch that visits it), whether or not its box
    /// then takes the exact test; for a join, each pair of lanes its leaf
    /// pairs test.
    pub entries_tested: u64,
}

/// Work done by mutations since the tree was created or
/// [`RTree::take_maintenance_stats`](super::RTree::take_maintenance_stats)
/// was last called. Each change the caller makes is counted once, as it is
/// made: a rebuild applying the changes made while it was built to its new
/// structure counts only as its rebuild.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MaintenanceStats {
    /// Entries inserted one by one.
    pub inserts: u64,
    /// Entries removed.
    pub removals: u64,
    /// Moves that stayed inside the entry's enlarged box: one lane write.
    pub moves_in_place: u64,
    /// Moves that left the enlarged box but stayed inside the leaf's bound:
    /// a new enlarged box and one lane write, no structural change.
    pub moves_in_leaf: u64,
    /// Moves that left the leaf's bound but not its parent's: the leaf's
    /// bound grew, O(1).
    pub moves_leaf_grown: u64,
    /// Moves that left the leaf's parent's bound: the entry was reinserted.
    pub moves_reinserted: u64,
    /// Node splits.
    pub splits: u64,
    /// Nodes that underflowed and had their entries reinserted.
    pub condensed_nodes: u64,
    /// Nodes repacked by [`RTree::optimize`](super::RTree::optimize).
    pub repacks: u64,
    /// Rebuilds swapped in by [`RTree::step_rebuild`](super::RTree::step_rebuild).
    pub rebuilds: u64,
}

/// The memory a tree holds, in bytes (allocated capacity), by part:
/// [`RTree::memory`](super::RTree::memory).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct MemoryUse {
    /// The node pool (boxes of every lane, children, order) and the
    /// per-node side tables (churn, held bounds, free list, repair queue).
    pub nodes: usize,
    /// The entry records (enlarged box, leaf, lane) and their free list.
    pub entries: usize,
    /// The entries' keys.
    pub keys: usize,
    /// The handles' generations.
    pub handles: usize,
    /// A rebuild in progress ([`RTree::start_rebuild`](super::RTree::start_rebuild)):
    /// the new structure and its working buffers (0 when none runs). While
    /// its tiling runs elsewhere as a [`RebuildWork`](super::RebuildWork),
    /// which owns the structure, this counts only what the tree keeps to
    /// note the changes made meanwhile (a few bytes a slot).
    pub rebuild: usize,
}

impl MemoryUse {
    /// Every part together.
    pub fn total(&self) -> usize {
        self.nodes + self.entries + self.keys + self.handles + self.rebuild
    }
}
