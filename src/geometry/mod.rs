//! Geometry: boxes, rays, frustums, the error type, and the predicates that
//! define every answer of the index (the [contract](crate::contract)).

mod aabb;
#[cfg(feature = "bevy_camera")]
mod bevy_types;
mod error;
mod frustum;
mod frustum_sat;
pub(crate) mod predicates;
mod ray;

pub use aabb::{Aabb, MAX_COORD};
pub use error::SpatialError;
pub use frustum::{Frustum, HalfSpace};
pub use frustum_sat::FrustumSat;
pub use ray::{PreparedRay, Ray};
