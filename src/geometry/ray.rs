//! Rays as closed segments ([contract S3](crate::contract)).

use glam::Vec3;

use super::predicates::{RayTest, ray_box_entry};
use super::{Aabb, SpatialError};

/// A ray: the closed segment `{origin + t * dir : 0 <= t <= max_t}`.
///
/// `t` is measured in units of `|dir|`: the direction is *not* normalised for
/// you, so with a unit direction `t` is a distance in metres. `max_t` may be
/// `f32::INFINITY` for an unbounded ray.
///
/// The fields are public so that a batch of raw rays can be handed to a query,
/// which checks each one and reports an invalid ray in its own result slot.
/// [`Ray::canonicalized`] is that check.
///
/// ```
/// use bevy_rtree::Ray;
/// use bevy_rtree::glam::Vec3;
///
/// let ray = Ray::new(Vec3::ZERO, Vec3::X, 10.0)?;
/// assert_eq!(ray.point_at(2.5), Vec3::new(2.5, 0.0, 0.0));
/// assert!(Ray::new(Vec3::ZERO, Vec3::ZERO, 1.0).is_err());
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Where the segment starts (`t = 0`).
    pub origin: Vec3,
    /// The direction; its length is the unit of `t`.
    pub dir: Vec3,
    /// Where the segment ends, in `[0, +inf]`.
    pub max_t: f32,
}

impl Ray {
    /// A checked, canonical ray (see [`Ray::canonicalized`]).
    pub fn new(origin: Vec3, dir: Vec3, max_t: f32) -> Result<Ray, SpatialError> {
        Ray { origin, dir, max_t }.canonicalized()
    }

    /// The ray from `from` to `to` (`max_t = 1`), checked.
    pub fn segment(from: Vec3, to: Vec3) -> Result<Ray, SpatialError> {
        Ray::new(from, to - from, 1.0)
    }

    /// Checks the ray and returns its canonical form.
    ///
    /// Direction components with `|d| < f32::MIN_POSITIVE` (subnormals and
    /// `-0.0`) become `+0.0`. Valid iff the origin is finite, the direction is
    /// finite and non-zero after that, and `max_t` is in `[0, +inf]`.
    pub fn canonicalized(&self) -> Result<Ray, SpatialError> {
        let dir = Vec3::from_array(
            self.dir
                .to_array()
                .map(|d| if d.abs() < f32::MIN_POSITIVE { 0.0 } else { d }),
        );
        let max_t_ok = self.max_t >= 0.0; // false for NaN
        if !self.origin.is_finite() || !dir.is_finite() || dir == Vec3::ZERO || !max_t_ok {
            return Err(SpatialError::InvalidRay);
        }
        Ok(Ray {
            origin: self.origin,
            dir,
            max_t: self.max_t,
        })
    }

    /// `origin + t * dir`.
    #[inline]
    pub fn point_at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// A checked ray prepared for many box tests with the one ray-box predicate
/// of [contract S4](crate::contract), the same function the tree and the oracle call. Useful
/// for testing boxes outside the index (or for feeding another index).
///
/// ```
/// use bevy_rtree::{Aabb, Ray};
/// use bevy_rtree::glam::Vec3;
///
/// let ray = Ray::new(Vec3::ZERO, Vec3::X, 10.0)?.prepared()?;
/// let wall = Aabb::new(Vec3::new(4.0, -1.0, -1.0), Vec3::new(5.0, 1.0, 1.0))?;
/// assert_eq!(ray.entry(&wall, ray.max_t()), Some(4.0));
/// assert_eq!(ray.entry(&wall, 3.0), None); // beyond the limit
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct PreparedRay {
    test: RayTest,
    max_t: f32,
}

impl Ray {
    /// The ray checked, canonicalised and prepared for box tests.
    pub fn prepared(&self) -> Result<PreparedRay, SpatialError> {
        let ray = self.canonicalized()?;
        Ok(PreparedRay {
            test: RayTest::new(&ray),
            max_t: ray.max_t,
        })
    }
}

impl PreparedRay {
    /// The ray's own `max_t`.
    pub fn max_t(&self) -> f32 {
        self.max_t
    }

    /// Where the ray enters `aabb` (`0` if it starts inside or on it), if it
    /// does so at `t <= limit`; pass [`max_t`](Self::max_t) or a smaller
    /// limit such as the best hit so far. A box with a NaN coordinate is
    /// entered nowhere, as every other predicate of the crate treats it.
    #[inline]
    pub fn entry(&self, aabb: &Aabb, limit: f32) -> Option<f32> {
        // The slab test skips a NaN bound (`t0 > lo` is false), which would
        // make an all-NaN box a hit at 0; the tree never stores one, so only
        // this public helper checks.
        if aabb.min.is_nan() || aabb.max.is_nan() {
            return None;
        }
        ray_box_entry(&self.test, limit, aabb.min.to_array(), aabb.max.to_array())
    }
}
