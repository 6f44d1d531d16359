//! The wide, dynamic R-tree.
//!
//! One operation per file, all as `impl RTree` blocks:
//! - `node`: the structure-of-arrays node and its lane tests;
//! - `handle`: stable [`ProxyId`] handles and the per-entry record;
//! - `insert`, `choose`, `split`: insertion, choose-subtree (four lanes at
//!   a time) and R*-style splits;
//! - `remove`: removal with condensing and reinsertion of orphans;
//! - `update`: moves, absorbed by enlarged bounds when small;
//! - `bulk`: bulk loading (median cuts) and rebuilds;
//! - `cut_axis`: which axis each median cut of a tiling takes;
//! - `optimize`: local repacking of churned subtrees;
//! - `prefetch`: cache hints for box queries, batched moves and repacks
//!   (the tree's only `unsafe`; the queries' SIMD twins have the rest);
//! - `validate`: the invariant checker of [contract S10](crate::contract).

mod bulk;
mod choose;
mod cut_axis;
mod handle;
mod insert;
pub(crate) mod node;
mod optimize;
pub(crate) mod prefetch;
mod rebuild;
mod rebuild_away;
mod rebuild_catch_up;
mod remove;
mod repair_queue;
mod settings;
mod split;
mod stats;
mod update;
mod validate;

pub use handle::ProxyId;
pub use rebuild_away::RebuildWork;
pub use settings::TreeSettings;
pub use split::SplitStrategy;
pub use stats::{MaintenanceStats, MemoryUse, QueryStats};
pub use update::MoveKind;
pub use validate::InvariantViolation;

use crate::geometry::{Aabb, SpatialError};
use handle::{Proxy, Stamp};
use node::{FREE_LEVEL, NIL, Node};
use repair_queue::RepairQueue;

/// The smallest node width the tree supports.
const MIN_WIDTH: usize = 4;
/// The largest node width the tree supports (split scratch is sized for it).
const MAX_WIDTH: usize = 16;

/// A wide, dynamic R-tree over `(key, box)` entries.
///
/// `K` is the caller's key (an ECS entity, an index, ...): answers report it
/// and break ties by it. `W` is the node width, a multiple of 4 from 4 to 16
/// (16 is the default; other widths fail to compile); see the crate docs
/// ("Node width") for the measurements behind the default.
///
/// Each entry keeps its exact box, used by every answer, and an enlarged box
/// used only by the tree's structure, so that small moves cost O(1)
/// (see [`TreeSettings`]).
///
/// ```
/// use bevy_rtree::{Aabb, RTree};
/// use bevy_rtree::glam::Vec3;
///
/// let mut tree = RTree::new();
/// let crate_box = tree.insert("crate", Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
/// tree.insert("lamp", Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0))?)?;
///
/// let mut found = tree.overlapping(&Aabb::new(Vec3::splat(0.5), Vec3::splat(2.0))?);
/// assert_eq!(found, vec!["crate"]);
///
/// tree.update(crate_box, Aabb::new(Vec3::splat(10.0), Vec3::splat(11.0))?)?;
/// found = tree.overlapping(&Aabb::new(Vec3::splat(0.5), Vec3::splat(2.0))?);
/// assert!(found.is_empty());
/// tree.validate().expect("invariants hold");
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Debug)]
pub struct RTree<K, const W: usize = 16> {
    /// The node pool; freed nodes are recycled through `free_nodes`.
    nodes: Vec<Node<W>>,
    free_nodes: Vec<u32>,
    root: u32,
    /// The entry records, indexed by `ProxyId::index`.
    proxies: Vec<Proxy>,
    /// The entries' keys, indexed like `proxies`; kept apart so traversals
    /// that report keys read a dense array.
    keys: Vec<K>,
    /// Each slot's generation and liveness, indexed like `proxies`; kept
    /// apart so checking handles reads a dense array.
    stamps: Vec<Stamp>,
    /// Restructuring moves absorbed per node since its last repack, indexed
    /// like `nodes`; drives `optimize`.
    churn: Vec<u32>,
    /// The bound each node's parent holds for it (a copy of that lane box;
    /// all space for the root, which no bound confines; meaningless for free
    /// nodes), indexed like `nodes`. A move that leaves its enlarged box
    /// checks its leaf's bound here, in one line that stays in the
    /// second-level cache, instead of reading the leaf's parent link and
    /// then the parent's lanes.
    held_bounds: Vec<Aabb>,
    free_proxies: Vec<u32>,
    len: usize,
    settings: TreeSettings,
    /// Level-1 nodes whose churn crossed the threshold, for `optimize`.
    dirty: RepairQueue,
    maintenance: MaintenanceStats,
    /// A rebuild under way ([`RTree::start_rebuild`]).
    rebuild_job: Option<Box<rebuild::RebuildJob<W>>>,
    /// Changes that wear the tiling (inserts, removals, moves that grew a
    /// leaf or were reinserted, a jump that left its leaf twice) since the
    /// last bulk load or rebuild.
    wear: u64,
}

impl<K: Copy + Ord> Default for RTree<K, 16> {
    fn default() -> Self {
        Self::new()
    }
}

impl<K: Copy + Ord> RTree<K, 16> {
    /// An empty tree of width 16 with default settings.
    pub fn new() -> Self {
        Self::with_settings(TreeSettings::default()).expect("default settings are valid")
    }
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The node width `W`: children per node.
    ///
    /// ```
    /// use bevy_rtree::RTree;
    ///
    /// assert_eq!(RTree::<u32>::WIDTH, 16);
    /// assert_eq!(RTree::<u32, 8>::WIDTH, 8);
    /// ```
    pub const WIDTH: usize = W;

    /// Minimum fill of every node but the root: 40 % of `W`, as in the R*-tree.
    pub(crate) const MIN_FILL: usize = if W * 2 / 5 < 2 { 2 } else { W * 2 / 5 };

    // Lane tests take four lanes at a time, so the width is a multiple of 4.
    const WIDTH_OK: () =
        assert!(W >= MIN_WIDTH && W <= MAX_WIDTH && W.is_multiple_of(node::LANES_PER_TEST));

    /// An empty tree with the given settings (of any supported width `W`).
    pub fn with_settings(settings: TreeSettings) -> Result<Self, SpatialError> {
        let () = Self::WIDTH_OK;
        settings.validate()?;
        Ok(RTree {
            nodes: vec![Node::empty(0, NIL)],
            free_nodes: Vec::new(),
            root: 0,
            proxies: Vec::new(),
            keys: Vec::new(),
            stamps: Vec::new(),
            churn: vec![0],
            held_bounds: vec![Aabb::EVERYWHERE],
            free_proxies: Vec::new(),
            len: 0,
            settings,
            dirty: RepairQueue::default(),
            maintenance: MaintenanceStats::default(),
            rebuild_job: None,
            wear: 0,
        })
    }

    /// The memory the tree holds, by part (allocated capacity, so a tree
    /// that shrank keeps what it grew to). A rebuild under way
    /// ([`RTree::start_rebuild`]) holds a second structure and a snapshot
    /// beside the tree until its swap: [`MemoryUse::rebuild`].
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// for i in 0..1_000u32 {
    ///     tree.insert(i, Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))?)?;
    /// }
    /// let memory = tree.memory();
    /// assert!(memory.total() / tree.len() < 200, "{memory:?}");
    /// assert_eq!(memory.rebuild, 0);
    ///
    /// // While a rebuild runs, its structure is counted too, until the swap.
    /// tree.start_rebuild();
    /// tree.step_rebuild_units(1);
    /// assert!(tree.memory().rebuild > 0);
    /// while !tree.step_rebuild_units(1_000) {}
    /// assert_eq!(tree.memory().rebuild, 0);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn memory(&self) -> MemoryUse {
        use rebuild::bytes;
        MemoryUse {
            nodes: bytes(&self.nodes)
                + bytes(&self.churn)
                + bytes(&self.held_bounds)
                + bytes(&self.free_nodes)
                + self.dirty.memory(),
            entries: bytes(&self.proxies) + bytes(&self.free_proxies),
            keys: bytes(&self.keys),
            handles: bytes(&self.stamps),
            rebuild: self.rebuild_job.as_ref().map_or(0, |job| job.memory()),
        }
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the tree has no entries.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The settings the tree was built with.
    pub fn settings(&self) -> &TreeSettings {
        &self.settings
    }

    /// A box around every entry's exact box (the union of the root's
    /// lanes), or `None` for an empty tree.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// assert_eq!(tree.bounds(), None);
    /// tree.insert(1u8, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// tree.insert(2u8, Aabb::new(Vec3::splat(4.0), Vec3::splat(5.0))?)?;
    /// let all = tree.bounds().unwrap();
    /// assert!(all.contains(&Aabb::new(Vec3::ZERO, Vec3::splat(5.0))?));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn bounds(&self) -> Option<Aabb> {
        (!self.is_empty()).then(|| self.nodes[self.root as usize].lanes_union())
    }

    /// Levels from the root to the leaves (1 for a tree that is one leaf).
    pub fn height(&self) -> usize {
        self.nodes[self.root as usize].level as usize + 1
    }

    /// Live nodes in the pool.
    pub fn node_count(&self) -> usize {
        self.nodes.len() - self.free_nodes.len()
    }

    /// Live nodes at `level` (0 for the leaves), a linear scan for
    /// diagnostics. [`RTree::pending_repairs`] never exceeds the count at
    /// level 1.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert_bulk((0..1000u32).map(|i| {
    ///     let p = Vec3::new(i as f32, 0.0, 0.0);
    ///     (i, Aabb::new(p, p + Vec3::ONE).unwrap())
    /// }))?;
    /// assert_eq!(tree.nodes_at_level(0), 1000 / 16 + 1);
    /// assert_eq!(tree.nodes_at_level(tree.height() - 1), 1);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn nodes_at_level(&self, level: usize) -> usize {
        // Nodes on the free list carry a level of their own, above any
        // tree's height: they are not counted at it.
        if level >= usize::from(FREE_LEVEL) {
            return 0;
        }
        self.nodes
            .iter()
            .filter(|n| n.level as usize == level)
            .count()
    }

    /// The key and exact box of a live entry.
    pub fn get(&self, id: ProxyId) -> Result<(K, Aabb), SpatialError> {
        let index = self.check(id)?;
        let proxy = &self.proxies[index as usize];
        let aabb = self.nodes[proxy.leaf as usize].lane_box(proxy.lane as usize);
        Ok((self.keys[index as usize], aabb))
    }

    /// The enlarged box the structure uses for a live entry (for diagnostics;
    /// answers never depend on it).
    pub fn enlarged_box(&self, id: ProxyId) -> Result<Aabb, SpatialError> {
        let index = self.check(id)?;
        Ok(self.proxies[index as usize].fat)
    }

    /// Whether `id` names a live entry.
    pub fn contains(&self, id: ProxyId) -> bool {
        self.check(id).is_ok()
    }

    /// Every live entry as `(id, key, exact box)`, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (ProxyId, K, Aabb)> + '_ {
        self.proxies
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_live())
            .map(|(i, p)| {
                let id = self.handle(i as u32);
                (
                    id,
                    self.keys[i],
                    self.nodes[p.leaf as usize].lane_box(p.lane as usize),
                )
            })
    }

    /// Removes every entry; handles issued before are refused afterwards.
    pub fn clear(&mut self) {
        self.rebuild_job = None;
        for (proxy, stamp) in self.proxies.iter_mut().zip(&mut self.stamps) {
            if proxy.is_live() {
                proxy.leaf = NIL;
                *stamp = stamp.retired();
            }
        }
        self.free_proxies = (0..self.proxies.len() as u32)
            .rev()
            .filter(|&slot| !self.stamps[slot as usize].is_exhausted())
            .collect();
        self.nodes.clear();
        self.nodes.push(Node::empty(0, NIL));
        self.churn.clear();
        self.churn.push(0);
        self.held_bounds.clear();
        self.held_bounds.push(Aabb::EVERYWHERE);
        self.free_nodes.clear();
        self.dirty.clear();
        self.root = 0;
        self.len = 0;
    }

    /// Counters of the work mutations did since the last call.
    pub fn take_maintenance_stats(&mut self) -> MaintenanceStats {
        std::mem::take(&mut self.maintenance)
    }

    /// The proxy index of a live handle, or `UnknownProxy`.
    #[inline]
    fn check(&self, id: ProxyId) -> Result<u32, SpatialError> {
        match self.stamps.get(id.index as usize) {
            Some(stamp) if stamp.admits(id) => Ok(id.index),
            _ => Err(SpatialError::UnknownProxy),
        }
    }

    /// Entry slots ever issued (live, free and retired): every live
    /// handle's index is below it.
    #[cfg_attr(not(feature = "plugin"), allow(dead_code))]
    pub(crate) fn slot_count(&self) -> u32 {
        self.proxies.len() as u32
    }

    /// The root node's index (for traversals).
    #[inline]
    pub(crate) fn root(&self) -> u32 {
        self.root
    }

    #[inline]
    pub(crate) fn node(&self, index: u32) -> &Node<W> {
        &self.nodes[index as usize]
    }

    #[inline]
    pub(crate) fn key_of(&self, proxy: u32) -> K {
        self.keys[proxy as usize]
    }

    fn alloc_node(&mut self, level: u16, parent: u32) -> u32 {
        match self.free_nodes.pop() {
            Some(index) => {
                self.nodes[index as usize] = Node::empty(level, parent);
                self.churn[index as usize] = 0;
                self.held_bounds[index as usize] = Aabb::EVERYWHERE;
                index
            }
            None => {
                self.nodes.push(Node::empty(level, parent));
                self.churn.push(0);
                self.held_bounds.push(Aabb::EVERYWHERE);
                (self.nodes.len() - 1) as u32
            }
        }
    }

    fn free_node(&mut self, index: u32) {
        self.dirty.remove(index);
        let node = &mut self.nodes[index as usize];
        *node = Node::empty(FREE_LEVEL, NIL);
        self.free_nodes.push(index);
    }

    /// A slot for a new entry, marked live; the caller links it into a leaf.
    fn alloc_proxy(&mut self, key: K, fat: Aabb) -> u32 {
        match self.free_proxies.pop() {
            Some(index) => {
                self.proxies[index as usize].fat = fat;
                self.keys[index as usize] = key;
                let stamp = &mut self.stamps[index as usize];
                *stamp = stamp.revived();
                index
            }
            None => {
                self.proxies.push(Proxy {
                    fat,
                    leaf: NIL,
                    lane: 0,
                });
                self.keys.push(key);
                self.stamps.push(Stamp::FRESH.revived());
                (self.proxies.len() - 1) as u32
            }
        }
    }

    /// The live handle of a proxy index.
    pub(crate) fn handle(&self, proxy: u32) -> ProxyId {
        ProxyId {
            index: proxy,
            generation: self.stamps[proxy as usize].generation(),
        }
    }

    /// The bound a node presents to its parent: for a leaf, the union of its
    /// entries' enlarged boxes; for an internal node, the union of its lanes.
    fn node_bound(&self, index: u32) -> Aabb {
        let node = &self.nodes[index as usize];
        if node.is_leaf() {
            node.child[..node.len()]
                .iter()
                .fold(Aabb::INVERTED, |acc, &p| {
                    acc.union(&self.proxies[p as usize].fat)
                })
        } else {
            node.lanes_union()
        }
    }

    /// Points the child in `lane` of `node` back at `node`.
    #[inline]
    fn link(&mut self, node: u32, lane: usize) {
        let n = &self.nodes[node as usize];
        let child = n.child[lane];
        if n.is_leaf() {
            let proxy = &mut self.proxies[child as usize];
            proxy.leaf = node;
            proxy.lane = lane as u32;
        } else {
            self.held_bounds[child as usize] = n.lane_box(lane);
            self.nodes[child as usize].parent = node;
        }
    }

    /// Sets the bound internal node `parent` holds in `lane`, and its
    /// child's copy of it (`held_bounds`).
    fn set_child_bound(&mut self, parent: u32, lane: usize, bound: &Aabb) {
        let p = &mut self.nodes[parent as usize];
        debug_assert!(!p.is_leaf());
        p.set_lane_box(lane, bound);
        self.held_bounds[p.child[lane] as usize] = *bound;
    }
}

/// One child on its way into a node: a proxy (into a leaf) or a node.
#[derive(Clone, Copy, Debug)]
struct Entry {
    /// What the lane will store: the exact box for a proxy, the bound for a node.
    lane_box: Aabb,
    /// What the structure uses: the enlarged box for a proxy, the bound for a node.
    bound: Aabb,
    /// Proxy or node index.
    child: u32,
}
