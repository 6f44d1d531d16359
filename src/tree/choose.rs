//! Choose-subtree: which child of a node should take a new bound.
//!
//! The child whose box grows least in surface, then in margin, then the
//! smallest: the classic R-tree heuristic, computed four lanes at a time.
//!
//! Surface growth is not taken as `area(grown) - area(lane)`: in `f32` that
//! difference cancels (a lane spanning the standard scene's 2000 × 100 ×
//! 2000 m world has a half area of 4.4·10⁶ m², whose `f32` spacing is
//! 0.5 m², more than a small box may add). Instead, with `e`
//! the lane's extent and `g` how far the bound sticks out of the lane per
//! axis (both `>= 0`), the growth is the sum of the terms that the union
//! adds, `e_x·g_y + g_x·e_y + g_x·g_y` over the three pairs of axes, all
//! non-negative, so its relative error stays a few `f32` ulps whatever the
//! lane's size.

use glam::Vec4;

use super::node::{LANES_PER_TEST, Node, four_lanes};
use crate::geometry::Aabb;

/// Per-lane costs of taking a bound, for lanes `0..W`.
struct GrowthCosts<const W: usize> {
    surface: [f32; W],
    margin: [f32; W],
    area: [f32; W],
}

impl<const W: usize> Node<W> {
    /// The used lane whose box needs the least enlargement to contain
    /// `bound`: least growth of half surface area, then of margin (so flat
    /// and point boxes still order), then the smallest half area, then the
    /// lowest lane.
    ///
    /// Replaced a per-lane loop in `f64` that took about half of the time of
    /// 100,000 single inserts.
    pub(crate) fn least_growth_lane(&self, bound: &Aabb) -> usize {
        debug_assert!(self.len() > 0);
        let costs = self.growth_costs(bound);
        let mut best = 0;
        for lane in 1..self.len() {
            let key = |l: usize| (costs.surface[l], costs.margin[l], costs.area[l]);
            if key(lane) < key(best) {
                best = lane;
            }
        }
        best
    }

    /// What taking `bound` costs each lane (meaningless for unused lanes,
    /// whose inverted boxes give NaN; only `..len` is read).
    #[inline(always)]
    fn growth_costs(&self, bound: &Aabb) -> GrowthCosts<W> {
        let lo = bound.min.to_array().map(Vec4::splat);
        let hi = bound.max.to_array().map(Vec4::splat);
        let mut costs = GrowthCosts {
            surface: [0.0; W],
            margin: [0.0; W],
            area: [0.0; W],
        };
        for first in (0..W).step_by(LANES_PER_TEST) {
            let mut extent = [Vec4::ZERO; 3];
            let mut out = [Vec4::ZERO; 3];
            for axis in 0..3 {
                let lane_lo = four_lanes(&self.min[axis], first);
                let lane_hi = four_lanes(&self.max[axis], first);
                extent[axis] = lane_hi - lane_lo;
                out[axis] =
                    (lane_lo - lo[axis]).max(Vec4::ZERO) + (hi[axis] - lane_hi).max(Vec4::ZERO);
            }
            let [ex, ey, ez] = extent;
            let [gx, gy, gz] = out;
            let surface = ex * gy
                + gx * ey
                + gx * gy
                + (ey * gz + gy * ez + gy * gz)
                + (ez * gx + gz * ex + gz * gx);
            let margin = gx + gy + gz;
            let area = ex * ey + ey * ez + ez * ex;
            let range = first..first + LANES_PER_TEST;
            surface.write_to_slice(&mut costs.surface[range.clone()]);
            margin.write_to_slice(&mut costs.margin[range.clone()]);
            area.write_to_slice(&mut costs.area[range]);
        }
        costs
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::node::LaneSamples;
    use glam::Vec3;

    /// The scalar reference: the same three costs in `f64` from the lane's
    /// box and its union with the bound.
    fn reference(lane: &Aabb, bound: &Aabb) -> (f64, f64, f64) {
        let grown = lane.union(bound);
        (
            grown.half_area() - lane.half_area(),
            grown.margin() - lane.margin(),
            lane.half_area(),
        )
    }

    fn check<const W: usize>(grid: bool, seed: u64) {
        let mut samples = LaneSamples::new(seed, 1000.0);
        for round in 0..2000 {
            let len = 1 + round % W;
            let node: Node<W> = samples.node(grid, len);
            let bound = samples.aabb(grid);
            let chosen = node.least_growth_lane(&bound);
            assert!(chosen < len);
            let costs: Vec<_> = (0..len)
                .map(|lane| reference(&node.lane_box(lane), &bound))
                .collect();
            let least = costs
                .iter()
                .copied()
                .fold(costs[0], |a, b| if b < a { b } else { a });
            if grid {
                // Coordinates on a coarse dyadic grid: every `f32` sum and
                // product is exact, so the choice is exactly the reference's
                // first least lane.
                let first = costs.iter().position(|c| *c == least).unwrap();
                assert_eq!(chosen, first, "round {round}: {costs:?}");
            } else {
                // Otherwise the chosen lane's surface growth is the least up
                // to `f32` rounding of the terms (relative, not cancelling).
                let (surface, _, _) = costs[chosen];
                let tolerance = 1e-5 * least.0.max(1e-30) + 1e-30;
                assert!(
                    surface <= least.0 + tolerance,
                    "round {round}: chose {surface}, least {}",
                    least.0
                );
            }
        }
    }

    #[test]
    fn the_least_growth_lane_matches_the_f64_reference_on_a_dyadic_grid() {
        check::<4>(true, 1);
        check::<8>(true, 2);
        check::<16>(true, 3);
    }

    #[test]
    fn the_least_growth_lane_is_least_up_to_rounding_anywhere() {
        check::<4>(false, 4);
        check::<8>(false, 5);
        check::<16>(false, 6);
    }

    #[test]
    fn the_growth_of_a_huge_lane_by_a_sliver_keeps_its_precision() {
        // A 2,000 m lane whose half area (4.4·10⁶ m²) has an `f32` spacing
        // of 0.5 m²; the bound sticks out by 1 cm, adding 21 m². By
        // subtraction in `f32` that growth would be off by up to 2 %.
        let mut node: Node<4> = Node::empty(1, crate::tree::node::NIL);
        let huge = Aabb::new(Vec3::ZERO, Vec3::new(2000.0, 100.0, 2000.0)).unwrap();
        node.set_lane_box(0, &huge);
        node.len = 1;
        let bound = Aabb::new(
            Vec3::new(1999.5, 10.0, 10.0),
            Vec3::new(2000.01, 11.0, 11.0),
        )
        .unwrap();
        let costs = node.growth_costs(&bound);
        let (surface, margin, area) = reference(&huge, &bound);
        let close = |got: f32, want: f64| ((got as f64 - want) / want).abs() < 1e-5;
        assert!(
            close(costs.surface[0], surface),
            "{} vs {surface}",
            costs.surface[0]
        );
        assert!(
            close(costs.margin[0], margin),
            "{} vs {margin}",
            costs.margin[0]
        );
        assert!(close(costs.area[0], area), "{} vs {area}", costs.area[0]);
    }
}
