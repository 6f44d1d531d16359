//! Moves: absorbed by the enlarged box when small, by the leaf's bound when
//! moderate, and by a reinsertion otherwise.

use super::node::NIL;
use super::{Entry, RTree};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::ProxyId;

/// What a move cost, from cheapest to dearest.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MoveKind {
    /// The new box is inside the entry's enlarged box: one lane write.
    InPlace,
    /// The entry got a new enlarged box that still fits its leaf's bound:
    /// one lane write, no structural change.
    InLeaf,
    /// The entry left its leaf's bound but stayed inside the bound of the
    /// leaf's parent: the leaf's bound grew to take it, O(1). The parent is
    /// marked churned, so [`RTree::optimize`] later re-tiles its leaves.
    LeafGrown,
    /// The entry left its leaf's parent's bound and was reinserted from the
    /// root.
    Reinserted,
}

/// How many moves ahead `update_batch` asks for the leaf it will write:
/// far enough for the load to land before the write, near enough that the
/// line is still in cache (8 and 16 measured the same).
const LEAF_AHEAD: usize = 8;

/// How many moves ahead `update_batch` asks for a proxy record: twice
/// `LEAF_AHEAD`, so the record has landed when its leaf is asked for.
const PROXY_AHEAD: usize = 2 * LEAF_AHEAD;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Moves an entry to a new exact box.
    ///
    /// Fails with [`SpatialError::InvalidBox`] or
    /// [`SpatialError::UnknownProxy`] and changes nothing. The handle stays
    /// the same whatever the move cost.
    /// For a frame's many moves, [`RTree::update_batch`] is faster.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, MoveKind, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
    /// let id = tree.insert(1u8, unit)?;
    /// let nudged = Aabb::new(Vec3::splat(0.01), Vec3::splat(1.01))?;
    /// assert_eq!(tree.update(id, nudged)?, MoveKind::InPlace);
    /// assert_eq!(tree.get(id)?.1, nudged); // answers use the exact box
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn update(&mut self, id: ProxyId, aabb: Aabb) -> Result<MoveKind, SpatialError> {
        aabb.validate()?;
        let proxy = self.check(id)?;
        Ok(self.move_proxy(proxy, aabb))
    }

    /// Moves many entries at once, in order: a frame's moves belong here.
    ///
    /// Every move is checked before any is applied: if a box is invalid or a
    /// handle unknown, that error is returned and nothing moves. An entry may
    /// appear more than once; its last box wins. Answers afterwards are the
    /// same as after calling [`RTree::update`] on each move in turn.
    ///
    /// On large trees it is faster than that loop: the checking pass reads
    /// only the handles' stamps (4 bytes each, in a dense array that stays in
    /// cache), and while the applying pass applies one move it asks for the
    /// record of the move sixteen places ahead and the lane bounds of the
    /// leaf of the move eight places ahead, so their loads overlap (on the
    /// standard scene's 10,000 moves per frame, 25 to 33 % less time than
    /// one `update` per move in this machine's runs).
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree, SpatialError};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let unit = Aabb::new(Vec3::ZERO, Vec3::ONE)?;
    /// let a = tree.insert('a', unit)?;
    /// let b = tree.insert('b', unit)?;
    /// let far = Aabb::new(Vec3::splat(50.0), Vec3::splat(51.0))?;
    /// tree.update_batch(&[(a, far), (b, far)])?;
    /// assert_eq!(tree.get(b)?.1, far);
    ///
    /// // One bad box: an error, and neither entry moves.
    /// let bad = Aabb { min: Vec3::ONE, max: Vec3::ZERO };
    /// let refused = tree.update_batch(&[(a, unit), (b, bad)]);
    /// assert_eq!(refused, Err(SpatialError::InvalidBox));
    /// assert_eq!(tree.get(a)?.1, far);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn update_batch(&mut self, moves: &[(ProxyId, Aabb)]) -> Result<(), SpatialError> {
        for (id, aabb) in moves {
            aabb.validate()?;
            self.check(*id)?;
        }
        for (i, &(id, aabb)) in moves.iter().enumerate() {
            if let Some((ahead, _)) = moves.get(i + PROXY_AHEAD) {
                self.prefetch_proxy(ahead.index);
            }
            if let Some((ahead, _)) = moves.get(i + LEAF_AHEAD) {
                self.prefetch_leaf_for_move(self.proxies[ahead.index as usize].leaf);
            }
            self.move_proxy(id.index, aabb);
        }
        Ok(())
    }

    /// Moves entries by handles kept beside their keys (the plugin keeps
    /// one on each entity), boxes already valid: a move applies if its
    /// handle names `key`'s live entry, and is skipped otherwise, its index
    /// in `moves` pushed to `refused` (a stale handle, or one copied to
    /// another entity; the caller finds that entry another way). The
    /// handle's stamp and the key are requested with the record sixteen
    /// moves ahead, so the checks add no wait of their own to the moves.
    #[cfg_attr(not(feature = "plugin"), allow(dead_code))]
    pub(crate) fn update_kept(&mut self, moves: &[(ProxyId, K, Aabb)], refused: &mut Vec<usize>) {
        for (i, &(id, key, aabb)) in moves.iter().enumerate() {
            if let Some(&(ahead, ..)) = moves.get(i + PROXY_AHEAD) {
                self.prefetch_proxy(ahead.index);
                self.prefetch_handle_check(ahead.index);
            }
            if let Some((ahead, ..)) = moves.get(i + LEAF_AHEAD)
                && let Some(record) = self.proxies.get(ahead.index as usize)
            {
                self.prefetch_leaf_for_move(record.leaf);
            }
            match self.check(id) {
                Ok(proxy) if self.keys[proxy as usize] == key => {
                    self.move_proxy(proxy, aabb);
                }
                _ => refused.push(i),
            }
        }
    }

    fn move_proxy(&mut self, proxy: u32, aabb: Aabb) -> MoveKind {
        let kind = self.move_proxy_here(proxy, aabb);
        if self.rebuild_job.is_some() {
            let fat = self.proxies[proxy as usize].fat;
            self.note_change(proxy, Some((&aabb, &fat)));
        }
        kind
    }

    /// [`Self::move_proxy`] in this structure (a rebuild under way is told
    /// afterwards).
    #[inline(always)]
    fn move_proxy_here(&mut self, proxy: u32, aabb: Aabb) -> MoveKind {
        let (leaf, lane, fat) = {
            let p = &self.proxies[proxy as usize];
            (p.leaf, p.lane as usize, p.fat)
        };
        if fat.contains(&aabb) {
            self.nodes[leaf as usize].set_lane_box(lane, &aabb);
            self.maintenance.moves_in_place += 1;
            return MoveKind::InPlace;
        }

        let old = self.nodes[leaf as usize].lane_box(lane);
        let displacement = (aabb.min - old.min + aabb.max - old.max) * 0.5;
        let new_fat = self.settings.fatten(&aabb, displacement);
        let kind = self.move_proxy_with_fat(proxy, aabb, new_fat);
        let left_its_leaf = matches!(kind, MoveKind::LeafGrown | MoveKind::Reinserted);
        if left_its_leaf && self.settings.is_jump(&aabb, displacement) {
            // A jump leaves a hole in one part of the tiling and lands far
            // away, as a removal and an insert do (a respawn): it wears the
            // tiling twice. Counted once, 1 % teleports a frame kept the
            // join's small trees 1.25–1.27 × fresh over the last 200 frames
            // of the decay bench, against 1.22 counted twice, for the same
            // maintenance.
            self.wear += 1;
        }
        kind
    }

    /// Moves the entry in `proxy` to `aabb` with the enlarged box `new_fat`
    /// (which contains it): a lane write if `new_fat` fits its leaf's bound,
    /// else the leaf's bound grown, else a reinsertion.
    #[inline(always)]
    pub(super) fn move_proxy_with_fat(
        &mut self,
        proxy: u32,
        aabb: Aabb,
        new_fat: Aabb,
    ) -> MoveKind {
        let (leaf, lane) = {
            let p = &self.proxies[proxy as usize];
            (p.leaf, p.lane as usize)
        };
        if self.leaf_bound_contains(leaf, &new_fat) {
            self.proxies[proxy as usize].fat = new_fat;
            self.nodes[leaf as usize].set_lane_box(lane, &aabb);
            self.maintenance.moves_in_leaf += 1;
            return MoveKind::InLeaf;
        }

        let old_parent = self.nodes[leaf as usize].parent;
        if self.try_grow_leaf(leaf, &new_fat) {
            self.proxies[proxy as usize].fat = new_fat;
            self.nodes[leaf as usize].set_lane_box(lane, &aabb);
            self.note_churn(old_parent);
            self.maintenance.moves_leaf_grown += 1;
            self.wear += 1;
            return MoveKind::LeafGrown;
        }

        self.detach(proxy);
        self.proxies[proxy as usize].fat = new_fat;
        let new_leaf = self.insert_entry(
            Entry {
                lane_box: aabb,
                bound: new_fat,
                child: proxy,
            },
            0,
        );
        self.note_churn(old_parent);
        let new_parent = self.nodes[new_leaf as usize].parent;
        if new_parent != old_parent {
            self.note_churn(new_parent);
        }
        self.maintenance.moves_reinserted += 1;
        self.wear += 1;
        MoveKind::Reinserted
    }

    /// Whether `fat` fits the bound the parent holds for `leaf` (the root
    /// leaf has no bound to leave: its copy is all space).
    fn leaf_bound_contains(&self, leaf: u32, fat: &Aabb) -> bool {
        self.held_bounds[leaf as usize].contains(fat)
    }

    /// Grows the bound the parent holds for `leaf` to take `fat`, if the
    /// parent's own bound (held by the grandparent) already contains `fat`.
    /// Nothing above the parent changes, so this is O(1); a parent that is
    /// the root has no bound to stay within, and is left to reinsertion.
    fn try_grow_leaf(&mut self, leaf: u32, fat: &Aabb) -> bool {
        let parent = self.nodes[leaf as usize].parent;
        if parent == NIL || self.nodes[parent as usize].parent == NIL {
            return false;
        }
        if !self.held_bounds[parent as usize].contains(fat) {
            return false;
        }
        let Some(lane) = self.nodes[parent as usize].lane_of(leaf) else {
            return false;
        };
        let grown = self.held_bounds[leaf as usize].union(fat);
        self.set_child_bound(parent, lane, &grown);
        true
    }

    /// Counts a restructuring move against a level-1 node and queues it for
    /// repacking once it crosses the threshold.
    fn note_churn(&mut self, node: u32) {
        if node == NIL {
            return;
        }
        if self.nodes[node as usize].level != 1 {
            return;
        }
        let threshold = self.settings.repack_threshold(W);
        let churn = &mut self.churn[node as usize];
        // Saturates: a caller that never repairs may count past any limit.
        *churn = churn.saturating_add(1);
        if *churn >= threshold {
            self.dirty.push(node);
        }
    }
}
