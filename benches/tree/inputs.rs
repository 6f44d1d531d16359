//! The scene's boxes as each contender takes them, the query boxes, the
//! trees every group starts from, and the contenders' sorted answers held
//! to the oracle's.

use super::QUERY_HALF_EXTENT;
use super::common::{RstarBox, sorted, to_parry, to_rstar};
use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::{SceneRng, WORLD_MAX};
use bevy_rtree::{Aabb, ProxyId, RTree, TreeSettings};
use glam::Vec3;
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::partitioning::Bvh;
use rstar::AABB as RstarEnvelope;

pub(crate) fn rstar_envelope(aabb: &Aabb) -> RstarEnvelope<[f32; 3]> {
    RstarEnvelope::from_corners(aabb.min.to_array(), aabb.max.to_array())
}

pub(crate) fn keyed(boxes: &[Aabb]) -> Vec<(u32, Aabb)> {
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| (i as u32, *b))
        .collect()
}

pub(crate) fn rstar_items(boxes: &[Aabb]) -> Vec<RstarBox> {
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| to_rstar(b, i as u32))
        .collect()
}

pub(crate) fn parry_leaves(boxes: &[Aabb]) -> Vec<ParryAabb> {
    boxes.iter().map(to_parry).collect()
}

pub(crate) fn oracle_of(boxes: &[Aabb]) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    oracle
}

/// Deterministic query boxes: centres uniform in the world volume, a
/// `QUERY_HALF_EXTENT` cube around each, clamped to the world in y.
pub(crate) fn query_boxes(count: usize, seed: u64) -> Vec<Aabb> {
    let mut rng = SceneRng::new(seed);
    (0..count)
        .map(|_| {
            let c = rng.point_in_world();
            let mut min = c - Vec3::splat(QUERY_HALF_EXTENT);
            let mut max = c + Vec3::splat(QUERY_HALF_EXTENT);
            min.y = min.y.max(0.0);
            max.y = max.y.min(WORLD_MAX.y);
            Aabb::new(min, max).expect("query boxes are valid")
        })
        .collect()
}

pub(crate) fn bulk_tree(boxes: &[Aabb]) -> (RTree<u32>, Vec<ProxyId>) {
    bulk_tree_with(boxes, TreeSettings::default())
}

pub(crate) fn bulk_tree_with(boxes: &[Aabb], settings: TreeSettings) -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::with_settings(settings).expect("valid settings");
    let ids = tree
        .insert_bulk(keyed(boxes))
        .expect("scene boxes are valid");
    (tree, ids)
}

// Correctness helpers: sorted answers of each contender.

pub(crate) fn answer_rstar(tree: &rstar::RTree<RstarBox>, q: &Aabb) -> Vec<u32> {
    sorted(
        tree.locate_in_envelope_intersecting(rstar_envelope(q))
            .map(|g| g.data)
            .collect(),
    )
}

pub(crate) fn answer_parry(bvh: &Bvh, q: &Aabb) -> Vec<u32> {
    let pq = to_parry(q);
    sorted(bvh.intersect_aabb(&pq).collect())
}

/// Panics with a readable message when `got` differs from the oracle.
pub(crate) fn assert_same(who: &str, q: &Aabb, got: &[u32], want: &[u32]) {
    if got != want {
        let missing: Vec<_> = want.iter().filter(|k| !got.contains(k)).collect();
        let extra: Vec<_> = got.iter().filter(|k| !want.contains(k)).collect();
        panic!(
            "{who} disagrees with the oracle on {q:?}: {} vs {} ids; missing {missing:?}, extra {extra:?}",
            got.len(),
            want.len()
        );
    }
}
