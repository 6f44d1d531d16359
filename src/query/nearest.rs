//! Nearest neighbours: the `k` entries closest to a point, optionally no
//! further than a maximum distance.
//!
//! The distance from a point to an entry is the Euclidean distance to the
//! entry's closed exact box (`0` inside or on it), decided by its square in
//! `f64`. The search is best first: a priority queue holds nodes keyed by the
//! squared distance to their bound, the nearest node is expanded next, and the
//! search ends once the nearest queued node is strictly further than the
//! current `k`-th best. Nodes at exactly that distance are still expanded,
//! because they may hold an entry at the same distance with a smaller key.

use std::cmp::Ordering;
use std::ops::ControlFlow;

use glam::Vec3;

use super::QueryWorkspace;
use crate::geometry::predicates::{check_point, check_radius_sq, point_box_distance_sq};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::RTree;

/// An entry and its distance from a query point.
///
/// `distance_sq` is the squared Euclidean distance from the point to the
/// entry's closed exact box, computed in `f64` from the `f32` inputs: `0` when
/// the point is inside or on the box. Lists of neighbours are sorted by
/// `(distance_sq, key)`, which is the order of [`Neighbor::distance`] with ties
/// broken by key.
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

/// A node waiting in the best-first queue, ordered so that
/// `BinaryHeap` (a max-heap) pops the smallest distance first.
#[derive(Clone, Copy, Debug)]
pub(crate) struct QueuedNode {
    distance_sq: f64,
    node: u32,
}

impl Ord for QueuedNode {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .distance_sq
            .total_cmp(&self.distance_sq)
            .then(other.node.cmp(&self.node))
    }
}

impl PartialOrd for QueuedNode {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for QueuedNode {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for QueuedNode {}

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
    /// Nodes are expanded nearest first and skipped once their bound is
    /// strictly beyond the limit, so entries at exactly the limit are still
    /// reported. Entries come roughly nearest first, not sorted.
    ///
    /// Errors, checked before any work: [`SpatialError::InvalidBox`] if
    /// `point` is not finite or beyond [`MAX_COORD`](crate::MAX_COORD);
    /// [`SpatialError::InvalidDistance`] if `max_distance` is negative, NaN
    /// or infinite.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree};
    /// use glam::Vec3;
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
        self.best_first(point, limit, ws, visit);
        Ok(())
    }

    /// The best-first traversal behind [`RTree::visit_nearest`], on checked
    /// input.
    fn best_first<F>(&self, point: Vec3, mut limit: f64, ws: &mut QueryWorkspace, mut visit: F)
    where
        F: FnMut(K, &Aabb, f64) -> ControlFlow<(), f64>,
    {
        let queue = &mut ws.nearest;
        queue.clear();
        queue.push(QueuedNode {
            distance_sq: 0.0,
            node: self.root(),
        });
        while let Some(QueuedNode { distance_sq, node }) = queue.pop() {
            // The queue pops in distance order: everything left is as far.
            if distance_sq > limit {
                break;
            }
            let node = self.node(node);
            ws.stats.nodes_visited += 1;
            if node.is_leaf() {
                ws.stats.entries_tested += node.len() as u64;
                for lane in 0..node.len() {
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
                for lane in 0..node.len() {
                    let d2 = point_box_distance_sq(point, &node.lane_box(lane));
                    if d2 <= limit {
                        queue.push(QueuedNode {
                            distance_sq: d2,
                            node: node.child[lane],
                        });
                    }
                }
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
    /// use glam::Vec3;
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
        if k == 0 {
            return Err(SpatialError::InvalidCount);
        }
        check_point(point)?;
        let limit = limit_sq(max_distance)?;
        out.clear();
        // `out` is a max-heap by (distance_sq, key) of the best `k` so far:
        // its top is the one to evict, and its distance the search limit.
        self.best_first(point, limit, ws, |key, _, distance_sq| {
            let candidate = Neighbor { key, distance_sq };
            if out.len() < k {
                let last = out.len();
                out.push(candidate);
                sift_up(out, last);
            } else if candidate.rank(&out[0]) == Ordering::Less {
                out[0] = candidate;
                sift_down(out);
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
    /// use glam::Vec3;
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
