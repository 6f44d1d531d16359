//! Frustum culling: which entries are visible from one or several views.
//!
//! One traversal serves up to eight frustums. For each frustum a node carries
//! the mask of planes its parent was not yet fully inside; a child that is
//! fully inside a plane drops it, and a child inside all planes has its whole
//! subtree emitted without further tests. Leaf entries get the cheap
//! one-corner "outside?" test for the planes that remain.

use std::ops::ControlFlow;

use glam::Vec4;

use super::QueryWorkspace;
use crate::geometry::predicates::frustum_exact_rest;
use crate::geometry::{Frustum, FrustumSat};
use crate::tree::RTree;
use crate::tree::node::{LANES_PER_TEST, Node, four_lanes};

/// How a frustum decides that a box is visible ([contract S7](crate::contract)).
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CullMode {
    /// Visible iff the box's furthest corner along every plane normal is
    /// strictly inside (Bevy's convention). Cheap; a large box near a frustum
    /// edge can pass every plane and still lie outside (a false positive).
    #[default]
    Conservative,
    /// Conservative, and then no separating axis between box and frustum
    /// (the box's face normals, and its edges crossed with the frustum's
    /// edges, in `f64`; the frustum's own planes are the conservative
    /// test). Where rounding leaves a projection uncertain its interval is
    /// widened, so rounding can keep a box that lies just outside but never
    /// drop one that is inside, but for slivers thinner than about 1e-11 of
    /// their distance from the eye (contract, S7): a frustum of next to no
    /// volume may count as empty and see nothing, and one that runs without
    /// end along a line may miss such a sliver beside it. A frustum whose planes have no common
    /// corner (two side planes alone, a wedge) is projected from its slice
    /// through the eye. Costs a few dozen dot products per boundary entry.
    Exact,
}

/// Frustums one traversal can carry (one byte of plane mask each).
pub const FRUSTUMS_PER_PASS: usize = 8;

/// Bit set in a frustum's mask byte while the frustum still sees the subtree.
pub(super) const ALIVE: u64 = 0x80;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Calls `visit(view, key, exact_box)` for every entry visible in
    /// `frustums[view]`, all views in one traversal per eight, in tree order.
    /// Stops when `visit` breaks.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, CullMode, Frustum, QueryWorkspace, RTree};
    /// use bevy_rtree::glam::{Quat, Vec3};
    /// use std::ops::ControlFlow;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::new(-1.0, -1.0, -11.0), Vec3::new(1.0, 1.0, -9.0))?)?;
    /// tree.insert(2u32, Aabb::new(Vec3::new(-1.0, -1.0, 9.0), Vec3::new(1.0, 1.0, 11.0))?)?;
    /// let fov = 60f32.to_radians();
    /// let front = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, fov, 1.0, 0.1, 100.0)?;
    /// let back = Frustum::perspective(Vec3::ZERO, Quat::from_rotation_y(std::f32::consts::PI), fov, 1.0, 0.1, 100.0)?;
    ///
    /// let mut seen = vec![Vec::new(), Vec::new()];
    /// tree.visit_visible(&[front, back], CullMode::Conservative, &mut QueryWorkspace::default(), |view, key, _| {
    ///     seen[view].push(key);
    ///     ControlFlow::Continue(())
    /// });
    /// assert_eq!(seen, [vec![1], vec![2]]);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn visit_visible<F>(
        &self,
        frustums: &[Frustum],
        mode: CullMode,
        ws: &mut QueryWorkspace,
        visit: F,
    ) where
        F: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        self.cull_in_passes::<true, F>(frustums, mode, ws, visit);
    }

    /// One traversal per [`FRUSTUMS_PER_PASS`] frustums, the visitor given
    /// each frustum's index in `frustums`; stops at a `Break`. `BOXES`
    /// false: the visitor reads no box of an entry in a subtree reported
    /// whole (see [`RTree::cull_subtree`]).
    fn cull_in_passes<const BOXES: bool, F>(
        &self,
        frustums: &[Frustum],
        mode: CullMode,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) where
        F: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        for (chunk, views) in frustums.chunks(FRUSTUMS_PER_PASS).enumerate() {
            let first_view = chunk * FRUSTUMS_PER_PASS;
            let prepared: Vec<PreparedView> =
                views.iter().map(|f| PreparedView::new(f, mode)).collect();
            let flow = self.cull_pass::<BOXES, _>(&prepared, ws, &mut |view, key, aabb| {
                visit(first_view + view, key, aabb)
            });
            if flow.is_break() {
                return;
            }
        }
    }

    /// Appends the keys visible in each frustum to the matching list of `out`,
    /// in tree order. One traversal per eight frustums.
    ///
    /// `out` is first made one list per frustum: lists beyond the last
    /// frustum are dropped and missing ones added empty; the lists kept are
    /// appended to, not cleared.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, CullMode, Frustum, QueryWorkspace, RTree};
    /// use bevy_rtree::glam::{Quat, Vec3};
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(7u32, Aabb::new(Vec3::new(-1.0, -1.0, -6.0), Vec3::new(1.0, 1.0, -4.0))?)?;
    /// let view = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.0, 0.1, 100.0)?;
    /// let mut out = Vec::new();
    /// tree.visible_into(&[view, view], CullMode::Conservative, &mut QueryWorkspace::default(), &mut out);
    /// assert_eq!(out, [vec![7], vec![7]]);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn visible_into(
        &self,
        frustums: &[Frustum],
        mode: CullMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<Vec<K>>,
    ) {
        out.resize_with(frustums.len(), Vec::new);
        // Keys only: subtrees reported whole are read for their links, not
        // their boxes (two lines of a leaf's eight).
        self.cull_in_passes::<false, _>(frustums, mode, ws, |view, key, _| {
            out[view].push(key);
            ControlFlow::Continue(())
        });
    }

    /// The keys visible in one frustum, sorted.
    pub fn visible(&self, frustum: &Frustum, mode: CullMode) -> Vec<K> {
        let mut out = Vec::with_capacity(1);
        self.visible_into(
            std::slice::from_ref(frustum),
            mode,
            &mut QueryWorkspace::default(),
            &mut out,
        );
        let mut keys = out.pop().unwrap_or_default();
        keys.sort_unstable();
        keys
    }

    /// One traversal for up to eight views.
    fn cull_pass<const BOXES: bool, V>(
        &self,
        views: &[PreparedView],
        ws: &mut QueryWorkspace,
        visit: &mut V,
    ) -> ControlFlow<()>
    where
        V: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        match self.cull_start(views) {
            Some(start) => self.cull_subtree::<BOXES, V>(views, start, ws, visit),
            None => ControlFlow::Continue(()),
        }
    }

    /// The root with every view's active planes, or `None` when no view can
    /// see anything.
    pub(crate) fn cull_start(&self, views: &[PreparedView]) -> Option<CullItem> {
        let mut start_mask = 0u64;
        for (v, view) in views.iter().enumerate() {
            // An exact view of an empty volume sees nothing: not even the
            // subtrees its planes would report whole.
            if view.sat.as_ref().is_some_and(FrustumSat::sees_nothing) {
                continue;
            }
            start_mask |= (ALIVE | view.active_planes as u64) << (8 * v);
        }
        (start_mask != 0).then_some((self.root(), start_mask))
    }

    /// Pushes onto `out`, in lane order (the order a stack reports last
    /// first), the children of the internal node `index` that some view
    /// alive in `mask` may see, each with the planes each view still has to
    /// test; with `prefetch`, starts their loads (of a child every view
    /// contains, with `BOXES` false, only its links). A node every view
    /// contains passes its mask to all its children untested.
    #[inline]
    pub(crate) fn push_visible_children<const BOXES: bool>(
        &self,
        views: &[PreparedView],
        (index, mask): CullItem,
        prefetch: bool,
        out: &mut Vec<CullItem>,
    ) {
        let node = self.node(index);
        if fully_inside(mask) {
            let children = &node.child[..node.len()];
            if prefetch {
                for &child in children {
                    self.prefetch_cull_item::<BOXES>((child, mask));
                }
            }
            out.extend(children.iter().map(|&child| (child, mask)));
            return;
        }
        let used = node.used_lanes();
        let mut lane_masks = [0u64; W];
        for (v, view, planes) in views_alive(views, mask) {
            if planes == 0 {
                for (lane, m) in lane_masks.iter_mut().enumerate() {
                    if used & (1 << lane) != 0 {
                        *m |= ALIVE << (8 * v);
                    }
                }
                continue;
            }
            let (alive, remaining) = view.test_lanes::<W, true>(node, planes);
            let mut alive = alive & used;
            while alive != 0 {
                let lane = alive.trailing_zeros() as usize;
                alive &= alive - 1;
                lane_masks[lane] |= (ALIVE | remaining[lane] as u64) << (8 * v);
            }
        }
        for (lane, &lane_mask) in lane_masks.iter().enumerate() {
            if lane_mask != 0 {
                if prefetch {
                    self.prefetch_cull_item::<BOXES>((node.child[lane], lane_mask));
                }
                out.push((node.child[lane], lane_mask));
            }
        }
    }

    /// Starts the load of what the cull reads of `item`'s node: its links
    /// alone where every view contains it and `BOXES` is false, the whole
    /// node otherwise.
    #[inline(always)]
    pub(super) fn prefetch_cull_item<const BOXES: bool>(&self, (index, mask): CullItem) {
        if !BOXES && fully_inside(mask) {
            self.prefetch_node_links(index);
        } else {
            self.prefetch_node(index);
        }
    }

    /// A leaf not inside every plane of every view: per view, its entries
    /// outside none of the planes left (and, in exact mode, with no
    /// separating axis), in lane order.
    ///
    /// View by view, going straight to the visible lanes: building one
    /// mask per lane for all views first and then walking every lane, as
    /// internal nodes do, made a cull of the standard scene take 61–63 µs
    /// instead of 45–46 µs.
    #[inline]
    pub(super) fn cull_leaf<V>(
        &self,
        views: &[PreparedView],
        mask: u64,
        node: &Node<W>,
        ws: &mut QueryWorkspace,
        visit: &mut V,
    ) -> ControlFlow<()>
    where
        V: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        let used = node.used_lanes();
        let mut tested = false;
        for (v, view, planes) in views_alive(views, mask) {
            // Only the exact mode's extra test needs to know which planes
            // an entry is not yet inside of; conservative culling skips
            // computing them, which is half of every leaf's plane arithmetic.
            let (alive, remaining) = if planes == 0 {
                (used, None)
            } else if view.sat.is_none() {
                (view.test_lanes::<W, false>(node, planes).0, None)
            } else {
                let (alive, remaining) = view.test_lanes::<W, true>(node, planes);
                (alive, Some(remaining))
            };
            tested |= planes != 0;
            let mut alive = alive & used;
            while alive != 0 {
                let lane = alive.trailing_zeros() as usize;
                alive &= alive - 1;
                let aabb = node.lane_box(lane);
                if let Some(remaining) = &remaining
                    && remaining[lane] != 0
                    && !view.exact_rest(&aabb)
                {
                    continue;
                }
                visit(v, self.key_of(node.child[lane]), &aabb)?;
            }
        }
        if tested {
            ws.stats.entries_tested += node.len() as u64;
        }
        ControlFlow::Continue(())
    }
}

/// The views alive in `mask`, each with its index and the planes it still
/// has to test.
#[inline]
pub(super) fn views_alive(
    views: &[PreparedView],
    mask: u64,
) -> impl Iterator<Item = (usize, &PreparedView, u8)> {
    views.iter().enumerate().filter_map(move |(v, view)| {
        let byte = (mask >> (8 * v)) & 0xFF;
        (byte & ALIVE != 0).then_some((v, view, (byte & 0x3F) as u8))
    })
}

/// The views alive in a mask, one bit per view.
#[inline]
pub(super) fn alive_views(mask: u64) -> u32 {
    // Each byte's alive bit moved to the byte's lowest bit; the product
    // then gathers byte `v`'s bit at bit `56 + v`, the partial sums never
    // meeting (the bits land at distinct positions, so nothing carries).
    const ONE_PER_BYTE: u64 = 0x0101_0101_0101_0101;
    const GATHER: u64 = 0x0102_0408_1020_4080;
    const _: () = assert!(ALIVE == 0x80 && FRUSTUMS_PER_PASS == 8);
    ((((mask >> 7) & ONE_PER_BYTE).wrapping_mul(GATHER)) >> 56) as u32
}

/// Whether every view alive in `mask` has no plane left to test: the node
/// and all below it are visible to each of them.
#[inline]
pub(crate) fn fully_inside(mask: u64) -> bool {
    // Each byte is ALIVE | planes; no byte may hold a plane bit.
    const PLANES: u64 = 0x3F3F_3F3F_3F3F_3F3F;
    mask != 0 && mask & PLANES == 0
}

/// A node to visit and, per view, its alive bit and the planes it still
/// has to be tested against.
pub(crate) type CullItem = (u32, u64);

/// A frustum ready for lane tests: active planes and, in exact mode, the
/// separating-axis precomputation.
pub(crate) struct PreparedView {
    frustum: Frustum,
    pub(crate) active_planes: u8,
    sat: Option<FrustumSat>,
}

impl PreparedView {
    pub(crate) fn new(frustum: &Frustum, mode: CullMode) -> PreparedView {
        let mut active_planes = 0u8;
        for (i, plane) in frustum.planes().iter().enumerate() {
            if !plane.is_inactive() {
                active_planes |= 1 << i;
            }
        }
        let sat = (mode == CullMode::Exact).then(|| FrustumSat::new(frustum));
        PreparedView {
            frustum: *frustum,
            active_planes,
            sat,
        }
    }

    /// For the planes in `planes`: the lanes not outside any of them, and per
    /// lane the planes it is not yet fully inside (with `INSIDE`; without,
    /// every lane keeps all of `planes`).
    #[inline]
    pub(crate) fn test_lanes<const W: usize, const INSIDE: bool>(
        &self,
        node: &Node<W>,
        planes: u8,
    ) -> (u32, [u8; W]) {
        let eye = self.frustum.eye();
        let mut alive = u32::MAX;
        let mut remaining = [planes; W];
        let mut bits = planes;
        while bits != 0 {
            let p = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let plane = self.frustum.planes()[p];
            let n = plane.normal;
            // The p-vertex reads max where n >= 0, the n-vertex the other.
            let (px, nx) = if n.x >= 0.0 {
                (&node.max[0], &node.min[0])
            } else {
                (&node.min[0], &node.max[0])
            };
            let (py, ny) = if n.y >= 0.0 {
                (&node.max[1], &node.min[1])
            } else {
                (&node.min[1], &node.max[1])
            };
            let (pz, nz) = if n.z >= 0.0 {
                (&node.max[2], &node.min[2])
            } else {
                (&node.min[2], &node.max[2])
            };
            // `plane_value` four lanes at a time, same operations in the same
            // order, so the bits agree with the scalar predicate.
            let value = |x: &[f32; W], y: &[f32; W], z: &[f32; W], first: usize| {
                let four = |row: &[f32; W]| four_lanes(row, first);
                Vec4::splat(n.x) * (four(x) - Vec4::splat(eye.x))
                    + Vec4::splat(n.y) * (four(y) - Vec4::splat(eye.y))
                    + Vec4::splat(n.z) * (four(z) - Vec4::splat(eye.z))
                    + Vec4::splat(plane.offset)
            };
            let mut outside_free = 0u32;
            for first in (0..W).step_by(LANES_PER_TEST) {
                let far = value(px, py, pz, first);
                outside_free |= far.cmpgt(Vec4::ZERO).bitmask() << first;
            }
            alive &= outside_free;
            if !INSIDE {
                continue;
            }
            let mut inside = 0u32;
            for first in (0..W).step_by(LANES_PER_TEST) {
                let near = value(nx, ny, nz, first);
                inside |= near.cmpgt(Vec4::ZERO).bitmask() << first;
            }
            let mut inside_lanes = inside;
            while inside_lanes != 0 {
                let lane = inside_lanes.trailing_zeros() as usize;
                inside_lanes &= inside_lanes - 1;
                remaining[lane] &= !(1u8 << p);
            }
        }
        (alive, remaining)
    }

    /// The exact mode's extra test for an entry that passed the planes.
    #[inline]
    fn exact_rest(&self, aabb: &crate::Aabb) -> bool {
        match &self.sat {
            Some(sat) => frustum_exact_rest(&self.frustum, sat, aabb),
            None => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::HalfSpace;
    use crate::geometry::predicates::{frustum_conservative, frustum_contains, plane_value};
    use crate::tree::node::LaneSamples;
    use glam::Vec3;

    /// The lane test (four lanes at a time) and the scalar S7 corner tests
    /// agree lane by lane: a lane is alive iff its box passes the
    /// conservative test, and has no plane left iff the frustum contains
    /// it. Grid values (signed zeros included) make corners land exactly on
    /// planes.
    fn lanes_agree_with_the_scalar_predicates<const W: usize>() {
        let mut samples = LaneSamples::new(11, 4.0);
        let mut checked = 0;
        for round in 0..20_000 {
            let grid = round % 2 == 0;
            let lanes = 1 + round % W;
            let node = samples.node::<W>(grid, lanes);
            let eye = samples.point(grid);
            let planes = std::array::from_fn(|i| {
                if i == 5 && round % 3 == 0 {
                    return HalfSpace::INACTIVE;
                }
                let normal = samples.point(grid);
                let offset = if round % 4 == 1 {
                    // Through a lane's corner, in the scalar order of
                    // operations: its value is exactly zero there, and any
                    // other order of the same sums may round it either way.
                    let aabb = node.lane_box(i % lanes);
                    let (far, near) = (normal.cmpge(Vec3::ZERO), normal.cmplt(Vec3::ZERO));
                    let corner_is_far = i % 2 == 0;
                    let corner =
                        Vec3::select(if corner_is_far { far } else { near }, aabb.max, aabb.min);
                    -plane_value(normal, 0.0, eye, corner)
                } else {
                    samples.value(grid) + 2.0
                };
                HalfSpace { normal, offset }
            });
            let Ok(frustum) = Frustum::new(eye, planes) else {
                continue;
            };
            let view = PreparedView::new(&frustum, CullMode::Conservative);
            let (alive, remaining) = view.test_lanes::<W, true>(&node, view.active_planes);
            let (alive_only, _) = view.test_lanes::<W, false>(&node, view.active_planes);
            assert_eq!(alive, alive_only, "round {round}");
            for (lane, remaining) in remaining.iter().enumerate().take(lanes) {
                let aabb = node.lane_box(lane);
                let visible = frustum_conservative(&frustum, &aabb);
                assert_eq!(alive >> lane & 1 == 1, visible, "lane {lane} round {round}");
                let contained = frustum_contains(&frustum, &aabb);
                assert_eq!(*remaining == 0, contained, "lane {lane} round {round}");
            }
            checked += 1;
        }
        assert!(checked > 10_000, "most random frustums are valid");
    }

    #[test]
    fn lane_tests_agree_bit_for_bit_with_the_scalar_predicates() {
        lanes_agree_with_the_scalar_predicates::<4>();
        lanes_agree_with_the_scalar_predicates::<8>();
        lanes_agree_with_the_scalar_predicates::<16>();
    }

    /// The gathered alive bits are the bytes' alive bits, one by one.
    #[test]
    fn alive_views_gathers_each_byte_s_alive_bit() {
        let mut rng = crate::scene::SceneRng::new(3);
        for _ in 0..10_000 {
            let mask = rng.next_u64();
            let mut want = 0u32;
            for view in 0..FRUSTUMS_PER_PASS {
                if (mask >> (8 * view)) & ALIVE != 0 {
                    want |= 1 << view;
                }
            }
            assert_eq!(alive_views(mask), want, "{mask:#x}");
        }
    }
}
