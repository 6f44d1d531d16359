//! The cross join: every pair of an entry of one tree and an entry of
//! another within a distance. It shares the lock-step descent and the
//! lane-pair step with the self join (`join.rs`); what is its own is the
//! descent of the taller tree alone until the levels meet, and the pairs'
//! two key spaces.

use std::ops::ControlFlow;

use super::QueryWorkspace;
use super::join::{
    JoinItem, JoinMode, JoinTest, LaneMasks, NodePair, cross_roots, four_lane_masks, grow,
    join_lane_pairs, meet,
};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::RTree;
use crate::tree::node::{Node, QueryCorners};

/// The children of `node` whose bound overlaps `region`, each with the
/// region cut down to its bound grown by `reach`: the items of a node that
/// descends alone against a shorter partner.
#[inline(always)]
fn children_in_region<'a, const W: usize>(
    node: &'a Node<W>,
    region: &'a Aabb,
    reach: f32,
    masks: impl LaneMasks<W> + 'a,
) -> impl Iterator<Item = (u32, Aabb)> + 'a {
    let mut mask = masks(node, &QueryCorners::of(region), node.used_lanes());
    std::iter::from_fn(move || {
        if mask == 0 {
            return None;
        }
        let lane = mask.trailing_zeros() as usize;
        mask &= mask - 1;
        let cut = meet(region, &grow(&node.lane_box(lane), reach));
        Some((node.child[lane], cut))
    })
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Calls `visit(a, b)` once for every pair of an entry `a` of this tree
    /// and an entry `b` of `other` within `distance`, with `a != b` by key,
    /// until `visit` breaks. The two trees may have different shapes and
    /// widths of the same `W`.
    pub fn visit_cross_join<F>(
        &self,
        other: &RTree<K, W>,
        distance: f32,
        mode: JoinMode,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) -> Result<(), SpatialError>
    where
        F: FnMut(K, K) -> ControlFlow<()>,
    {
        let test = JoinTest::new(distance, mode)?;
        if self.is_empty() || other.is_empty() {
            return Ok(());
        }
        ws.join_stack.clear();
        ws.join_stack.push(self.cross_join_roots(other, test));
        let _ = self.drain_cross_join(other, test, ws, &mut visit);
        Ok(())
    }

    /// The first pair of a cross join with `other`: the two roots.
    pub(crate) fn cross_join_roots(&self, other: &RTree<K, W>, test: JoinTest) -> JoinItem {
        let (a, b) = (self.root(), other.root());
        cross_roots((a, self.node(a)), (b, other.node(b)), test.reach)
    }

    /// Runs the cross join with `other` from the node pairs on
    /// `ws.join_stack`, as [`RTree::drain_self_join`].
    pub(crate) fn drain_cross_join(
        &self,
        other: &RTree<K, W>,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        #[cfg(target_arch = "x86_64")]
        if super::join_avx512::avx512_tests_nodes::<W>() {
            // SAFETY: as in `drain_self_join`.
            #[allow(unsafe_code)]
            return unsafe { self.drain_cross_join_avx512(other, test, ws, visit) };
        }
        self.drain_cross_join_with(other, test, ws, visit, four_lane_masks::<W>)
    }

    /// [`RTree::drain_cross_join`] on the lane test `masks`.
    #[inline(always)]
    pub(super) fn drain_cross_join_with(
        &self,
        other: &RTree<K, W>,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
        masks: impl LaneMasks<W>,
    ) -> ControlFlow<()> {
        while let Some(item) = ws.join_stack.pop() {
            self.cross_join_step(other, item, test, ws, masks, visit)?;
        }
        ControlFlow::Continue(())
    }

    /// One pair of nodes of a cross join: the taller side descends alone
    /// until the levels meet; then as [`RTree::self_join_step`].
    #[inline(always)]
    pub(crate) fn cross_join_step(
        &self,
        other: &RTree<K, W>,
        item: JoinItem,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        masks: impl LaneMasks<W>,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        ws.stats.nodes_visited += 1;
        let JoinItem { a, b, region } = item;
        let (na, nb) = (self.node(a), other.node(b));
        // The taller side descends alone, paired with the other node as is.
        if na.level != nb.level {
            let a_descends = na.level > nb.level;
            let taller = if a_descends { na } else { nb };
            for (child, region) in children_in_region(taller, &region, test.reach, masks) {
                let (a, b) = if a_descends { (child, b) } else { (a, child) };
                ws.join_stack.push(JoinItem { a, b, region });
            }
            return ControlFlow::Continue(());
        }
        let base = ws.join_stack.len();
        let flow = join_lane_pairs(
            na,
            nb,
            NodePair::TwoTrees,
            &region,
            test,
            ws,
            masks,
            |i, j| {
                let (ka, kb) = (self.key_of(na.child[i]), other.key_of(nb.child[j]));
                if ka == kb {
                    return ControlFlow::Continue(());
                }
                visit(ka, kb)
            },
        );
        // As in the self join: the pushed pairs' nodes start loading now.
        for pushed in &ws.join_stack[base.min(ws.join_stack.len())..] {
            self.prefetch_node(pushed.a);
            other.prefetch_node(pushed.b);
        }
        flow
    }

    /// All pairs of [`RTree::visit_cross_join`], sorted.
    pub fn cross_join(
        &self,
        other: &RTree<K, W>,
        distance: f32,
        mode: JoinMode,
    ) -> Result<Vec<(K, K)>, SpatialError> {
        let mut out = Vec::new();
        self.cross_join_into(
            other,
            distance,
            mode,
            &mut QueryWorkspace::default(),
            &mut out,
        )?;
        out.sort_unstable();
        Ok(out)
    }

    /// Appends the pairs of [`RTree::visit_cross_join`] to `out`, unordered.
    pub fn cross_join_into(
        &self,
        other: &RTree<K, W>,
        distance: f32,
        mode: JoinMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<(K, K)>,
    ) -> Result<(), SpatialError> {
        self.visit_cross_join(other, distance, mode, ws, |a, b| {
            out.push((a, b));
            ControlFlow::Continue(())
        })
    }
}
