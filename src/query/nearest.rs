//! Nearest neighbours: the `k` entries closest to a point, optionally no
//! further than a maximum distance.
//!
//! The distance from a point to an entry is the Euclidean distance to the
//! entry's closed exact box (`0` inside or on it), decided by its square in
//! `f64`. The search is depth first, each node's two nearest children
//! first (by the squared distance to their bound), so the first leaves
//! reached are near the point and the limit (the current `k`-th best)
//! shrinks early; a node whose bound is strictly further than the limit is
//! skipped. Nodes at exactly that distance are still visited, because they
//! may hold an entry at the same distance with a smaller key.
//!
//! Each node's lanes are first tested, four at a time, against the cube
//! that holds every box within the limit (`predicates::sphere_reach`); only
//! the lanes in it take the exact `f64` test. Measured on the standard
//! scene (`cargo bench --bench proximity`), 1,000 queries for the 8
//! nearest: 2.81 ms with the earlier best-first search, whose priority
//! queue took a push for every child within the limit, and 2.21 ms with
//! this depth-first walk, although it visits more nodes (14.9 against
//! about 13 per query); 1.38 ms since the changes described at
//! [`nearest_on_top`] and [`SORTED_UP_TO`].

use std::cmp::Ordering;
use std::ops::ControlFlow;

use glam::Vec3;

use super::QueryWorkspace;
use crate::geometry::predicates::{
    check_point, check_radius_sq, point_box_distance_sq, sphere_reach,
};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::RTree;

/// An entry and its distance from a query point.
///
/// `distance_sq` is the squared Euclidean distance from the point to the
/// entry's closed exact box, computed in `f64` from the `f32` inputs: `0` when
/// the point is inside or on the box. Lists of neighbours are sorted by
/// `(distance_sq, key)`: ties are broken by key only where `distance_sq` ties.
/// Two squared distances that differ can round to the same
/// [`Neighbor::distance`] (its square root, rounded); the nearer by
/// `distance_sq` comes first then, whatever the keys.
///
/// ```
/// use bevy_rtree::Neighbor;
///
/// let n = Neighbor { key: 3u32, distance_sq: 25.0 };
/// assert_eq!(n.distance(), 5.0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbor<K> {
    /// The entry.
    pub key: K,
    /// Squared distance from the query point to the entry's box.
    pub distance_sq: f64,
}

impl<K> Neighbor<K> {
    /// The Euclidean distance, `sqrt(distance_sq)`.
    ///
    /// ```
    /// use bevy_rtree::Neighbor;
    ///
    /// assert_eq!(Neighbor { key: 'a', distance_sq: 2.25 }.distance(), 1.5);
    /// ```
    #[inline]
    pub fn distance(&self) -> f64 {
        self.distance_sq.sqrt()
    }
}

impl<K: Ord> Neighbor<K> {
    /// The order of every neighbour list: `(distance_sq, key)`.
    #[inline]
    pub(crate) fn rank(&self, other: &Self) -> Ordering {
        self.distance_sq
            .total_cmp(&other.distance_sq)
            .then_with(|| self.key.cmp(&other.key))
    }
}

/// The box holding every box whose squared distance from `point` is at
/// most `limit_sq` by the `f64` predicate: the sphere reach of a radius
/// just above `sqrt(limit_sq)` (infinite for an infinite limit).
fn reach_cube(point: Vec3, limit_sq: f64) -> Aabb {
    // `as f32` may round down and `sqrt` is rounded: one step up makes the
    // radius's exact square at least `limit_sq`.
    let radius = (limit_sq.sqrt() as f32).next_up();
    sphere_reach(point, radius)
}

/// Up to this many neighbours a query keeps them in a list in rank order
/// ([`insert_ranked`]), beyond it in a heap. For the 8 nearest on the
/// standard scene the heap's `sift_down` and the final sort were a quarter
/// of the profile; with the list, 1,000 queries took 1.52 → 1.38 ms warm
/// (criterion) and 0.28 → 0.27 × rstar's time cold (paired blocks).
const SORTED_UP_TO: usize = 16;

/// Adds `candidate` to `best`, the best `k` so far in rank order, where it
/// ranks among them: the last drops out when `best` is full, and nothing
/// changes when the candidate ranks after all `k`.
#[inline]
fn insert_ranked<K: Ord>(best: &mut Vec<Neighbor<K>>, k: usize, candidate: Neighbor<K>) {
    if best.len() == k {
        match best.last() {
            Some(last) if candidate.rank(last) == Ordering::Less => {
                best.pop();
            }
            _ => return,
        }
    }
    let mut at = best.len();
    while at > 0 && candidate.rank(&best[at - 1]) == Ordering::Less {
        at -= 1;
    }
    best.insert(at, candidate);
}

/// Restores the max-heap order (by [`Neighbor::rank`]) after a push at `i`.
fn sift_up<K: Ord>(heap: &mut [Neighbor<K>], mut i: usize) {
    while i > 0 {
        let parent = (i - 1) / 2;
        if heap[parent].rank(&heap[i]) != Ordering::Less {
            break;
        }
        heap.swap(parent, i);
        i = parent;
    }
}

/// Moves the nearest two of the children a node just pushed to the top of
/// the stack, nearest on top, to be walked first; the others follow in no
/// particular order. (A full sort of up to sixteen children, far to near, was a
/// third of a query's time warm, in mispredicted branches: the standard
/// scene's 1,000 queries of the 8 nearest 1.71 → 1.58 ms warm and 3–5 %
/// faster cold without it, for 15.5 nodes visited a query instead of
/// 14.9. The order changes the work, never the answer.)
#[inline(always)]
fn nearest_on_top(pushed: &mut [(u32, f64)]) {
    let Some(last) = pushed.len().checked_sub(1) else {
        return;
    };
    let mut nearest = 0;
    for (i, item) in pushed.iter().enumerate().skip(1) {
        if item.1 < pushed[nearest].1 {
            nearest = i;
        }
    }
    pushed.swap(nearest, last);
    if last < 2 {
        return;
    }
    let mut second = 0;
    for (i, item) in pushed[..last].iter().enumerate().skip(1) {
        if item.1 < pushed[second].1 {
            second = i;
        }
    }
    pushed.swap(second, last - 1);
}

/// Restores the max-heap order after the top was replaced.
fn sift_down<K: Ord>(heap: &mut [Neighbor<K>]) {
    let mut i = 0;
    loop {
        let mut largest = i;
        for child in [2 * i + 1, 2 * i + 2] {
            if child < heap.len() && heap[largest].rank(&heap[child]) == Ordering::Less {
                largest = child;
            }
        }
        if largest == i {
            return;
        }
        heap.swap(i, largest);
        i = largest;
    }
}

/// Checks a maximum distance (`None` = unbounded) and returns its square.
fn limit_sq(max_distance: Option<f32>) -> Result<f64, SpatialError> {
    max_distance.map_or(Ok(f64::INFINITY), check_radius_sq)
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The visitor core of nearest-neighbour search: calls
    /// `visit(key, exact_box, distance_sq)` for entries whose squared
    /// distance from `point` is `<= limit`, where the limit starts at
    /// `max_distance²` (`None`: unbounded) and becomes whatever `visit`
    /// returns in `Continue(limit)` when that is smaller; `Break` stops.
    ///
    /// The walk is depth first, each node's two nearest children first, and
    /// skips a node once its bound is strictly beyond the limit, so entries
    /// at exactly the limit are still reported. Entries come roughly
    /// nearest first, not sorted.
    ///
    /// Errors, checked before any work: [`SpatialError::InvalidBox`] if
    /// `point` is not finite or beyond [`MAX_COORD`](crate::MAX_COORD);
    /// [`SpatialError::InvalidDistance`] if `max_distance` is negative, NaN
    /// or infinite.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree};
    /// use bevy_rtree::glam::Vec3;
    /// use std::ops::ControlFlow;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::new(3.0, 0.0, 0.0), Vec3::new(4.0, 1.0, 1.0))?)?;
    /// tree.insert(2u32, Aabb::new(Vec3::new(0.0, 9.0, 0.0), Vec3::new(1.0, 10.0, 1.0))?)?;
    /// // The nearest entry with an even key: keep the limit at the best so far.
    /// let mut best = None;
    /// tree.visit_nearest(Vec3::ZERO, None, &mut QueryWorkspace::default(), |key, _, d2| {
    ///     if key % 2 == 0 && best.is_none_or(|(_, b)| d2 < b) {
    ///         best = Some((key, d2));
    ///     }
    ///     ControlFlow::Continue(best.map_or(f64::INFINITY, |(_, b)| b))
    /// })?;
    /// assert_eq!(best, Some((2, 81.0)));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn visit_nearest<F>(
        &self,
        point: Vec3,
        max_distance: Option<f32>,
        ws: &mut QueryWorkspace,
        visit: F,
    ) -> Result<(), SpatialError>
    where
        F: FnMut(K, &Aabb, f64) -> ControlFlow<(), f64>,
    {
        check_point(point)?;
        let limit = limit_sq(max_distance)?;
        self.nearest_first(point, limit, ws, visit);
        Ok(())
    }

    /// The traversal behind [`RTree::visit_nearest`], on checked input:
    /// depth first, each node's two nearest children first.
    fn nearest_first<F>(&self, point: Vec3, mut limit: f64, ws: &mut QueryWorkspace, mut visit: F)
    where
        F: FnMut(K, &Aabb, f64) -> ControlFlow<(), f64>,
    {
        let stack = &mut ws.nearest;
        stack.clear();
        stack.push((self.root(), 0.0));
        // The cube that holds every box within the limit, recomputed only
        // when the limit shrinks; an infinite limit keeps every lane.
        let mut reach_of = f64::INFINITY;
        let mut reach = reach_cube(point, reach_of);
        while let Some((index, distance_sq)) = stack.pop() {
            if distance_sq > limit {
                continue;
            }
            if limit < reach_of {
                reach_of = limit;
                reach = reach_cube(point, limit);
            }
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            let mut near = node.overlap_mask_among(&reach, node.used_lanes());
            if node.is_leaf() {
                ws.stats.entries_tested += node.len() as u64;
                if near != 0 {
                    // The keys live apart from the leaf: asked for before
                    // the lanes' distances are computed, their load overlaps
                    // that work (1,000 queries of the 8 nearest, cold:
                    // 0.254-0.257 -> 0.236-0.238 x rstar's time; warm the
                    // same, 1.37 ms).
                    self.prefetch_keys_of_leaf(node);
                }
                while near != 0 {
                    let lane = near.trailing_zeros() as usize;
                    near &= near - 1;
                    let aabb = node.lane_box(lane);
                    let d2 = point_box_distance_sq(point, &aabb);
                    if d2 > limit {
                        continue;
                    }
                    match visit(self.key_of(node.child[lane]), &aabb, d2) {
                        // Written so that a NaN limit is ignored.
                        ControlFlow::Continue(next) => {
                            if next < limit {
                                limit = next;
                            }
                        }
                        ControlFlow::Break(()) => return,
                    }
                }
            } else {
                let base = stack.len();
                while near != 0 {
                    let lane = near.trailing_zeros() as usize;
                    near &= near - 1;
                    let d2 = point_box_distance_sq(point, &node.lane_box(lane));
                    if d2 <= limit {
                        // Loads of the children overlap instead of
                        // queueing when the tree is not in cache.
                        self.prefetch_node(node.child[lane]);
                        stack.push((node.child[lane], d2));
                    }
                }
                nearest_on_top(&mut stack[base..]);
            }
        }
    }

    /// The `k` entries nearest to `point`, written to `out` (cleared first)
    /// sorted by `(distance_sq, key)`: ties in distance go to the smaller
    /// key, so the answer is unique. With `max_distance`, only entries at a
    /// distance `<= max_distance` count (inclusive). Fewer than `k` when
    /// fewer entries qualify.
    ///
    /// Errors, checked before `out` is touched:
    /// [`SpatialError::InvalidCount`] if `k == 0`, and those of
    /// [`RTree::visit_nearest`].
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// for (key, x) in [(5u32, 2.0), (4, 2.0), (9, 7.0), (1, 30.0)] {
    ///     tree.insert(key, Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0))?)?;
    /// }
    /// let mut ws = QueryWorkspace::default();
    /// let mut out = Vec::new();
    /// tree.nearest_into(Vec3::ZERO, 3, Some(10.0), &mut ws, &mut out)?;
    /// let found: Vec<(u32, f64)> = out.iter().map(|n| (n.key, n.distance())).collect();
    /// assert_eq!(found, [(4, 2.0), (5, 2.0), (9, 7.0)]);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn nearest_into(
        &self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
        ws: &mut QueryWorkspace,
        out: &mut Vec<Neighbor<K>>,
    ) -> Result<(), SpatialError> {
        self.nearest_where_into(point, k, max_distance, ws, out, |_| true)
    }

    /// [`RTree::nearest_into`] among the entries whose key `allow` accepts:
    /// the `k` nearest of those.
    pub fn nearest_where_into(
        &self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
        ws: &mut QueryWorkspace,
        out: &mut Vec<Neighbor<K>>,
        allow: impl Fn(K) -> bool,
    ) -> Result<(), SpatialError> {
        if k == 0 {
            return Err(SpatialError::InvalidCount);
        }
        check_point(point)?;
        let limit = limit_sq(max_distance)?;
        out.clear();
        if k <= SORTED_UP_TO {
            // `out` is the best `k` so far in rank order: its last is the
            // one to evict, and its distance the search limit.
            self.nearest_first(point, limit, ws, |key, _, distance_sq| {
                let candidate = Neighbor { key, distance_sq };
                if allow(key) {
                    insert_ranked(out, k, candidate);
                }
                ControlFlow::Continue(if out.len() < k {
                    limit
                } else {
                    out[k - 1].distance_sq
                })
            });
            return Ok(());
        }
        // `out` is a max-heap by (distance_sq, key) of the best `k` so far:
        // its top is the one to evict, and its distance the search limit.
        self.nearest_first(point, limit, ws, |key, _, distance_sq| {
            let candidate = Neighbor { key, distance_sq };
            if allow(key) {
                if out.len() < k {
                    let last = out.len();
                    out.push(candidate);
                    sift_up(out, last);
                } else if candidate.rank(&out[0]) == Ordering::Less {
                    out[0] = candidate;
                    sift_down(out);
                }
            }
            ControlFlow::Continue(if out.len() < k {
                limit
            } else {
                out[0].distance_sq
            })
        });
        out.sort_unstable_by(Neighbor::rank);
        Ok(())
    }

    /// The `k` entries nearest to `point`, sorted by `(distance_sq, key)`,
    /// within `max_distance` (inclusive) if given. See
    /// [`RTree::nearest_into`] for the rules and errors.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree, SpatialError};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// tree.insert(2u32, Aabb::new(Vec3::splat(5.0), Vec3::splat(6.0))?)?;
    /// let near = tree.nearest(Vec3::splat(0.5), 1, None)?;
    /// assert_eq!((near[0].key, near[0].distance_sq), (1, 0.0)); // inside: distance 0
    /// assert_eq!(tree.nearest(Vec3::ZERO, 0, None), Err(SpatialError::InvalidCount));
    /// # Ok::<(), SpatialError>(())
    /// ```
    pub fn nearest(
        &self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
    ) -> Result<Vec<Neighbor<K>>, SpatialError> {
        let mut out = Vec::new();
        self.nearest_into(
            point,
            k,
            max_distance,
            &mut QueryWorkspace::default(),
            &mut out,
        )?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::predicates::boxes_overlap;

    #[test]
    fn the_two_nearest_children_go_on_top_and_none_is_lost() {
        for len in 0..=16usize {
            for rotation in 0..len.max(1) {
                // Distances with ties, rotated so the nearest sit anywhere.
                let pushed: Vec<(u32, f64)> = (0..len)
                    .map(|i| (i as u32, (((i + rotation) % len.max(1)) / 2) as f64))
                    .collect();
                let mut ordered = pushed.clone();
                nearest_on_top(&mut ordered);
                let mut by_distance = pushed.clone();
                by_distance.sort_by(|a, b| a.1.total_cmp(&b.1));
                let mut same = ordered.clone();
                same.sort_unstable_by_key(|p| p.0);
                assert_eq!(same, pushed, "the same children");
                if len >= 1 {
                    assert_eq!(ordered[len - 1].1, by_distance[0].1, "{ordered:?}");
                }
                if len >= 2 {
                    assert_eq!(ordered[len - 2].1, by_distance[1].1, "{ordered:?}");
                }
            }
        }
    }

    #[test]
    fn the_reach_cube_holds_every_box_at_exactly_the_limit() {
        // The hardest case: a box whose distance is the limit itself, at
        // scales from the origin to far out, with gaps on one to three
        // axes, so that the limit is rarely the square of an `f32`.
        let mut checked = 0;
        for scale in [1e-3f32, 1.0, 37.0, 1e4, 1e9, 1e14] {
            for i in 0..400u32 {
                let f = |k: u32| ((i * k) % 97) as f32 / 97.0 - 0.5;
                let point = Vec3::new(f(7), f(13), f(29)) * scale;
                let gap = Vec3::new(f(3).max(0.0), f(5).max(0.0), f(11).max(0.0)) * scale;
                let min = point + gap;
                let aabb = Aabb::new(min, min + Vec3::splat(scale)).unwrap();
                let limit = point_box_distance_sq(point, &aabb);
                assert!(
                    boxes_overlap(&aabb, &reach_cube(point, limit)),
                    "{aabb:?} at {limit} from {point:?}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 2_400);
        // An infinite limit keeps everything; a zero limit the boxes that
        // hold the point.
        let unit = Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap();
        assert!(boxes_overlap(
            &unit,
            &reach_cube(Vec3::splat(1e15), f64::INFINITY)
        ));
        assert!(boxes_overlap(&unit, &reach_cube(Vec3::ONE, 0.0)));
    }
}
