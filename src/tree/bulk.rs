//! Bulk loading: entries are tiled into compact groups by median cuts, each
//! along the axis that leaves its two sides the least surface, and packed
//! bottom-up into nearly full nodes.

use super::cut_axis::cut_axis;
use super::node::NIL;
use super::{Entry, RTree};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::ProxyId;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Inserts many entries at once and rebuilds the whole tree, grouping
    /// entries by median cuts.
    ///
    /// Much faster than inserting one by one and gives a better tree; existing
    /// handles stay valid. Into an empty tree (new, cleared or emptied by
    /// removals), leaves are packed full (for entries that will move,
    /// [`RTree::insert_bulk_with_room`] leaves room); into
    /// one that holds entries, this is a rebuild, and leaves keep room for
    /// two more entries as [`RTree::rebuild`] leaves them, and a rebuild
    /// under way is dropped, as `rebuild` drops it. Parents keep
    /// room for more leaves (14 of 16 at the default width) where that adds
    /// no level, for the splits the first frames of movement bring. An
    /// empty `entries` changes nothing.
    ///
    /// All boxes are checked first: if any is invalid, nothing is inserted
    /// and the error is returned.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let ids = tree.insert_bulk((0..1000u32).map(|i| {
    ///     let p = Vec3::new(i as f32, 0.0, 0.0);
    ///     (i, Aabb::new(p, p + Vec3::ONE).unwrap())
    /// }))?;
    /// assert_eq!(ids.len(), 1000);
    /// assert_eq!(tree.len(), 1000);
    /// tree.validate().unwrap();
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn insert_bulk(
        &mut self,
        entries: impl IntoIterator<Item = (K, Aabb)>,
    ) -> Result<Vec<ProxyId>, SpatialError> {
        self.insert_bulk_filled(entries, W)
    }

    /// [`RTree::insert_bulk`] for entries that will move: into an empty tree
    /// too, each leaf keeps room for two more entries (14 of 16 at the
    /// default width), as a rebuild leaves it. Into a tree that holds
    /// entries, the same as `insert_bulk`.
    ///
    /// Packed full, every leaf splits at the first entry that moves into
    /// it, so the first seconds after a scene is loaded pay a split for
    /// nearly every move that leaves its leaf; with room, those moves land
    /// in the room. The plugin loads its indexes this way. Measured on a
    /// map of 1,000,000 entries, 1 % moving (`cargo bench --bench
    /// bevy_visibility -- map`), the tree moves of the first 138 frames
    /// took 3.42 → 2.43 ms a frame (medians). The cost, on a tree where
    /// nothing moves: about 3 % more nodes per query and 11–14 % more node
    /// pairs in a self join than packed full (docs/performance.md, "The
    /// plugin's first load leaves room in the leaves").
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let unit = |i: u32| {
    ///     let p = Vec3::new(i as f32 * 2.0, 0.0, 0.0);
    ///     (i, Aabb::new(p, p + Vec3::ONE).unwrap())
    /// };
    /// let mut full = RTree::new();
    /// full.insert_bulk((0..1600).map(unit))?;
    /// let mut roomy = RTree::new();
    /// roomy.insert_bulk_with_room((0..1600).map(unit))?;
    /// assert_eq!(roomy.nodes_at_level(0), 1600usize.div_ceil(14));
    /// assert_eq!(full.nodes_at_level(0), 1600 / 16);
    /// // An entry inserted among the others splits no leaf.
    /// let nodes = roomy.node_count();
    /// roomy.insert(1600, Aabb::new(Vec3::new(3.1, 0.0, 0.0), Vec3::new(3.9, 1.0, 1.0))?)?;
    /// assert_eq!(roomy.node_count(), nodes);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn insert_bulk_with_room(
        &mut self,
        entries: impl IntoIterator<Item = (K, Aabb)>,
    ) -> Result<Vec<ProxyId>, SpatialError> {
        self.insert_bulk_filled(entries, Self::LEAF_FILL_WITH_ROOM)
    }

    /// [`RTree::insert_bulk`], with `fresh_leaf_fill` entries to a leaf
    /// where the tree is empty.
    fn insert_bulk_filled(
        &mut self,
        entries: impl IntoIterator<Item = (K, Aabb)>,
        fresh_leaf_fill: usize,
    ) -> Result<Vec<ProxyId>, SpatialError> {
        let entries: Vec<(K, Aabb)> = entries.into_iter().collect();
        if let Some(bad) = entries.iter().find(|(_, aabb)| !aabb.is_valid()) {
            bad.1.validate()?;
        }
        if entries.is_empty() {
            return Ok(Vec::new());
        }
        if self.len == 0 {
            return Ok(self.load_fresh(entries, fresh_leaf_fill));
        }
        // This retiles every entry, as `rebuild` does: a rebuild under way
        // would swap in the tiling from before and then insert every new
        // entry into it one by one.
        self.rebuild_job = None;
        let mut ids = Vec::with_capacity(entries.len());
        let mut level_entries = self.live_entries_in_leaf_order();
        for (key, aabb) in entries {
            let fat = self.settings.fatten(&aabb, glam::Vec3::ZERO);
            let proxy = self.alloc_proxy(key, fat);
            // Live from here on; the packing below gives it its leaf.
            self.proxies[proxy as usize].leaf = 0;
            ids.push(self.handle(proxy));
            self.len += 1;
            self.note_change(proxy, None);
            level_entries.push(Entry {
                lane_box: aabb,
                bound: fat,
                child: proxy,
            });
        }
        self.pack_rebuilt(level_entries);
        Ok(ids)
    }

    /// [`RTree::insert_bulk`] into an empty tree (new, cleared, or emptied
    /// by removals: a scene loaded again): the entries are tiled first and
    /// get their slots in the order of the leaves, so that the keys of a
    /// leaf (one array indexed by slot) sit side by side and a query that
    /// reports a leaf reads one or two cache lines of keys instead of one
    /// per entry; `leaf_fill` entries to a leaf. Returns the handles in the
    /// order of `entries`.
    fn load_fresh(&mut self, entries: Vec<(K, Aabb)>, leaf_fill: usize) -> Vec<ProxyId> {
        // The new structure is as fresh as a rebuild would make it.
        self.rebuild_job = None;
        // Slots freed by removals are reused lowest first, as a new tree
        // hands them out, so that each leaf's slots make a run.
        self.free_proxies.sort_unstable_by(|a, b| b.cmp(a));
        let settings = self.settings;
        let mut tiled: Vec<Entry> = entries
            .iter()
            .enumerate()
            .map(|(i, &(_, aabb))| Entry {
                lane_box: aabb,
                bound: settings.fatten(&aabb, glam::Vec3::ZERO),
                child: i as u32,
            })
            .collect();
        if tiled.len() > W {
            let groups = Self::groups_at(0, tiled.len(), leaf_fill);
            tile_partition(&mut tiled, groups);
        }
        let mut slot_of = vec![0u32; entries.len()];
        self.proxies.reserve(entries.len());
        self.keys.reserve(entries.len());
        self.stamps.reserve(entries.len());
        for entry in &mut tiled {
            let input = entry.child as usize;
            let proxy = self.alloc_proxy(entries[input].0, entry.bound);
            slot_of[input] = proxy;
            entry.child = proxy;
        }
        self.len = tiled.len();
        // The entries are in tiling order: the first level is tiled already.
        self.pack(tiled, leaf_fill, true);
        slot_of.into_iter().map(|slot| self.handle(slot)).collect()
    }

    /// Rebuilds the whole tree by bulk loading from the entries' current
    /// boxes, tiled as a new tree of the same boxes but with room for two
    /// more entries in each leaf (14 of 16; see the performance notes): a
    /// tree worth rebuilding keeps changing, and the room takes the
    /// inserts and reinsertions of the frames after without splitting
    /// leaves. Every enlarged box starts again from the exact box and the
    /// margin, without the stretch of past moves. Handles stay valid;
    /// answers do not change.
    pub fn rebuild(&mut self) {
        // A rebuild under way would only redo this.
        self.rebuild_job = None;
        let entries = self.live_entries_in_leaf_order();
        self.pack_rebuilt(entries);
    }

    /// Every entry, with its exact box and a fresh enlarged box (without
    /// the stretch of past moves), read leaf by leaf in the order of the
    /// node pool: a sequential scan, where reading slot by slot would jump
    /// through memory once per entry. A rebuild at once and one in steps
    /// both start from it, so that they tile alike (the tiling's cuts judge
    /// long ranges from a sample that depends on the entries' order).
    pub(super) fn live_entries_in_leaf_order(&self) -> Vec<Entry> {
        let settings = self.settings;
        let mut entries = Vec::with_capacity(self.len);
        for node in &self.nodes {
            if !node.is_leaf() || node.level != 0 {
                continue;
            }
            for lane in 0..node.len() {
                let exact = node.lane_box(lane);
                entries.push(Entry {
                    lane_box: exact,
                    bound: settings.fatten(&exact, glam::Vec3::ZERO),
                    child: node.child[lane],
                });
            }
        }
        entries
    }

    /// Packs `entries` (`child` their proxy, `bound` their new enlarged
    /// box) into a new structure with the room of a rebuild.
    fn pack_rebuilt(&mut self, entries: Vec<Entry>) {
        for entry in &entries {
            self.proxies[entry.child as usize].fat = entry.bound;
        }
        self.pack(entries, Self::LEAF_FILL_WITH_ROOM, false);
    }

    /// Packs entries (`child` their proxy, fresh enlarged boxes) into a
    /// new structure, bottom-up, `leaf_fill` entries to a leaf; `tiled`:
    /// they are in the first level's tiling order already.
    fn pack(&mut self, mut level_entries: Vec<Entry>, leaf_fill: usize, tiled: bool) {
        self.wear = 0;
        self.nodes.clear();
        self.churn.clear();
        self.held_bounds.clear();
        self.free_nodes.clear();
        self.dirty.clear();
        let mut level = 0u16;
        loop {
            if level_entries.len() <= W {
                let root = self.alloc_node(level, NIL);
                self.fill_node(root, &level_entries);
                self.root = root;
                return;
            }
            let groups = Self::groups_at(level, level_entries.len(), leaf_fill);
            if !(tiled && level == 0) {
                tile_partition(&mut level_entries, groups);
            }
            let mut next = Vec::with_capacity(groups);
            for group in 0..groups {
                let range = group_range(level_entries.len(), groups, group);
                let node = self.alloc_node(level, NIL);
                self.fill_node(node, &level_entries[range]);
                next.push(self.node_entry(node));
            }
            level_entries = next;
            level += 1;
        }
    }

    /// How many nodes bulk loading packs `entries` entries of `level` into:
    /// `leaf_fill` entries to a leaf (`W` for a fresh load,
    /// [`Self::LEAF_FILL_WITH_ROOM`] for a rebuild or a load with room), full
    /// nodes above, except
    /// that leaves go [`Self::LEVEL_ONE_FILL`] to a level-1 node when that
    /// adds no level to the tree.
    ///
    /// The room left in level-1 nodes is for the first frames of movement:
    /// packed full at every level, a bulk-loaded tree lets the leaves that the
    /// first reinsertions split overflow their level-1 nodes, and each such
    /// split halves a node whose leaves were grouped for a full one. On the
    /// standard scene, four seeds, after 600 frames: 3–6 % fewer nodes per
    /// box query, 3–6 % fewer per incoherent ray, 1.5–3.5 % fewer self-join
    /// node pairs; on the fresh tree, box queries and the self join stay
    /// within 1 % of the full packing's visits, rays within 3 %. 15 leaves
    /// per level-1 node gained nothing and 12 lost; room in the leaves
    /// themselves made the fresh tree worse (see `docs/performance.md`).
    pub(super) fn groups_at(level: u16, entries: usize, leaf_fill: usize) -> usize {
        if level == 0 {
            return entries.div_ceil(leaf_fill.clamp(1, W));
        }
        let full = entries.div_ceil(W);
        if level != 1 {
            return full;
        }
        let slack = entries.div_ceil(Self::LEVEL_ONE_FILL);
        if levels_to_one_root(slack, W) == levels_to_one_root(full, W) {
            slack
        } else {
            full
        }
    }

    /// Leaves per level-1 node in a bulk-loaded tree: 14 of 16 (7 of 8, 4
    /// of 4), see [`Self::groups_at`].
    const LEVEL_ONE_FILL: usize = W - W / 8;

    /// Entries per leaf in a rebuilt tree (every rebuild: at once, in
    /// steps, on another thread, and a bulk insert into a tree that holds
    /// entries) and in a load with room ([`RTree::insert_bulk_with_room`]):
    /// 14 of 16 (7 of 8, 4 of 4), where a fresh load packs leaves full.
    ///
    /// A tree is rebuilt because entries keep changing place, and an
    /// insert into a full leaf splits it into two half-full leaves whose
    /// bounds were not tiled together: packed full, a rebuilt tree wore
    /// back within a few frames of 1 % teleports or respawns. With room
    /// for two, inserts land beside the entries removals left, without a
    /// split. The decay bench at 60 Hz, 2,000 frames, the work on another
    /// thread, nodes visited ÷ fresh over the last 200 frames, packed full
    /// → room for two: teleports 1.35 → 1.21, respawn 1.29 → 1.18, crowd
    /// 1.57 → 1.44, bullets 1.20 → 1.23, steps 1.09 → 1.10, vehicles 1.09
    /// → 1.11, asleep 1.04 → 1.10; the maintenance of teleports, respawn
    /// and bullets 5–24 % less (fewer splits), the others' the same. The
    /// cost: rebuilt with nothing moving, the tree visits 3 % more nodes
    /// than packed full, and a self join about 14 % more node pairs. Room
    /// for one (15) or three (13) did worse with teleports and respawns
    /// (1,000 frames: teleports 1.39 and 1.42 against 1.22, respawn 1.32
    /// and 1.33 against 1.17), and 13 alone costs 17 % more nodes.
    pub(super) const LEAF_FILL_WITH_ROOM: usize = W - W / 8;

    /// Reserves room for `additional` more entries and their nodes.
    /// Panics where that many cannot be counted in memory, as
    /// `Vec::reserve` does.
    pub fn reserve(&mut self, additional: usize) {
        self.proxies.reserve(additional);
        self.nodes.reserve(additional * 2 / W + 1);
    }
}

/// How many levels of nodes `width` wide stand above `nodes` nodes packed
/// full, up to a single root (0 for one node).
fn levels_to_one_root(mut nodes: usize, width: usize) -> u32 {
    let mut levels = 0;
    while nodes > 1 {
        nodes = nodes.div_ceil(width);
        levels += 1;
    }
    levels
}

/// The entries of group `g` when `n` entries are split into `groups` groups
/// as evenly as possible (sizes differ by at most one).
pub(super) fn group_range(n: usize, groups: usize, g: usize) -> std::ops::Range<usize> {
    // In u64: `n * g` passes 2^32 from about 250,000 entries, where `usize`
    // is 32 bits wide (wasm32).
    let at = |g: usize| (n as u64 * g as u64 / groups as u64) as usize;
    at(g)..at(g + 1)
}

/// Orders `entries` so that `group_range(len, groups, g)` is a spatially
/// compact tile for every `g`.
///
/// The entries are cut in two at a median by centre, along the axis that
/// leaves the two sides the least surface ([`cut_axis`]), with as many
/// groups on each side as the two halves hold; each half is cut again
/// until every group stands alone (a k-d tiling). Choosing the axis per cut
/// adapts the tiles to the data: on a world 20 times wider than tall, fixed
/// slab counts per axis (sort-tile-recursive) cut thin slices in height,
/// whereas this cuts height only where boxes are stacked. On the standard
/// scene it halves the nodes a ray or a join visits (see
/// `docs/performance.md`).
pub(super) fn tile_partition(entries: &mut [Entry], groups: usize) {
    let n = entries.len();
    halve(entries, 0, groups, n, groups);
}

/// Tiles the groups `first..first + count` (of `total_groups` over
/// `total_entries`), whose entries are exactly `entries`.
fn halve(
    entries: &mut [Entry],
    first: usize,
    count: usize,
    total_entries: usize,
    total_groups: usize,
) {
    if count <= 1 {
        return;
    }
    let left = count / 2;
    let start = group_range(total_entries, total_groups, first).start;
    let cut = group_range(total_entries, total_groups, first + left).start - start;
    let axis = cut_axis(entries, cut);
    entries.select_nth_unstable_by(cut, |a, b| {
        centre_key(&a.bound, axis).total_cmp(&centre_key(&b.bound, axis))
    });
    let (low, high) = entries.split_at_mut(cut);
    halve(low, first, left, total_entries, total_groups);
    halve(
        high,
        first + left,
        count - left,
        total_entries,
        total_groups,
    );
}

/// Twice the centre along `axis` (halving would not change the order).
#[inline]
pub(super) fn centre_key(aabb: &Aabb, axis: usize) -> f32 {
    aabb.min[axis] + aabb.max[axis]
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::tree::node::FREE_LEVEL;

    /// Entry `i` of a 100 m square grid of unit boxes, 3 m apart.
    fn grid(i: u32) -> (u32, Aabb) {
        let at = Vec3::new((i % 100) as f32, 0.0, (i / 100) as f32) * 3.0;
        (i, Aabb::new(at, at + Vec3::ONE).unwrap())
    }

    /// A bulk-loaded tree of the grid's first `count` entries.
    fn grid_tree(count: u32) -> RTree<u32, 16> {
        let mut tree = RTree::new();
        tree.insert_bulk((0..count).map(grid)).unwrap();
        tree.validate().unwrap();
        tree
    }

    /// How many leaves hold slots that are not one run (as a load gives
    /// them, in the order of the leaves).
    fn leaves_not_one_run(tree: &RTree<u32, 16>) -> usize {
        let leaves = tree.nodes.iter().filter(|n| n.level == 0);
        let slot_runs = leaves.map(|n| &n.child[..n.len()]);
        slot_runs
            .filter(|slots| {
                let (lo, hi) = (slots.iter().min().unwrap(), slots.iter().max().unwrap());
                (hi - lo) as usize != slots.len() - 1
            })
            .count()
    }

    /// The number of children of every node at `level` (free nodes have a
    /// level of their own).
    fn fills(tree: &RTree<u32, 16>, level: u16) -> Vec<usize> {
        tree.nodes
            .iter()
            .filter(|n| n.level == level)
            .map(|n| n.len())
            .collect()
    }

    #[test]
    fn level_one_nodes_keep_room_for_two_leaves() {
        let tree = grid_tree(20_000);
        // 1,250 full leaves under 90 level-1 nodes rather than 79.
        assert!(fills(&tree, 0).iter().all(|&n| n == 16));
        let level_one = fills(&tree, 1);
        assert_eq!(level_one.len(), 1250usize.div_ceil(14));
        assert!(level_one.iter().all(|&n| n <= 14), "{level_one:?}");
        assert_eq!(tree.height(), 4, "as full packing: 1,250 → 79 → 5 → 1");
    }

    #[test]
    fn level_one_nodes_pack_full_where_room_would_add_a_level() {
        // 256 leaves: full packing needs 16 level-1 nodes under the root,
        // room for two more leaves would need 19 and another level.
        let tree = grid_tree(4096);
        assert_eq!(fills(&tree, 1), vec![16; 16]);
        assert_eq!(tree.height(), 3);
    }

    #[test]
    fn rebuilt_leaves_keep_room_for_two_entries() {
        let mut tree = grid_tree(20_000);
        tree.rebuild();
        tree.validate().unwrap();
        let leaves = fills(&tree, 0);
        assert_eq!(leaves.len(), 20_000usize.div_ceil(14));
        assert!(leaves.iter().all(|&n| n <= 14), "{leaves:?}");
        // The stepped rebuild tiles the same way.
        let mut stepped = grid_tree(20_000);
        stepped.start_rebuild();
        while !stepped.step_rebuild_units(64) {}
        stepped.validate().unwrap();
        assert_eq!(fills(&stepped, 0), leaves);
        // So an entry inserted among the others splits nothing.
        let nodes = tree.node_count();
        let between = Aabb::new(Vec3::new(1.5, 0.0, 1.5), Vec3::new(2.5, 1.0, 2.5)).unwrap();
        tree.insert(20_000, between).unwrap();
        tree.validate().unwrap();
        assert_eq!(tree.node_count(), nodes);
    }

    #[test]
    fn a_load_with_room_leaves_two_lanes_free_in_every_leaf() {
        let mut tree = RTree::<u32, 16>::new();
        let ids = tree.insert_bulk_with_room((0..20_000).map(grid)).unwrap();
        tree.validate().unwrap();
        let leaves = fills(&tree, 0);
        assert_eq!(leaves.len(), 20_000usize.div_ceil(14));
        assert!(leaves.iter().all(|&n| n <= 14), "{leaves:?}");
        assert!(
            ids.iter()
                .enumerate()
                .all(|(i, &id)| tree.get(id) == Ok(grid(i as u32)))
        );
        // Each leaf's slots are one run, as in a load packed full.
        assert_eq!(leaves_not_one_run(&tree), 0);
        // Into a tree that holds entries, the same as `insert_bulk`.
        let mut again = grid_tree(10_000);
        let mut again_roomy = grid_tree(10_000);
        again.insert_bulk((10_000..20_000).map(grid)).unwrap();
        again_roomy
            .insert_bulk_with_room((10_000..20_000).map(grid))
            .unwrap();
        assert_eq!(fills(&again_roomy, 0), fills(&again, 0));
    }

    /// A tree emptied by `clear` or by removals loads as a new one does:
    /// leaves packed full, each leaf's slots one run, and the handles from
    /// before stale.
    #[test]
    fn an_emptied_tree_loads_as_a_new_one() {
        let fresh = grid_tree(2_000);
        assert_eq!(leaves_not_one_run(&fresh), 0);
        for emptied_by_removals in [false, true] {
            let mut tree = RTree::<u32, 16>::new();
            let before = tree.insert_bulk((0..2_000).map(grid)).unwrap();
            // Removed in an order that leaves the free slots shuffled.
            if emptied_by_removals {
                for &id in before
                    .iter()
                    .step_by(2)
                    .chain(before.iter().skip(1).step_by(2).rev())
                {
                    tree.remove(id).unwrap();
                }
            } else {
                tree.clear();
            }
            assert!(tree.is_empty());
            let ids = tree.insert_bulk((0..2_000).map(grid)).unwrap();
            tree.validate().unwrap();
            assert_eq!(fills(&tree, 0), fills(&fresh, 0));
            assert_eq!(tree.height(), fresh.height());
            let scattered = leaves_not_one_run(&tree);
            assert_eq!(scattered, 0, "leaves whose slots are not one run");
            assert_eq!(tree.get(ids[7]), Ok(grid(7)));
            assert!(before.iter().all(|&old| tree.get(old).is_err()));
        }
    }

    /// A tree just packed (a bulk load, a rebuild after churn) is as tight
    /// and as ordered as packing makes it, which `validate` cannot ask of
    /// a tree in use: every inner lane is exactly its child's bound, and
    /// every axis's visiting order sorts the lanes by centre (rays walk
    /// children near to far by it; a wrong key would cost time, not
    /// answers).
    #[test]
    fn packed_trees_are_tight_and_ordered() {
        let mut tree = grid_tree(5_000);
        let check = |tree: &RTree<u32, 16>| {
            let inner = tree
                .nodes
                .iter()
                .filter(|n| n.level != 0 && n.level != FREE_LEVEL);
            for node in inner {
                for lane in 0..node.len() {
                    assert_eq!(node.lane_box(lane), tree.node_bound(node.child[lane]));
                }
                for (axis, order) in node.order.iter().enumerate() {
                    let centres: Vec<f32> = order[..node.len()]
                        .iter()
                        .map(|&lane| centre_key(&node.lane_box(lane as usize), axis))
                        .collect();
                    assert!(centres.is_sorted(), "axis {axis}: {centres:?}");
                }
            }
        };
        check(&tree);
        let ids: Vec<ProxyId> = tree.iter().map(|(id, ..)| id).collect();
        for (i, &id) in ids.iter().enumerate().step_by(7) {
            let at = Vec3::new((i * 31 % 300) as f32, 0.0, (i * 17 % 150) as f32);
            tree.update(id, Aabb::new(at, at + Vec3::ONE).unwrap())
                .unwrap();
        }
        tree.rebuild();
        tree.validate().unwrap();
        check(&tree);
    }

    /// The groups hold every entry once, sizes differing by at most one,
    /// up to the most entries a 32-bit `usize` can count, where `n * g`
    /// overflows 32 bits (checked here against `u128` arithmetic). The
    /// overflow itself only shows on a 32-bit target (`--target
    /// i686-unknown-linux-gnu`, wasm32); on a 64-bit one this checks the
    /// ranges the 64-bit arithmetic gives.
    #[test]
    fn group_ranges_split_evenly_without_overflow() {
        // Cases where 32 bits overflow: `n * g` past `u32::MAX`.
        assert!(300_000u32.checked_mul(21_428).is_none());
        assert!(u32::MAX.checked_mul(2).is_none());
        for n in [0usize, 1, 15, 16, 300_000, u32::MAX as usize] {
            for groups in [1usize, 2, 7, 16, 21_429] {
                let mut next = 0;
                for g in [0, 1, groups / 2, groups - 1] {
                    let range = group_range(n, groups, g);
                    let exact = |g: usize| (n as u128 * g as u128 / groups as u128) as usize;
                    assert_eq!(range, exact(g)..exact(g + 1), "{n} {groups} {g}");
                    assert!(range.len() == n / groups || range.len() == n / groups + 1);
                    if g == 0 {
                        next = range.end;
                    } else if g == 1 {
                        assert_eq!(range.start, next);
                    }
                }
                assert_eq!(group_range(n, groups, groups - 1).end, n);
            }
        }
    }

    #[test]
    fn levels_to_one_root_counts_full_levels() {
        assert_eq!(levels_to_one_root(1, 16), 0);
        assert_eq!(levels_to_one_root(16, 16), 1);
        assert_eq!(levels_to_one_root(17, 16), 2);
        assert_eq!(levels_to_one_root(256, 16), 2);
        assert_eq!(levels_to_one_root(257, 16), 3);
    }
}
