//! Traversals over the tree, one file per query family, and the brute-force
//! oracle every answer is checked against.
//!
//! Each family has one visitor-style core (`visit_*`) that reports entries to
//! a closure able to stop the traversal, plus a few conveniences built on it.
//! Traversal state lives in a reusable [`QueryWorkspace`], so queries run
//! every frame do not allocate.

mod cross_join;
mod frustum;
mod frustum_levels;
mod frustum_proof;
mod join;
#[cfg(target_arch = "x86_64")]
mod join_avx512;
mod nearest;
pub mod oracle;
mod overlap;
#[cfg(feature = "parallel")]
mod parallel;
#[cfg(feature = "parallel")]
mod parallel_claim;
#[cfg(feature = "parallel")]
mod parallel_workspace;
mod ray;
#[cfg(target_arch = "x86_64")]
mod ray_avx;
#[cfg(target_arch = "x86_64")]
mod ray_avx512;
mod ray_batch;
mod ray_lanes;
mod ray_origin;
#[cfg(test)]
mod ray_pair_tests;
mod ray_results;
mod sphere;
mod workspace;

pub use frustum::{CullMode, FRUSTUMS_PER_PASS};
pub use join::JoinMode;
pub use nearest::Neighbor;
#[cfg(feature = "parallel")]
pub use parallel::ParallelWorkspace;
pub use ray::{RayHit, RayMode};
pub use ray_results::RayResults;
pub use workspace::QueryWorkspace;

/// Orders the children a node just pushed onto a depth-first stack by
/// their distance `D` (a ray's entry `t`, a point's squared distance),
/// farthest first, so that the nearest is popped next. Children are few,
/// so an insertion sort, in place and stable: equal distances keep the
/// order they were pushed in.
#[inline(always)]
pub(crate) fn sort_far_to_near<D: PartialOrd + Copy>(pushed: &mut [(u32, D)]) {
    // Each new child shifts the nearer ones already placed one slot
    // towards the top.
    for next in 1..pushed.len() {
        let item = pushed[next];
        let mut slot = next;
        while slot > 0 && pushed[slot - 1].1 < item.1 {
            pushed[slot] = pushed[slot - 1];
            slot -= 1;
        }
        pushed[slot] = item;
    }
}
