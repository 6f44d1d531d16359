//! How much the tree enlarges entry boxes, how it repairs churn, and how it
//! splits full nodes.

use glam::Vec3;

use super::SplitStrategy;
use crate::geometry::{Aabb, MAX_COORD, SpatialError};

/// Tuning of an [`RTree`](super::RTree). Every field has a documented range;
/// [`TreeSettings::validate`] enforces it.
///
/// The enlarged ("fat") box of an entry is its exact box grown on every side
/// by `margin + margin_fraction * extent` (per axis, in metres), and further
/// stretched along its last displacement by `displacement_factor` times that
/// displacement. A move whose new exact box stays inside the fat box costs
/// O(1) and changes nothing structural. Answers never use the fat box: every
/// query tests the exact box ([contract S2](crate::contract)), so these settings trade update
/// time against query work, never against correctness.
///
/// The stretch cannot run away: a displacement longer than
/// [`jump_limit`](Self::jump_limit) box sizes is a jump (a teleport, a
/// respawn), not motion, and gets no stretch, so no enlarged box reaches
/// more than `displacement_factor * jump_limit` box sizes ahead. A stretch
/// is replaced when the entry next leaves its enlarged box, and
/// [`RTree::rebuild`](super::RTree::rebuild) starts every entry afresh,
/// without stretch, so the stretch of an entry that slowed down or stopped
/// lasts until then. (Refitting such a stretch at its next move inside the
/// box cost a frame's moves on the standard scene 8 % when counted in the
/// entry's record and 25 % when judged from its previous box, for no change
/// there: steady movers use their stretch; see docs/performance.md.)
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
    ///
    /// The default, `4`: on the standard scene after 600 frames, 16 and 32
    /// cut a frame's update and repairs by 6–14 % and 16–22 %, but the
    /// fatter internal bounds made a self join visit 10–11 % and 19–23 %
    /// more node pairs, which cost it more time than the update saved
    /// (`cargo run --release --example accuracy_cost --features bevy_camera`).
    /// 8 saved 6–12 % of the update for 4 % more node pairs, about as much
    /// time again in a frame with a self join, and stretches a fast mover's
    /// box twice as far as 4 does.
    pub displacement_factor: f32,
    /// The longest displacement that counts as motion, in box sizes (the
    /// box's largest extent, or `margin` if that is larger). A longer move
    /// is a jump: its enlarged box gets no stretch, so a teleport across
    /// the world does not leave a box kilometres long behind for every
    /// later small move to stay inside, and a jump that leaves its leaf
    /// wears the tiling twice toward a rebuild
    /// ([`RTree::is_worn`](crate::RTree::is_worn)), as a respawn does.
    /// Range `[0, 1e4]`.
    ///
    /// The default, `2`: a vehicle at 30 m/s at 60 Hz moves 0.5 m a frame,
    /// one size of the standard scene's smallest boxes, so every mover of
    /// that scene keeps its stretch; a respawn hundreds of metres away is
    /// a jump for any box under a hundred metres.
    pub jump_limit: f32,
    /// How much churn a level-1 node absorbs before
    /// [`RTree::optimize`](super::RTree::optimize) repacks it: restructuring
    /// moves in its subtree, as a fraction of the entries it can hold
    /// (`W * W`), rounded up, at least one. Range `(0, 16]`.
    ///
    /// The default, `0.25`, means 16 moves at width 8 and 64 at width 16.
    /// Measured on the standard scene: at width 8, 16 moves kept churned box
    /// queries at 1.40–1.44 × the fresh tree's time against 1.52–1.61 × for
    /// 64 or 256; at width 16, 64 moves cut a frame's moves (with their
    /// repairs) from 0.65–0.71 ms to 0.51–0.53 ms against 16, with churned
    /// queries within the noise (11.0 nodes per query either way).
    /// Waiting for 256 moves (`1.0`) made a frame's moves 4–11 % cheaper
    /// in the tree bench (1.6 instead of 5.7 repacks per frame), but the
    /// churned tree's self join visited 7–9 % more node pairs (58,615
    /// against 54,706 after 600 frames, 62,259 against 57,324 after
    /// 4,000), about 0.35 ms more per join against 0.02–0.05 ms saved on
    /// the moves, and a cull 4–6 % more nodes: the default stays `0.25`.
    pub repack_fraction: f32,
    /// How an overflowing node divides its entries. Any strategy is valid.
    pub split: SplitStrategy,
}

impl Default for TreeSettings {
    fn default() -> Self {
        TreeSettings {
            margin: 0.1,
            margin_fraction: 0.0,
            displacement_factor: 4.0,
            jump_limit: 2.0,
            repack_fraction: 0.25,
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
            && in_range(self.jump_limit, 1e4)
            && self.repack_fraction.is_finite()
            && self.repack_fraction > 0.0
            && self.repack_fraction <= 16.0
        {
            Ok(())
        } else {
            Err(SpatialError::InvalidSettings)
        }
    }

    /// Restructuring moves a level-1 node of a width-`width` tree absorbs
    /// before it is queued for repacking.
    pub(crate) fn repack_threshold(&self, width: usize) -> u32 {
        let capacity = (width * width) as f32;
        ((self.repack_fraction * capacity).ceil() as u32).max(1)
    }

    /// The enlarged box for `exact` after a move by `displacement`, cut to
    /// `±MAX_COORD` so that it is a valid box too.
    ///
    /// Always contains `exact`: every term added to `max` (subtracted from
    /// `min`) is non-negative, f32 rounding of `x + y` with `y >= 0` never
    /// goes below `x`, and a valid `exact` lies within `±MAX_COORD`.
    #[inline]
    pub(crate) fn fatten(&self, exact: &Aabb, displacement: Vec3) -> Aabb {
        let grow = self.grow(exact);
        let ahead = self.stretch(exact, displacement);
        let limit = Vec3::splat(MAX_COORD);
        Aabb {
            min: (exact.min - grow + ahead.min(Vec3::ZERO)).max(-limit),
            max: (exact.max + grow + ahead.max(Vec3::ZERO)).min(limit),
        }
    }

    /// The enlargement on every side of `exact`, per axis.
    #[inline]
    fn grow(&self, exact: &Aabb) -> Vec3 {
        Vec3::splat(self.margin) + exact.extent() * self.margin_fraction
    }

    /// How far the enlarged box reaches ahead of a move by `displacement`:
    /// `displacement_factor` times it, or nothing for a jump (see
    /// [`TreeSettings::jump_limit`]).
    #[inline]
    fn stretch(&self, exact: &Aabb, displacement: Vec3) -> Vec3 {
        if self.is_jump(exact, displacement) {
            Vec3::ZERO
        } else {
            displacement * self.displacement_factor
        }
    }

    /// Whether a move of `exact` by `displacement` is a jump rather than
    /// motion (see [`TreeSettings::jump_limit`]).
    #[inline]
    pub(crate) fn is_jump(&self, exact: &Aabb, displacement: Vec3) -> bool {
        let size = exact.extent().max_element().max(self.margin);
        displacement.abs().max_element() > self.jump_limit * size
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_repack_threshold_scales_with_a_level_one_node_s_capacity() {
        let default = TreeSettings::default();
        assert_eq!(default.repack_threshold(8), 16);
        assert_eq!(default.repack_threshold(16), 64);
        let eager = TreeSettings {
            repack_fraction: f32::MIN_POSITIVE,
            ..default
        };
        assert_eq!(eager.repack_threshold(4), 1);
        let most = TreeSettings {
            repack_fraction: 16.0,
            ..default
        };
        assert_eq!(most.repack_threshold(16), 4096);
        assert!(most.validate().is_ok());
    }
}
