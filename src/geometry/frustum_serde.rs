//! A [`Frustum`] saved and loaded by serde (feature `reflect`, for Bevy's
//! scenes, which save reflected components through serde).
//!
//! A frustum is written as its eye and its six planes, each a normal and an
//! offset, `None` for an inactive plane: the inactive pattern's infinite
//! offset is a number that not every format can write (JSON cannot).
//! Loading goes through [`Frustum::new`], so a scene edited by hand into a
//! plane no frustum may have (a NaN, a zero normal) is refused with the
//! frustum's own error rather than loaded into a camera.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Frustum, HalfSpace};

/// One plane as written: `None` for an inactive plane, else its normal and
/// offset.
type SavedPlane = Option<([f32; 3], f32)>;

/// A frustum as written: its eye, then its six planes.
type SavedFrustum = ([f32; 3], [SavedPlane; 6]);

impl Serialize for Frustum {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let planes = self
            .planes()
            .map(|plane| (!plane.is_inactive()).then(|| (plane.normal.to_array(), plane.offset)));
        let saved: SavedFrustum = (self.eye().to_array(), planes);
        saved.serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for Frustum {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let (eye, planes) = SavedFrustum::deserialize(deserializer)?;
        let planes = planes.map(|plane| {
            plane.map_or(HalfSpace::INACTIVE, |(normal, offset)| HalfSpace {
                normal: normal.into(),
                offset,
            })
        });
        Frustum::new(eye.into(), planes).map_err(D::Error::custom)
    }
}
