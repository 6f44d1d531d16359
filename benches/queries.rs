//! The frame's queries on the standard "town" scene
//! (`bevy_rtree::scene::TownScene`, 100,000 entities), single-threaded,
//! `bevy_rtree` side by side with parry3d 0.31 (`partitioning::Bvh`), rstar
//! 0.14 and a brute-force loop over a structure-of-arrays box list.
//!
//! Every index is first *maintained* through `WARM_FRAMES` frames of the
//! scene's movement (10 % of the entities move each frame), the way a game
//! keeps it, so the queries run on updated trees, not freshly loaded ones:
//! - bevy_rtree: `update` per moved entity, then `optimize`;
//! - parry3d: `insert_or_update_partially` (margin 0, so leaves hold exact
//!   boxes and need no filtering), then `refit` and `optimize_incremental`
//!   (the latter keeps its tree at its best quality, which can only favour
//!   parry3d);
//! - rstar: `remove` + `insert` per moved entity.
//!
//! Groups (one iteration = one operation of one frame):
//! - `queries/frustum`: cull the standard camera, conservative mode
//!   (SEMANTICS S7). Iterations cycle through the camera's 60 yaws. parry3d
//!   and rstar test every visited node against the planes (their traversal
//!   APIs carry no per-node plane mask).
//! - `queries/rays_incoherent`: 1,000 incoherent rays, first hit (S4/S5);
//!   iterations cycle through `INCOHERENT_BATCHES` batches.
//!   `bevy_rtree` is the batched `cast_rays`; `bevy_rtree_single` a loop of
//!   `cast_ray`. parry3d is `Bvh::cast_ray` (best-first). rstar has no ray
//!   API: it is `locate_with_selection_function` with the S4 slab test and a
//!   limit that shrinks to the best hit found so far.
//! - `queries/rays_coherent`: 1,000 rays from the eye through a 40 x 25 grid,
//!   first hit; iterations cycle through `COHERENT_VIEWS` yaws. The eye sits
//!   inside scene boxes, so every first hit is at `t = 0`: the group measures
//!   how fast a traversal settles a tie at the origin (S5 breaks it by key).
//!   `cast_rays` answers such a batch from one point query at the shared
//!   origin, so this group mostly times that shortcut.
//! - `queries/rays_coherent_clear_eye`: the same ray grids from the nearest
//!   point above the eye that no box contains, so that every ray walks the
//!   tree: the coherent traversal itself.
//! - `queries/cross_join`: enemies (0..10k) x barrels (10k..15k) within 5 m,
//!   Euclidean (S8). bevy_rtree joins two trees maintained from frame to
//!   frame. `parry3d_with_build` builds its two `Bvh`s (binned) every
//!   iteration then runs `leaf_pairs`: the setup the cross join's target is
//!   set against; `parry3d_maintained` runs `leaf_pairs` on two maintained
//!   `Bvh`s, for information. rstar runs `intersection_candidates_with_other_tree` on a
//!   maintained tree of enemy boxes grown by 5 m and one of barrels. All
//!   peers filter candidates with the exact Euclidean test. brute_force is a
//!   sort-and-sweep on x.
//! - `queries/self_join`: all touching or overlapping pairs (d = 0) of the
//!   100k entities. parry3d: `traverse_bvtt_single_tree`; rstar:
//!   `intersection_candidates_with_other_tree` of the tree with itself;
//!   brute_force: sort-and-sweep on x.
//!
//! Before any timing every contender's answers are compared with the oracle
//! (`bevy_rtree::oracle::BruteForce`) on every input that is timed: sorted
//! keys or pairs must be equal, and for rays the hit key and `t` must be
//! equal bit for bit. parry3d's best-first search keeps the first of several
//! hits at the same `t`, so on such a tie it may name another key than the
//! smallest: that is accepted (and counted) when that key is also hit at
//! exactly that `t`. Anything else panics.
//!
//! After the groups, `paired_ratios` times bevy_rtree and parry3d once more
//! for each target, in alternating short blocks, so that both see the same
//! state of a shared machine (`common/paired.rs`), and prints the ratio's
//! median and range over the rounds; the table is also written to
//! `target/criterion/queries_paired_ratios.md`.
//!
//! Reading the output: `time: [lo mid hi]` is criterion's estimate for one
//! iteration (the middle number is the point estimate); compare contenders
//! within a group, never across runs or machines. The median of each
//! contender is under `"median"` in
//! `target/criterion/queries_<group>/<contender>/new/estimates.json`.
//! The check phase prints, per query, the answer sizes and bevy_rtree's
//! `QueryStats` (nodes visited, entries tested).

use std::cell::Cell;
use std::ops::Range;
use std::time::{Duration, Instant};

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, PreparedRay, QueryWorkspace, Ray, RayHit, RayMode,
    RayResults,
};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use glam::Vec3;
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhNode, BvhWorkspace, TraversalAction};
use parry3d::query::Ray as ParryRay;
use rstar::{AABB as RstarEnvelope, SelectionFunction};

mod common;
use common::indexes::{BevyIndex, ParryIndex, RstarIndex, parry_node_box};
use common::{RstarBox, bench_answers, bench_list, sorted, to_parry};

/// The scene's seed (the same as the other benchmark's).
const SEED: u64 = 0x5EED_2024;
/// Frames of movement applied to every index before checking and timing:
/// one full turn of the camera, whose frustums are the ones timed.
const WARM_FRAMES: u64 = 60;
/// Camera yaws whose coherent ray grids are timed (checking a batch against
/// the oracle costs 1,000 x 100,000 box tests, so only a few are used).
const COHERENT_VIEWS: usize = 4;
/// Batches of incoherent rays timed, for the same reason.
const INCOHERENT_BATCHES: usize = 4;
/// Rays per incoherent batch.
const RAYS_PER_BATCH: usize = 1_000;
/// The self join's distance: touching or overlapping pairs.
const SELF_JOIN_DISTANCE: f32 = 0.0;

// ---------------------------------------------------------------------------
// The predicates of the contract (`docs/contract.md`) for the peers. Rays use the crate's own S4
// test (`PreparedRay`). The frustum test is restated over the active planes
// only, in the crate's operation order, so a peer's answer compares bit for
// bit and its traversal is not slowed by inactive planes; the brute force's
// slab loop is written out over lane blocks so that it vectorises.

/// A frustum's active planes, ready for the conservative test (S7).
#[derive(Clone, Copy)]
struct Planes {
    eye: Vec3,
    normal: [Vec3; 6],
    offset: [f32; 6],
    count: usize,
}

impl Planes {
    fn new(frustum: &Frustum) -> Planes {
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
    fn visible(&self, min: Vec3, max: Vec3) -> bool {
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
struct RayPrep {
    origin: [f32; 3],
    dir: [f32; 3],
    inv: [f32; 3],
    max_t: f32,
    s4: PreparedRay,
}

impl RayPrep {
    fn new(ray: &Ray) -> RayPrep {
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
fn axis_gap(a: &Aabb, b: &Aabb, axis: usize) -> f64 {
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
fn within_euclidean(a: &Aabb, b: &Aabb, d: f64) -> bool {
    let mut sum = 0.0f64;
    for axis in 0..3 {
        let g = axis_gap(a, b, axis);
        sum += g * g;
    }
    sum <= d * d
}

// ---------------------------------------------------------------------------
// The brute-force contender: structure-of-arrays boxes, padded to whole
// blocks with inverted boxes (which every predicate rejects), so the lane
// loops have no tail and vectorise.

const LANES: usize = 16;

/// One coordinate of `LANES` boxes: a fixed-size block, so the lane loops
/// have a known length and no bounds checks.
type Block = [f32; LANES];

struct SoaBoxes {
    /// `min[axis][block][lane]`, likewise `max`.
    min: [Vec<Block>; 3],
    max: [Vec<Block>; 3],
}

impl SoaBoxes {
    fn new(boxes: &[Aabb]) -> Self {
        let blocks = boxes.len().div_ceil(LANES);
        let inverted = Aabb {
            min: Vec3::splat(f32::INFINITY),
            max: Vec3::splat(f32::NEG_INFINITY),
        };
        let mut soa = SoaBoxes {
            min: std::array::from_fn(|_| vec![[0.0; LANES]; blocks]),
            max: std::array::from_fn(|_| vec![[0.0; LANES]; blocks]),
        };
        for i in 0..blocks * LANES {
            let b = boxes.get(i).unwrap_or(&inverted);
            for axis in 0..3 {
                soa.min[axis][i / LANES][i % LANES] = b.min[axis];
                soa.max[axis][i / LANES][i % LANES] = b.max[axis];
            }
        }
        soa
    }

    fn blocks(&self) -> usize {
        self.min[0].len()
    }

    /// Appends the indices of the boxes visible in `planes` (S7 conservative).
    fn visible_into(&self, planes: &Planes, out: &mut Vec<u32>) {
        let e = planes.eye;
        for block in 0..self.blocks() {
            // Per-lane flags first, the bit mask once per block: a shape the
            // compiler turns into packed compares.
            let mut keep = [true; LANES];
            for i in 0..planes.count {
                let n = planes.normal[i];
                // The p-vertex: per axis the max where the normal is >= 0.
                let pick = |axis: usize, positive: bool| -> &Block {
                    if positive {
                        &self.max[axis][block]
                    } else {
                        &self.min[axis][block]
                    }
                };
                let (px, py, pz) = (
                    pick(0, n.x >= 0.0),
                    pick(1, n.y >= 0.0),
                    pick(2, n.z >= 0.0),
                );
                for j in 0..LANES {
                    let v = n.x * (px[j] - e.x)
                        + n.y * (py[j] - e.y)
                        + n.z * (pz[j] - e.z)
                        + planes.offset[i];
                    keep[j] &= v > 0.0;
                }
            }
            let mut mask = 0u32;
            for (j, &k) in keep.iter().enumerate() {
                mask |= (k as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out.push((block * LANES + j) as u32);
            }
        }
    }

    /// The first hit `(key, t)` of one ray: the smallest `(t, key)`. Blocks
    /// are visited in key order, so a strictly smaller `t` is needed to
    /// replace the best, and the limit is the best `t` (closed, S5).
    fn first_hit(&self, ray: &RayPrep) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        let mut limit = ray.max_t;
        for block in 0..self.blocks() {
            let mut lo: Block = [0.0; LANES];
            let mut hi: Block = [limit; LANES];
            let mut slab_ok = [true; LANES];
            for axis in 0..3 {
                let o = ray.origin[axis];
                let (min, max) = (&self.min[axis][block], &self.max[axis][block]);
                if ray.dir[axis] == 0.0 {
                    for j in 0..LANES {
                        slab_ok[j] &= !(o < min[j] || o > max[j]);
                    }
                    continue;
                }
                let inv = ray.inv[axis];
                let (near, far) = if inv > 0.0 { (min, max) } else { (max, min) };
                for j in 0..LANES {
                    let t0 = (near[j] - o) * inv;
                    let t1 = (far[j] - o) * inv;
                    // Explicit selects, as S4 writes them.
                    lo[j] = if t0 > lo[j] { t0 } else { lo[j] };
                    hi[j] = if t1 < hi[j] { t1 } else { hi[j] };
                }
            }
            let mut mask = 0u32;
            for j in 0..LANES {
                mask |= ((slab_ok[j] & (lo[j] <= hi[j])) as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if best.is_none_or(|(_, t)| lo[j] < t) {
                    best = Some(((block * LANES + j) as u32, lo[j]));
                    limit = lo[j];
                }
            }
        }
        best
    }
}

/// The brute-force joins: sort-and-sweep on x, buffers kept between frames.
#[derive(Default)]
struct Sweep {
    order_a: Vec<u32>,
    order_b: Vec<u32>,
}

impl Sweep {
    /// Self join: sort by `min.x`; each box meets the boxes after it until
    /// their `min.x` alone is more than `d` past its `max.x`.
    fn self_join(&mut self, boxes: &[Aabb], d: f32, out: &mut Vec<(u32, u32)>) {
        let order = &mut self.order_a;
        order.clear();
        order.extend(0..boxes.len() as u32);
        order
            .sort_unstable_by(|&a, &b| boxes[a as usize].min.x.total_cmp(&boxes[b as usize].min.x));
        let exact = d as f64;
        for (i, &a) in order.iter().enumerate() {
            let ba = &boxes[a as usize];
            for &b in &order[i + 1..] {
                let bb = &boxes[b as usize];
                if bb.min.x as f64 - ba.max.x as f64 > exact {
                    break;
                }
                if within_euclidean(ba, bb, exact) {
                    out.push((a.min(b), a.max(b)));
                }
            }
        }
    }

    /// Cross join: sort `b` by `min.x`; for each box of `a` scan the `b`s
    /// whose `min.x` can be within `d` (from `a.min.x - d - widest b` to
    /// `a.max.x + d`).
    fn cross_join(
        &mut self,
        boxes: &[Aabb],
        a: Range<usize>,
        b: Range<usize>,
        d: f32,
        out: &mut Vec<(u32, u32)>,
    ) {
        let order = &mut self.order_b;
        order.clear();
        order.extend(b.start as u32..b.end as u32);
        order
            .sort_unstable_by(|&x, &y| boxes[x as usize].min.x.total_cmp(&boxes[y as usize].min.x));
        let widest = order
            .iter()
            .map(|&i| boxes[i as usize].max.x as f64 - boxes[i as usize].min.x as f64)
            .fold(0.0f64, f64::max);
        let exact = d as f64;
        for ia in a {
            let ba = &boxes[ia];
            let from = ba.min.x as f64 - exact - widest;
            let start = order.partition_point(|&i| (boxes[i as usize].min.x as f64) < from);
            for &ib in &order[start..] {
                let bb = &boxes[ib as usize];
                if bb.min.x as f64 - ba.max.x as f64 > exact {
                    break;
                }
                if ia as u32 != ib && within_euclidean(ba, bb, exact) {
                    out.push((ia as u32, ib));
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------
// The peers' queries.

fn parry_visible_into(bvh: &Bvh, planes: &Planes, out: &mut Vec<u32>) {
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

struct RstarFrustum<'a>(&'a Planes);

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

fn rstar_visible_into(tree: &rstar::RTree<RstarBox>, planes: &Planes, out: &mut Vec<u32>) {
    out.extend(
        tree.locate_with_selection_function(RstarFrustum(planes))
            .map(|item| item.data),
    );
}

fn parry_first_hit(bvh: &Bvh, boxes: &[Aabb], ray: &Ray) -> Option<(u32, f32)> {
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
struct RstarRay<'a> {
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
fn from_corners(lower: [f32; 3], upper: [f32; 3]) -> Aabb {
    Aabb {
        min: Vec3::from_array(lower),
        max: Vec3::from_array(upper),
    }
}

fn rstar_first_hit(tree: &rstar::RTree<RstarBox>, ray: &Ray) -> Option<(u32, f32)> {
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
/// `f32`, so a gap of at most `d` never rounds above it: the test keeps
/// every pair within `d`, in two vector subtractions and compares.
fn parry_within(a: &BvhNode, b: &BvhNode, d: f32) -> bool {
    let (amin, amax) = parry_node_box(a);
    let (bmin, bmax) = parry_node_box(b);
    let reach = glam::Vec3::splat(d);
    (amin - bmax).cmple(reach).all() && (bmin - amax).cmple(reach).all()
}

/// The cross join as its target counts parry3d: build both `Bvh`s from
/// their leaves (binned), then join them.
fn parry_build_and_cross_join(
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

fn parry_cross_join(
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

fn rstar_cross_join(
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

fn rstar_self_join(tree: &rstar::RTree<RstarBox>, d: f32, out: &mut Vec<(u32, u32)>) {
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

fn parry_self_join(bvh: &Bvh, workspace: &mut BvhWorkspace, d: f32, out: &mut Vec<(u32, u32)>) {
    // Leaves are exact (margin 0) and parry's overlap test is closed, so at
    // d = 0 the leaf pairs are the answer: no second test (bevy_rtree's
    // join makes none at d = 0 either).
    debug_assert_eq!(d, 0.0);
    bvh.traverse_bvtt_single_tree::<false>(workspace, &mut |a, b| {
        out.push((a.min(b), a.max(b)));
    });
}

// ---------------------------------------------------------------------------
// Checks.

/// Panics with the first differences when `got` (sorted) is not `want`.
fn assert_same<T: Ord + std::fmt::Debug>(who: &str, what: &str, got: &[T], want: &[T]) {
    if got != want {
        let missing: Vec<_> = want
            .iter()
            .filter(|k| got.binary_search(k).is_err())
            .take(10)
            .collect();
        let extra: Vec<_> = got
            .iter()
            .filter(|k| want.binary_search(k).is_err())
            .take(10)
            .collect();
        panic!(
            "{who} disagrees with the oracle on {what}: {} answers vs {}; first missing {missing:?}, first extra {extra:?}",
            got.len(),
            want.len()
        );
    }
}

/// Compares one ray's first hit with the oracle's sorted hits. With
/// `tie_ok`, another key hit at exactly the first `t` is accepted; returns
/// whether that happened.
fn check_ray(
    who: &str,
    ray_index: usize,
    got: Option<(u32, f32)>,
    hits: &[RayHit<u32>],
    tie_ok: bool,
) -> bool {
    let want = hits.first().map(|h| (h.key, h.t));
    let same = |a: Option<(u32, f32)>, b: Option<(u32, f32)>| match (a, b) {
        (None, None) => true,
        (Some((ka, ta)), Some((kb, tb))) => ka == kb && ta.to_bits() == tb.to_bits(),
        _ => false,
    };
    if same(got, want) {
        return false;
    }
    if tie_ok
        && let (Some((key, t)), Some((_, first_t))) = (got, want)
        && t.to_bits() == first_t.to_bits()
        && hits
            .iter()
            .take_while(|h| h.t == first_t)
            .any(|h| h.key == key)
    {
        return true;
    }
    panic!("{who} disagrees with the oracle on ray {ray_index}: got {got:?}, want {want:?}");
}

fn hit_pair(hit: Option<RayHit<u32>>) -> Option<(u32, f32)> {
    hit.map(|h| (h.key, h.t))
}

// ---------------------------------------------------------------------------
// The benchmark.

struct Contenders {
    boxes: Vec<Aabb>,
    bevy: BevyIndex,
    bevy_enemies: BevyIndex,
    bevy_barrels: BevyIndex,
    parry: ParryIndex,
    parry_enemies: ParryIndex,
    parry_barrels: ParryIndex,
    rstar: RstarIndex,
    rstar_enemies_grown: RstarIndex,
    rstar_barrels: RstarIndex,
    soa: SoaBoxes,
    frustums: Vec<Frustum>,
    coherent: Vec<Vec<Ray>>,
    /// `coherent` from the lowest point above the eye inside no box.
    coherent_clear_eye: Vec<Vec<Ray>>,
    incoherent: Vec<Vec<Ray>>,
}

fn n() -> usize {
    TownScene::STANDARD_COUNT
}

/// Loads the scene into every index, then runs `WARM_FRAMES` frames of
/// movement through all of them, collecting each frame's camera.
fn setup() -> Contenders {
    let start = Instant::now();
    let mut scene = TownScene::new(n(), SEED);
    let boxes = scene.boxes();
    let d = TownScene::JOIN_DISTANCE;
    let mut c = Contenders {
        bevy: BevyIndex::new(boxes, 0..n()),
        bevy_enemies: BevyIndex::new(boxes, TownScene::ENEMIES),
        bevy_barrels: BevyIndex::new(boxes, TownScene::BARRELS),
        parry: ParryIndex::new(boxes, 0..n()),
        parry_enemies: ParryIndex::new(boxes, TownScene::ENEMIES),
        parry_barrels: ParryIndex::new(boxes, TownScene::BARRELS),
        rstar: RstarIndex::new(boxes, 0..n(), 0.0),
        rstar_enemies_grown: RstarIndex::new(boxes, TownScene::ENEMIES, d),
        rstar_barrels: RstarIndex::new(boxes, TownScene::BARRELS, 0.0),
        soa: SoaBoxes::new(boxes),
        boxes: Vec::new(),
        frustums: Vec::new(),
        coherent: Vec::new(),
        coherent_clear_eye: Vec::new(),
        incoherent: Vec::new(),
    };
    let views_every = WARM_FRAMES as usize / COHERENT_VIEWS;
    for frame in 1..=WARM_FRAMES as usize {
        scene.advance_frame();
        let (moved, boxes) = (scene.moved(), scene.boxes());
        c.bevy.apply(moved, boxes);
        c.bevy_enemies.apply(moved, boxes);
        c.bevy_barrels.apply(moved, boxes);
        c.parry.apply(moved, boxes);
        c.parry_enemies.apply(moved, boxes);
        c.parry_barrels.apply(moved, boxes);
        c.rstar.apply(moved, boxes);
        c.rstar_enemies_grown.apply(moved, boxes);
        c.rstar_barrels.apply(moved, boxes);
        c.frustums.push(scene.frustum());
        if frame % views_every == 0 {
            c.coherent.push(scene.coherent_rays());
        }
    }
    c.boxes = scene.boxes().to_vec();
    c.soa = SoaBoxes::new(&c.boxes);
    let eye = scene.clear_eye();
    c.coherent_clear_eye = c
        .coherent
        .iter()
        .map(|rays| rays.iter().map(|&ray| Ray { origin: eye, ..ray }).collect())
        .collect();
    // From a copy: drawing rays advances the scene's generator.
    let mut rays_from = scene.clone();
    c.incoherent = (0..INCOHERENT_BATCHES)
        .map(|_| rays_from.incoherent_rays(RAYS_PER_BATCH))
        .collect();
    for tree in [&c.bevy, &c.bevy_enemies, &c.bevy_barrels] {
        tree.tree.validate().expect("bevy_rtree invariants hold");
    }
    eprintln!(
        "setup: {n} entities, {WARM_FRAMES} frames of movement applied to every index in {:.1} s; bevy_rtree height {}, nodes {}",
        start.elapsed().as_secs_f64(),
        c.bevy.tree.height(),
        c.bevy.tree.node_count(),
        n = n(),
    );
    c
}

fn oracle_of(boxes: &[Aabb], range: Range<usize>) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for i in range {
        oracle.insert(i as u32, boxes[i]);
    }
    oracle
}

/// Compares every contender with the oracle on every timed input, and prints
/// the answer sizes and bevy_rtree's work per query.
fn check(c: &Contenders) {
    let start = Instant::now();
    let boxes = &c.boxes;
    let oracle = oracle_of(boxes, 0..n());
    let mut ws = QueryWorkspace::default();
    let per = |total: u64, count: usize| total as f64 / count as f64;

    // Frustums.
    let mut visible = 0usize;
    for (f, frustum) in c.frustums.iter().enumerate() {
        let what = format!("frustum of frame {}", f + 1);
        let want = oracle.visible(frustum, CullMode::Conservative);
        visible += want.len();
        let mut out = vec![Vec::new()];
        c.bevy.tree.visible_into(
            std::slice::from_ref(frustum),
            CullMode::Conservative,
            &mut ws,
            &mut out,
        );
        let got = out.pop().unwrap_or_default();
        assert_same("bevy_rtree", &what, &sorted(got), &want);
        let planes = Planes::new(frustum);
        let mut got = Vec::new();
        parry_visible_into(&c.parry.bvh, &planes, &mut got);
        assert_same("parry3d", &what, &sorted(got), &want);
        let mut got = Vec::new();
        rstar_visible_into(&c.rstar.tree, &planes, &mut got);
        assert_same("rstar", &what, &sorted(got), &want);
        let mut got = Vec::new();
        c.soa.visible_into(&planes, &mut got);
        assert_same("brute_force", &what, &got, &want);
    }
    let s = ws.take_stats();
    let views = c.frustums.len();
    eprintln!(
        "check frustum ok: {views} views, {:.0} visible per view; bevy_rtree per view: {:.0} nodes visited, {:.0} entries tested",
        per(visible as u64, views),
        per(s.nodes_visited, views),
        per(s.entries_tested, views)
    );

    // Rays.
    let kinds = [
        ("incoherent", &c.incoherent),
        ("coherent", &c.coherent),
        ("coherent, clear eye", &c.coherent_clear_eye),
    ];
    for (kind, batches) in kinds {
        let (mut hits, mut at_zero, mut parry_ties) = (0usize, 0usize, 0usize);
        let mut single_ws = QueryWorkspace::default();
        let mut results = RayResults::default();
        let rays_total: usize = batches.iter().map(Vec::len).sum();
        for rays in batches.iter() {
            c.bevy
                .tree
                .cast_rays(rays, RayMode::First, &mut ws, &mut results);
            for (i, ray) in rays.iter().enumerate() {
                let all = oracle.ray_hits(ray).expect("the scene's rays are valid");
                hits += !all.is_empty() as usize;
                at_zero += all.first().is_some_and(|h| h.t == 0.0) as usize;
                let batched = hit_pair(results.first(i).expect("valid ray"));
                check_ray("bevy_rtree (cast_rays)", i, batched, &all, false);
                let single = c
                    .bevy
                    .tree
                    .cast_ray(ray, &mut single_ws)
                    .expect("valid ray");
                check_ray("bevy_rtree (cast_ray)", i, hit_pair(single), &all, false);
                let parry = parry_first_hit(&c.parry.bvh, boxes, ray);
                parry_ties += check_ray("parry3d", i, parry, &all, true) as usize;
                check_ray("rstar", i, rstar_first_hit(&c.rstar.tree, ray), &all, false);
                let brute = c.soa.first_hit(&RayPrep::new(ray));
                check_ray("brute_force", i, brute, &all, false);
            }
        }
        let (s, s1) = (ws.take_stats(), single_ws.take_stats());
        let batches_n = batches.len();
        eprintln!(
            "check rays {kind} ok: {batches_n} batches of {} rays, {:.0} % hit, {:.0} % first hit at t = 0 (origin in a box); parry3d named another key at a tied t on {parry_ties} rays; bevy_rtree cast_rays per batch: {:.0} nodes visited, {:.0} ray-entry tests; cast_ray per ray: {:.1} nodes, {:.1} entries",
            rays_total / batches_n.max(1),
            100.0 * hits as f64 / rays_total as f64,
            100.0 * at_zero as f64 / rays_total as f64,
            per(s.nodes_visited, batches_n),
            per(s.entries_tested, batches_n),
            per(s1.nodes_visited, rays_total),
            per(s1.entries_tested, rays_total),
        );
    }

    eprintln!(
        "the eye is inside {} boxes: every coherent ray starts inside them, so its first hit is at t = 0 and S5 ties are broken by key among them",
        oracle.containing_point(TownScene::eye()).len()
    );
    eprintln!(
        "the clear eye of queries/rays_coherent_clear_eye is {:?}, inside no box",
        c.coherent_clear_eye[0][0].origin
    );

    // Cross join.
    let d = TownScene::JOIN_DISTANCE;
    let want = oracle_of(boxes, TownScene::ENEMIES)
        .cross_join(
            &oracle_of(boxes, TownScene::BARRELS),
            d,
            JoinMode::Euclidean,
        )
        .expect("valid distance");
    let what = "the cross join";
    let mut got = Vec::new();
    c.bevy_enemies
        .tree
        .cross_join_into(
            &c.bevy_barrels.tree,
            d,
            JoinMode::Euclidean,
            &mut ws,
            &mut got,
        )
        .expect("valid distance");
    assert_same("bevy_rtree", what, &sorted(got), &want);
    let s = ws.take_stats();
    let mut got = Vec::new();
    let (enemy_leaves, barrel_leaves) = (
        parry_leaves(boxes, TownScene::ENEMIES),
        parry_leaves(boxes, TownScene::BARRELS),
    );
    parry_build_and_cross_join(&enemy_leaves, &barrel_leaves, boxes, d, &mut got);
    assert_same("parry3d_with_build", what, &sorted(got), &want);
    let mut got = Vec::new();
    parry_cross_join(
        &c.parry_enemies.bvh,
        &c.parry_barrels.bvh,
        boxes,
        d,
        &mut got,
    );
    assert_same("parry3d_maintained", what, &sorted(got), &want);
    let mut got = Vec::new();
    rstar_cross_join(
        &c.rstar_enemies_grown.tree,
        &c.rstar_barrels.tree,
        boxes,
        d,
        &mut got,
    );
    assert_same("rstar", what, &sorted(got), &want);
    let mut got = Vec::new();
    Sweep::default().cross_join(boxes, TownScene::ENEMIES, TownScene::BARRELS, d, &mut got);
    assert_same("brute_force", what, &sorted(got), &want);
    eprintln!(
        "check cross join ok: {} pairs; bevy_rtree: {} node pairs visited, {} entry pairs tested",
        want.len(),
        s.nodes_visited,
        s.entries_tested
    );

    // Self join.
    let want = oracle
        .self_join(SELF_JOIN_DISTANCE, JoinMode::Euclidean)
        .expect("valid distance");
    let what = "the self join";
    let mut got = Vec::new();
    c.bevy
        .tree
        .self_join_into(SELF_JOIN_DISTANCE, JoinMode::Euclidean, &mut ws, &mut got)
        .expect("valid distance");
    assert_same("bevy_rtree", what, &sorted(got), &want);
    let s = ws.take_stats();
    let mut got = Vec::new();
    parry_self_join(
        &c.parry.bvh,
        &mut BvhWorkspace::default(),
        SELF_JOIN_DISTANCE,
        &mut got,
    );
    assert_same("parry3d", what, &sorted(got), &want);
    let mut got = Vec::new();
    rstar_self_join(&c.rstar.tree, SELF_JOIN_DISTANCE, &mut got);
    assert_same("rstar", what, &sorted(got), &want);
    let mut got = Vec::new();
    Sweep::default().self_join(boxes, SELF_JOIN_DISTANCE, &mut got);
    assert_same("brute_force", what, &sorted(got), &want);
    eprintln!(
        "check self join ok: {} pairs; bevy_rtree: {} node pairs visited, {} entry pairs tested",
        want.len(),
        s.nodes_visited,
        s.entries_tested
    );
    eprintln!(
        "all answers equal the oracle's ({:.1} s)\n",
        start.elapsed().as_secs_f64()
    );
}

fn parry_leaves(boxes: &[Aabb], range: Range<usize>) -> Vec<ParryAabb> {
    boxes[range].iter().map(to_parry).collect()
}

/// Cycles through `inputs`, one per iteration, so the timing averages over
/// them (different camera yaws, different ray batches).
fn cycle<'a, T>(inputs: &'a [T]) -> impl FnMut() -> &'a T {
    let mut next = 0usize;
    move || {
        let input = &inputs[next % inputs.len()];
        next += 1;
        input
    }
}

fn bench_frustum(cr: &mut Criterion, c: &Contenders) {
    let mut group = cr.benchmark_group("queries/frustum");
    let (mut ws, mut next) = (QueryWorkspace::default(), cycle(&c.frustums));
    bench_answers(&mut group, "bevy_rtree", vec![Vec::new()], |out| {
        out[0].clear();
        let frustum = std::slice::from_ref(next());
        let mode = CullMode::Conservative;
        c.bevy.tree.visible_into(frustum, mode, &mut ws, out);
    });
    let mut next = cycle(&c.frustums);
    bench_list(&mut group, "parry3d", |out| {
        parry_visible_into(&c.parry.bvh, &Planes::new(next()), out);
    });
    let mut next = cycle(&c.frustums);
    bench_list(&mut group, "rstar", |out| {
        rstar_visible_into(&c.rstar.tree, &Planes::new(next()), out);
    });
    let mut next = cycle(&c.frustums);
    bench_list(&mut group, "brute_force", |out| {
        c.soa.visible_into(&Planes::new(next()), out);
    });
    group.finish();
}

fn bench_rays(cr: &mut Criterion, c: &Contenders, name: &str, batches: &[Vec<Ray>]) {
    let mut group = cr.benchmark_group(name);
    let (mut ws, mut next) = (QueryWorkspace::default(), cycle(batches));
    bench_answers(&mut group, "bevy_rtree", RayResults::default(), |out| {
        c.bevy.tree.cast_rays(next(), RayMode::First, &mut ws, out);
    });
    let (mut ws, mut next) = (QueryWorkspace::default(), cycle(batches));
    bench_list(&mut group, "bevy_rtree_single", |out| {
        let hits = next().iter().map(|ray| c.bevy.tree.cast_ray(ray, &mut ws));
        out.extend(hits.map(|hit| hit.expect("valid ray")));
    });
    let mut next = cycle(batches);
    bench_list(&mut group, "parry3d", |out| {
        out.extend(
            next()
                .iter()
                .map(|ray| parry_first_hit(&c.parry.bvh, &c.boxes, ray)),
        );
    });
    let mut next = cycle(batches);
    bench_list(&mut group, "rstar", |out| {
        out.extend(next().iter().map(|ray| rstar_first_hit(&c.rstar.tree, ray)));
    });
    // About 0.1 s per iteration: ten samples of one iteration each.
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let mut next = cycle(batches);
    bench_list(&mut group, "brute_force", |out| {
        out.extend(next().iter().map(|ray| c.soa.first_hit(&RayPrep::new(ray))));
    });
    group.finish();
}

fn bench_cross_join(cr: &mut Criterion, c: &Contenders) {
    let d = TownScene::JOIN_DISTANCE;
    let mut group = cr.benchmark_group("queries/cross_join");
    group.sampling_mode(SamplingMode::Flat);
    let mut ws = QueryWorkspace::default();
    bench_list(&mut group, "bevy_rtree", |out| {
        let (enemies, barrels) = (&c.bevy_enemies.tree, &c.bevy_barrels.tree);
        let result = enemies.cross_join_into(barrels, d, JoinMode::Euclidean, &mut ws, out);
        result.expect("valid distance");
    });
    // The leaves are converted outside the timing: a parry3d user holds its
    // boxes as parry3d AABBs already.
    let enemy_leaves = parry_leaves(&c.boxes, TownScene::ENEMIES);
    let barrel_leaves = parry_leaves(&c.boxes, TownScene::BARRELS);
    bench_list(&mut group, "parry3d_with_build", |out| {
        parry_build_and_cross_join(&enemy_leaves, &barrel_leaves, &c.boxes, d, out);
    });
    bench_list(&mut group, "parry3d_maintained", |out| {
        let (enemies, barrels) = (&c.parry_enemies.bvh, &c.parry_barrels.bvh);
        parry_cross_join(enemies, barrels, &c.boxes, d, out);
    });
    bench_list(&mut group, "rstar", |out| {
        let (enemies, barrels) = (&c.rstar_enemies_grown.tree, &c.rstar_barrels.tree);
        rstar_cross_join(enemies, barrels, &c.boxes, d, out);
    });
    let mut sweep = Sweep::default();
    bench_list(&mut group, "brute_force", |out| {
        let (enemies, barrels) = (TownScene::ENEMIES, TownScene::BARRELS);
        sweep.cross_join(&c.boxes, enemies, barrels, d, out);
    });
    group.finish();
}

fn bench_self_join(cr: &mut Criterion, c: &Contenders) {
    let d = SELF_JOIN_DISTANCE;
    let mut group = cr.benchmark_group("queries/self_join");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let mut ws = QueryWorkspace::default();
    bench_list(&mut group, "bevy_rtree", |out| {
        let result = c
            .bevy
            .tree
            .self_join_into(d, JoinMode::Euclidean, &mut ws, out);
        result.expect("valid distance");
    });
    let mut ws = BvhWorkspace::default();
    bench_list(&mut group, "parry3d", |out| {
        parry_self_join(&c.parry.bvh, &mut ws, d, out);
    });
    bench_list(&mut group, "rstar", |out| {
        rstar_self_join(&c.rstar.tree, d, out);
    });
    let mut sweep = Sweep::default();
    bench_list(&mut group, "brute_force", |out| {
        sweep.self_join(&c.boxes, d, out);
    });
    group.finish();
}

fn bench_all(cr: &mut Criterion) {
    eprintln!(
        "queries bench: one iteration = one operation of one frame on the standard town scene \
         ({} entities, {WARM_FRAMES} frames of movement applied to every index first), single-threaded.\n\
         Compare contenders within a group only; `time: [lo mid hi]` is criterion's estimate per \
         iteration; the medians are under \"median\" in \
         target/criterion/queries_<group>/<contender>/new/estimates.json. \
         The ratio that matters is bevy_rtree time / parry3d time per group (below 1: bevy_rtree \
         is faster; targets: frustum <= 0.25, incoherent rays <= 0.4, coherent rays <= 0.33, \
         cross join <= 0.125 against parry3d_with_build, self join <= 0.4); the table printed \
         last gives it from alternating blocks.\n",
        n()
    );
    let contenders = setup();
    check(&contenders);
    bench_frustum(cr, &contenders);
    bench_rays(
        cr,
        &contenders,
        "queries/rays_incoherent",
        &contenders.incoherent,
    );
    bench_rays(
        cr,
        &contenders,
        "queries/rays_coherent",
        &contenders.coherent,
    );
    bench_rays(
        cr,
        &contenders,
        "queries/rays_coherent_clear_eye",
        &contenders.coherent_clear_eye,
    );
    bench_cross_join(cr, &contenders);
    bench_self_join(cr, &contenders);
    paired_ratios(&contenders);
    cold_ratios(&contenders);
}

/// Where the machine drifts during a run, criterion's medians of two
/// contenders, timed seconds apart, drift with it. For each target, this
/// times bevy_rtree and parry3d in alternating short blocks
/// (`common::paired`) and prints the ratio of neighbouring blocks: its
/// median and its range over the rounds. Written to
/// `target/criterion/queries_paired_ratios.md` as well.
fn paired_ratios(c: &Contenders) {
    const ROUNDS: usize = 41;
    // (query, target, inputs per iteration, ratio)
    let mut rows: Vec<(&str, f64, usize, common::paired::PairedRatio)> = Vec::new();

    // One iteration runs every input of the group's cycle (the 60 camera
    // yaws, the 4 ray batches), so that both blocks of a round time the same
    // inputs; the table gives the time per view or per batch.
    let views = c.frustums.len();
    let mut ws = QueryWorkspace::default();
    let (mut out, mut list) = (vec![Vec::new()], Vec::new());
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        3,
        || {
            let mut visible = 0;
            for frustum in &c.frustums {
                out[0].clear();
                let mode = CullMode::Conservative;
                let frustum = std::slice::from_ref(frustum);
                c.bevy.tree.visible_into(frustum, mode, &mut ws, &mut out);
                visible += out[0].len();
            }
            visible
        },
        || {
            let mut visible = 0;
            for frustum in &c.frustums {
                list.clear();
                parry_visible_into(&c.parry.bvh, &Planes::new(frustum), &mut list);
                visible += list.len();
            }
            visible
        },
    );
    rows.push(("frustum cull", 0.25, views, ratio));

    for (name, target, batches) in [
        ("1,000 incoherent rays", 0.40, &c.incoherent),
        ("1,000 coherent rays, standard eye", 1.0 / 3.0, &c.coherent),
        (
            "1,000 coherent rays, clear eye",
            1.0 / 3.0,
            &c.coherent_clear_eye,
        ),
    ] {
        let mut ws = QueryWorkspace::default();
        let (mut out, mut hits) = (RayResults::default(), Vec::new());
        let ratio = common::paired::paired_ratio(
            ROUNDS,
            3,
            || {
                let mut answered = 0;
                for rays in batches {
                    c.bevy
                        .tree
                        .cast_rays(rays, RayMode::First, &mut ws, &mut out);
                    answered += out.len();
                }
                answered
            },
            || {
                for rays in batches {
                    hits.clear();
                    let first_hits = rays
                        .iter()
                        .map(|ray| parry_first_hit(&c.parry.bvh, &c.boxes, ray));
                    hits.extend(first_hits);
                }
                hits.len()
            },
        );
        rows.push((name, target, batches.len(), ratio));
    }

    let d = TownScene::JOIN_DISTANCE;
    let enemy_leaves = parry_leaves(&c.boxes, TownScene::ENEMIES);
    let barrel_leaves = parry_leaves(&c.boxes, TownScene::BARRELS);
    let (mut ws, mut out, mut peer_out) = (QueryWorkspace::default(), Vec::new(), Vec::new());
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        4,
        || {
            out.clear();
            let (enemies, barrels) = (&c.bevy_enemies.tree, &c.bevy_barrels.tree);
            let result =
                enemies.cross_join_into(barrels, d, JoinMode::Euclidean, &mut ws, &mut out);
            result.expect("valid distance");
            out.len()
        },
        || {
            peer_out.clear();
            let (enemies, barrels) = (&enemy_leaves, &barrel_leaves);
            parry_build_and_cross_join(enemies, barrels, &c.boxes, d, &mut peer_out);
            peer_out.len()
        },
    );
    rows.push(("cross join (parry3d builds its trees)", 0.125, 1, ratio));

    let d = SELF_JOIN_DISTANCE;
    let (mut ws, mut peer_ws) = (QueryWorkspace::default(), BvhWorkspace::default());
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        3,
        || {
            out.clear();
            let result = c
                .bevy
                .tree
                .self_join_into(d, JoinMode::Euclidean, &mut ws, &mut out);
            result.expect("valid distance");
            out.len()
        },
        || {
            peer_out.clear();
            parry_self_join(&c.parry.bvh, &mut peer_ws, d, &mut peer_out);
            peer_out.len()
        },
    );
    rows.push(("self join", 0.40, 1, ratio));

    let mut table = format!(
        "bevy_rtree time ÷ parry3d time, alternating blocks, {ROUNDS} rounds\n\n\
         | query | bevy_rtree (µs) | parry3d (µs) | ratio, median | ratio, range | target |\n\
         |---|---:|---:|---:|---:|---:|\n"
    );
    for (name, target, inputs, r) in &rows {
        let per_input = |us: f64| us / *inputs as f64;
        table += &format!(
            "| {name} | {:.1} | {:.1} | {:.3} | {:.3}–{:.3} | ≤ {target:.3} |\n",
            per_input(r.a_us),
            per_input(r.b_us),
            r.median,
            r.low,
            r.high
        );
    }
    eprintln!("\n{table}");
    let path = std::path::Path::new("target/criterion/queries_paired_ratios.md");
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_millis(500), Duration::from_secs(2));
    targets = bench_all
}
criterion_main!(benches);

/// The paired ratios again with cold caches, as a game frame meets the
/// tree: before each timed call (one view, one batch of rays, one join) a
/// buffer several times the last-level cache is streamed through
/// (`common::paired::paired_ratio_cold`). Printed and written to
/// `target/criterion/queries_cold_ratios.md`, beside each contender's warm
/// time per call from the same inputs.
fn cold_ratios(c: &Contenders) {
    use common::paired::paired_ratio_cold;
    const ROUNDS: usize = 31;
    let mut rows: Vec<(&str, common::paired::PairedRatio)> = Vec::new();
    let mut ws = QueryWorkspace::default();
    let (mut out, mut list) = (vec![Vec::new()], Vec::new());
    let views = &c.frustums;
    let ratio = paired_ratio_cold(
        ROUNDS,
        |i| {
            out[0].clear();
            let frustum = std::slice::from_ref(&views[i % views.len()]);
            c.bevy
                .tree
                .visible_into(frustum, CullMode::Conservative, &mut ws, &mut out);
            out[0].len()
        },
        |i| {
            list.clear();
            let planes = Planes::new(&views[i % views.len()]);
            parry_visible_into(&c.parry.bvh, &planes, &mut list);
            list.len()
        },
    );
    rows.push(("frustum cull", ratio));
    for (name, batches) in [
        ("1,000 incoherent rays", &c.incoherent),
        ("1,000 coherent rays, clear eye", &c.coherent_clear_eye),
    ] {
        let (mut out, mut hits) = (RayResults::default(), Vec::new());
        let ratio = paired_ratio_cold(
            ROUNDS,
            |i| {
                let rays = &batches[i % batches.len()];
                c.bevy
                    .tree
                    .cast_rays(rays, RayMode::First, &mut ws, &mut out);
                out.len()
            },
            |i| {
                hits.clear();
                let rays = &batches[i % batches.len()];
                let first = rays
                    .iter()
                    .map(|ray| parry_first_hit(&c.parry.bvh, &c.boxes, ray));
                hits.extend(first);
                hits.len()
            },
        );
        rows.push((name, ratio));
    }
    let d = SELF_JOIN_DISTANCE;
    let (mut pairs, mut peer_pairs) = (Vec::new(), Vec::new());
    let mut peer_ws = BvhWorkspace::default();
    let ratio = paired_ratio_cold(
        ROUNDS,
        |_| {
            pairs.clear();
            let tree = &c.bevy.tree;
            let result = tree.self_join_into(d, JoinMode::Euclidean, &mut ws, &mut pairs);
            result.expect("valid distance");
            pairs.len()
        },
        |_| {
            peer_pairs.clear();
            parry_self_join(&c.parry.bvh, &mut peer_ws, d, &mut peer_pairs);
            peer_pairs.len()
        },
    );
    rows.push(("self join", ratio));

    let mut table = format!(
        "cold caches (a 128 MB buffer streamed through before each call): bevy_rtree time \
         ÷ parry3d time, {ROUNDS} alternating rounds of one call each\n\n\
         | query | bevy_rtree cold (µs) | parry3d cold (µs) | ratio, median | ratio, range |\n\
         |---|---:|---:|---:|---:|\n"
    );
    for (name, r) in &rows {
        table += &format!(
            "| {name} | {:.1} | {:.1} | {:.3} | {:.3}–{:.3} |\n",
            r.a_us, r.b_us, r.median, r.low, r.high
        );
    }
    let n = c.bevy.tree.len().max(1);
    let ours = c.bevy.tree.memory();
    table += &format!(
        "\nmemory per entry: bevy_rtree {} B (nodes {}, entry records {}, keys {}, handles {}); \
         parry3d {} B (`Bvh::total_memory_size`); rstar not reported\n",
        ours.total() / n,
        ours.nodes / n,
        ours.entries / n,
        ours.keys / n,
        ours.handles / n,
        c.parry.bvh.total_memory_size() / n,
    );
    eprintln!("\n{table}");
    let path = std::path::Path::new("target/criterion/queries_cold_ratios.md");
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}
