//! Removal: take the entry out of its leaf, then condense the path: an
//! underflowing node leaves the tree and its children are reinserted.

use super::node::NIL;
use super::{Entry, RTree};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::ProxyId;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Removes an entry and returns its key.
    ///
    /// A handle that is not live (never issued here, or already removed) is
    /// refused with [`SpatialError::UnknownProxy`] and nothing changes.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree, SpatialError};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let id = tree.insert('a', Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// assert_eq!(tree.remove(id), Ok('a'));
    /// assert_eq!(tree.remove(id), Err(SpatialError::UnknownProxy));
    /// assert!(tree.is_empty());
    /// # Ok::<(), SpatialError>(())
    /// ```
    pub fn remove(&mut self, id: ProxyId) -> Result<K, SpatialError> {
        let proxy = self.check(id)?;
        self.detach(proxy);
        self.proxies[proxy as usize].leaf = NIL;
        let stamp = &mut self.stamps[proxy as usize];
        *stamp = stamp.retired();
        if !stamp.is_exhausted() {
            self.free_proxies.push(proxy);
        }
        self.len -= 1;
        self.maintenance.removals += 1;
        self.wear += 1;
        self.note_change(proxy, None);
        Ok(self.keys[proxy as usize])
    }

    /// Takes a live proxy out of its leaf and condenses the tree. The proxy
    /// record stays allocated (the caller frees or reinserts it).
    pub(super) fn detach(&mut self, proxy: u32) {
        let (leaf, lane) = {
            let p = &self.proxies[proxy as usize];
            (p.leaf, p.lane as usize)
        };
        self.remove_lane(leaf, lane);
        self.condense(leaf);
    }

    /// Removes `lane` from `node` by moving the last lane into its place.
    pub(super) fn remove_lane(&mut self, node: u32, lane: usize) {
        let n = &mut self.nodes[node as usize];
        let last = n.len() - 1;
        if lane != last {
            let moved = n.lane_box(last);
            n.set_lane_box(lane, &moved);
            n.child[lane] = n.child[last];
        }
        n.clear_lane(last);
        n.len -= 1;
        n.refresh_order();
        if lane != last {
            self.link(node, lane);
        }
    }

    /// Walks from `start` to the root. A node below minimum fill is cut out
    /// and its children kept as orphans; every other node's bound in its
    /// parent is tightened. Orphans are then reinserted at their own level
    /// (highest first, so subtrees find a tree tall enough) and a root with a
    /// single child is replaced by that child.
    fn condense(&mut self, start: u32) {
        let mut orphans: Vec<(Entry, u16)> = Vec::new();
        let mut current = start;
        while current != self.root {
            let parent = self.nodes[current as usize].parent;
            let lane = self.nodes[parent as usize]
                .lane_of(current)
                .expect("parent links its child");
            if self.nodes[current as usize].len() < Self::MIN_FILL {
                self.remove_lane(parent, lane);
                let level = self.nodes[current as usize].level;
                orphans.extend(self.node_entries(current).into_iter().map(|e| (e, level)));
                self.free_node(current);
                self.maintenance.condensed_nodes += 1;
            } else {
                let bound = self.node_bound(current);
                if self.nodes[parent as usize].lane_box(lane) == bound {
                    // Nothing above can change: every ancestor already holds
                    // this bound and lost no child.
                    break;
                }
                self.set_child_bound(parent, lane, &bound);
            }
            current = parent;
        }
        orphans.sort_by_key(|orphan| std::cmp::Reverse(orphan.1));
        for (entry, level) in orphans {
            self.insert_entry(entry, level);
        }
        self.shrink_root();
    }

    /// While the root is an internal node with one child, that child becomes
    /// the root.
    pub(super) fn shrink_root(&mut self) {
        loop {
            let root = &self.nodes[self.root as usize];
            if root.is_leaf() || root.len() != 1 {
                return;
            }
            let child = root.child[0];
            self.free_node(self.root);
            self.root = child;
            self.nodes[child as usize].parent = NIL;
            self.held_bounds[child as usize] = Aabb::EVERYWHERE;
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::tree::handle::Stamp;

    #[test]
    fn a_slot_that_ran_through_every_generation_is_never_reused() {
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap();
        let mut tree = RTree::<u32>::new();
        let first = tree.insert(0, unit).unwrap();
        tree.remove(first).unwrap();
        // The slot as 2^31 - 1 insert / remove cycles leave it.
        tree.stamps[first.index as usize] = Stamp::LAST_FREE;
        let last = tree.insert(1, unit).unwrap();
        assert_eq!(last.index, first.index, "the free slot is reused once more");
        tree.remove(last).unwrap();
        let next = tree.insert(2, unit).unwrap();
        assert_ne!(next.index, first.index, "the exhausted slot stays retired");
        assert!(!tree.contains(first) && !tree.contains(last));
        assert_eq!(tree.remove(first), Err(SpatialError::UnknownProxy));
        assert_eq!(tree.len(), 1);
        tree.validate().unwrap();
        tree.clear();
        let after_clear = tree.insert(3, unit).unwrap();
        assert_ne!(after_clear.index, first.index, "clear() does not revive it");
        assert!(!tree.contains(first));
        tree.validate().unwrap();
    }
}
