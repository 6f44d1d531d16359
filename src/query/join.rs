//! Distance joins: every pair of entries within a distance, of one tree with
//! itself or of two trees (the cross join's own steps are in
//! `cross_join.rs`).
//!
//! The traversal descends pairs of nodes in lock step: for two nodes it tests
//! every pair of their children and recurses only into the pairs that can
//! still be within the distance, so whole regions far apart are dismissed at
//! once. Entry pairs are decided by the predicate of [contract S8](crate::contract) in `f64`.

use std::ops::ControlFlow;

use glam::Vec3;

use super::QueryWorkspace;
use crate::geometry::predicates::{check_distance, within_chebyshev, within_euclidean};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::node::{Node, QueryCorners};
use crate::tree::{ProxyId, RTree};

/// Which distance a join uses ([contract S8](crate::contract)).
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum JoinMode {
    /// Pair iff the Euclidean distance between the closed boxes is `<= d`.
    #[default]
    Euclidean,
    /// Pair iff the gap on every axis is `<= d` (the box grown by `d`
    /// overlaps): a superset of the Euclidean pairs (it adds diagonal
    /// neighbours up to `d·√3` apart). It skips the `f64` distance, but on
    /// the standard scene the join took from 4 % more to 13 % less time
    /// than in the Euclidean mode over recent runs (see
    /// docs/accuracy_cost.md), so prefer it only where the grown-box test is
    /// what you want.
    Chebyshev,
}

impl JoinMode {
    /// The pair predicate of this mode ([contract S8](crate::contract)).
    #[inline]
    pub(crate) fn accepts(self, a: &Aabb, b: &Aabb, distance: f64) -> bool {
        match self {
            JoinMode::Euclidean => within_euclidean(a, b, distance),
            JoinMode::Chebyshev => within_chebyshev(a, b, distance),
        }
    }
}

/// A join's distance test, checked once per call: `reach` grows boxes
/// during the traversal, `exact` (the distance widened to `f64`) decides
/// entry pairs by `mode`, except where [`JoinTest::masks_decide`].
///
/// At distance 0 both modes of S8 accept exactly the pairs of closed boxes
/// that overlap: every axis gap must be 0, and the `f64` gap of two `f32`
/// coordinates is positive exactly when one exceeds the other (a nonzero
/// difference never rounds to zero, and its square never underflows in
/// `f64`). The lane masks compare the `f32` coordinates themselves with a
/// reach of 0, so the pairs they keep are the answer and the `f64` test is
/// skipped: self join of the standard scene 2.77–2.86 →
/// 2.68–2.71 ms in a probe, alternating builds, the same pairs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct JoinTest {
    pub(super) reach: f32,
    exact: f64,
    mode: JoinMode,
}

impl JoinTest {
    /// Fails with [`SpatialError::InvalidDistance`] unless `distance` is
    /// finite and `>= 0`.
    pub(crate) fn new(distance: f32, mode: JoinMode) -> Result<Self, SpatialError> {
        Ok(JoinTest {
            exact: check_distance(distance)?,
            reach: reach_of(distance),
            mode,
        })
    }

    /// Whether the lane masks alone decide entry pairs: at distance 0,
    /// the one distance whose reach is 0 (see [`reach_of`]).
    #[inline]
    fn masks_decide(&self) -> bool {
        self.reach == 0.0
    }

    /// The pair predicate of [contract S8](crate::contract).
    #[inline]
    fn accepts(&self, a: &Aabb, b: &Aabb) -> bool {
        self.mode.accepts(a, b, self.exact)
    }
}

/// How far the traversal grows boxes for a join within `distance`: the
/// `f32` just above `distance` (`0` for `0`).
///
/// S8 rounds each axis gap to `f64`, so it accepts some pairs whose real
/// gap exceeds `distance` by up to a few `2^-53` of it, never more than
/// `2^-49` of it; the next `f32` up is at least `2^-24` of it higher, so
/// every pair S8 accepts has real gaps `<= reach` on every axis. For `0`
/// the `f64` gap is exact (a nonzero difference of two `f32` never rounds
/// to zero), so nothing needs adding.
fn reach_of(distance: f32) -> f32 {
    if distance == 0.0 {
        0.0
    } else {
        distance.next_up()
    }
}

/// `aabb` grown by `by` (a join's reach, see [`reach_of`]) on every side, in
/// plain `f32` arithmetic.
///
/// A lane test against the grown box never dismisses a pair S8 accepts,
/// although each sum is rounded: such a pair has
/// `lane.min <= aabb.max + reach` on every axis in real arithmetic, and
/// rounding to nearest is monotonic and leaves the representable
/// `lane.min` as it is, so `lane.min <= fl(aabb.max + reach)` too (and
/// likewise on the other side). Regions only take minima and maxima of such
/// sums, which keeps the argument. Rounding every sum outward instead
/// (`next_down` / `next_up`) cost a quarter of a self join, and still
/// missed pairs near zero (see `reach_of`).
#[inline(always)]
pub(super) fn grow(aabb: &Aabb, by: f32) -> Aabb {
    let d = Vec3::splat(by);
    Aabb {
        min: aabb.min - d,
        max: aabb.max + d,
    }
}

/// The number of lanes set in `mask`, for masks of at most 16 lanes.
///
/// `u32::count_ones` needs the `popcnt` instruction, which the default
/// x86-64 target does not assume, so it compiles to a dozen shifts and
/// masks; two lookups in a 256-entry table cost less on a join's hot path.
#[inline(always)]
fn lane_count(mask: u32) -> u32 {
    const BITS: [u8; 256] = {
        let mut table = [0u8; 256];
        let mut i = 0;
        while i < 256 {
            table[i] = (i as u32).count_ones() as u8;
            i += 1;
        }
        table
    };
    debug_assert!(mask <= u16::MAX as u32);
    (BITS[(mask & 0xff) as usize] + BITS[((mask >> 8) & 0xff) as usize]) as u32
}

/// A pair of nodes still to be joined, with the region their pairs can lie
/// in: the intersection of both nodes' bounds grown by the distance (for
/// the root pair, all of space).
///
/// A lane of either node that can be within the distance of anything in
/// the other node overlaps the region, so one mask test per node dismisses
/// every other lane. Carrying the region costs one box per pair; computing
/// each node's bound from its lanes instead cost about a fifth of a join.
#[derive(Clone, Copy, Debug)]
pub(crate) struct JoinItem {
    pub a: u32,
    pub b: u32,
    pub region: Aabb,
}

impl JoinItem {
    /// The item of a tree's root with itself (a self join).
    pub(crate) fn roots(a: u32, b: u32) -> Self {
        let everywhere = Aabb {
            min: Vec3::NEG_INFINITY,
            max: Vec3::INFINITY,
        };
        JoinItem {
            a,
            b,
            region: everywhere,
        }
    }
}

/// The item of the roots of two trees (a cross join): their region is
/// already the meeting of both roots' bounds grown by `reach`, so that
/// while the taller tree descends alone its children are tested against
/// the shorter tree's bound, not against all of space.
pub(crate) fn cross_roots<const W: usize>(
    (a, na): (u32, &Node<W>),
    (b, nb): (u32, &Node<W>),
    reach: f32,
) -> JoinItem {
    let region = meet(
        &grow(&na.lanes_union(), reach),
        &grow(&nb.lanes_union(), reach),
    );
    JoinItem { a, b, region }
}

/// The intersection of two boxes (inverted when they are apart).
#[inline(always)]
pub(super) fn meet(a: &Aabb, b: &Aabb) -> Aabb {
    Aabb {
        min: a.min.max(b.min),
        max: a.max.min(b.max),
    }
}

/// The box lane test a join runs on: `masks(node, query, lanes)` is the set
/// of `lanes` of `node` whose boxes overlap `query` (S2), as
/// [`Node::overlap_mask_among`] computes it four lanes at a time, or its
/// AVX-512 twin (`join_avx512.rs`) sixteen at a time. Both give the same
/// bits, so the traversal and its answers are the same either way.
pub(crate) trait LaneMasks<const W: usize>:
    Fn(&Node<W>, &QueryCorners, u32) -> u32 + Copy
{
}

impl<const W: usize, L: Fn(&Node<W>, &QueryCorners, u32) -> u32 + Copy> LaneMasks<W> for L {}

/// The four-lane box lane test, which every processor runs.
#[inline(always)]
pub(crate) fn four_lane_masks<const W: usize>(
    node: &Node<W>,
    query: &QueryCorners,
    lanes: u32,
) -> u32 {
    node.overlap_mask_among_corners(query, lanes)
}

/// Which two nodes a step of a join pairs, for the choices that differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum NodePair {
    /// A node with itself (self join): each unordered lane pair once, and
    /// every child of an internal node also paired with itself.
    Same,
    /// Two nodes of one tree (self join).
    OneTree,
    /// A node of each of two trees (cross join).
    TwoTrees,
}

/// The lane-pair step both joins share, for two nodes at the same level
/// whose pairs lie in `region`: for each lane `i` of `na`, the lanes `j` of
/// `nb` that can still be within `distance`. Pairs of internal nodes go on
/// the join stack; pairs of leaf entries that pass the exact predicate go to
/// `emit(i, j)`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn join_lane_pairs<const W: usize>(
    na: &Node<W>,
    nb: &Node<W>,
    pair: NodePair,
    region: &Aabb,
    test: JoinTest,
    ws: &mut QueryWorkspace,
    masks: impl LaneMasks<W>,
    emit: impl FnMut(usize, usize) -> ControlFlow<()>,
) -> ControlFlow<()> {
    if pair == NodePair::Same {
        let lanes = na.used_lanes();
        // Each lane meets the lanes above it only: each unordered pair once.
        let above = |i: usize| lanes & !((2u32 << i) - 1);
        return if na.is_leaf() {
            lane_pairs::<W, true>(na, lanes, na, above, true, true, test, ws, masks, emit)
        } else {
            lane_pairs::<W, false>(na, lanes, na, above, true, true, test, ws, masks, emit)
        };
    }
    let a_lanes = masks(na, &QueryCorners::of(region), na.used_lanes());
    if pair == NodePair::OneTree && na.is_leaf() {
        // Two leaves of a self join: `na`'s lanes near the region go
        // outside, against all of `nb`'s. Testing `nb`'s lanes against the
        // region too, to put the side with fewer outside as below, cost
        // more than it saved: both leaves hold boxes of one kind, so their
        // counts are alike (self join of the standard scene 3–4 % faster
        // without it, alternating builds, the same pairs). A lane of `nb`
        // that meets a lane of `na` inside the region meets the region, so
        // the answer is the same. The cross join keeps the choice: with
        // enemies against barrels the counts differ, and the cross join took
        // 16 % longer without it.
        let all_of_nb = |_| nb.used_lanes();
        return lane_pairs::<W, true>(
            na, a_lanes, nb, all_of_nb, true, false, test, ws, masks, emit,
        );
    }
    let b_lanes = masks(nb, &QueryCorners::of(region), nb.used_lanes());
    // The side with fewer lanes near the other goes outside: each of its
    // lanes costs one test of the other side's groups. Chosen by value, so
    // that one copy of `lane_pairs` serves both ways.
    let a_outside = lane_count(a_lanes) <= lane_count(b_lanes);
    let (outer, outer_lanes, inner, inner_lanes) = if a_outside {
        (na, a_lanes, nb, b_lanes)
    } else {
        (nb, b_lanes, na, a_lanes)
    };
    let inner_lanes = |_| inner_lanes;
    if na.is_leaf() {
        lane_pairs::<W, true>(
            outer,
            outer_lanes,
            inner,
            inner_lanes,
            a_outside,
            false,
            test,
            ws,
            masks,
            emit,
        )
    } else {
        lane_pairs::<W, false>(
            outer,
            outer_lanes,
            inner,
            inner_lanes,
            a_outside,
            false,
            test,
            ws,
            masks,
            emit,
        )
    }
}

/// Each lane `o` of `outer` among `outer_lanes` against the lanes of
/// `inner` among `inner_lanes(o)` whose boxes are within reach, tested only
/// in the groups of lanes that hold such lanes ([`Node::overlap_mask_among`]:
/// after a join's region test a leaf keeps about two of its lanes, so most
/// groups of four hold none). `outer_is_a` tells which node is `na`, so
/// that either can go outside. `same_node` says that `outer` and `inner`
/// are one node of a self join ([`NodePair::Same`]): each child of an
/// internal node is then also paired with itself. It is told, not found by
/// comparing addresses: a cross join of a tree with itself pairs a node
/// with itself too, and there every child already meets itself among its
/// partners.
///
/// Two passes: the first tests every outer lane and only records its mask,
/// the second visits the lanes that have any partner. Most lanes have none
/// or one, at random, so a loop that tested a lane and then branched on its
/// answer was mispredicted about every other lane; with the tests apart,
/// the branches follow the few lanes with partners. Self join in a probe,
/// alternating builds: 3.2–3.5 → 2.8–2.9 ms, the same pairs in the same
/// order (a leaf with itself 0.9 → 0.7 ms of it, pairs of internal nodes
/// about 0.85 → 0.7 ms, pairs of two leaves unchanged at 1.5 ms).
///
/// `LEAVES` says whether both nodes are leaves, so that each kind of node
/// pair runs its own copy of the loop with no branch on the kind inside
/// (self join 2.88–3.19 → 2.80–2.82 ms in a probe, alternating builds).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn lane_pairs<const W: usize, const LEAVES: bool>(
    outer: &Node<W>,
    outer_lanes: u32,
    inner: &Node<W>,
    inner_lanes: impl Fn(usize) -> u32,
    outer_is_a: bool,
    same_node: bool,
    test: JoinTest,
    ws: &mut QueryWorkspace,
    masks: impl LaneMasks<W>,
    mut emit: impl FnMut(usize, usize) -> ControlFlow<()>,
) -> ControlFlow<()> {
    let a_b = |o: u32, n: u32| if outer_is_a { (o, n) } else { (n, o) };
    let mut partners = [0u32; W];
    let mut with_partners = 0u32;
    let mut lanes = outer_lanes;
    while lanes != 0 {
        let o = lanes.trailing_zeros() as usize;
        lanes &= lanes - 1;
        let reach = QueryCorners::of_grown_lane(outer, o, test.reach);
        let mask = masks(inner, &reach, inner_lanes(o));
        partners[o] = mask;
        with_partners |= ((mask != 0) as u32) << o;
    }
    // A child of an internal node paired with itself needs no partner.
    let mut lanes = if same_node && !LEAVES {
        outer_lanes
    } else {
        with_partners
    };
    while lanes != 0 {
        let o = lanes.trailing_zeros() as usize;
        lanes &= lanes - 1;
        let mut mask = partners[o];
        let lane_box = outer.lane_box(o);
        let lane_reach = grow(&lane_box, test.reach);
        if same_node && !LEAVES {
            ws.join_stack.push(JoinItem {
                a: outer.child[o],
                b: outer.child[o],
                region: lane_reach,
            });
        }
        while mask != 0 {
            let n = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if !LEAVES {
                let (a, b) = a_b(outer.child[o], inner.child[n]);
                let region = meet(&lane_reach, &grow(&inner.lane_box(n), test.reach));
                ws.join_stack.push(JoinItem { a, b, region });
                continue;
            }
            // Counted here rather than with one `count_ones` of the mask:
            // see `lane_count`.
            ws.stats.entries_tested += 1;
            if test.masks_decide() || test.accepts(&lane_box, &inner.lane_box(n)) {
                let (i, j) = a_b(o as u32, n as u32);
                emit(i as usize, j as usize)?;
            }
        }
    }
    ControlFlow::Continue(())
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Calls `visit(lo, hi)` once for every unordered pair of distinct
    /// entries within `distance` (`lo <= hi` by key), until `visit` breaks.
    /// Fails with [`SpatialError::InvalidDistance`] unless `distance` is
    /// finite and `>= 0`.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, JoinMode, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// tree.insert(2u32, Aabb::new(Vec3::new(3.0, 0.0, 0.0), Vec3::new(4.0, 1.0, 1.0))?)?;
    /// tree.insert(3u32, Aabb::new(Vec3::splat(50.0), Vec3::splat(51.0))?)?;
    /// assert_eq!(tree.self_join(2.0, JoinMode::Euclidean)?, vec![(1, 2)]);
    /// assert!(tree.self_join(1.5, JoinMode::Euclidean)?.is_empty());
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn visit_self_join<F>(
        &self,
        distance: f32,
        mode: JoinMode,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) -> Result<(), SpatialError>
    where
        F: FnMut(K, K) -> ControlFlow<()>,
    {
        let test = JoinTest::new(distance, mode)?;
        ws.join_stack.clear();
        ws.join_stack
            .push(JoinItem::roots(self.root(), self.root()));
        let _ = self.drain_self_join(test, ws, &mut visit);
        Ok(())
    }

    /// Runs the self join from the node pairs on `ws.join_stack` until the
    /// stack is empty or `visit` breaks: on the AVX-512 lane test where
    /// `join_avx512::avx512_tests_nodes` allows it, on the four-lane test
    /// otherwise.
    pub(crate) fn drain_self_join(
        &self,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        #[cfg(target_arch = "x86_64")]
        if super::join_avx512::avx512_tests_nodes::<W>() {
            // SAFETY: `avx512_tests_nodes` is true only once the standard
            // library's run-time check has found AVX-512 on this
            // processor, the one requirement of a function compiled with
            // it enabled.
            #[allow(unsafe_code)]
            return unsafe { self.drain_self_join_avx512(test, ws, visit) };
        }
        self.drain_self_join_with(test, ws, visit, four_lane_masks::<W>)
    }

    /// [`RTree::drain_self_join`] on the lane test `masks`.
    #[inline(always)]
    pub(super) fn drain_self_join_with(
        &self,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
        masks: impl LaneMasks<W>,
    ) -> ControlFlow<()> {
        while let Some(item) = ws.join_stack.pop() {
            self.self_join_step(item, test, ws, masks, visit)?;
        }
        ControlFlow::Continue(())
    }

    /// One pair of nodes of a self join: pushes the child pairs that can
    /// still hold pairs within `distance`, or, for two leaves, reports the
    /// entry pairs.
    #[inline(always)]
    pub(crate) fn self_join_step(
        &self,
        item: JoinItem,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        masks: impl LaneMasks<W>,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        ws.stats.nodes_visited += 1;
        let JoinItem { a, b, region } = item;
        let (na, nb) = (self.node(a), self.node(b));
        let base = ws.join_stack.len();
        let pair = if a == b {
            NodePair::Same
        } else {
            NodePair::OneTree
        };
        let flow = join_lane_pairs(na, nb, pair, &region, test, ws, masks, |i, j| {
            let (ka, kb) = (self.key_of(na.child[i]), self.key_of(nb.child[j]));
            visit(ka.min(kb), ka.max(kb))
        });
        // The pairs just pushed: their nodes' loads overlap, where the tree
        // is not in cache, instead of stalling pair after pair.
        for pushed in &ws.join_stack[base.min(ws.join_stack.len())..] {
            self.prefetch_node(pushed.a);
            self.prefetch_node(pushed.b);
        }
        flow
    }

    /// All pairs of [`RTree::visit_self_join`], sorted.
    pub fn self_join(&self, distance: f32, mode: JoinMode) -> Result<Vec<(K, K)>, SpatialError> {
        let mut out = Vec::new();
        self.self_join_into(distance, mode, &mut QueryWorkspace::default(), &mut out)?;
        out.sort_unstable();
        Ok(out)
    }

    /// Appends the pairs of [`RTree::visit_self_join`] to `out`, unordered.
    pub fn self_join_into(
        &self,
        distance: f32,
        mode: JoinMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<(K, K)>,
    ) -> Result<(), SpatialError> {
        self.visit_self_join(distance, mode, ws, |a, b| {
            out.push((a, b));
            ControlFlow::Continue(())
        })
    }

    /// The self-join pairs that involve at least one entry of `moved`, each
    /// once, as `(lo, hi)` by key: with the previous frame's pairs of those
    /// entries, a caller derives pair-started and pair-ended events without
    /// a full join. Fails on an unknown handle or an invalid distance before
    /// reporting anything.
    pub fn visit_self_join_moved<F>(
        &self,
        moved: &[ProxyId],
        distance: f32,
        mode: JoinMode,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) -> Result<(), SpatialError>
    where
        F: FnMut(K, K) -> ControlFlow<()>,
    {
        let test = JoinTest::new(distance, mode)?;
        let mut sorted = std::mem::take(&mut ws.moved);
        sorted.clear();
        for id in moved {
            self.get(*id)?;
            sorted.push(id.index());
        }
        sorted.sort_unstable();
        sorted.dedup();
        for &m in &sorted {
            let (key_m, box_m) = self.get(self.handle(m)).expect("checked above");
            let mut inner = ControlFlow::Continue(());
            self.visit_overlapping_proxies(&grow(&box_m, test.reach), ws, |c, box_c| {
                // A pair of two moved entries is reported from the lower one.
                if c == m || (c < m && sorted.binary_search(&c).is_ok()) {
                    return ControlFlow::Continue(());
                }
                if test.accepts(&box_m, box_c) {
                    let key_c = self.key_of(c);
                    inner = visit(key_m.min(key_c), key_m.max(key_c));
                    return inner;
                }
                ControlFlow::Continue(())
            });
            if inner.is_break() {
                break;
            }
        }
        ws.moved = sorted;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{grow, lane_count};
    use crate::tree::node::{LaneSamples, QueryCorners};

    /// The corners a join's inner step builds from a lane's rows are those
    /// of the lane's box grown as `grow` grows it, bit for bit, on grid
    /// values, arbitrary floats and the reaches a join uses.
    #[test]
    fn a_grown_lane_s_corners_are_the_grown_box_s() {
        let mut samples = LaneSamples::new(5, 1e6);
        for round in 0..2_000 {
            let node = samples.node::<16>(round % 2 == 0, 16);
            let by = [0.0, 5.0f32.next_up(), 1e-3, samples.value(false).abs()][round % 4];
            for lane in 0..16 {
                let from_rows = QueryCorners::of_grown_lane(&node, lane, by);
                let from_box = QueryCorners::of(&grow(&node.lane_box(lane), by));
                let bits = |c: [f32; 3]| c.map(f32::to_bits);
                assert_eq!(bits(from_rows.min()), bits(from_box.min()), "round {round}");
                assert_eq!(bits(from_rows.max()), bits(from_box.max()), "round {round}");
            }
        }
    }

    #[test]
    fn lane_count_agrees_with_count_ones_on_every_sixteen_lane_mask() {
        for mask in 0..=u16::MAX as u32 {
            assert_eq!(lane_count(mask), mask.count_ones(), "mask {mask:#06x}");
        }
    }
}
