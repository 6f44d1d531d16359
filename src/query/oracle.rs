//! The brute-force oracle: a plain list of `(key, box)` and, per query
//! family, a loop that applies the very predicate the tree uses.
//!
//! Tests compare every tree answer with it; benchmarks time it as the
//! baseline. It is slow on purpose and obviously right.

use glam::Vec3;

use crate::geometry::predicates;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Aabb, Frustum, FrustumSat, Ray, SpatialError};
use crate::query::{CullMode, JoinMode, RayHit};

/// A flat list of entries answering every query by testing all of them.
///
/// ```
/// use bevy_rtree::oracle::BruteForce;
/// use bevy_rtree::Aabb;
/// use glam::Vec3;
///
/// let mut all = BruteForce::default();
/// all.insert(3u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?);
/// assert_eq!(all.overlapping(&Aabb::new(Vec3::ONE, Vec3::splat(2.0))?), [3]);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Debug, Default)]
pub struct BruteForce<K> {
    entries: Vec<(K, Aabb)>,
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

    /// Sorted keys of entries whose closed box overlaps `query`.
    pub fn overlapping(&self, query: &Aabb) -> Vec<K> {
        let mut out: Vec<K> = self
            .entries
            .iter()
            .filter(|(_, aabb)| predicates::boxes_overlap(aabb, query))
            .map(|(key, _)| *key)
            .collect();
        out.sort_unstable();
        out
    }

    /// Sorted keys of entries whose closed box contains `point`.
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

    /// Every hit of `ray`, sorted by `(t, key)` (SEMANTICS S4, S5).
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

    /// Sorted `(lo, hi)` pairs of distinct entries within `distance`, by a
    /// sort-and-sweep along x (SEMANTICS S8).
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
