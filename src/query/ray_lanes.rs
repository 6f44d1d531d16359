//! The lane test of a ray against a node: which of the node's children the
//! ray enters within a limit, and where, for all lanes at once. Every ray
//! walk uses it (`ray.rs`, `ray_batch.rs`); the AVX and AVX-512 walks have
//! their own versions of it (`ray_avx.rs`, `ray_avx512.rs`), held to the
//! scalar predicate by the harness in this file's tests.

use glam::{BVec4A, Vec4};

use crate::geometry::predicates::{RayTest, finite_limit};
use crate::tree::node::{LANES_PER_TEST, Node, four_lanes};

/// Lane mask and entry `t` per lane of one ray against one node: the S4
/// predicate of `predicates::ray_box_entry`, written over the lane arrays
/// with the same operations in the same order, so that it agrees bit for bit.
///
/// Four lanes at a time in `glam::Vec4`, the bits taken with one movemask:
/// the per-lane loop the compiler vectorised turned its bools into bits
/// slowly (see `Node::overlap_mask`). A ray with no zero direction component
/// (nearly every ray) takes a path with no branch inside the node: which row
/// is near is chosen once per axis, not once per four lanes.
// Always inlined: the inner step of every ray traversal; as a call (with its
// lane array returned through memory) it was about half of a ray's time.
#[inline(always)]
pub(crate) fn ray_lanes<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    if ray.has_flat_axis {
        ray_lanes_with_flat_axis(ray, limit, node)
    } else {
        lanes_of::<W, false>(ray, limit, node)
    }
}

/// [`ray_lanes`] for a ray that runs flat along some axis (a zero direction
/// component), out of line: such rays are rare, and the common path stays
/// small in every traversal it is inlined into.
#[inline(never)]
fn ray_lanes_with_flat_axis<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    lanes_of::<W, true>(ray, limit, node)
}

/// Per axis, the rows of `node`'s bounds through which `ray` enters and
/// leaves the lanes' slabs: `(min, max)` where the ray runs towards `+`,
/// `(max, min)` otherwise. Shared by the four-, eight- and sixteen-lane
/// tests; a plain function, not `array::from_fn`, so that it inlines into
/// the walks compiled for AVX and AVX-512.
#[inline(always)]
pub(super) fn near_far_rows<'a, const W: usize>(
    ray: &RayTest,
    node: &'a Node<W>,
) -> [(&'a [f32; W], &'a [f32; W]); 3] {
    let rows = |axis: usize| {
        if ray.inv[axis] > 0.0 {
            (&node.min[axis], &node.max[axis])
        } else {
            (&node.max[axis], &node.min[axis])
        }
    };
    [rows(0), rows(1), rows(2)]
}

/// The lane test of [`ray_lanes`]. With `FLAT`, an axis the ray runs flat
/// along is a slab test on the origin, as in the scalar predicate; without,
/// the ray must have no zero direction component, and the check is
/// compiled out.
#[inline(always)]
fn lanes_of<const W: usize, const FLAT: bool>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    let rows = near_far_rows(ray, node);
    let origin = ray.origin.map(Vec4::splat);
    let inv = ray.inv.map(Vec4::splat);
    let mut entry = [0.0f32; W];
    let mut mask = 0u32;
    for first in (0..W).step_by(LANES_PER_TEST) {
        let mut lo = Vec4::ZERO;
        let mut hi = Vec4::splat(finite_limit(limit));
        let mut slab_ok = BVec4A::splat(true);
        for axis in 0..3 {
            if FLAT && ray.dir[axis] == 0.0 {
                let o = origin[axis];
                let min = four_lanes(&node.min[axis], first);
                let max = four_lanes(&node.max[axis], first);
                slab_ok &= !(o.cmplt(min) | o.cmpgt(max));
                continue;
            }
            let (near, far) = rows[axis];
            let t0 = (four_lanes(near, first) - origin[axis]) * inv[axis];
            let t1 = (four_lanes(far, first) - origin[axis]) * inv[axis];
            lo = greater_or_keep(t0, lo);
            hi = less_or_keep(t1, hi);
        }
        let hit = if FLAT {
            slab_ok & lo.cmple(hi)
        } else {
            lo.cmple(hi)
        };
        mask |= hit.bitmask() << first;
        lo.write_to_slice(&mut entry[first..first + LANES_PER_TEST]);
    }
    (mask, entry)
}

/// Per lane, `t` where `t > bound`, else `bound`: a NaN `t` (0 · inf)
/// leaves the bound as it is, as the scalar `if` does. `f32::max` would
/// not (it returns the other operand), so this is not a max.
#[inline(always)]
fn greater_or_keep(t: Vec4, bound: Vec4) -> Vec4 {
    // glam's SSE2 `max` is `maxps t, bound`, defined as `t > bound ? t :
    // bound`: exactly this, in one instruction instead of the three of a
    // compare-and-select. The lane tests' bit-for-bit unit tests hold it to
    // the scalar predicate.
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        t.max(bound)
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::select(t.cmpgt(bound), t, bound)
    }
}

/// Per lane, `t` where `t < bound`, else `bound` (see [`greater_or_keep`]).
#[inline(always)]
fn less_or_keep(t: Vec4, bound: Vec4) -> Vec4 {
    // `minps t, bound` is `t < bound ? t : bound`.
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        t.min(bound)
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::select(t.cmplt(bound), t, bound)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::geometry::predicates::ray_box_entry;
    use crate::tree::node::LaneSamples;

    /// Holds the lane test `lanes` to the scalar S4 predicate bit for bit,
    /// on grid values that make slabs touch (signed zeros included) and on
    /// arbitrary floats from `seed`; one round in five of each is a hard
    /// case: a direction so short that slab distances overflow, boxes and
    /// origin far from the world's origin, or a limit equal to a lane's
    /// entry `t`. `lanes` may decline a ray (`None`: a ray its path does
    /// not take); returns how many rays it took.
    pub(in crate::query) fn lanes_agree_with_the_scalar_predicate<const W: usize>(
        seed: u64,
        lanes: impl Fn(&RayTest, f32, &Node<W>) -> Option<(u32, [f32; W])>,
    ) -> usize {
        let mut samples = LaneSamples::new(seed, 5.0);
        let mut taken = 0;
        for round in 0..20_000 {
            let grid = round % 2 == 0;
            let mut node = samples.node::<W>(grid, 1 + round % W);
            let mut origin = samples.point(grid);
            let mut dir = samples.point(grid);
            let mut max_t = samples.value(grid).abs() * 3.0;
            match round % 5 {
                1 => {
                    dir *= 1e-37;
                    max_t = f32::INFINITY;
                }
                3 => {
                    // One ulp is 1 m out here.
                    let far = 1.0e7;
                    origin += glam::Vec3::splat(far);
                    for row in node.min.iter_mut().chain(node.max.iter_mut()) {
                        row.iter_mut().for_each(|v| *v += far);
                    }
                }
                _ => {}
            }
            let Ok(ray) = Ray::new(origin, dir, max_t) else {
                continue;
            };
            let test = RayTest::new(&ray);
            let tie = (round % 5 == 2)
                .then(|| {
                    let b = node.lane_box(0);
                    ray_box_entry(&test, f32::INFINITY, b.min.to_array(), b.max.to_array())
                })
                .flatten();
            let limit = match tie {
                Some(t) => t,
                None if round % 3 == 0 => f32::INFINITY,
                None => ray.max_t,
            };
            let Some((mask, lane_t)) = lanes(&test, limit, &node) else {
                continue;
            };
            taken += 1;
            for (lane, lane_t) in lane_t.iter().enumerate() {
                let b = node.lane_box(lane);
                let scalar = ray_box_entry(&test, limit, b.min.to_array(), b.max.to_array());
                assert_eq!(
                    mask & (1 << lane) != 0,
                    scalar.is_some(),
                    "lane {lane} round {round}"
                );
                if let Some(t) = scalar {
                    assert_eq!(t.to_bits(), lane_t.to_bits(), "lane {lane} round {round}");
                }
            }
        }
        taken
    }

    /// The four-lane test, on every ray.
    fn four_lane_test_agrees<const W: usize>() {
        let taken = lanes_agree_with_the_scalar_predicate::<W>(5, |ray, limit, node| {
            Some(ray_lanes(ray, limit, node))
        });
        assert!(taken > 10_000, "only {taken} valid rays");
    }

    #[test]
    fn lane_test_agrees_bit_for_bit_with_the_scalar_predicate() {
        four_lane_test_agrees::<4>();
        four_lane_test_agrees::<8>();
        four_lane_test_agrees::<12>();
        four_lane_test_agrees::<16>();
    }
}
