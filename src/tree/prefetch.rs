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
//! in a probe). Rays, joins and culling
//! measured no gain from it (they do more work per node, which already
//! hides the loads), so they do not use it.
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
    /// live apart from the leaf (one array indexed by proxy): the lines of
    /// its first and last key. A leaf as bulk loading fills it (slots given
    /// in leaf order) has its keys in one run between them, a line or two.
    /// A leaf whose entries came since, from moves and inserts, gets two of
    /// its keys asked for and the others read when reached: asking for every
    /// key of such leaves cost a cull of the standard scene's maintained
    /// tree 13 % more warm and gained nothing cold (57 → 54 µs without).
    /// A hint only.
    #[inline(always)]
    pub(crate) fn prefetch_keys_of_leaf(&self, leaf: &super::node::Node<W>) {
        let keys = self.keys.as_ptr();
        let slots = &leaf.child[..leaf.len()];
        let (Some(&first), Some(&last)) = (slots.first(), slots.last()) else {
            return;
        };
        // No bounds checks: a prefetch of any address is sound (see
        // `prefetch_address`), and a leaf's slots index `keys`.
        prefetch_address(keys.wrapping_add(first as usize).cast());
        prefetch_address(keys.wrapping_add(last as usize).cast());
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

/// Requests every cache line of `value` (eight for a node of the default
/// width, one for a proxy record).
#[inline(always)]
pub(crate) fn prefetch_lines<T>(value: &T) {
    let base = std::ptr::from_ref(value).cast::<i8>();
    for offset in (0..std::mem::size_of::<T>()).step_by(64) {
        prefetch_address(base.wrapping_add(offset));
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
}
