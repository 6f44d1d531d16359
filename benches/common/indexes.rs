//! The indexes the query benches maintain through the scene's frames, the
//! way a game keeps them. Each covers the entities of `range`; keys are
//! entity indices, parry3d leaf indices are entity index minus
//! `range.start`.

use std::ops::Range;

use bevy_rtree::{Aabb, ProxyId, RTree};
use glam::Vec3;
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode, BvhWorkspace};

use super::{RstarBox, to_parry, to_rstar};

/// `aabb` grown by `d` on every side, rounded outward, so that an overlap
/// test against it never dismisses a pair within `d`.
pub fn grown(aabb: &Aabb, d: f32) -> Aabb {
    Aabb {
        min: Vec3::from_array((aabb.min - Vec3::splat(d)).to_array().map(f32::next_down)),
        max: Vec3::from_array((aabb.max + Vec3::splat(d)).to_array().map(f32::next_up)),
    }
}

/// A parry3d node's box as two corners.
pub fn parry_node_box(node: &BvhNode) -> (Vec3, Vec3) {
    (
        Vec3::from_array(node.mins().to_array()),
        Vec3::from_array(node.maxs().to_array()),
    )
}

pub struct BevyIndex {
    pub tree: RTree<u32>,
    pub ids: Vec<ProxyId>,
    pub range: Range<usize>,
}

impl BevyIndex {
    pub fn new(boxes: &[Aabb], range: Range<usize>) -> Self {
        let mut tree = RTree::new();
        let ids = tree
            .insert_bulk(range.clone().map(|i| (i as u32, boxes[i])))
            .expect("scene boxes are valid");
        BevyIndex { tree, ids, range }
    }

    pub fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) {
        for &i in moved {
            let i = i as usize;
            if self.range.contains(&i) {
                self.tree
                    .update(self.ids[i - self.range.start], boxes[i])
                    .expect("scene boxes are valid");
            }
        }
        self.tree.optimize(usize::MAX);
    }
}

pub struct ParryIndex {
    pub bvh: Bvh,
    pub workspace: BvhWorkspace,
    pub range: Range<usize>,
}

impl ParryIndex {
    pub fn new(boxes: &[Aabb], range: Range<usize>) -> Self {
        let leaves: Vec<ParryAabb> = boxes[range.clone()].iter().map(to_parry).collect();
        ParryIndex {
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves),
            workspace: BvhWorkspace::default(),
            range,
        }
    }

    pub fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) {
        for &i in moved {
            let i = i as usize;
            if self.range.contains(&i) {
                let leaf = (i - self.range.start) as u32;
                self.bvh
                    .insert_or_update_partially(to_parry(&boxes[i]), leaf, 0.0);
            }
        }
        self.bvh.refit(&mut self.workspace);
        self.bvh.optimize_incremental(&mut self.workspace);
    }
}

pub struct RstarIndex {
    pub tree: rstar::RTree<RstarBox>,
    /// The item each entity has in the tree now (`remove` needs it).
    pub current: Vec<RstarBox>,
    pub range: Range<usize>,
    /// Every stored box is the entity's box grown by this (0: exact).
    pub grow: f32,
}

impl RstarIndex {
    pub fn item(aabb: &Aabb, key: usize, grow: f32) -> RstarBox {
        let stored = if grow > 0.0 { grown(aabb, grow) } else { *aabb };
        to_rstar(&stored, key as u32)
    }

    pub fn new(boxes: &[Aabb], range: Range<usize>, grow: f32) -> Self {
        let current: Vec<RstarBox> = range
            .clone()
            .map(|i| Self::item(&boxes[i], i, grow))
            .collect();
        RstarIndex {
            tree: rstar::RTree::bulk_load(current.clone()),
            current,
            range,
            grow,
        }
    }

    pub fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) {
        for &i in moved {
            let i = i as usize;
            if self.range.contains(&i) {
                let new = Self::item(&boxes[i], i, self.grow);
                let old = std::mem::replace(&mut self.current[i - self.range.start], new);
                assert!(self.tree.remove(&old).is_some(), "rstar lost entity {i}");
                self.tree.insert(new);
            }
        }
    }
}
