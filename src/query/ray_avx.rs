//! The ray lane test eight lanes at a time, on processors with AVX.
//!
//! The default x86-64 target assumes SSE2 only, so [`ray_lanes`] tests four
//! lanes per instruction. Nearly every x86-64 processor a game runs on has
//! AVX, which tests eight: the single-ray walk is compiled a second time
//! with AVX enabled, and [`walk_is_avx`] chooses it at run time. Measured
//! on the standard scene, one `cast_ray` per ray, alternating builds in a
//! probe: 1,000 incoherent rays 0.442–0.452 → 0.396–0.421 ms, 1,000
//! coherent rays from the clear eye 0.220–0.221 → 0.195–0.199 ms, with the
//! same answers bit for bit.
//!
//! The test performs the same operations in the same order as
//! [`ray_lanes`], so it agrees with the scalar predicate bit for bit (a unit
//! test holds it to that). It covers rays with no zero direction component;
//! a ray that runs flat along an axis keeps the four-lane walk.
//!
//! Calling a function compiled for AVX is `unsafe`: on a processor without
//! AVX it would execute instructions the processor lacks. The crate's one
//! such call is in `RTree::walk_one` (`ray.rs`), made only after
//! [`walk_is_avx`] (the standard library's run-time check) has found AVX;
//! this file's unit test makes another the same way.
//!
//! [`ray_lanes`]: super::ray_lanes::ray_lanes

use std::arch::x86_64::{
    __m256, _CMP_LE_OQ, _mm256_castps256_ps128, _mm256_cmp_ps, _mm256_extractf128_ps,
    _mm256_max_ps, _mm256_min_ps, _mm256_movemask_ps, _mm256_mul_ps, _mm256_set_m128,
    _mm256_set1_ps, _mm256_setzero_ps, _mm256_sub_ps,
};

use std::ops::ControlFlow;

use glam::Vec4;

use super::ray_lanes::near_far_rows;
use crate::geometry::predicates::{RayTest, finite_limit};
use crate::tree::node::{LANES_PER_TEST, Node, four_lanes};
use crate::tree::{QueryStats, RTree};

/// Lanes one AVX test covers.
const LANES_PER_AVX_TEST: usize = 2 * LANES_PER_TEST;

/// Whether the single-ray walk of `ray` through nodes `W` wide runs on the
/// AVX lane test: the processor has AVX, the width is a multiple of eight
/// and the ray has no zero direction component. The standard library
/// caches the processor check, so this costs a load and a few compares.
#[inline]
pub(super) fn walk_is_avx<const W: usize>(ray: &RayTest) -> bool {
    W.is_multiple_of(LANES_PER_AVX_TEST)
        && !ray.has_flat_axis
        && std::is_x86_feature_detected!("avx")
}

/// Lanes `first..first + 8` of a row as one AVX register.
#[target_feature(enable = "avx")]
#[inline]
fn eight_lanes<const W: usize>(row: &[f32; W], first: usize) -> __m256 {
    let low = four_lanes(row, first).into();
    let high = four_lanes(row, first + LANES_PER_TEST).into();
    _mm256_set_m128(high, low)
}

/// [`super::ray_lanes::ray_lanes`] for a ray with no zero direction component,
/// eight lanes at a time. `W` must be a multiple of eight.
#[target_feature(enable = "avx")]
#[inline]
pub(super) fn avx_ray_lanes<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    let rows = near_far_rows(ray, node);
    let mut entry = [0.0f32; W];
    let mut mask = 0u32;
    for first in (0..W).step_by(LANES_PER_AVX_TEST) {
        let mut lo = _mm256_setzero_ps();
        let mut hi = _mm256_set1_ps(finite_limit(limit));
        for (axis, &(near, far)) in rows.iter().enumerate() {
            let origin = _mm256_set1_ps(ray.origin[axis]);
            let inv = _mm256_set1_ps(ray.inv[axis]);
            let t0 = _mm256_mul_ps(_mm256_sub_ps(eight_lanes(near, first), origin), inv);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(eight_lanes(far, first), origin), inv);
            // `vmaxps t0, lo` is `t0 > lo ? t0 : lo`, as `maxps` is (see
            // `greater_or_keep`): a NaN `t` keeps the bound.
            lo = _mm256_max_ps(t0, lo);
            hi = _mm256_min_ps(t1, hi);
        }
        let hit = _mm256_cmp_ps::<_CMP_LE_OQ>(lo, hi);
        mask |= (_mm256_movemask_ps(hit) as u32) << first;
        Vec4::from(_mm256_castps256_ps128(lo))
            .write_to_slice(&mut entry[first..first + LANES_PER_TEST]);
        Vec4::from(_mm256_extractf128_ps::<1>(lo))
            .write_to_slice(&mut entry[first + LANES_PER_TEST..first + LANES_PER_AVX_TEST]);
    }
    (mask, entry)
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The walk compiled with AVX enabled: the lane test inlined into it
    /// (through the closure, which inherits the target feature) tests
    /// eight lanes per instruction.
    /// Call it only where [`walk_is_avx`] is true (`RTree::walk_one` does).
    #[target_feature(enable = "avx")]
    pub(super) fn walk_one_avx<F>(
        &self,
        start: u32,
        test: &RayTest,
        limit: f32,
        stack: &mut Vec<(u32, f32)>,
        stats: &mut QueryStats,
        visit: F,
    ) -> f32
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
    {
        self.walk_with(
            start,
            test,
            limit,
            stack,
            stats,
            visit,
            |ray, limit, node| avx_ray_lanes(ray, limit, node),
            super::ray::push_far_to_near::<W>,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::query::ray_lanes::tests::lanes_agree_with_the_scalar_predicate;

    /// The AVX lane test on the rays `walk_is_avx` gives it.
    fn avx_lanes_agree_with_the_scalar_predicate<const W: usize>() -> usize {
        lanes_agree_with_the_scalar_predicate::<W>(7, |ray, limit, node| {
            if !walk_is_avx::<W>(ray) {
                return None;
            }
            // SAFETY: `walk_is_avx` found AVX on this processor.
            #[allow(unsafe_code)]
            Some(unsafe { avx_ray_lanes(ray, limit, node) })
        })
    }

    #[test]
    fn avx_lane_test_agrees_bit_for_bit_with_the_scalar_predicate() {
        let checked = avx_lanes_agree_with_the_scalar_predicate::<8>()
            + avx_lanes_agree_with_the_scalar_predicate::<16>();
        if std::is_x86_feature_detected!("avx") {
            assert!(checked > 10_000, "only {checked} rays took the AVX test");
        } else {
            assert_eq!(checked, 0, "no AVX, yet the AVX test ran");
        }
    }

    /// The whole AVX walk against the four-lane walk on the same trees
    /// and rays: the same hits in the same order with the same `t` bits,
    /// the same final limit and the same nodes visited, from an empty
    /// tree to one of several levels, every hit and first hit.
    fn avx_walk_agrees<const W: usize>(seed: u64) -> usize {
        use crate::query::ray_pair_tests::{Walked, alone, random_tree, recorder};
        use crate::scene::SceneRng;
        use glam::Vec3;
        let mut rng = SceneRng::new(seed);
        let mut walked = 0;
        for entries in [0u32, 1, 3, 17, 2_000] {
            let world = Vec3::new(100.0, 20.0, 100.0);
            let tree = random_tree::<W>(&mut rng, entries, world, (0.0, 6.0));
            for round in 0..300 {
                let origin = Vec3::new(
                    rng.range(-10.0, 110.0),
                    rng.range(-5.0, 25.0),
                    rng.range(-10.0, 110.0),
                );
                // Tiny directions too: `t` then runs to huge values.
                let scale = [1.0, 1e-30, 40.0][round % 3];
                let max_t = [f32::INFINITY, rng.range(1.0, 120.0)][round % 2];
                let Ok(ray) = Ray::new(origin, rng.direction() * scale, max_t) else {
                    continue;
                };
                let test = RayTest::new(&ray);
                if !walk_is_avx::<W>(&test) {
                    continue;
                }
                for first in [false, true] {
                    let scalar = alone(&tree, &test, ray.max_t, first);
                    let (mut hits, mut stack, mut stats) =
                        (Vec::new(), Vec::new(), QueryStats::default());
                    let visit = recorder(&mut hits, ray.max_t, first);
                    // SAFETY: `walk_is_avx` found AVX on this processor.
                    #[allow(unsafe_code)]
                    let end = unsafe {
                        tree.walk_one_avx(
                            tree.root(),
                            &test,
                            ray.max_t,
                            &mut stack,
                            &mut stats,
                            visit,
                        )
                    };
                    let avx: Walked = (hits, end, stats.nodes_visited);
                    let bits = |w: &Walked| {
                        let hits: Vec<(u32, u32)> =
                            w.0.iter().map(|&(p, t)| (p, t.to_bits())).collect();
                        (hits, w.1.to_bits(), w.2)
                    };
                    assert_eq!(bits(&avx), bits(&scalar), "{entries} entries, ray {round}");
                    walked += 1;
                }
            }
        }
        walked
    }

    #[test]
    fn the_avx_walk_agrees_bit_for_bit_with_the_four_lane_walk() {
        let walked = avx_walk_agrees::<8>(11) + avx_walk_agrees::<16>(12);
        if std::is_x86_feature_detected!("avx") {
            assert!(walked > 2_000, "only {walked} walks took the AVX path");
        } else {
            assert_eq!(walked, 0, "no AVX, yet the AVX walk ran");
        }
    }

    #[test]
    fn width_four_and_flat_rays_keep_the_four_lane_walk() {
        let slanted = RayTest::new(&Ray::new(glam::Vec3::ZERO, glam::Vec3::ONE, 1.0).unwrap());
        let flat = RayTest::new(&Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 1.0).unwrap());
        assert!(!walk_is_avx::<4>(&slanted));
        assert!(!walk_is_avx::<16>(&flat));
        assert_eq!(
            walk_is_avx::<16>(&slanted),
            std::is_x86_feature_detected!("avx")
        );
    }
}
