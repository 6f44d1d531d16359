//! The wide node: child bounds as a structure of arrays in one fixed-size,
//! cache-line-aligned block.

use crate::geometry::Aabb;

/// "No node" / "no proxy" sentinel for indices.
pub(crate) const NIL: u32 = u32::MAX;

/// Lanes one `glam::Vec4` lane test covers; node widths are multiples of it.
pub(crate) const LANES_PER_TEST: usize = 4;

/// Lanes `first..first + LANES_PER_TEST` of one row of a node's bounds
/// (`min[axis]` or `max[axis]`), for the four-lanes-at-a-time tests of boxes,
/// rays and frustum planes.
#[inline(always)]
pub(crate) fn four_lanes<const W: usize>(row: &[f32; W], first: usize) -> glam::Vec4 {
    glam::Vec4::from_slice(&row[first..first + LANES_PER_TEST])
}

/// The `level` of a node that sits on the free list.
pub(crate) const FREE_LEVEL: u16 = u16::MAX;

/// One node of the tree, `W` children wide.
///
/// Child bounds are stored per axis (`min[axis][lane]`), so one query tests
/// all `W` lanes with the same instructions and no branch per lane. Unused
/// lanes hold the inverted box (`+inf` / `-inf`), which every predicate
/// rejects for a bounded query; lane tests that may meet an unbounded
/// query mask in the used lanes (`used_lanes`).
///
/// In a leaf (`level == 0`) the lanes hold the entries' *exact* boxes and
/// `child` holds proxy indices; every answer is decided there. In an internal
/// node the lanes hold each child node's bound and `child` holds node indices.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
pub(crate) struct Node<const W: usize> {
    /// Lower corners per axis: `min[axis][lane]`. 12·W bytes.
    pub min: [[f32; W]; 3],
    /// Upper corners per axis: `max[axis][lane]`. 12·W bytes.
    pub max: [[f32; W]; 3],
    /// Child node index (internal) or proxy index (leaf) per lane. 4·W bytes.
    pub child: [u32; W],
    /// Parent node index, `NIL` at the root. 4 bytes.
    pub parent: u32,
    /// Lanes in ascending order of their box centre along x, y and z
    /// (internal nodes only): rays visit children near-to-far by reading
    /// the order of their dominant axis forwards or backwards. 3·W bytes.
    pub order: [[u8; W]; 3],
    /// Number of used lanes (`0..=W`); used lanes come first. 2 bytes.
    pub len: u16,
    /// Height above the leaves (0 = leaf), or `FREE_LEVEL`. 2 bytes.
    pub level: u16,
}

// W = 8 and 16 fill exactly 32·W bytes (four and eight cache lines), so
// nodes never straddle more lines than they must; W = 4 needs 132 bytes and
// rounds up to three lines.
const _: () = assert!(std::mem::size_of::<Node<4>>() == 192);
const _: () = assert!(std::mem::size_of::<Node<8>>() == 256);
const _: () = assert!(std::mem::size_of::<Node<16>>() == 512);

impl<const W: usize> Node<W> {
    /// An empty node at `level`.
    pub fn empty(level: u16, parent: u32) -> Self {
        Node {
            min: [[f32::INFINITY; W]; 3],
            max: [[f32::NEG_INFINITY; W]; 3],
            child: [NIL; W],
            order: [std::array::from_fn(|i| i as u8); 3],
            parent,
            len: 0,
            level,
        }
    }

    #[inline]
    pub fn is_leaf(&self) -> bool {
        self.level == 0
    }

    #[inline]
    pub fn len(&self) -> usize {
        self.len as usize
    }

    /// The box stored in `lane`.
    #[inline]
    pub fn lane_box(&self, lane: usize) -> Aabb {
        Aabb {
            min: glam::Vec3::new(self.min[0][lane], self.min[1][lane], self.min[2][lane]),
            max: glam::Vec3::new(self.max[0][lane], self.max[1][lane], self.max[2][lane]),
        }
    }

    /// Writes the box of `lane`.
    #[inline]
    pub fn set_lane_box(&mut self, lane: usize, aabb: &Aabb) {
        for axis in 0..3 {
            self.min[axis][lane] = aabb.min[axis];
            self.max[axis][lane] = aabb.max[axis];
        }
    }

    /// Marks `lane` unused (inverted box, `NIL` child).
    #[inline]
    pub fn clear_lane(&mut self, lane: usize) {
        self.set_lane_box(lane, &Aabb::INVERTED);
        self.child[lane] = NIL;
    }

    /// The union of the used lanes' boxes.
    pub fn lanes_union(&self) -> Aabb {
        (0..self.len()).fold(Aabb::INVERTED, |acc, lane| acc.union(&self.lane_box(lane)))
    }

    /// Recomputes `order` from the lane boxes. Called when the set of
    /// children changes; growth of a lane box alone keeps the old order,
    /// which stays a good visiting order and costs nothing to keep.
    pub fn refresh_order(&mut self) {
        if self.is_leaf() {
            return;
        }
        let len = self.len();
        for axis in 0..3 {
            let centre = |lane: usize| self.min[axis][lane] + self.max[axis][lane];
            let mut lanes: [u8; W] = std::array::from_fn(|i| i as u8);
            lanes[..len]
                .sort_unstable_by(|&a, &b| centre(a as usize).total_cmp(&centre(b as usize)));
            self.order[axis] = lanes;
        }
    }

    /// Adds the last used lane (`len - 1`, just filled) to `order`, just
    /// before the first lane there whose centre lies above its own (last if
    /// none). The other lanes keep their relative order, which may be stale
    /// after lane boxes grew, as `refresh_order` allows.
    /// Sorting all lanes again on every insertion into an internal node
    /// took a tenth of the time of 100,000 single inserts.
    pub fn order_new_lane(&mut self) {
        if self.is_leaf() {
            return;
        }
        let new = self.len() - 1;
        for axis in 0..3 {
            let centre = |lane: u8| self.min[axis][lane as usize] + self.max[axis][lane as usize];
            let own = centre(new as u8);
            let order = &self.order[axis];
            let at = (0..new)
                .find(|&i| centre(order[i]).total_cmp(&own).is_gt())
                .unwrap_or(new);
            let order = &mut self.order[axis];
            order.copy_within(at..new, at + 1);
            order[at] = new as u8;
        }
    }

    /// The lane holding `child`, if any.
    #[inline]
    pub fn lane_of(&self, child: u32) -> Option<usize> {
        self.child[..self.len()].iter().position(|&c| c == child)
    }

    /// Bit `i` set for each used lane `i` (`0..len`).
    #[inline]
    pub fn used_lanes(&self) -> u32 {
        if self.len() >= 32 {
            u32::MAX
        } else {
            (1u32 << self.len()) - 1
        }
    }

    /// Bit `i` set iff lane `i` is used and its box overlaps `query`
    /// (closed boxes).
    ///
    /// Unused lanes hold the inverted box, which no finite query overlaps;
    /// a query unbounded on both sides of every axis (a join's reach at
    /// `f32::MAX` rounds to one) would pass it, so the used lanes are
    /// masked in as well.
    ///
    /// Four lanes at a time in `glam::Vec4` (glam's SIMD backend: SSE2 on
    /// x86-64, NEON on aarch64, plain floats where it has none): the six
    /// comparisons of the scalar predicate per lane,
    /// combined and turned into bits with one movemask. The loop over lanes
    /// it replaced was vectorised by the compiler, but turned its bools into
    /// bits slowly: box queries took twice as long with it, a self join 40 %
    /// longer. A unit test checks that the mask agrees with the scalar
    /// predicate bit for bit.
    // Always inlined: it is the inner step of every overlap and join
    // traversal, and as a call it cost about half of a self join.
    #[inline(always)]
    pub fn overlap_mask(&self, query: &Aabb) -> u32 {
        let corners = QueryCorners::of(query);
        let mut mask = 0u32;
        for first in (0..W).step_by(LANES_PER_TEST) {
            mask |= self.overlap_bits(&corners, first);
        }
        mask & self.used_lanes()
    }

    /// [`Node::overlap_mask`] restricted to `lanes`: only the groups of four
    /// lanes that hold one of them are tested.
    ///
    /// For the joins, whose lanes near the other node are few (on the
    /// standard scene's self join, two of a leaf's lanes on average): the
    /// groups with none of them are skipped.
    #[inline(always)]
    pub fn overlap_mask_among(&self, query: &Aabb, lanes: u32) -> u32 {
        self.overlap_mask_among_corners(&QueryCorners::of(query), lanes)
    }

    /// [`Node::overlap_mask_among`] for a query given by its corners.
    #[inline(always)]
    pub fn overlap_mask_among_corners(&self, corners: &QueryCorners, lanes: u32) -> u32 {
        let mut mask = 0u32;
        for first in (0..W).step_by(LANES_PER_TEST) {
            if (lanes >> first) & 0b1111 != 0 {
                mask |= self.overlap_bits(corners, first);
            }
        }
        mask & lanes
    }

    /// The overlap bits of lanes `first..first + 4`, at their place in the
    /// mask.
    #[inline(always)]
    fn overlap_bits(&self, q: &QueryCorners, first: usize) -> u32 {
        let four = |row: &[f32; W]| four_lanes(row, first);
        let hit = four(&self.min[0]).cmple(q.hi[0])
            & four(&self.min[1]).cmple(q.hi[1])
            & four(&self.min[2]).cmple(q.hi[2])
            & q.lo[0].cmple(four(&self.max[0]))
            & q.lo[1].cmple(four(&self.max[1]))
            & q.lo[2].cmple(four(&self.max[2]));
        hit.bitmask() << first
    }
}

/// A query box's corners, each coordinate splat to four lanes: what a box
/// lane test compares each group of lanes with.
#[derive(Clone, Copy, Debug)]
pub(crate) struct QueryCorners {
    lo: [glam::Vec4; 3],
    hi: [glam::Vec4; 3],
}

impl QueryCorners {
    #[inline(always)]
    pub(crate) fn of(query: &Aabb) -> Self {
        QueryCorners {
            lo: query.min.to_array().map(glam::Vec4::splat),
            hi: query.max.to_array().map(glam::Vec4::splat),
        }
    }

    /// The box of `lane` of `node` grown by `by` on every side (in plain
    /// `f32` arithmetic, as the joins grow boxes), read from the node's
    /// rows into the splats at once.
    ///
    /// A join's inner step. Built as an `Aabb` first, the box went through
    /// memory in a build with link-time optimization: stored as 16 and 8
    /// bytes and read back as 16 bytes straddling both, a load the
    /// processor cannot forward from the stores, which waited on every
    /// outer lane (a sixth of the self join's samples; the join took 0.83
    /// to 0.86 × parry3d's time there, 0.55 to 0.65 × without it).
    #[inline(always)]
    pub(crate) fn of_grown_lane<const W: usize>(node: &Node<W>, lane: usize, by: f32) -> Self {
        QueryCorners {
            lo: [0, 1, 2].map(|axis| glam::Vec4::splat(node.min[axis][lane] - by)),
            hi: [0, 1, 2].map(|axis| glam::Vec4::splat(node.max[axis][lane] + by)),
        }
    }

    /// The lower corner (for the AVX-512 join's broadcasts).
    #[inline(always)]
    #[cfg_attr(not(any(target_arch = "x86_64", test)), allow(dead_code))]
    pub(crate) fn min(&self) -> [f32; 3] {
        self.lo.map(|splat| splat.x)
    }

    /// The upper corner (for the AVX-512 join's broadcasts).
    #[inline(always)]
    #[cfg_attr(not(any(target_arch = "x86_64", test)), allow(dead_code))]
    pub(crate) fn max(&self) -> [f32; 3] {
        self.hi.map(|splat| splat.x)
    }
}

/// Random lane contents for the lane tests' bit-for-bit checks against the
/// scalar predicates (here and in the ray and frustum queries).
#[cfg(test)]
pub(crate) struct LaneSamples {
    rng: crate::scene::SceneRng,
    range: f32,
}

#[cfg(test)]
impl LaneSamples {
    /// Arbitrary floats are drawn from `(-range, range)`.
    pub fn new(seed: u64, range: f32) -> Self {
        LaneSamples {
            rng: crate::scene::SceneRng::new(seed),
            range,
        }
    }

    /// With `grid`, a half unit from -2 to 2 or -0.0, so faces, slabs and
    /// planes touch and signed zeros meet; otherwise an arbitrary float.
    pub fn value(&mut self, grid: bool) -> f32 {
        if grid {
            match self.rng.below(10) {
                9 => -0.0,
                k => (k as f32 - 4.0) * 0.5,
            }
        } else {
            self.rng.range(-self.range, self.range)
        }
    }

    pub fn point(&mut self, grid: bool) -> glam::Vec3 {
        glam::Vec3::new(self.value(grid), self.value(grid), self.value(grid))
    }

    pub fn aabb(&mut self, grid: bool) -> Aabb {
        let (a, b) = (self.point(grid), self.point(grid));
        Aabb {
            min: a.min(b),
            max: a.max(b),
        }
    }

    /// A leaf with `lanes` random boxes in its first lanes (and `len` to
    /// match); the other lanes unused.
    pub fn node<const W: usize>(&mut self, grid: bool, lanes: usize) -> Node<W> {
        let mut node = Node::<W>::empty(0, NIL);
        for lane in 0..lanes {
            node.set_lane_box(lane, &self.aabb(grid));
        }
        node.len = lanes as u16;
        node
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::predicates::boxes_overlap;

    /// A box lane test `masks(node, query, lanes)` (see `overlap_mask_among`)
    /// and the scalar S2 predicate agree lane by lane, on grid values where
    /// faces touch and signed zeros meet, on arbitrary floats, on infinite
    /// queries and on unused (inverted) lanes; with a subset of lanes
    /// asked for, it gives exactly the full answer's bits among them,
    /// whichever groups those fall in. `masks` returns `None` where it does
    /// not apply (a processor without its instructions); returns how many
    /// nodes it was checked on.
    pub(crate) fn lane_masks_agree_with_the_scalar_predicate<const W: usize>(
        seed: u64,
        masks: impl Fn(&Node<W>, &Aabb, u32) -> Option<u32>,
    ) -> usize {
        let mut samples = LaneSamples::new(seed, 2.0);
        let all = u32::MAX >> (32 - W);
        let mut checked = 0;
        for round in 0..20_000 {
            let grid = round % 2 == 0;
            let node = samples.node::<W>(grid, 1 + round % W);
            let mut query = samples.aabb(grid);
            if round % 7 == 0 {
                query.max.y = f32::INFINITY;
                query.min.z = f32::NEG_INFINITY;
            }
            let Some(mask) = masks(&node, &query, all) else {
                continue;
            };
            for lane in 0..W {
                let scalar = boxes_overlap(&node.lane_box(lane), &query);
                assert_eq!(mask >> lane & 1 == 1, scalar, "lane {lane} round {round}");
            }
            assert_eq!(mask >> W, 0, "no bits above the width");
            let lanes = samples.rng.below(1 << W) as u32;
            assert_eq!(
                masks(&node, &query, lanes),
                Some(mask & lanes),
                "round {round}"
            );
            checked += 1;
        }
        checked
    }

    /// `overlap_mask` and `overlap_mask_among`, the four-lane tests.
    fn four_lane_masks_agree_with_the_scalar_predicate<const W: usize>() {
        let checked = lane_masks_agree_with_the_scalar_predicate::<W>(7, |node, query, lanes| {
            let among = node.overlap_mask_among(query, lanes);
            assert_eq!(among, node.overlap_mask(query) & lanes);
            Some(among)
        });
        assert_eq!(checked, 20_000);
    }

    #[test]
    fn overlap_mask_agrees_bit_for_bit_with_the_scalar_predicate() {
        four_lane_masks_agree_with_the_scalar_predicate::<4>();
        four_lane_masks_agree_with_the_scalar_predicate::<8>();
        four_lane_masks_agree_with_the_scalar_predicate::<12>();
        four_lane_masks_agree_with_the_scalar_predicate::<16>();
    }

    /// Lanes added one at a time keep each axis's order sorted by centre,
    /// as a full `refresh_order` would, on the grid (ties among equal
    /// centres) and on arbitrary floats.
    fn lanes_added_one_by_one_stay_in_centre_order<const W: usize>() {
        let mut samples = LaneSamples::new(11, 100.0);
        for round in 0..2_000 {
            let grid = round % 2 == 0;
            let mut node = Node::<W>::empty(1, NIL);
            for lane in 0..1 + round % W {
                node.set_lane_box(lane, &samples.aabb(grid));
                node.child[lane] = lane as u32;
                node.len += 1;
                node.order_new_lane();
            }
            let mut sorted = node.clone();
            sorted.refresh_order();
            for axis in 0..3 {
                let centres = |n: &Node<W>| -> Vec<f32> {
                    n.order[axis][..n.len()]
                        .iter()
                        .map(|&l| n.min[axis][l as usize] + n.max[axis][l as usize])
                        .collect()
                };
                assert_eq!(
                    centres(&node),
                    centres(&sorted),
                    "round {round} axis {axis}"
                );
                let mut lanes = node.order[axis][..node.len()].to_vec();
                lanes.sort_unstable();
                assert_eq!(lanes, (0..node.len() as u8).collect::<Vec<_>>());
            }
        }
    }

    #[test]
    fn adding_a_lane_keeps_the_children_order_sorted() {
        lanes_added_one_by_one_stay_in_centre_order::<4>();
        lanes_added_one_by_one_stay_in_centre_order::<8>();
        lanes_added_one_by_one_stay_in_centre_order::<16>();
    }
}
