//! Overlap queries: every entry whose closed exact box shares a point with a
//! query box (or contains a query point).

use std::ops::ControlFlow;

use glam::Vec3;

use super::QueryWorkspace;
use crate::geometry::Aabb;
use crate::tree::RTree;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Calls `visit(key, exact_box)` for every entry whose box overlaps
    /// `query` (closed boxes: touching counts), in no particular order, until
    /// `visit` breaks. A query box that is not valid ([`Aabb::is_valid`]:
    /// NaN, infinite, inverted on some axis, or beyond
    /// [`MAX_COORD`](crate::MAX_COORD)) matches nothing, and so does a point
    /// that is not a valid point box: no entry is tested against it.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// let inverted = Aabb { min: Vec3::ONE, max: Vec3::ZERO };
    /// assert!(tree.overlapping(&inverted).is_empty());
    /// assert_eq!(tree.overlapping(&Aabb::new(Vec3::ZERO, Vec3::ZERO)?), vec![1]);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn visit_overlapping<F>(&self, query: &Aabb, ws: &mut QueryWorkspace, mut visit: F)
    where
        F: FnMut(K, &Aabb) -> ControlFlow<()>,
    {
        if !query.is_valid() {
            return;
        }
        self.visit_overlapping_proxies(query, ws, |proxy, aabb| visit(self.key_of(proxy), aabb));
    }

    /// The traversal behind [`RTree::visit_overlapping`], reporting proxy
    /// indices so that other queries (joins) can tell entries apart.
    pub(crate) fn visit_overlapping_proxies<F>(
        &self,
        query: &Aabb,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) where
        F: FnMut(u32, &Aabb) -> ControlFlow<()>,
    {
        ws.stack.clear();
        ws.stack.push(self.root());
        while let Some(index) = ws.stack.pop() {
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            let mut mask = node.overlap_mask(query);
            if node.is_leaf() {
                ws.stats.entries_tested += node.len() as u64;
                while mask != 0 {
                    let lane = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    if visit(node.child[lane], &node.lane_box(lane)).is_break() {
                        return;
                    }
                }
            } else {
                while mask != 0 {
                    let lane = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    // Loads of siblings overlap instead of stalling in turn.
                    self.prefetch_node(node.child[lane]);
                    ws.stack.push(node.child[lane]);
                }
            }
        }
    }

    /// Calls `visit(key, exact_box)` for every entry whose box passes
    /// `test`, pruning every node whose bounds fail it. `test` must be
    /// monotone (a box that passes makes every box containing it pass), so
    /// that no node holding a passing entry is pruned.
    #[cfg_attr(not(feature = "bevy_light"), allow(dead_code))]
    pub(crate) fn visit_boxes_where(
        &self,
        ws: &mut QueryWorkspace,
        mut test: impl FnMut(&Aabb) -> bool,
        mut visit: impl FnMut(K, &Aabb),
    ) {
        if self.is_empty() {
            return;
        }
        ws.stack.clear();
        ws.stack.push(self.root());
        while let Some(index) = ws.stack.pop() {
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            if node.is_leaf() {
                ws.stats.entries_tested += node.len() as u64;
            }
            let mut lanes = node.used_lanes();
            while lanes != 0 {
                let lane = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                let bounds = node.lane_box(lane);
                if !test(&bounds) {
                    continue;
                }
                if node.is_leaf() {
                    visit(self.key_of(node.child[lane]), &bounds);
                } else {
                    self.prefetch_node(node.child[lane]);
                    ws.stack.push(node.child[lane]);
                }
            }
        }
    }

    /// Appends the keys of all entries overlapping `query` to `out`
    /// (unordered; sort if you need an order).
    pub fn overlapping_into(&self, query: &Aabb, ws: &mut QueryWorkspace, out: &mut Vec<K>) {
        self.visit_overlapping(query, ws, |key, _| {
            out.push(key);
            ControlFlow::Continue(())
        });
    }

    /// The keys of all entries overlapping `query`, sorted.
    pub fn overlapping(&self, query: &Aabb) -> Vec<K> {
        let mut out = Vec::new();
        self.overlapping_into(query, &mut QueryWorkspace::default(), &mut out);
        out.sort_unstable();
        out
    }

    /// Whether any entry overlaps `query`; stops at the first.
    pub fn any_overlapping(&self, query: &Aabb, ws: &mut QueryWorkspace) -> bool {
        let mut found = false;
        self.visit_overlapping(query, ws, |_, _| {
            found = true;
            ControlFlow::Break(())
        });
        found
    }

    /// The keys of all entries whose closed box contains `point`, sorted.
    pub fn containing_point(&self, point: Vec3) -> Vec<K> {
        self.overlapping(&Aabb {
            min: point,
            max: point,
        })
    }
}
