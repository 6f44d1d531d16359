//! How much the tree enlarges entry boxes, how it repairs churn, and how it
//! splits full nodes.

use glam::Vec3;

use super::SplitStrategy;
use crate::geometry::{Aabb, SpatialError};

/// Tuning of an [`RTree`](super::RTree). Every field has a documented range;
/// [`TreeSettings::validate`] enforces it.
///
/// The enlarged ("fat") box of an entry is its exact box grown on every side
/// by `margin + margin_fraction * extent` (per axis, in metres), and further
/// stretched along its last displacement by `displacement_factor` times that
/// displacement. A move whose new exact box stays inside the fat box costs
/// O(1) and changes nothing structural. Answers never use the fat box: every
/// query tests the exact box (SEMANTICS S2), so these settings trade update
/// time against query work, never against correctness.
///
/// ```
/// use bevy_rtree::{RTree, TreeSettings};
///
/// let settings = TreeSettings { margin: 0.5, ..TreeSettings::default() };
/// let tree: RTree<u32> = RTree::with_settings(settings)?;
/// assert_eq!(tree.settings().margin, 0.5);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TreeSettings {
    /// Absolute enlargement on every side, in metres. Range `[0, 1e4]`.
    pub margin: f32,
    /// Enlargement on every side as a fraction of the box's extent on that
    /// axis. Range `[0, 10]`.
    pub margin_fraction: f32,
    /// How far, in multiples of the last displacement, the fat box reaches
    /// ahead of a moving entry in its direction of motion. Range `[0, 100]`.
    pub displacement_factor: f32,
    /// Restructuring moves a node's subtree absorbs before
    /// [`RTree::optimize`](super::RTree::optimize) repacks it. Range `>= 1`.
    pub repack_threshold: u32,
    /// How an overflowing node divides its entries. Any strategy is valid.
    pub split: SplitStrategy,
}

impl Default for TreeSettings {
    fn default() -> Self {
        TreeSettings {
            margin: 0.1,
            margin_fraction: 0.0,
            displacement_factor: 4.0,
            repack_threshold: 16,
            split: SplitStrategy::RStar,
        }
    }
}

impl TreeSettings {
    /// `Ok(())` when every field is in its documented range.
    pub fn validate(&self) -> Result<(), SpatialError> {
        let in_range = |v: f32, hi: f32| v.is_finite() && (0.0..=hi).contains(&v);
        if in_range(self.margin, 1e4)
            && in_range(self.margin_fraction, 10.0)
            && in_range(self.displacement_factor, 100.0)
            && self.repack_threshold >= 1
        {
            Ok(())
        } else {
            Err(SpatialError::InvalidSettings)
        }
    }

    /// The enlarged box for `exact` after a move by `displacement`.
    ///
    /// Always contains `exact`: every term added to `max` (subtracted from
    /// `min`) is non-negative, and f32 rounding of `x + y` with `y >= 0` never
    /// goes below `x`.
    #[inline]
    pub(crate) fn fatten(&self, exact: &Aabb, displacement: Vec3) -> Aabb {
        let grow = Vec3::splat(self.margin) + exact.extent() * self.margin_fraction;
        let ahead = displacement * self.displacement_factor;
        Aabb {
            min: exact.min - grow + ahead.min(Vec3::ZERO),
            max: exact.max + grow + ahead.max(Vec3::ZERO),
        }
    }
}
