//! The peers' side of each query: the contract's predicates restated for
//! parry3d and rstar (the conservative frustum test over the active planes,
//! the S4 ray test, the exact Euclidean join test), and each peer's query
//! written the way its own API serves it best.

use super::common::indexes::parry_node_box;
use super::common::{RstarBox, to_parry};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, Frustum, PreparedRay, Ray};
use glam::Vec3;
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode, BvhWorkspace, TraversalAction};
use parry3d::query::Ray as ParryRay;
use rstar::{AABB as RstarEnvelope, SelectionFunction};
use std::cell::Cell;
use std::ops::Range;

// The predicates of the contract (`docs/contract.md`) for the peers. Rays use the crate's own S4
// test (`PreparedRay`). The frustum test is restated over the active planes
// only, in the crate's operation order, so a peer's answer compares bit for
// bit and its traversal is not slowed by inactive planes; the brute force's
// slab loop is written out over lane blocks so that it vectorises.

/// A frustum's active planes, ready for the conservative test (S7).
#[derive(Clone, Copy)]
pub(crate) struct Planes {
    pub(crate) eye: Vec3,
    pub(crate) normal: [Vec3; 6],
    pub(crate) offset: [f32; 6],
    pub(crate) count: usize,
}

impl Planes {
    pub(crate) fn new(frustum: &Frustum) -> Planes {
        let mut planes = Planes {
            eye: frustum.eye(),
            normal: [Vec3::ZERO; 6],
            offset: [0.0; 6],
            count: 0,
        };
        for plane in frustum.planes().iter().filter(|p| !p.is_inactive()) {
            planes.normal[planes.count] = plane.normal;
            planes.offset[planes.count] = plane.offset;
            planes.count += 1;
        }
        planes
    }

    /// S7 conservative: the box corner furthest along each normal is strictly
    /// inside, evaluated relative to the eye in the crate's operation order.
    #[inline]
    pub(crate) fn visible(&self, min: Vec3, max: Vec3) -> bool {
        let e = self.eye;
        (0..self.count).all(|i| {
            let n = self.normal[i];
            let p = Vec3::select(n.cmpge(Vec3::ZERO), max, min);
            n.x * (p.x - e.x) + n.y * (p.y - e.y) + n.z * (p.z - e.z) + self.offset[i] > 0.0
        })
    }
}

/// A canonical ray with `1 / dir` spelled out for the vectorised brute
/// force, and the crate's own S4 test (`PreparedRay`) for the peers.
#[derive(Clone, Copy)]
pub(crate) struct RayPrep {
    pub(crate) origin: [f32; 3],
    pub(crate) dir: [f32; 3],
    pub(crate) inv: [f32; 3],
    pub(crate) max_t: f32,
    s4: PreparedRay,
}

impl RayPrep {
    pub(crate) fn new(ray: &Ray) -> RayPrep {
        let ray = ray.canonicalized().expect("the scene's rays are valid");
        let dir = ray.dir.to_array();
        RayPrep {
            origin: ray.origin.to_array(),
            dir,
            inv: dir.map(|d| if d == 0.0 { 0.0 } else { 1.0 / d }),
            max_t: ray.max_t,
            s4: ray.prepared().expect("the scene's rays are valid"),
        }
    }
}

/// S8: the gap between two boxes on one axis, in `f64`.
#[inline]
pub(crate) fn axis_gap(a: &Aabb, b: &Aabb, axis: usize) -> f64 {
    let g1 = a.min[axis] as f64 - b.max[axis] as f64;
    let g2 = b.min[axis] as f64 - a.max[axis] as f64;
    let mut g = 0.0;
    if g1 > g {
        g = g1;
    }
    if g2 > g {
        g = g2;
    }
    g
}

/// S8 exact mode: Euclidean box distance `<= d`, in `f64`.
#[inline]
pub(crate) fn within_euclidean(a: &Aabb, b: &Aabb, d: f64) -> bool {
    let mut sum = 0.0f64;
    for axis in 0..3 {
        let g = axis_gap(a, b, axis);
        sum += g * g;
    }
    sum <= d * d
}

// The peers' queries.

pub(crate) fn parry_visible_into(bvh: &Bvh, planes: &Planes, out: &mut Vec<u32>) {
    bvh.traverse(|node| {
        let (min, max) = parry_node_box(node);
        if !planes.visible(min, max) {
            return TraversalAction::Prune;
        }
        // Leaves hold exact boxes (margin 0): passing the test decides.
        if let Some(leaf) = node.leaf_data() {
            out.push(leaf);
        }
        TraversalAction::Continue
    });
}

pub(crate) struct RstarFrustum<'a>(&'a Planes);

impl SelectionFunction<RstarBox> for RstarFrustum<'_> {
    fn should_unpack_parent(&self, envelope: &RstarEnvelope<[f32; 3]>) -> bool {
        self.0.visible(
            Vec3::from_array(envelope.lower()),
            Vec3::from_array(envelope.upper()),
        )
    }

    fn should_unpack_leaf(&self, leaf: &RstarBox) -> bool {
        self.0.visible(
            Vec3::from_array(leaf.geom().lower()),
            Vec3::from_array(leaf.geom().upper()),
        )
    }
}

pub(crate) fn rstar_visible_into(
    tree: &rstar::RTree<RstarBox>,
    planes: &Planes,
    out: &mut Vec<u32>,
) {
    out.extend(
        tree.locate_with_selection_function(RstarFrustum(planes))
            .map(|item| item.data),
    );
}

pub(crate) fn parry_first_hit(bvh: &Bvh, boxes: &[Aabb], ray: &Ray) -> Option<(u32, f32)> {
    let prep = RayPrep::new(ray);
    let pray = ParryRay::new(
        ParryVector::from_array(prep.origin),
        ParryVector::from_array(prep.dir),
    );
    bvh.cast_ray(&pray, prep.max_t, |leaf, best| {
        let b = &boxes[leaf as usize];
        prep.s4.entry(b, best)
    })
}

/// rstar's ray search: the S4 test against envelopes and leaves with a limit
/// that the consumer shrinks to the best hit; the selection function
/// records the entry `t` of the leaf it lets through.
pub(crate) struct RstarRay<'a> {
    ray: &'a RayPrep,
    limit: &'a Cell<f32>,
    last_t: &'a Cell<f32>,
}

impl SelectionFunction<RstarBox> for RstarRay<'_> {
    fn should_unpack_parent(&self, envelope: &RstarEnvelope<[f32; 3]>) -> bool {
        self.ray
            .s4
            .entry(
                &from_corners(envelope.lower(), envelope.upper()),
                self.limit.get(),
            )
            .is_some()
    }

    fn should_unpack_leaf(&self, leaf: &RstarBox) -> bool {
        let g = leaf.geom();
        match self
            .ray
            .s4
            .entry(&from_corners(g.lower(), g.upper()), self.limit.get())
        {
            Some(t) => {
                self.last_t.set(t);
                true
            }
            None => false,
        }
    }
}

/// An rstar box as ours (no checks: it was built from one of ours).
pub(crate) fn from_corners(lower: [f32; 3], upper: [f32; 3]) -> Aabb {
    Aabb {
        min: Vec3::from_array(lower),
        max: Vec3::from_array(upper),
    }
}

pub(crate) fn rstar_first_hit(tree: &rstar::RTree<RstarBox>, ray: &Ray) -> Option<(u32, f32)> {
    let prep = RayPrep::new(ray);
    let limit = Cell::new(prep.max_t);
    let last_t = Cell::new(0.0);
    let mut best: Option<(u32, f32)> = None;
    let select = RstarRay {
        ray: &prep,
        limit: &limit,
        last_t: &last_t,
    };
    for item in tree.locate_with_selection_function(select) {
        let (key, t) = (item.data, last_t.get());
        if best.is_none_or(|(bk, bt)| t < bt || (t == bt && key < bk)) {
            best = Some((key, t));
            limit.set(t);
        }
    }
    best
}

/// parry3d's pair test for `leaf_pairs`: the nodes can be within `d` (their
/// gap on every axis is at most `d`). Rounding is monotone and `d` is an
/// `f32`, so a gap of at most `d` never rounds above it; the exact test
/// also accepts gaps above `d` by at most about 2^-49 of it, and those
/// round to `d` too (the next `f32` is 2^-24 of it away). So the test keeps
/// every pair the exact test accepts, in two vector subtractions and
/// compares.
pub(crate) fn parry_within(a: &BvhNode, b: &BvhNode, d: f32) -> bool {
    let (amin, amax) = parry_node_box(a);
    let (bmin, bmax) = parry_node_box(b);
    let reach = glam::Vec3::splat(d);
    (amin - bmax).cmple(reach).all() && (bmin - amax).cmple(reach).all()
}

/// The cross join as its target counts parry3d: build both `Bvh`s from
/// their leaves (binned), then join them.
pub(crate) fn parry_build_and_cross_join(
    enemy_leaves: &[ParryAabb],
    barrel_leaves: &[ParryAabb],
    boxes: &[Aabb],
    d: f32,
    out: &mut Vec<(u32, u32)>,
) {
    let enemies = Bvh::from_leaves(BvhBuildStrategy::Binned, enemy_leaves);
    let barrels = Bvh::from_leaves(BvhBuildStrategy::Binned, barrel_leaves);
    parry_cross_join(&enemies, &barrels, boxes, d, out);
}

pub(crate) fn parry_cross_join(
    enemies: &Bvh,
    barrels: &Bvh,
    boxes: &[Aabb],
    d: f32,
    out: &mut Vec<(u32, u32)>,
) {
    let (ea, ba) = (
        TownScene::ENEMIES.start as u32,
        TownScene::BARRELS.start as u32,
    );
    let exact = d as f64;
    for (i, j) in enemies.leaf_pairs(barrels, |a, b| parry_within(a, b, d)) {
        let (ka, kb) = (ea + i, ba + j);
        if ka != kb && within_euclidean(&boxes[ka as usize], &boxes[kb as usize], exact) {
            out.push((ka, kb));
        }
    }
}

pub(crate) fn rstar_cross_join(
    enemies_grown: &rstar::RTree<RstarBox>,
    barrels: &rstar::RTree<RstarBox>,
    boxes: &[Aabb],
    d: f32,
    out: &mut Vec<(u32, u32)>,
) {
    let exact = d as f64;
    for (a, b) in enemies_grown.intersection_candidates_with_other_tree(barrels) {
        let (ka, kb) = (a.data, b.data);
        if ka != kb && within_euclidean(&boxes[ka as usize], &boxes[kb as usize], exact) {
            out.push((ka, kb));
        }
    }
}

pub(crate) fn rstar_self_join(tree: &rstar::RTree<RstarBox>, d: f32, out: &mut Vec<(u32, u32)>) {
    // The stored boxes are exact and rstar's envelope test is closed, so at
    // d = 0 its candidates are the answer: no second test (bevy_rtree's
    // join makes none at d = 0 either).
    debug_assert_eq!(d, 0.0);
    for (a, b) in tree.intersection_candidates_with_other_tree(tree) {
        // Every pair comes twice and every item with itself: keep one.
        let (ka, kb) = (a.data, b.data);
        if ka < kb {
            out.push((ka, kb));
        }
    }
}

pub(crate) fn parry_self_join(
    bvh: &Bvh,
    workspace: &mut BvhWorkspace,
    d: f32,
    out: &mut Vec<(u32, u32)>,
) {
    // Leaves are exact (margin 0) and parry's overlap test is closed, so at
    // d = 0 the leaf pairs are the answer: no second test (bevy_rtree's
    // join makes none at d = 0 either).
    debug_assert_eq!(d, 0.0);
    bvh.traverse_bvtt_single_tree::<false>(workspace, &mut |a, b| {
        out.push((a.min(b), a.max(b)));
    });
}

/// parry3d's leaves for the boxes in `range`.
pub(crate) fn parry_leaves(boxes: &[Aabb], range: Range<usize>) -> Vec<ParryAabb> {
    boxes[range].iter().map(to_parry).collect()
}
