//! Conversions between the crate's geometry and Bevy's (feature
//! `bevy_camera`): Bevy's `Aabb` component, its `Frustum`, `Ray3d` and
//! `Dir3`.

use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum};
use bevy_math::Dir3;
use bevy_shape::Ray3d;
use glam::{Affine3A, Vec3};

use super::{Aabb, Frustum, Ray, SpatialError};

impl TryFrom<&BevyAabb> for Aabb {
    type Error = SpatialError;

    /// The box around Bevy's centre and half extents, rounded outward so
    /// that it contains Bevy's box; an [`SpatialError::InvalidBox`] for a
    /// NaN, infinite or negative input or a box beyond
    /// [`MAX_COORD`](crate::MAX_COORD).
    ///
    /// ```
    /// use bevy_camera::primitives::Aabb as BevyAabb;
    /// use bevy_rtree::Aabb;
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let bevy = BevyAabb::from_min_max(Vec3::ZERO, Vec3::ONE);
    /// let ours = Aabb::try_from(&bevy)?;
    /// assert_eq!(ours, Aabb::new(Vec3::ZERO, Vec3::ONE)?);
    /// assert_eq!(BevyAabb::from(ours), bevy);
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    fn try_from(aabb: &BevyAabb) -> Result<Aabb, SpatialError> {
        // Where the corners are exact in `f32`, they are the box: kept so,
        // up to `MAX_COORD` itself, which the outward rounding would pass.
        let (min, max) = (Vec3::from(aabb.min()), Vec3::from(aabb.max()));
        let (c, h) = (Vec3::from(aabb.center), Vec3::from(aabb.half_extents));
        let exact = (0..3)
            .all(|i| sum_is_exactly(c[i], -h[i], min[i]) && sum_is_exactly(c[i], h[i], max[i]));
        // A negative half extent makes `min` above `max`, which `new` refuses.
        if exact && let Ok(exact) = Aabb::new(min, max) {
            return Ok(exact);
        }
        Aabb::from_oriented(c, h, &Affine3A::IDENTITY)
    }
}

/// Whether `a + b` is exactly `sum`, as real numbers: the `f64` sum of two
/// `f32`s and its rounding error (a two-sum, exact in `f64`) must be `sum`
/// and zero. A plain `f64` difference is not exact where the two differ
/// in magnitude by more than `f64`'s extra bits (a centre of 1e-17 beside
/// a half extent of 1).
fn sum_is_exactly(a: f32, b: f32, sum: f32) -> bool {
    let (a, b) = (f64::from(a), f64::from(b));
    let s = a + b;
    let b_part = s - a;
    let error = (a - (s - b_part)) + (b - b_part);
    s == f64::from(sum) && error == 0.0
}

impl From<Aabb> for BevyAabb {
    /// Bevy's box with the same corners (Bevy stores the centre and half
    /// extents, so far from the origin its corners may round).
    fn from(aabb: Aabb) -> BevyAabb {
        BevyAabb::from_min_max(aabb.min, aabb.max)
    }
}

/// The index of Bevy's far plane among a `Frustum`'s half-spaces.
const FAR_PLANE: usize = 5;

impl Frustum {
    /// Bevy's `Frustum` (world-space half-spaces, as Bevy's camera keeps
    /// it) re-based on `eye`, usually the camera's position. All six planes
    /// are kept, the far one too (Bevy's own camera culling ignores it; see
    /// the `BevyVisibilityPlugin` for Bevy's exact behaviour); a plane that
    /// never culls in Bevy's tests (an infinite far plane) is inactive.
    ///
    /// ```
    /// use bevy_camera::{CameraProjection, PerspectiveProjection};
    /// use bevy_rtree::{Aabb, Frustum};
    /// use bevy_transform::prelude::GlobalTransform;
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let camera = GlobalTransform::from_xyz(0.0, 0.0, 10.0);
    /// let bevy = PerspectiveProjection::default().compute_frustum(&camera);
    /// let frustum = Frustum::from_bevy(&bevy, camera.translation())?;
    /// let ahead = Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0))?;
    /// assert!(frustum.intersects_conservative(&ahead));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn from_bevy(frustum: &BevyFrustum, eye: Vec3) -> Result<Frustum, SpatialError> {
        let mut planes = frustum.half_spaces.map(|h| (Vec3::from(h.normal()), h.d()));
        // Bevy's infinite far plane (`far: f32::INFINITY`) never culls in
        // its tests: it is stored as `(n, +inf)`, as `(n, NaN)` with a
        // finite `n` that has a zero, or as `(NaN, +inf)`. A NaN in any
        // other plane (a camera at a NaN position or turned by a NaN), and
        // a NaN far distance (which gives `(n, NaN)` whatever `n`, so only
        // where `n` has no zero can it be told apart), are refused.
        let (normal, d) = planes[FAR_PLANE];
        let has_a_zero = normal.cmpeq(Vec3::ZERO).any();
        if d == f32::INFINITY || (d.is_nan() && normal.is_finite() && has_a_zero) {
            planes[FAR_PLANE] = (Vec3::ZERO, f32::INFINITY);
        }
        Frustum::from_world_planes(eye, planes)
    }
}

impl Ray {
    /// A ray from `origin` along Bevy's unit direction, `max_distance`
    /// metres long (`f32::INFINITY` for no end): `t` is in metres.
    ///
    /// ```
    /// use bevy_math::Dir3;
    /// use bevy_rtree::Ray;
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let ray = Ray::from_dir(Vec3::ZERO, Dir3::NEG_Z, 50.0)?;
    /// assert_eq!(ray.point_at(10.0), Vec3::new(0.0, 0.0, -10.0));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn from_dir(origin: Vec3, direction: Dir3, max_distance: f32) -> Result<Ray, SpatialError> {
        Ray::new(origin, direction.as_vec3(), max_distance)
    }
}

impl TryFrom<Ray3d> for Ray {
    type Error = SpatialError;

    /// Bevy's `Ray3d` as an unbounded ray, `t` in metres.
    fn try_from(ray: Ray3d) -> Result<Ray, SpatialError> {
        Ray::from_dir(ray.origin, ray.direction, f32::INFINITY)
    }
}
