//! Stable handles to entries and the per-entry record behind them.

use crate::geometry::Aabb;

use super::node::NIL;

/// A stable handle to one entry of an [`RTree`](super::RTree).
///
/// Returned by insert; every later update or removal uses it, so the tree
/// never searches for an entry. A handle carries a generation: once its entry
/// is removed the handle is refused with
/// [`SpatialError::UnknownProxy`](crate::SpatialError::UnknownProxy), even
/// after the slot is reused by a new entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ProxyId {
    pub(crate) index: u32,
    pub(crate) generation: u32,
}

impl ProxyId {
    /// The slot index, dense from 0 (useful to key side tables).
    pub fn index(self) -> u32 {
        self.index
    }
}

/// What the tree knows about one entry besides its exact box (in its leaf
/// lane) and its key (in the tree's dense key array, which traversals read).
#[derive(Clone, Debug)]
pub(crate) struct Proxy {
    /// The enlarged box the tree's structure is built from (contains the
    /// exact box). Small moves inside it change nothing structural.
    pub fat: Aabb,
    /// The leaf holding the entry, or `NIL` when this slot is free.
    pub leaf: u32,
    /// The lane within that leaf.
    pub lane: u32,
    /// Bumped on every removal so stale handles are detected.
    pub generation: u32,
}

impl Proxy {
    #[inline]
    pub fn is_live(&self) -> bool {
        self.leaf != NIL
    }
}
