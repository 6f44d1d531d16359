//! The joins' box lane test sixteen lanes at a time, on processors with
//! AVX-512.
//!
//! A join spends most of its time in box lane tests: each pair of nodes
//! tests both nodes' lanes against the pair's region, then each remaining
//! lane of one against the other's. [`Node::overlap_mask_among`] tests four
//! lanes per instruction (the default x86-64 target assumes SSE2 only), so
//! a node of the default width takes four groups of six compares. With
//! AVX-512 one group of six compares covers all sixteen lanes, their masks
//! joined by ANDs. The joins' traversal is compiled a second time with
//! AVX-512 enabled, and [`avx512_tests_nodes`] chooses it at run time.
//! Measured on the standard scene, self join of 100,000 entries in a probe,
//! alternating builds: about 4.8 → 3.9 ms (see the CHANGELOG for the bench
//! run), with the same pairs in the same order.
//!
//! The test is a compare per face, as the four-lane one, so it agrees with
//! the scalar predicate bit for bit (a unit test holds it to that).
//!
//! Calling a function compiled for AVX-512 is `unsafe`: on a processor
//! without it, it would execute instructions the processor lacks. The
//! crate's calls are in `RTree::drain_self_join` and
//! `RTree::drain_cross_join` (`join.rs`, `cross_join.rs`), made only after
//! [`avx512_tests_nodes`] (the standard library's run-time check) has found
//! AVX-512; this file's unit test makes another the same way.
//!
//! [`Node::overlap_mask_among`]: crate::tree::node::Node::overlap_mask_among

use std::arch::x86_64::{__m512, _CMP_LE_OQ, _mm512_cmp_ps_mask, _mm512_loadu_ps, _mm512_set1_ps};
use std::ops::ControlFlow;

use super::QueryWorkspace;
use super::join::JoinTest;
use crate::tree::RTree;
use crate::tree::node::{Node, QueryCorners};

/// Lanes one AVX-512 test covers.
pub(super) const LANES_PER_AVX512_TEST: usize = 16;

/// Whether nodes `W` wide take the AVX-512 lane tests (the joins' here, the
/// rays' in `ray_avx512.rs`): the width is a multiple of sixteen and the
/// processor has AVX-512 (its foundation instructions). The standard
/// library caches the processor check, so this costs a load and a compare.
#[inline]
pub(super) fn avx512_tests_nodes<const W: usize>() -> bool {
    W.is_multiple_of(LANES_PER_AVX512_TEST) && std::is_x86_feature_detected!("avx512f")
}

/// Lanes `first..first + 16` of a row as one AVX-512 register (for the
/// joins' and the rays' AVX-512 lane tests).
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn sixteen_lanes<const W: usize>(row: &[f32; W], first: usize) -> __m512 {
    let lanes = &row[first..first + LANES_PER_AVX512_TEST];
    // SAFETY: `lanes` holds exactly the sixteen floats the unaligned load
    // reads (the slice above is bounds-checked), and AVX-512, which the
    // load needs, is enabled in this function.
    #[allow(unsafe_code)]
    unsafe {
        _mm512_loadu_ps(lanes.as_ptr())
    }
}

/// [`Node::overlap_mask_among`] sixteen lanes at a time: the `lanes` of
/// `node` whose boxes overlap `query` (closed boxes, S2). `W` must be a
/// multiple of sixteen.
#[target_feature(enable = "avx512f")]
#[inline]
pub(super) fn avx512_lane_masks<const W: usize>(
    node: &Node<W>,
    query: &QueryCorners,
    lanes: u32,
) -> u32 {
    let lo = query.min();
    let hi = query.max();
    let mut mask = 0u32;
    for first in (0..W).step_by(LANES_PER_AVX512_TEST) {
        // Six independent compares, one per face, joined by a tree of ANDs.
        // Each compare could keep only the lanes the previous one kept (a
        // masked compare), but that chains six compare latencies per test,
        // and a join runs a handful of tests per node pair back to back.
        // With the compares independent, the self join of the standard
        // scene took 2.41–2.51 ms against 2.70–2.87 ms chained (alternating
        // builds on an AMD EPYC, Zen 4), with the same pairs: the bits are
        // the conjunction of the same six compares either way.
        let asked = (lanes >> first) as u16;
        if asked == 0 {
            continue;
        }
        let mut faces = [0u16; 6];
        for axis in 0..3 {
            let min = sixteen_lanes(&node.min[axis], first);
            let max = sixteen_lanes(&node.max[axis], first);
            faces[2 * axis] = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(min, _mm512_set1_ps(hi[axis]));
            faces[2 * axis + 1] = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(_mm512_set1_ps(lo[axis]), max);
        }
        let kept = asked & (faces[0] & faces[1]) & (faces[2] & faces[3]) & (faces[4] & faces[5]);
        mask |= (kept as u32) << first;
    }
    mask
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The self join's traversal compiled with AVX-512 enabled, on the
    /// AVX-512 lane test (inlined through the closure, which inherits the
    /// target feature). Call it only where [`avx512_tests_nodes`] is true
    /// (`RTree::drain_self_join` does).
    #[target_feature(enable = "avx512f")]
    pub(super) fn drain_self_join_avx512(
        &self,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        self.drain_self_join_with(test, ws, visit, |node, query, lanes| {
            avx512_lane_masks(node, query, lanes)
        })
    }

    /// The cross join's traversal compiled with AVX-512 enabled, as
    /// [`RTree::drain_self_join_avx512`].
    #[target_feature(enable = "avx512f")]
    pub(super) fn drain_cross_join_avx512(
        &self,
        other: &RTree<K, W>,
        test: JoinTest,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, K) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        self.drain_cross_join_with(other, test, ws, visit, |node, query, lanes| {
            avx512_lane_masks(node, query, lanes)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::node::tests::lane_masks_agree_with_the_scalar_predicate;

    #[test]
    fn avx512_lane_test_agrees_bit_for_bit_with_the_scalar_predicate() {
        let checked = lane_masks_agree_with_the_scalar_predicate::<16>(13, |node, query, lanes| {
            if !avx512_tests_nodes::<16>() {
                return None;
            }
            // SAFETY: `avx512_tests_nodes` found AVX-512 on this processor.
            #[allow(unsafe_code)]
            Some(unsafe { avx512_lane_masks(node, &QueryCorners::of(query), lanes) })
        });
        if std::is_x86_feature_detected!("avx512f") {
            assert!(
                checked > 10_000,
                "only {checked} nodes took the AVX-512 test"
            );
        } else {
            assert_eq!(checked, 0, "no AVX-512, yet the AVX-512 test ran");
        }
    }

    #[test]
    fn narrower_nodes_keep_the_four_lane_test() {
        assert!(!avx512_tests_nodes::<4>());
        assert!(!avx512_tests_nodes::<8>());
        assert_eq!(
            avx512_tests_nodes::<16>(),
            std::is_x86_feature_detected!("avx512f")
        );
    }
}
