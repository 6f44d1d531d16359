//! The predicates of the [contract](crate::contract), one function each.
//!
//! The tree and the brute-force oracle both call these functions, so an answer
//! can only differ from the oracle if the tree prunes something it should not.
//! The tree's node tests apply the same formulas to node boxes; each formula is
//! monotone under box containment, which is what makes pruning safe.

use glam::Vec3;

use super::{Aabb, Frustum, Ray};

/// Closed-box overlap: the boxes share at least one point (S0).
#[inline]
pub(crate) fn boxes_overlap(a: &Aabb, b: &Aabb) -> bool {
    a.min.cmple(b.max).all() && b.min.cmple(a.max).all()
}

/// A ray prepared for repeated box tests: the canonical ray plus `1 / dir`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RayTest {
    pub origin: [f32; 3],
    pub dir: [f32; 3],
    pub inv: [f32; 3],
    /// Whether some direction component is zero: the lane tests take a
    /// slower path for such a ray.
    pub has_flat_axis: bool,
}

impl RayTest {
    /// `ray` must be canonical ([`Ray::canonicalized`]).
    #[inline]
    pub fn new(ray: &Ray) -> RayTest {
        let dir = ray.dir.to_array();
        RayTest {
            origin: ray.origin.to_array(),
            dir,
            inv: dir.map(|d| if d == 0.0 { 0.0 } else { 1.0 / d }),
            has_flat_axis: dir.contains(&0.0),
        }
    }
}

/// The ray / box predicate of S4, with `max_t` replaced by `limit` (the
/// caller's current best, or `ray.max_t`). Returns the entry `t` on a hit.
///
/// The comparisons are written out on purpose: `f32::min`/`max` treat NaN
/// differently on different targets, which would turn grazing rays into misses.
///
/// The limit is taken as at most `f32::MAX` ([`finite_limit`]): an entry
/// `t` has to be a number the answer can report. Without that, an unbounded
/// ray with a tiny direction, whose slab distances all overflow to
/// infinity, "hit" boxes it passes far from at `t = inf` (`lo = hi = inf`).
/// A node's entry is never later than its entries', so the tree still
/// prunes only what cannot hit.
#[inline]
pub(crate) fn ray_box_entry(
    ray: &RayTest,
    limit: f32,
    min: [f32; 3],
    max: [f32; 3],
) -> Option<f32> {
    let mut lo = 0.0f32;
    let mut hi = finite_limit(limit);
    for i in 0..3 {
        let o = ray.origin[i];
        if ray.dir[i] == 0.0 {
            if o < min[i] || o > max[i] {
                return None;
            }
            continue;
        }
        let inv = ray.inv[i];
        let (near, far) = if inv > 0.0 {
            (min[i], max[i])
        } else {
            (max[i], min[i])
        };
        let t0 = (near - o) * inv;
        let t1 = (far - o) * inv;
        if t0 > lo {
            lo = t0;
        }
        if t1 < hi {
            hi = t1;
        }
    }
    if lo <= hi { Some(lo) } else { None }
}

/// `limit`, or `f32::MAX` if it is larger (an unbounded ray's): the ray
/// predicate's starting `hi`, in the scalar test and in every lane test,
/// so that an entry at `t = inf` is a miss (see [`ray_box_entry`]).
#[inline(always)]
pub(crate) fn finite_limit(limit: f32) -> f32 {
    if limit > f32::MAX { f32::MAX } else { limit }
}

/// `dot(n, p - eye) + offset`, with the association order fixed, so that the
/// tree's lane tests and this scalar code compute bit-identical values.
#[inline(always)]
pub(crate) fn plane_value(normal: Vec3, offset: f32, eye: Vec3, p: Vec3) -> f32 {
    normal.x * (p.x - eye.x) + normal.y * (p.y - eye.y) + normal.z * (p.z - eye.z) + offset
}

/// The conservative frustum test of S7 on one box: for every active plane,
/// the box corner furthest along the normal is strictly inside.
#[inline]
pub(crate) fn frustum_conservative(frustum: &Frustum, aabb: &Aabb) -> bool {
    corner_inside_every_plane(frustum, aabb, true)
}

/// Whether the box lies strictly inside every active plane: its corner
/// *nearest* along each normal is inside. Such a box is visible in both modes.
#[inline]
pub(crate) fn frustum_contains(frustum: &Frustum, aabb: &Aabb) -> bool {
    corner_inside_every_plane(frustum, aabb, false)
}

/// For every active plane, whether the box corner furthest along the normal
/// (`furthest`) or nearest to it is strictly inside.
#[inline]
fn corner_inside_every_plane(frustum: &Frustum, aabb: &Aabb, furthest: bool) -> bool {
    let eye = frustum.eye();
    let (along, against) = if furthest {
        (aabb.max, aabb.min)
    } else {
        (aabb.min, aabb.max)
    };
    frustum.planes().iter().all(|plane| {
        if plane.is_inactive() {
            return true;
        }
        let p = Vec3::select(plane.normal.cmpge(Vec3::ZERO), along, against);
        plane_value(plane.normal, plane.offset, eye, p) > 0.0
    })
}

/// The exact frustum test of S7: conservative, and then either contained in
/// every plane or not separated on any of the remaining axes of the
/// separating-axis theorem (box edges crossed with frustum edges), in `f64`.
#[inline]
pub(crate) fn frustum_exact(frustum: &Frustum, sat: &super::FrustumSat, aabb: &Aabb) -> bool {
    frustum_conservative(frustum, aabb) && frustum_exact_rest(frustum, sat, aabb)
}

/// The part of [`frustum_exact`] that follows the conservative test.
#[inline]
pub(crate) fn frustum_exact_rest(frustum: &Frustum, sat: &super::FrustumSat, aabb: &Aabb) -> bool {
    // An empty volume sees nothing, even a box its planes' `f32` values
    // each put inside (two planes that face away from each other round so
    // at some points).
    !sat.sees_nothing() && (frustum_contains(frustum, aabb) || !sat.separates(aabb))
}

/// Squared Euclidean distance between two closed boxes, in `f64` (S8).
#[inline]
pub(crate) fn box_distance_sq(a: &Aabb, b: &Aabb) -> f64 {
    let mut sum = 0.0f64;
    for i in 0..3 {
        let g = axis_gap(a, b, i);
        sum += g * g;
    }
    sum
}

/// Squared Euclidean distance from a point to a closed box, in `f64`: `0`
/// when the point is inside or on the box. The point is the zero-extent box
/// at `point`, so this is [`box_distance_sq`] and agrees with the joins.
///
/// Sphere overlap, within-radius and nearest-neighbour answers are all decided
/// by this one value. Applied to a node's bound it never exceeds the value for
/// any box inside that bound: each per-axis difference, square and sum is
/// rounded monotonically, so pruning by it never loses an answer.
#[inline]
pub(crate) fn point_box_distance_sq(point: Vec3, aabb: &Aabb) -> f64 {
    box_distance_sq(
        &Aabb {
            min: point,
            max: point,
        },
        aabb,
    )
}

/// Checks a query point: finite with every `|coordinate| <= MAX_COORD`, the
/// same rule as a box corner, so a bad point is `SpatialError::InvalidBox`.
pub(crate) fn check_point(point: Vec3) -> Result<(), super::SpatialError> {
    Aabb::from_point(point).map(|_| ())
}

/// Checks a radius or maximum distance (finite, `>= 0`) and returns its
/// square in `f64`. The square is exact: an `f32` has 24 significant bits,
/// its square at most 48, well within `f64`'s 53 and its exponent range.
pub(crate) fn check_radius_sq(radius: f32) -> Result<f64, super::SpatialError> {
    let r = check_distance(radius)?;
    Ok(r * r)
}

/// The closed-sphere / closed-box predicate: they share a point iff the
/// box's squared distance from the centre is `<= radius²`. Returns that
/// squared distance when they do. Within-radius and a nearest-neighbour
/// search with a maximum distance accept entries by this same test.
#[inline]
pub(crate) fn sphere_box_distance_sq(center: Vec3, radius_sq: f64, aabb: &Aabb) -> Option<f64> {
    let d2 = point_box_distance_sq(center, aabb);
    if d2 <= radius_sq { Some(d2) } else { None }
}

/// A box that every box the sphere predicate accepts for (`center`,
/// `radius`) overlaps: the cube `center ± radius`, widened on every side by
/// `(|center| + radius)·2⁻²⁰`. Traversals test a node's lanes against it
/// four or sixteen at a time, then decide only the lanes it keeps with the
/// exact `f64` test.
///
/// Why the widening: the predicate decides on `f64` gaps that are rounded,
/// so it accepts some boxes whose real gap exceeds the radius by a few
/// `2⁻⁵³` of the coordinates, and the cube's corners are rounded to `f32`,
/// whose step near zero (where `center ± radius` may fall) is far smaller
/// than those errors. `2⁻²⁰` of the coordinates' magnitude covers both with
/// room to spare: about a millimetre a kilometre from the origin, a few
/// extra candidates that the exact test then rejects. A radius so large
/// that the sum overflows gives an infinite cube, which keeps every lane.
#[inline]
pub(crate) fn sphere_reach(center: Vec3, radius: f32) -> Aabb {
    let r = Vec3::splat(radius);
    let slack = (center.abs() + r) * (1.0 / 1_048_576.0);
    Aabb {
        min: center - r - slack,
        max: center + r + slack,
    }
}

/// The gap between two boxes along one axis (0 when their ranges overlap).
#[inline]
pub(crate) fn axis_gap(a: &Aabb, b: &Aabb, axis: usize) -> f64 {
    let g1 = a.min[axis] as f64 - b.max[axis] as f64;
    let g2 = b.min[axis] as f64 - a.max[axis] as f64;
    let mut g = 0.0;
    if g1 > g {
        g = g1;
    }
    if g2 > g {
        g = g2;
    }
    g
}

/// The join predicate in exact mode: Euclidean box distance `<= d` (S8).
#[inline]
pub(crate) fn within_euclidean(a: &Aabb, b: &Aabb, distance: f64) -> bool {
    box_distance_sq(a, b) <= distance * distance
}

/// The join predicate in fast mode: every axis gap `<= d` (Chebyshev, S8).
/// A superset of [`within_euclidean`].
#[inline]
pub(crate) fn within_chebyshev(a: &Aabb, b: &Aabb, distance: f64) -> bool {
    (0..3).all(|i| axis_gap(a, b, i) <= distance)
}

/// Checks a join or radius distance: finite and `>= 0` (S8).
pub(crate) fn check_distance(distance: f32) -> Result<f64, super::SpatialError> {
    if distance.is_finite() && distance >= 0.0 {
        Ok(distance as f64)
    } else {
        Err(super::SpatialError::InvalidDistance)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Coordinates where rounding bites: zero, the smallest floats, the
    /// scene's scale and the largest allowed coordinate, each either side.
    const MAGNITUDES: [f32; 9] = [0.0, 1e-40, 1e-20, 0.5, 10.0, 1000.0, 1e7, 1e12, 1e15];

    /// A small xorshift generator, so the test needs no dependency.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        fn pick<T: Copy>(&mut self, from: &[T]) -> T {
            from[(self.next() % from.len() as u64) as usize]
        }

        /// A coordinate: a signed magnitude, sometimes nudged by a few
        /// `f32` steps.
        fn coordinate(&mut self) -> f32 {
            let mut v = self.pick(&MAGNITUDES);
            if self.next().is_multiple_of(2) {
                v = -v;
            }
            for _ in 0..self.next() % 3 {
                v = if self.next().is_multiple_of(2) {
                    v.next_up()
                } else {
                    v.next_down()
                };
            }
            v
        }
    }

    #[test]
    fn every_box_the_sphere_predicate_accepts_overlaps_the_sphere_reach() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let radii = [0.0, 1e-40, 1e-20, 0.5, 10.0, 1e3, 1e10, 1e30, f32::MAX];
        let mut accepted = 0;
        for _ in 0..200_000 {
            let center = Vec3::new(rng.coordinate(), rng.coordinate(), rng.coordinate());
            let radius: f32 = rng.pick(&radii);
            // Boxes whose near face lies about `radius` from the centre on
            // one axis, from either side, or anywhere.
            let axis = (rng.next() % 3) as usize;
            let mut min = Vec3::new(rng.coordinate(), rng.coordinate(), rng.coordinate());
            let mut max = min;
            match rng.next() % 3 {
                0 => min[axis] = center[axis] + radius + rng.coordinate() * 1e-7,
                1 => max[axis] = center[axis] - radius + rng.coordinate() * 1e-7,
                _ => {}
            }
            let (min, max) = (min.min(max), min.max(max));
            let Ok(aabb) = Aabb::new(min, max) else {
                continue;
            };
            let radius_sq = (radius as f64) * (radius as f64);
            if sphere_box_distance_sq(center, radius_sq, &aabb).is_some() {
                accepted += 1;
                let reach = sphere_reach(center, radius);
                assert!(
                    boxes_overlap(&aabb, &reach),
                    "{aabb:?} is within {radius} of {center:?} but outside {reach:?}"
                );
            }
        }
        assert!(accepted > 20_000, "only {accepted} boxes were within reach");
    }

    #[test]
    fn the_sphere_reach_covers_a_face_next_to_zero() {
        // The gap 10 + 1e-20 rounds to 10 in `f64`, so the predicate accepts
        // the box, although `center + radius` is 0 and the next `f32` above
        // it is far below 1e-20.
        let center = Vec3::new(-10.0, 0.0, 0.0);
        let aabb = Aabb::new(Vec3::new(1e-20, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0)).unwrap();
        assert_eq!(sphere_box_distance_sq(center, 100.0, &aabb), Some(100.0));
        assert!(boxes_overlap(&aabb, &sphere_reach(center, 10.0)));
    }
}
