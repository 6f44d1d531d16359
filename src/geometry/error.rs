//! The one error type of the crate.

use std::fmt;

/// Why a mutation or query was refused.
///
/// Every fallible operation of the crate returns this type. A mutation that
/// returns an error leaves the index observably unchanged ([contract S2](crate::contract)): same
/// `len()`, same answers, `validate()` still passes.
///
/// ```
/// use bevy_rtree::{Aabb, SpatialError};
/// use bevy_rtree::glam::Vec3;
///
/// let inverted = Aabb::new(Vec3::ONE, Vec3::ZERO);
/// assert_eq!(inverted, Err(SpatialError::InvalidBox));
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum SpatialError {
    /// A box with a NaN or infinite coordinate, `min > max` on some axis, or a
    /// coordinate whose magnitude exceeds [`MAX_COORD`](crate::MAX_COORD).
    InvalidBox,
    /// A ray whose origin is not finite, whose direction is zero or not finite
    /// after canonicalisation, or whose `max_t` is negative or NaN.
    InvalidRay,
    /// A frustum with a NaN plane (but for Bevy's infinite far plane in
    /// `Frustum::from_bevy`, feature `bevy_camera`), a zero normal with a
    /// finite offset, or an
    /// eye position that is not finite or lies beyond
    /// [`MAX_COORD`](crate::MAX_COORD); for [`Frustum::perspective`](crate::Frustum::perspective),
    /// also a camera parameter out of its range or a zero or non-finite
    /// rotation.
    InvalidFrustum,
    /// A distance that is negative, NaN or infinite.
    InvalidDistance,
    /// A count that must be positive was zero (for example `k = 0` nearest).
    InvalidCount,
    /// A [`ProxyId`](crate::ProxyId) that does not name a live entry of this
    /// index (never issued, already removed, or from another index where
    /// it names none of this one's live entries: see `ProxyId`).
    UnknownProxy,
    /// A setting outside its documented range (for example a negative margin).
    InvalidSettings,
}

impl fmt::Display for SpatialError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let text = match self {
            SpatialError::InvalidBox => "invalid box: non-finite, inverted or beyond MAX_COORD",
            SpatialError::InvalidRay => {
                "invalid ray: non-finite origin, zero direction or bad max_t"
            }
            SpatialError::InvalidFrustum => {
                "invalid frustum: NaN plane, zero normal, non-finite eye or camera parameter out of range"
            }
            SpatialError::InvalidDistance => "invalid distance: must be finite and >= 0",
            SpatialError::InvalidCount => "invalid count: must be at least 1",
            SpatialError::UnknownProxy => "unknown proxy: not a live entry of this index",
            SpatialError::InvalidSettings => "invalid settings: value outside its documented range",
        };
        f.write_str(text)
    }
}

impl std::error::Error for SpatialError {}
