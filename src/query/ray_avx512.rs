//! The ray lane test sixteen lanes at a time, on processors with AVX-512.
//!
//! The AVX walk (`ray_avx.rs`) tests a node of the default width in two
//! groups of eight lanes; with AVX-512 one group covers all sixteen. The
//! single-ray walk is compiled a third time with AVX-512 enabled, and
//! `RTree::walk_one` (`ray.rs`) chooses it where [`walk_is_avx512`] allows,
//! before trying AVX. Measured on the standard scene: see the CHANGELOG.
//!
//! The test performs the same operations in the same order as the four-
//! and eight-lane tests, so it agrees with the scalar predicate bit for bit
//! (a unit test holds it to that). It covers rays with no zero direction
//! component; a ray that runs flat along an axis keeps the four-lane walk.
//!
//! Calling a function compiled for AVX-512 is `unsafe` (see
//! `join_avx512.rs`); the crate's call of this walk is in `RTree::walk_one`,
//! made only after [`walk_is_avx512`] has found AVX-512.

use std::arch::x86_64::{
    _CMP_LE_OQ, _mm512_cmp_ps_mask, _mm512_extractf32x4_ps, _mm512_max_ps, _mm512_min_ps,
    _mm512_mul_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_sub_ps,
};
use std::ops::ControlFlow;

use glam::Vec4;

use super::join_avx512::{LANES_PER_AVX512_TEST, avx512_tests_nodes, sixteen_lanes};
use super::ray::near_far_rows;
use crate::geometry::predicates::RayTest;
use crate::tree::node::{LANES_PER_TEST, Node};
use crate::tree::{QueryStats, RTree};

/// Whether the single-ray walk of `ray` through nodes `W` wide runs on the
/// AVX-512 lane test: the processor has AVX-512 (its foundation
/// instructions), the width is a multiple of sixteen and the ray has no
/// zero direction component.
#[inline]
pub(super) fn walk_is_avx512<const W: usize>(ray: &RayTest) -> bool {
    !ray.has_flat_axis && avx512_tests_nodes::<W>()
}

/// [`super::ray::ray_lanes`] for a ray with no zero direction component,
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
        let mut hi = _mm512_set1_ps(limit);
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

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The walk compiled with AVX-512 enabled, on the AVX-512 lane test.
    /// Call it only where [`walk_is_avx512`] is true (`RTree::walk_one`
    /// does).
    #[target_feature(enable = "avx512f")]
    pub(super) fn walk_one_avx512<F>(
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
            |ray, limit, node| avx512_ray_lanes(ray, limit, node),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::query::ray::tests::lanes_agree_with_the_scalar_predicate;

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
