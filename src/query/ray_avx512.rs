//! The ray lane test sixteen lanes at a time, on processors with AVX-512,
//! and the placing of a node's hit children on the walk's stack by rank.
//!
//! The AVX walk (`ray_avx.rs`) tests a node of the default width in two
//! groups of eight lanes; with AVX-512 one group covers all sixteen. The
//! single-ray walk is compiled with AVX-512 enabled twice, once with the
//! insertion sort that orders a node's hit children and once with
//! [`push_far_to_near_ranked`], which places them in the same order without
//! a branch per comparison; `RTree::walk_one` (`ray.rs`) chooses this walk
//! where [`walk_is_avx512`] allows, before trying AVX, and the copy by
//! whether the ray starts where the last walked ray started (see
//! `RayWalkScratch`). Measured on the standard scene: see the CHANGELOG.
//!
//! The lane test performs the same operations in the same order as the
//! four- and eight-lane tests, so it agrees with the scalar predicate bit
//! for bit (a unit test holds it to that), and a second test holds the
//! ranked placing to the insertion sort's order. The walk covers rays with
//! no zero direction component; a ray that runs flat along an axis keeps
//! the four-lane walk.
//!
//! Calling a function compiled for AVX-512 is `unsafe` (see
//! `join_avx512.rs`); the crate's calls of these walks are in
//! `RTree::walk_one` and, for two rays from one point, in `ray_batch.rs`'s
//! `pair_from`, each made only after [`walk_is_avx512`] has found AVX-512
//! and `popcnt` for its rays.

use std::arch::x86_64::{
    _CMP_EQ_OQ, _CMP_GT_OQ, _CMP_LE_OQ, _mm512_cmp_ps_mask, _mm512_extractf32x4_ps,
    _mm512_mask_cmp_ps_mask, _mm512_max_ps, _mm512_min_ps, _mm512_mul_ps, _mm512_set1_ps,
    _mm512_setzero_ps, _mm512_sub_ps,
};
use std::ops::ControlFlow;

use glam::Vec4;

use super::join_avx512::{LANES_PER_AVX512_TEST, avx512_tests_nodes, sixteen_lanes};
use super::ray_lanes::near_far_rows;
use crate::geometry::predicates::{RayTest, finite_limit};
use crate::tree::node::{LANES_PER_TEST, Node};
use crate::tree::{QueryStats, RTree};

/// Whether the single-ray walk of `ray` through nodes `W` wide runs on the
/// AVX-512 lane test: the processor has AVX-512 (its foundation
/// instructions) and `popcnt` (every processor with AVX-512 has it), the
/// width is a multiple of sixteen and the ray has no zero direction
/// component.
#[inline]
pub(super) fn walk_is_avx512<const W: usize>(ray: &RayTest) -> bool {
    !ray.has_flat_axis && avx512_tests_nodes::<W>() && std::is_x86_feature_detected!("popcnt")
}

/// [`super::ray_lanes::ray_lanes`] for a ray with no zero direction component,
/// sixteen lanes at a time. `W` must be a multiple of sixteen.
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn avx512_ray_lanes<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    let rows = near_far_rows(ray, node);
    let mut entry = [0.0f32; W];
    let mut mask = 0u32;
    for first in (0..W).step_by(LANES_PER_AVX512_TEST) {
        let mut lo = _mm512_setzero_ps();
        let mut hi = _mm512_set1_ps(finite_limit(limit));
        for (axis, &(near, far)) in rows.iter().enumerate() {
            let origin = _mm512_set1_ps(ray.origin[axis]);
            let inv = _mm512_set1_ps(ray.inv[axis]);
            let t0 = _mm512_mul_ps(_mm512_sub_ps(sixteen_lanes(near, first), origin), inv);
            let t1 = _mm512_mul_ps(_mm512_sub_ps(sixteen_lanes(far, first), origin), inv);
            // `vmaxps t0, lo` is `t0 > lo ? t0 : lo`, as `maxps` is (see
            // `greater_or_keep`): a NaN `t` keeps the bound.
            lo = _mm512_max_ps(t0, lo);
            hi = _mm512_min_ps(t1, hi);
        }
        mask |= (_mm512_cmp_ps_mask::<_CMP_LE_OQ>(lo, hi) as u32) << first;
        // Four safe stores rather than one through a pointer: the entry
        // `t`s are read only for the lanes that hit.
        let quarters = [
            _mm512_extractf32x4_ps::<0>(lo),
            _mm512_extractf32x4_ps::<1>(lo),
            _mm512_extractf32x4_ps::<2>(lo),
            _mm512_extractf32x4_ps::<3>(lo),
        ];
        for (k, quarter) in quarters.into_iter().enumerate() {
            let at = first + k * LANES_PER_TEST;
            Vec4::from(quarter).write_to_slice(&mut entry[at..at + LANES_PER_TEST]);
        }
    }
    (mask, entry)
}

/// [`super::ray::push_far_to_near`] without the insertion sort's branches
/// (see `RayWalkScratch` in `ray.rs` for when the walk uses it): the same
/// children in the same order. One child is pushed as it is and two are
/// swapped by a select; from three on, each child goes straight to its
/// slot, counted sixteen lanes at a time as the hit children that go below
/// it: those that are farther, and those as far that were pushed before
/// it (the sort is stable).
///
/// Unlike the lane test, this function is not compiled with AVX-512
/// enabled: `#[inline(always)]` is refused with `#[target_feature]`, and
/// the compiler kept it out of line, a call per internal node that also
/// spilled the walk's vector registers. Forced inline into the AVX-512
/// walk, whose features its intrinsics then use: 1,000 incoherent rays
/// 0.322–0.330 → 0.313–0.320 ms in a probe (eight batches in turn,
/// alternating builds).
///
/// # Safety
///
/// The processor must have AVX-512 (its foundation instructions) and
/// `popcnt`, as for a function compiled with them enabled. (`W` must be a
/// multiple of sixteen too; another width panics, as a slice out of range
/// does, and reads nothing it should not.)
#[inline(always)]
#[allow(unsafe_code)]
pub(super) unsafe fn push_far_to_near_ranked<const W: usize>(
    stack: &mut Vec<(u32, f32)>,
    node: &Node<W>,
    mask: u32,
    lane_t: &[f32; W],
) {
    let count = mask.count_ones() as usize;
    if count <= 1 {
        if mask != 0 {
            let lane = mask.trailing_zeros() as usize;
            stack.push((node.child[lane], lane_t[lane]));
        }
        return;
    }
    if count == 2 {
        let first = mask.trailing_zeros() as usize;
        let second = (mask & (mask - 1)).trailing_zeros() as usize;
        let pushed_first = (node.child[first], lane_t[first]);
        let pushed_second = (node.child[second], lane_t[second]);
        // The farther goes below; on a tie, the one pushed first.
        let swap = pushed_first.1 < pushed_second.1;
        stack.push(if swap { pushed_second } else { pushed_first });
        stack.push(if swap { pushed_first } else { pushed_second });
        return;
    }
    let base = stack.len();
    stack.resize(base + count, (0, 0.0));
    let slots = &mut stack[base..];
    let mut hits = mask;
    while hits != 0 {
        let lane = hits.trailing_zeros() as usize;
        hits &= hits - 1;
        // A NaN would compare neither farther nor as far, and two children
        // would share a slot; the lane tests never report one as a hit
        // (their entry `t` starts at 0 and `max` keeps it on a NaN).
        debug_assert!(!lane_t[lane].is_nan(), "a hit lane with a NaN entry t");
        // SAFETY (this block and the next): the caller guarantees
        // AVX-512, which these intrinsics (and `sixteen_lanes`) need.
        #[allow(unsafe_code)]
        let t = unsafe { _mm512_set1_ps(lane_t[lane]) };
        let pushed_before = (1u32 << lane) - 1;
        let mut below = 0;
        for first in (0..W).step_by(LANES_PER_AVX512_TEST) {
            let hit = (mask >> first) as u16;
            let before = hit & (pushed_before >> first) as u16;
            #[allow(unsafe_code)]
            let (farther, tied) = unsafe {
                let row = sixteen_lanes(lane_t, first);
                (
                    _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(hit, row, t),
                    _mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(before, row, t),
                )
            };
            below += (farther | tied).count_ones() as usize;
        }
        slots[below] = (node.child[lane], lane_t[lane]);
    }
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The walk compiled with AVX-512 enabled, on the AVX-512 lane test.
    /// Call it only where [`walk_is_avx512`] is true (`RTree::walk_one`
    /// does).
    /// With `ranked`, a node's hit children are placed by
    /// [`push_far_to_near_ranked`], otherwise by the insertion sort.
    #[target_feature(enable = "avx512f,popcnt")]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn walk_one_avx512<F>(
        &self,
        start: u32,
        test: &RayTest,
        limit: f32,
        stack: &mut Vec<(u32, f32)>,
        stats: &mut QueryStats,
        visit: F,
        ranked: bool,
    ) -> f32
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
    {
        let lanes = |ray: &RayTest, limit, node: &Node<W>| avx512_ray_lanes(ray, limit, node);
        // Two copies of the walk, each with its ordering compiled in: one
        // walk choosing the ordering at every node measured 2–3 % slower in
        // a probe (within its noise, but on both kinds of rays).
        if ranked {
            self.walk_with(
                start,
                test,
                limit,
                stack,
                stats,
                visit,
                lanes,
                // SAFETY: this walk runs only where the processor has
                // AVX-512 and `popcnt` (its own requirement).
                #[allow(unsafe_code)]
                |stack, node, mask, t| unsafe { push_far_to_near_ranked(stack, node, mask, t) },
            )
        } else {
            self.walk_with(
                start,
                test,
                limit,
                stack,
                stats,
                visit,
                lanes,
                super::ray::push_far_to_near::<W>,
            )
        }
    }

    /// Two rays' walks in lock step ([`RTree::walk_pair_with`]) compiled
    /// with AVX-512 enabled, on the AVX-512 lane test, their children
    /// ordered by the insertion sort (the pair's rays start at one point,
    /// whose rays keep the sort, see [`RayWalkScratch`]). Call it only
    /// where [`walk_is_avx512`] is true for both rays.
    ///
    /// [`RayWalkScratch`]: super::ray::RayWalkScratch
    #[target_feature(enable = "avx512f,popcnt")]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn walk_pair_avx512<FA, FB>(
        &self,
        start: u32,
        tests: [&RayTest; 2],
        limits: [f32; 2],
        stacks: [&mut Vec<(u32, f32)>; 2],
        stats: &mut QueryStats,
        visits: (FA, FB),
    ) -> [f32; 2]
    where
        FA: FnMut(u32, f32) -> ControlFlow<(), f32>,
        FB: FnMut(u32, f32) -> ControlFlow<(), f32>,
    {
        self.walk_pair_with(
            start,
            tests,
            limits,
            stacks,
            stats,
            visits,
            |ray: &RayTest, limit, node: &Node<W>| avx512_ray_lanes(ray, limit, node),
            super::ray::push_far_to_near::<W>,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::query::ray_lanes::tests::lanes_agree_with_the_scalar_predicate;

    #[test]
    fn avx512_lane_test_agrees_bit_for_bit_with_the_scalar_predicate() {
        let checked = lanes_agree_with_the_scalar_predicate::<16>(17, |ray, limit, node| {
            if !walk_is_avx512::<16>(ray) {
                return None;
            }
            // SAFETY: `walk_is_avx512` found AVX-512 on this processor.
            #[allow(unsafe_code)]
            Some(unsafe { avx512_ray_lanes(ray, limit, node) })
        });
        if std::is_x86_feature_detected!("avx512f") {
            assert!(checked > 5_000, "only {checked} rays took the AVX-512 test");
        } else {
            assert_eq!(checked, 0, "no AVX-512, yet the AVX-512 test ran");
        }
    }

    /// Pushes the children of `mask` with both orderings, onto a stack that
    /// already holds an item, for `cases` random masks and entry `t`s drawn
    /// from few values (so that ties are common); returns the cases run.
    fn ranked_push_agrees_with_the_insertion_sort<const W: usize>(
        seed: u64,
        cases: usize,
    ) -> usize {
        if !(avx512_tests_nodes::<W>() && std::is_x86_feature_detected!("popcnt")) {
            return 0;
        }
        let mut node = Node::<W>::empty(1, crate::tree::node::NIL);
        for (lane, child) in node.child.iter_mut().enumerate() {
            *child = 100 + lane as u32;
        }
        node.len = W as u16;
        let mut state = seed;
        let mut next = move || {
            // xorshift64: enough to spread masks and ties.
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        // Signed zeros and infinity too: an entry `t` can be either zero,
        // and infinite on a long ray through huge coordinates.
        let values = [
            0.0f32,
            -0.0,
            0.5,
            1.0,
            1.0 + f32::EPSILON,
            7.25,
            1e30,
            f32::INFINITY,
        ];
        // Cases seen with 0, 1, 2 and 3 or more children: each path of the
        // ranked push must have run.
        let mut seen = [0usize; 4];
        for case in 0..cases {
            // Every third mask keeps about one lane in eight, so that
            // one, two and three children are common too.
            let sparse = if case % 3 == 0 {
                next() & next() & next()
            } else {
                u64::MAX
            };
            let mask = (next() & sparse) as u32 & node.used_lanes();
            seen[(mask.count_ones() as usize).min(3)] += 1;
            let lane_t: [f32; W] =
                std::array::from_fn(|_| values[(next() % values.len() as u64) as usize]);
            let mut sorted = vec![(7u32, 9.0f32)];
            crate::query::ray::push_far_to_near(&mut sorted, &node, mask, &lane_t);
            let mut ranked = vec![(7u32, 9.0f32)];
            // SAFETY: checked above that this processor has AVX-512 and popcnt.
            #[allow(unsafe_code)]
            unsafe {
                push_far_to_near_ranked(&mut ranked, &node, mask, &lane_t)
            };
            let bits =
                |v: &[(u32, f32)]| v.iter().map(|&(c, t)| (c, t.to_bits())).collect::<Vec<_>>();
            assert_eq!(bits(&ranked), bits(&sorted), "mask {mask:#x}, t {lane_t:?}");
        }
        assert!(seen.iter().all(|&n| n > 0), "child counts seen: {seen:?}");
        cases
    }

    #[test]
    fn ranked_push_orders_children_as_the_insertion_sort_does() {
        let checked =
            ranked_push_agrees_with_the_insertion_sort::<16>(0x9E37_79B9_7F4A_7C15, 20_000)
                + ranked_push_agrees_with_the_insertion_sort::<32>(0xD1B5_4A32_D192_ED03, 5_000);
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("popcnt") {
            assert_eq!(checked, 25_000);
        } else {
            assert_eq!(checked, 0, "no AVX-512, yet the ranked push ran");
        }
    }

    /// What one ray's walk did: the hits it reported, in order, and the
    /// limit it ended with.
    type Walked = (Vec<(u32, u32)>, u32);

    /// A visitor that records each hit and answers as `mode` does: 0 keeps
    /// the first hit (the smallest `t`), 1 takes every hit, 2 stops at the
    /// first.
    fn recorder(
        mode: u8,
        hits: &mut Vec<(u32, u32)>,
    ) -> impl FnMut(u32, f32) -> ControlFlow<(), f32> + '_ {
        let mut best = f32::INFINITY;
        move |proxy, t| {
            hits.push((proxy, t.to_bits()));
            best = best.min(t);
            match mode {
                0 => ControlFlow::Continue(best),
                1 => ControlFlow::Continue(f32::INFINITY),
                _ => ControlFlow::Break(()),
            }
        }
    }

    /// Two rays walked in lock step report, each in its own order, the
    /// hits of their own walks alone, end with the same limits and count
    /// the same nodes and entries: on a town of 20,000 entities, pairs of
    /// rays from one eye and from scattered origins, for first, all and any
    /// hit.
    #[test]
    fn rays_in_lockstep_walk_as_each_walks_alone() {
        let mut scene = crate::scene::TownScene::new(20_000, 11);
        let (tree, _) = scene.bulk_loaded_tree();
        let mut rays = scene.coherent_rays_from(scene.clear_eye());
        rays.truncate(400);
        rays.extend(scene.incoherent_rays(400));
        let (mut stack, mut partner) = (Vec::new(), Vec::new());
        let mut checked = 0;
        for (pair, mode) in rays.chunks_exact(2).zip((0..3u8).cycle()) {
            let tests = [0, 1].map(|k| RayTest::new(&pair[k].canonicalized().unwrap()));
            if !tests.iter().all(walk_is_avx512::<16>) {
                continue;
            }
            let max_t = [pair[0].max_t, pair[1].max_t];
            let mut alone_stats = QueryStats::default();
            let alone: [Walked; 2] = [0, 1].map(|k| {
                let mut hits = Vec::new();
                // SAFETY: `walk_is_avx512` found AVX-512 and `popcnt`.
                #[allow(unsafe_code)]
                let limit = unsafe {
                    tree.walk_one_avx512(
                        tree.root(),
                        &tests[k],
                        max_t[k],
                        &mut stack,
                        &mut alone_stats,
                        recorder(mode, &mut hits),
                        false,
                    )
                };
                (hits, limit.to_bits())
            });
            let (mut hits_a, mut hits_b) = (Vec::new(), Vec::new());
            let mut together_stats = QueryStats::default();
            // SAFETY: as above, for both rays.
            #[allow(unsafe_code)]
            let limits = unsafe {
                tree.walk_pair_avx512(
                    tree.root(),
                    [&tests[0], &tests[1]],
                    max_t,
                    [&mut stack, &mut partner],
                    &mut together_stats,
                    (recorder(mode, &mut hits_a), recorder(mode, &mut hits_b)),
                )
            };
            let together: [Walked; 2] =
                [(hits_a, limits[0].to_bits()), (hits_b, limits[1].to_bits())];
            assert_eq!(together, alone, "rays {pair:?}, mode {mode}");
            assert_eq!(together_stats, alone_stats, "rays {pair:?}, mode {mode}");
            checked += 1;
        }
        if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("popcnt") {
            assert!(checked > 300, "only {checked} pairs walked");
        } else {
            assert_eq!(checked, 0, "no AVX-512, yet the AVX-512 walk ran");
        }
    }

    #[test]
    fn narrower_nodes_and_flat_rays_keep_the_other_walks() {
        let slanted = RayTest::new(&Ray::new(glam::Vec3::ZERO, glam::Vec3::ONE, 1.0).unwrap());
        let flat = RayTest::new(&Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 1.0).unwrap());
        assert!(!walk_is_avx512::<8>(&slanted));
        assert!(!walk_is_avx512::<16>(&flat));
        assert_eq!(
            walk_is_avx512::<16>(&slanted),
            std::is_x86_feature_detected!("avx512f")
        );
    }
}
