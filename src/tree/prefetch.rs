//! Cache prefetch hints: start loading a node or an entry record before it
//! is read or written.
//!
//! A box query pushes the children it will visit and then pops them one by
//! one; asking for every pushed child's cache lines at push time lets their
//! loads overlap instead of each stalling the traversal in turn. Measured on
//! the standard scene (`cargo bench --bench tree -- query/boxes`), 1,000 box
//! queries took 10 % less time on the fresh tree and 16–20 % less on the
//! churned one, whose nodes lie scattered in the pool. `update_batch` asks
//! for the leaf of the move a few places ahead while it applies the current
//! one: a frame's 10,000 moves took 12 % less time
//! (`cargo bench --bench tree -- frame/moves`). It asks only for the lane
//! bounds, which a move inside its enlarged box writes (six of the leaf's
//! eight lines): the loop is bound by how many lines can be in flight at
//! once, and the whole node cost 5–6 % more time (median frame of 600,
//! 0.37–0.38 against 0.35–0.36 ms). A move out of its enlarged box reads
//! its leaf's bound from the tree's dense copy of held bounds, whose line
//! is asked for with the lanes: on the standard scene the copy stays in
//! the second-level cache and asking changes nothing, but on a map of a
//! million entities, where the frame's other passes evict it, the moves
//! took 1.40–1.45 ms instead of 1.62–1.72. Since its checking pass
//! reads only the dense handle stamps, it asks for the entries' records
//! ahead as well (one line each). `optimize` asks for a repacked node's
//! leaves and their entries' records before gathering them (15 % less time
//! in a probe). The queries measured cold (a frame's other work having
//! evicted the tree) ask for what they will read next too: the cull, the
//! joins, single rays, nearest and spheres the children they push, the
//! cull and nearest the keys of the leaves they reach (`docs/performance.md`,
//! "Cold caches").
//!
//! The prefetch intrinsic is an `unsafe fn` although it can neither fault
//! nor change memory; the crate's other `unsafe` is the SIMD lane tests,
//! each behind a check that the processor has the instructions.

use super::RTree;

impl<K, const W: usize> RTree<K, W> {
    /// Asks the CPU to start loading the node at `index` into cache. A hint
    /// only: it changes no answer, and an index outside the pool is ignored.
    #[inline(always)]
    pub(crate) fn prefetch_node(&self, index: u32) {
        if let Some(node) = self.nodes.get(index as usize) {
            prefetch_lines(node);
        }
    }

    /// Asks the CPU to start loading the links of the node at `index` (its
    /// children, count and level: two of its eight lines at the default
    /// width), all that a walk reporting its subtree whole without boxes
    /// reads.
    #[inline(always)]
    pub(crate) fn prefetch_node_links(&self, index: u32) {
        if let Some(node) = self.nodes.get(index as usize) {
            prefetch_lines(&node.child);
            prefetch_lines(&node.len);
        }
    }

    /// Asks the CPU to start loading the lane bounds of the node at `index`
    /// (six of its eight lines at the default width), what a move inside its
    /// enlarged box writes, and the leaf's held bound, which a move out of
    /// that box reads.
    #[inline(always)]
    pub(crate) fn prefetch_leaf_for_move(&self, index: u32) {
        if let Some(node) = self.nodes.get(index as usize) {
            prefetch_lines(&node.min);
            prefetch_lines(&node.max);
        }
        if let Some(held) = self.held_bounds.get(index as usize) {
            prefetch_lines(held);
        }
    }

    /// Asks the CPU to start loading the keys of a leaf's entries, which
    /// live apart from the leaf (one array indexed by proxy). A leaf as
    /// bulk loading fills it (slots given in leaf order) has its keys in one
    /// run, a line or two: the lines of its first and last key are asked
    /// for. A leaf whose slots are scattered ([`slots_scattered`]: entries
    /// inserted, respawned or moved in over a long session) gets every key
    /// asked for: on a tree of the standard scene whose slots were given in
    /// random order and then re-tiled, the cold cull took 196–212 µs
    /// instead of 308–337, warm the same; on the queries bench's maintained
    /// tree, whose leaves are mostly runs still, warm and cold the same
    /// within noise. Asking for every key where only the first and last
    /// slot lie far apart (a run with one entry from elsewhere counted as
    /// scattered) cost that maintained tree 4 % warm. A hint only.
    #[inline(always)]
    pub(crate) fn prefetch_keys_of_leaf(&self, leaf: &super::node::Node<W>) {
        let keys = self.keys.as_ptr();
        let slots = &leaf.child[..leaf.len()];
        let (Some(&first), Some(&last)) = (slots.first(), slots.last()) else {
            return;
        };
        // No bounds checks: a prefetch of any address is sound (see
        // `prefetch_address`), and a leaf's slots index `keys`.
        if slots_scattered(slots) {
            for &slot in slots {
                prefetch_address(keys.wrapping_add(slot as usize).cast());
            }
        } else {
            prefetch_address(keys.wrapping_add(first as usize).cast());
            prefetch_address(keys.wrapping_add(last as usize).cast());
        }
    }

    /// Asks the CPU to start loading what checking a handle of slot `index`
    /// against a key reads: the slot's stamp and its key. A hint only.
    #[inline(always)]
    pub(crate) fn prefetch_handle_check(&self, index: u32) {
        // Any address is sound to prefetch (see `prefetch_address`).
        let (keys, stamps) = (self.keys.as_ptr(), self.stamps.as_ptr());
        prefetch_address(keys.wrapping_add(index as usize).cast());
        prefetch_address(stamps.wrapping_add(index as usize).cast());
    }

    /// Asks the CPU to start loading the record of proxy `index`; an index
    /// outside the records is ignored.
    #[inline(always)]
    pub(crate) fn prefetch_proxy(&self, index: u32) {
        if let Some(proxy) = self.proxies.get(index as usize) {
            prefetch_lines(proxy);
        }
    }
}

/// Whether a leaf's slots (at least one) lie far apart: its first, middle
/// and last slot each further than the leaf's length from the next. Three
/// loads from one line; a run with a few entries from elsewhere (a leaf
/// after some moves) is still a run, whose first and last keys' lines
/// hold most of its keys.
#[inline(always)]
fn slots_scattered(slots: &[u32]) -> bool {
    let (first, middle, last) = (slots[0], slots[slots.len() / 2], slots[slots.len() - 1]);
    first.abs_diff(middle) as usize >= slots.len() && middle.abs_diff(last) as usize >= slots.len()
}

/// Requests every cache line of `value` (eight for a node of the default
/// width, one for a proxy record).
#[inline(always)]
pub(crate) fn prefetch_lines<T>(value: &T) {
    let base = std::ptr::from_ref(value).cast::<i8>();
    for offset in (0..std::mem::size_of::<T>()).step_by(64) {
        prefetch_address(base.wrapping_add(offset));
    }
}

/// Requests every cache line any byte of `value` lies on: one more than
/// [`prefetch_lines`] asks for where `value` is not aligned to a line and
/// straddles one (a 64-byte `GlobalTransform` in a column aligned to 16).
#[cfg_attr(not(feature = "bevy_camera"), allow(dead_code))]
#[inline(always)]
pub(crate) fn prefetch_every_line<T>(value: &T) {
    prefetch_lines(value);
    let size = std::mem::size_of::<T>();
    if size > 0 {
        // Any address is sound to prefetch (see `prefetch_address`).
        prefetch_address(
            std::ptr::from_ref(value)
                .cast::<i8>()
                .wrapping_add(size - 1),
        );
    }
}

/// Requests the cache line holding `address`, which need not point into
/// any allocation.
#[inline(always)]
fn prefetch_address(address: *const i8) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        #[allow(unsafe_code)]
        // SAFETY: `_mm_prefetch` is only a hint to the cache: it never
        // faults, reads nothing into a register and writes nothing, so any
        // address is sound, in an allocation or not. SSE, which it needs,
        // is part of every x86_64 target.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(address);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = address;
}

#[cfg(test)]
mod tests {
    use crate::geometry::Aabb;
    use crate::tree::RTree;
    use glam::Vec3;

    #[test]
    fn prefetch_ignores_indices_outside_the_pool_and_changes_nothing() {
        let mut tree = RTree::new();
        for i in 0..100u32 {
            let p = Vec3::splat(i as f32);
            tree.insert(i, Aabb::new(p, p + Vec3::ONE).unwrap())
                .unwrap();
        }
        let before = tree.overlapping(&Aabb::new(Vec3::ZERO, Vec3::splat(50.0)).unwrap());
        for index in [0, 1, tree.node_count() as u32, u32::MAX] {
            tree.prefetch_node(index);
        }
        let after = tree.overlapping(&Aabb::new(Vec3::ZERO, Vec3::splat(50.0)).unwrap());
        assert_eq!(before, after);
        assert_eq!(before, (0..=50).collect::<Vec<u32>>());
        tree.validate().unwrap();
    }

    /// The leaves of a bulk load are runs of slots; the leaves of the same
    /// boxes given their slots in random order and then re-tiled are
    /// scattered, nearly all of them.
    #[test]
    fn leaves_of_a_bulk_load_are_runs_and_of_shuffled_slots_scattered() {
        use crate::scene::{SceneRng, TownScene};
        let scene = TownScene::new(20_000, 5);
        let scattered_leaves = |tree: &RTree<u32>| {
            let leaves: Vec<_> = (0..tree.node_count() as u32)
                .map(|i| tree.node(i))
                .filter(|n| n.is_leaf() && n.len() > 0)
                .collect();
            let scattered = leaves
                .iter()
                .filter(|n| super::slots_scattered(&n.child[..n.len()]))
                .count();
            (scattered, leaves.len())
        };
        let (fresh, _) = scene.bulk_loaded_tree();
        assert_eq!(scattered_leaves(&fresh).0, 0);
        let mut order: Vec<u32> = (0..scene.len() as u32).collect();
        let mut rng = SceneRng::new(9);
        for i in (1..order.len()).rev() {
            order.swap(i, rng.below(i + 1));
        }
        let mut shuffled = RTree::new();
        for &i in &order {
            shuffled.insert(i, scene.boxes()[i as usize]).unwrap();
        }
        shuffled.rebuild();
        let (scattered, leaves) = scattered_leaves(&shuffled);
        assert!(scattered * 10 > leaves * 9, "{scattered} of {leaves}");
    }
}
