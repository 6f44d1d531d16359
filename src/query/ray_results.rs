//! The answers of a batch of rays, one slot per ray.

use std::ops::Range;

use super::ray::RayHit;
use crate::geometry::SpatialError;

/// The answers of a batch: slot `i` belongs to ray `i` ([contract S6](crate::contract)).
#[derive(Clone, Debug)]
pub struct RayResults<K> {
    pub(super) slots: Vec<Result<(Range<u32>, bool), SpatialError>>,
    pub(super) hits: Vec<RayHit<K>>,
}

// Not derived: an empty result needs no default key.
impl<K> Default for RayResults<K> {
    fn default() -> Self {
        RayResults {
            slots: Vec::new(),
            hits: Vec::new(),
        }
    }
}

impl<K: Copy> RayResults<K> {
    /// Number of slots (rays of the last batch).
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether the last batch was empty.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The hits of ray `i`, sorted by `(t, key)`: at most one in
    /// [`RayMode::First`], none in [`RayMode::Any`]. The ray's own error if
    /// it was invalid. Panics if `i` is out of range.
    ///
    /// [`RayMode::First`]: crate::RayMode::First
    /// [`RayMode::Any`]: crate::RayMode::Any
    pub fn hits(&self, i: usize) -> Result<&[RayHit<K>], SpatialError> {
        let (range, _) = self.slots[i].as_ref().map_err(|e| *e)?;
        Ok(&self.hits[range.start as usize..range.end as usize])
    }

    /// The first hit of ray `i` (in any mode but
    /// [`RayMode::Any`](crate::RayMode::Any)). Panics if `i` is out of
    /// range.
    pub fn first(&self, i: usize) -> Result<Option<RayHit<K>>, SpatialError> {
        Ok(self.hits(i)?.first().copied())
    }

    /// Appends the slots of `other` after this batch's slots.
    #[cfg(feature = "parallel")]
    pub(crate) fn append(&mut self, other: &RayResults<K>) {
        let offset = self.hits.len() as u32;
        self.hits.extend_from_slice(&other.hits);
        self.slots.extend(other.slots.iter().map(|slot| {
            slot.clone()
                .map(|(range, any)| (range.start + offset..range.end + offset, any))
        }));
    }

    /// Empties the results, keeping their memory.
    #[cfg(feature = "parallel")]
    pub(crate) fn clear(&mut self) {
        self.slots.clear();
        self.hits.clear();
    }

    /// Whether ray `i` hit anything (in every mode). Panics if `i` is out
    /// of range.
    pub fn any(&self, i: usize) -> Result<bool, SpatialError> {
        self.slots[i].as_ref().map(|(_, any)| *any).map_err(|e| *e)
    }
}
