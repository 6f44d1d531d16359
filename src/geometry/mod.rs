//! Geometry: boxes, rays, frustums, the error type, and the predicates that
//! define every answer of the index (the [contract](crate::contract)).

mod aabb;
#[cfg(feature = "bevy_camera")]
mod bevy_types;
mod error;
mod frustum;
mod frustum_sat;
#[cfg(feature = "reflect")]
mod frustum_serde;
pub(crate) mod predicates;
mod ray;

pub use aabb::{Aabb, MAX_COORD};

/// `v` at unit length, computed as glam's `normalize` computes it (bit for
/// bit) but without its check that the result is finite, which glam's
/// assertion features (Bevy's `debug_glam_assert`) turn into a panic: a
/// zero, infinite or NaN `v` from user data gives non-finite components
/// here, which the caller refuses with a typed error.
pub(crate) fn unit_or_nan(v: glam::Vec3) -> glam::Vec3 {
    v * v.length_recip()
}

/// [`unit_or_nan`] in `f64`.
pub(crate) fn unit_or_nan_f64(v: glam::DVec3) -> glam::DVec3 {
    v * v.length_recip()
}
pub use error::SpatialError;
pub use frustum::{Frustum, HalfSpace};
pub use frustum_sat::FrustumSat;
pub use ray::{PreparedRay, Ray};
