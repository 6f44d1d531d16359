//! The brute-force oracle: a plain list of `(key, box)` and, per query
//! family, a loop that applies the very predicate the tree uses.
//!
//! Tests compare every tree answer with it; benchmarks time it as the
//! baseline. It is slow on purpose and obviously right.

use glam::Vec3;

use crate::geometry::predicates;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Aabb, Frustum, FrustumSat, Ray, SpatialError};
use crate::query::{CullMode, JoinMode, Neighbor, RayHit};

/// A flat list of entries answering every query by testing all of them.
///
/// ```
/// use bevy_rtree::oracle::BruteForce;
/// use bevy_rtree::Aabb;
/// use bevy_rtree::glam::Vec3;
///
/// let mut all = BruteForce::default();
/// all.insert(3u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?);
/// assert_eq!(all.overlapping(&Aabb::new(Vec3::ONE, Vec3::splat(2.0))?), [3]);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Debug)]
pub struct BruteForce<K> {
    entries: Vec<(K, Aabb)>,
}

// Not derived: an empty oracle needs no default key.
impl<K> Default for BruteForce<K> {
    fn default() -> Self {
        BruteForce {
            entries: Vec::new(),
        }
    }
}

impl<K: Copy + Ord> BruteForce<K> {
    /// Adds an entry (no checks: the oracle mirrors what the tree accepted).
    pub fn insert(&mut self, key: K, aabb: Aabb) {
        self.entries.push((key, aabb));
    }

    /// Replaces the box of every entry with this key.
    pub fn update(&mut self, key: K, aabb: Aabb) {
        for entry in self.entries.iter_mut().filter(|(k, _)| *k == key) {
            entry.1 = aabb;
        }
    }

    /// Removes every entry with this key.
    pub fn remove(&mut self, key: K) {
        self.entries.retain(|(k, _)| *k != key);
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether there are no entries.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The entries.
    pub fn entries(&self) -> &[(K, Aabb)] {
        &self.entries
    }

    /// Sorted keys of entries whose closed box overlaps `query`; an invalid
    /// query box matches nothing, as in [`RTree::visit_overlapping`](crate::RTree::visit_overlapping).
    pub fn overlapping(&self, query: &Aabb) -> Vec<K> {
        if !query.is_valid() {
            return Vec::new();
        }
        let mut out: Vec<K> = self
            .entries
            .iter()
            .filter(|(_, aabb)| predicates::boxes_overlap(aabb, query))
            .map(|(key, _)| *key)
            .collect();
        out.sort_unstable();
        out
    }

    /// Sorted keys of entries whose closed box contains `point` (none for a
    /// point that is not a valid point box).
    pub fn containing_point(&self, point: Vec3) -> Vec<K> {
        self.overlapping(&Aabb {
            min: point,
            max: point,
        })
    }

    /// Sorted keys of entries visible in `frustum` under `mode`.
    pub fn visible(&self, frustum: &Frustum, mode: CullMode) -> Vec<K> {
        let sat = FrustumSat::new(frustum);
        let mut out: Vec<K> = self
            .entries
            .iter()
            .filter(|(_, aabb)| match mode {
                CullMode::Conservative => predicates::frustum_conservative(frustum, aabb),
                CullMode::Exact => predicates::frustum_exact(frustum, &sat, aabb),
            })
            .map(|(key, _)| *key)
            .collect();
        out.sort_unstable();
        out
    }

    /// Every hit of `ray`, sorted by `(t, key)` ([contract S4](crate::contract), S5).
    pub fn ray_hits(&self, ray: &Ray) -> Result<Vec<RayHit<K>>, SpatialError> {
        let ray = ray.canonicalized()?;
        let test = RayTest::new(&ray);
        let mut hits: Vec<RayHit<K>> = self
            .entries
            .iter()
            .filter_map(|(key, b)| {
                predicates::ray_box_entry(&test, ray.max_t, b.min.to_array(), b.max.to_array())
                    .map(|t| RayHit { key: *key, t })
            })
            .collect();
        hits.sort_unstable_by(|a, b| a.t.total_cmp(&b.t).then(a.key.cmp(&b.key)));
        Ok(hits)
    }

    /// The first hit of `ray`: the smallest `(t, key)`.
    pub fn ray_first(&self, ray: &Ray) -> Result<Option<RayHit<K>>, SpatialError> {
        Ok(self.ray_hits(ray)?.first().copied())
    }

    /// Sorted keys of entries whose closed box shares a point with the
    /// closed sphere: squared distance from `center` `<= radius²`, in `f64`.
    /// Errors as [`RTree::visit_sphere`](crate::RTree::visit_sphere).
    ///
    /// ```
    /// use bevy_rtree::oracle::BruteForce;
    /// use bevy_rtree::Aabb;
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut all = BruteForce::default();
    /// all.insert(1u32, Aabb::new(Vec3::new(2.0, 0.0, 0.0), Vec3::new(3.0, 1.0, 1.0))?);
    /// assert_eq!(all.overlapping_sphere(Vec3::ZERO, 2.0)?, [1]);
    /// assert!(all.overlapping_sphere(Vec3::ZERO, 1.5)?.is_empty());
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn overlapping_sphere(&self, center: Vec3, radius: f32) -> Result<Vec<K>, SpatialError> {
        let mut out: Vec<K> = self
            .within_radius(center, radius)?
            .into_iter()
            .map(|n| n.key)
            .collect();
        out.sort_unstable();
        Ok(out)
    }

    /// Every entry within `radius` of `point` with its squared distance,
    /// sorted by `(distance_sq, key)`: the sphere predicate.
    ///
    /// ```
    /// use bevy_rtree::oracle::BruteForce;
    /// use bevy_rtree::{Aabb, Neighbor};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut all = BruteForce::default();
    /// all.insert(4u32, Aabb::new(Vec3::new(3.0, 4.0, 0.0), Vec3::new(5.0, 5.0, 1.0))?);
    /// assert_eq!(all.within_radius(Vec3::ZERO, 5.0)?, [Neighbor { key: 4, distance_sq: 25.0 }]);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn within_radius(
        &self,
        point: Vec3,
        radius: f32,
    ) -> Result<Vec<Neighbor<K>>, SpatialError> {
        predicates::check_point(point)?;
        let radius_sq = predicates::check_radius_sq(radius)?;
        let mut out: Vec<Neighbor<K>> = self
            .entries
            .iter()
            .filter_map(|(key, aabb)| {
                predicates::sphere_box_distance_sq(point, radius_sq, aabb).map(|distance_sq| {
                    Neighbor {
                        key: *key,
                        distance_sq,
                    }
                })
            })
            .collect();
        out.sort_unstable_by(Neighbor::rank);
        Ok(out)
    }

    /// The `k` entries nearest to `point`, sorted by `(distance_sq, key)`,
    /// only those within `max_distance` (inclusive) if given: every entry
    /// sorted, then cut. Errors as
    /// [`RTree::nearest_into`](crate::RTree::nearest_into).
    ///
    /// ```
    /// use bevy_rtree::oracle::BruteForce;
    /// use bevy_rtree::Aabb;
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut all = BruteForce::default();
    /// for key in [8u32, 2, 5] {
    ///     all.insert(key, Aabb::new(Vec3::ONE, Vec3::splat(2.0))?);
    /// }
    /// let keys: Vec<u32> = all.nearest(Vec3::ZERO, 2, None)?.iter().map(|n| n.key).collect();
    /// assert_eq!(keys, [2, 5]); // equal distances: smaller keys first
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn nearest(
        &self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
    ) -> Result<Vec<Neighbor<K>>, SpatialError> {
        if k == 0 {
            return Err(SpatialError::InvalidCount);
        }
        predicates::check_point(point)?;
        let limit = max_distance.map_or(Ok(f64::INFINITY), predicates::check_radius_sq)?;
        let mut out: Vec<Neighbor<K>> = self
            .entries
            .iter()
            .filter_map(|(key, aabb)| {
                predicates::sphere_box_distance_sq(point, limit, aabb).map(|distance_sq| Neighbor {
                    key: *key,
                    distance_sq,
                })
            })
            .collect();
        out.sort_unstable_by(Neighbor::rank);
        out.truncate(k);
        Ok(out)
    }

    /// Sorted `(lo, hi)` pairs of distinct entries within `distance`, by a
    /// sort-and-sweep along x ([contract S8](crate::contract)).
    pub fn self_join(&self, distance: f32, mode: JoinMode) -> Result<Vec<(K, K)>, SpatialError> {
        let d = predicates::check_distance(distance)?;
        let mut order: Vec<usize> = (0..self.entries.len()).collect();
        order
            .sort_unstable_by(|&a, &b| self.entries[a].1.min.x.total_cmp(&self.entries[b].1.min.x));
        let mut out = Vec::new();
        for (i, &a) in order.iter().enumerate() {
            let (ka, ba) = self.entries[a];
            for &b in &order[i + 1..] {
                let (kb, bb) = self.entries[b];
                // Sorted by min.x: once the x gap alone exceeds d, stop.
                if bb.min.x as f64 - ba.max.x as f64 > d {
                    break;
                }
                if mode.accepts(&ba, &bb, d) {
                    out.push((ka.min(kb), ka.max(kb)));
                }
            }
        }
        out.sort_unstable();
        Ok(out)
    }

    /// Sorted `(a, b)` pairs, `a` from `self` and `b` from `other`, `a != b`,
    /// within `distance`.
    pub fn cross_join(
        &self,
        other: &BruteForce<K>,
        distance: f32,
        mode: JoinMode,
    ) -> Result<Vec<(K, K)>, SpatialError> {
        let d = predicates::check_distance(distance)?;
        let mut out = Vec::new();
        for (ka, ba) in &self.entries {
            for (kb, bb) in &other.entries {
                if ka != kb && mode.accepts(ba, bb, d) {
                    out.push((*ka, *kb));
                }
            }
        }
        out.sort_unstable();
        Ok(out)
    }
}
