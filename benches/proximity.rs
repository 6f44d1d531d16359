//! Proximity queries on the standard "town" scene
//! (`bevy_rtree::scene::TownScene`, 100,000 entities), single-threaded:
//! the `k` entities nearest to a point, and every entity whose box meets a
//! sphere. `bevy_rtree` side by side with rstar 0.14, parry3d 0.31 (spheres
//! only) and a brute-force loop.
//!
//! Every index is first maintained through `WARM_FRAMES` frames of the
//! scene's movement, as in the queries bench (`common::indexes`). The query
//! points are 1,000 points uniform in the world volume (the origins of a
//! batch of the scene's incoherent rays).
//!
//! Groups (one iteration = all 1,000 queries):
//! - `proximity/nearest_8`: the 8 entities nearest to each point, by the
//!   distance from the point to the box (0 inside), ties to the smaller key.
//!   bevy_rtree: `nearest_into`. rstar: `nearest_neighbor_iter`, first 8
//!   (its distances are `f32`). parry3d's `Bvh` has a best-first search for
//!   the single best leaf but no `k` nearest, so it is not a contender here.
//!   brute_force: every box's distance, the best 8 kept in order.
//! - `proximity/sphere_10m`: every entity whose box meets the closed sphere
//!   of radius 10 m around each point. bevy_rtree: `overlapping_sphere_into`;
//!   parry3d: `Bvh::traverse` with the cube around the sphere tested first
//!   at every node (in `f32`, as bevy_rtree's walk does), then the sphere
//!   test; rstar:
//!   `locate_within_distance` (its distances are `f32`); brute_force: every
//!   box's distance.
//!
//! Before timing, every contender's answers are compared with the oracle
//! (`bevy_rtree::oracle::BruteForce`) on every point. bevy_rtree, parry3d
//! (which applies the crate's own predicate) and the brute force must match
//! exactly. rstar computes distances in `f32`, so where two distances differ
//! by less than its rounding it may rank them the other way, or put an
//! entry on the other side of the radius: such answers are accepted (and
//! counted) when each differing entry's exact distance lies within
//! `F32_SLACK` (relative) of the one it stands for, or of the radius.
//! Anything else panics.
//!
//! The medians are under `"median"` in
//! `target/criterion/proximity_<group>/<contender>/new/estimates.json`.

use std::time::{Duration, Instant};

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, Neighbor, QueryWorkspace};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use glam::Vec3;
use parry3d::partitioning::TraversalAction;

mod common;
use common::indexes::{BevyIndex, ParryIndex, RstarIndex, parry_node_box};
use common::{bench_list, sorted};

/// The scene's seed (the same as the other benches').
const SEED: u64 = 0x5EED_2024;
/// Frames of movement applied to every index before checking and timing.
const WARM_FRAMES: usize = 60;
/// Query points per iteration.
const POINTS: usize = 1_000;
/// Neighbours per nearest query.
const K: usize = 8;
/// Sphere radius, metres: about the size of the tree bench's box queries.
const RADIUS: f32 = 10.0;
/// How far (relative) an `f32` distance may stray from the exact one.
const F32_SLACK: f64 = 1e-5;

/// The squared distance from `p` to the closed box `[min, max]` (0 inside),
/// in `f64` from `f32` inputs: the crate's point / box predicate, written
/// out so that the peers' answers are held to it.
#[inline]
fn distance_sq(p: Vec3, min: Vec3, max: Vec3) -> f64 {
    let mut sum = 0.0f64;
    for axis in 0..3 {
        let below = min[axis] as f64 - p[axis] as f64;
        let above = p[axis] as f64 - max[axis] as f64;
        let mut gap = 0.0f64;
        if below > gap {
            gap = below;
        }
        if above > gap {
            gap = above;
        }
        sum += gap * gap;
    }
    sum
}

/// The brute-force contender: the boxes' corners per axis, so the distance
/// loop reads three arrays and vectorises.
struct SoaCorners {
    min: [Vec<f32>; 3],
    max: [Vec<f32>; 3],
}

impl SoaCorners {
    fn new(boxes: &[Aabb]) -> Self {
        let axis = |f: fn(&Aabb) -> Vec3, a: usize| boxes.iter().map(|b| f(b)[a]).collect();
        SoaCorners {
            min: [0, 1, 2].map(|a| axis(|b| b.min, a)),
            max: [0, 1, 2].map(|a| axis(|b| b.max, a)),
        }
    }

    /// The squared distance of every box from `p`, into `out`.
    fn distances(&self, p: Vec3, out: &mut Vec<f64>) {
        out.clear();
        let [x0, y0, z0] = &self.min;
        let [x1, y1, z1] = &self.max;
        let (px, py, pz) = (p.x as f64, p.y as f64, p.z as f64);
        let gap = |lo: f32, hi: f32, q: f64| (lo as f64 - q).max(q - hi as f64).max(0.0);
        out.extend((0..x0.len()).map(|i| {
            let (gx, gy, gz) = (
                gap(x0[i], x1[i], px),
                gap(y0[i], y1[i], py),
                gap(z0[i], z1[i], pz),
            );
            gx * gx + gy * gy + gz * gz
        }));
    }

    /// The `K` nearest `(distance_sq, key)`, sorted, into `out`.
    fn nearest(&self, p: Vec3, scratch: &mut Vec<f64>, out: &mut Vec<(f64, u32)>) {
        self.distances(p, scratch);
        out.clear();
        for (key, &d) in scratch.iter().enumerate() {
            if out.len() == K && d >= out[K - 1].0 {
                continue;
            }
            let at = out.partition_point(|&(e, _)| e <= d);
            if out.len() == K {
                out.pop();
            }
            out.insert(at, (d, key as u32));
        }
    }

    /// The keys of the boxes within `RADIUS` of `p`, ascending, appended.
    fn sphere(&self, p: Vec3, scratch: &mut Vec<f64>, out: &mut Vec<u32>) {
        self.distances(p, scratch);
        let limit = (RADIUS as f64) * (RADIUS as f64);
        out.extend(
            scratch
                .iter()
                .enumerate()
                .filter(|&(_, &d)| d <= limit)
                .map(|(key, _)| key as u32),
        );
    }
}

fn parry_sphere(index: &ParryIndex, p: Vec3, out: &mut Vec<u32>) {
    let limit = (RADIUS as f64) * (RADIUS as f64);
    let reach = Vec3::splat(RADIUS);
    index.bvh.traverse(|node| {
        let (min, max) = parry_node_box(node);
        // The cube around the sphere first: a gap of at most `RADIUS` never
        // rounds above it (rounding is monotone), nor does one that the f64
        // distance accepts just above it (within 2^-49 of it, where the
        // next f32 is 2^-24 away), so no box within reach is pruned, and
        // most nodes are settled without the f64 distance.
        let in_cube = (p - max).cmple(reach).all() && (min - p).cmple(reach).all();
        if !in_cube || distance_sq(p, min, max) > limit {
            return TraversalAction::Prune;
        }
        // Leaves hold exact boxes (margin 0): passing the test decides.
        if let Some(leaf) = node.leaf_data() {
            out.push(leaf);
        }
        TraversalAction::Continue
    });
}

fn rstar_nearest(index: &RstarIndex, p: Vec3, out: &mut Vec<u32>) {
    let found = index.tree.nearest_neighbor_iter(p.to_array()).take(K);
    out.extend(found.map(|item| item.data));
}

fn rstar_sphere(index: &RstarIndex, p: Vec3, out: &mut Vec<u32>) {
    let found = index
        .tree
        .locate_within_distance(p.to_array(), RADIUS * RADIUS);
    out.extend(found.map(|item| item.data));
}

struct Contenders {
    boxes: Vec<Aabb>,
    bevy: BevyIndex,
    parry: ParryIndex,
    rstar: RstarIndex,
    soa: SoaCorners,
    points: Vec<Vec3>,
}

fn setup() -> Contenders {
    let start = Instant::now();
    let n = TownScene::STANDARD_COUNT;
    let mut scene = TownScene::new(n, SEED);
    let boxes = scene.boxes();
    let mut bevy = BevyIndex::new(boxes, 0..n);
    let mut parry = ParryIndex::new(boxes, 0..n);
    let mut rstar = RstarIndex::new(boxes, 0..n, 0.0);
    for _ in 0..WARM_FRAMES {
        scene.advance_frame();
        let (moved, boxes) = (scene.moved(), scene.boxes());
        bevy.apply(moved, boxes);
        parry.apply(moved, boxes);
        rstar.apply(moved, boxes);
    }
    bevy.tree.validate().expect("bevy_rtree invariants hold");
    let boxes = scene.boxes().to_vec();
    let points = scene
        .incoherent_rays(POINTS)
        .iter()
        .map(|ray| ray.origin)
        .collect();
    eprintln!(
        "setup: {n} entities, {WARM_FRAMES} frames of movement applied to every index in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    Contenders {
        soa: SoaCorners::new(&boxes),
        boxes,
        bevy,
        parry,
        rstar,
        points,
    }
}

/// Whether `got` and `want` (exact squared distances) agree within `f32`
/// rounding.
fn close(got: f64, want: f64) -> bool {
    (got - want).abs() <= F32_SLACK * want.max(1.0)
}

/// Compares every contender with the oracle on every point; returns how
/// many of rstar's answers differed within its `f32` rounding.
fn check(c: &Contenders) -> (usize, usize) {
    let start = Instant::now();
    let mut oracle = BruteForce::default();
    for (i, aabb) in c.boxes.iter().enumerate() {
        oracle.insert(i as u32, *aabb);
    }
    let exact = |key: u32, p: Vec3| {
        let b = &c.boxes[key as usize];
        distance_sq(p, b.min, b.max)
    };
    // One workspace per query family, so each one's work is counted apart.
    let (mut ws, mut sphere_ws) = (QueryWorkspace::default(), QueryWorkspace::default());
    let (mut neighbours, mut rstar_near, mut rstar_sphere_ties, mut in_sphere) = (0, 0, 0, 0);
    let mut scratch = Vec::new();
    for (i, &p) in c.points.iter().enumerate() {
        // Nearest.
        let want = oracle.nearest(p, K, None).expect("valid point");
        let want_pairs: Vec<(f64, u32)> = want.iter().map(|n| (n.distance_sq, n.key)).collect();
        let mut got: Vec<Neighbor<u32>> = Vec::new();
        c.bevy
            .tree
            .nearest_into(p, K, None, &mut ws, &mut got)
            .expect("valid point");
        assert_eq!(got, want, "bevy_rtree nearest of point {i}");
        let mut brute = Vec::new();
        c.soa.nearest(p, &mut scratch, &mut brute);
        assert_eq!(brute, want_pairs, "brute_force nearest of point {i}");
        let mut keys = Vec::new();
        rstar_nearest(&c.rstar, p, &mut keys);
        let mut ranked: Vec<(f64, u32)> = keys.iter().map(|&k| (exact(k, p), k)).collect();
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        if ranked != want_pairs {
            let agree = ranked.len() == want_pairs.len()
                && ranked.iter().zip(&want_pairs).all(|(g, w)| close(g.0, w.0));
            assert!(
                agree,
                "rstar nearest of point {i}: {ranked:?} against {want_pairs:?}"
            );
            rstar_near += 1;
        }
        neighbours += want.len();

        // Sphere.
        let want = oracle.overlapping_sphere(p, RADIUS).expect("valid sphere");
        in_sphere += want.len();
        let mut got = Vec::new();
        let result = c
            .bevy
            .tree
            .overlapping_sphere_into(p, RADIUS, &mut sphere_ws, &mut got);
        result.expect("valid sphere");
        assert_eq!(sorted(got), want, "bevy_rtree sphere at point {i}");
        let mut got = Vec::new();
        parry_sphere(&c.parry, p, &mut got);
        assert_eq!(sorted(got), want, "parry3d sphere at point {i}");
        let mut got = Vec::new();
        c.soa.sphere(p, &mut scratch, &mut got);
        assert_eq!(got, want, "brute_force sphere at point {i}");
        let mut got = Vec::new();
        rstar_sphere(&c.rstar, p, &mut got);
        let got = sorted(got);
        if got != want {
            let limit = (RADIUS as f64) * (RADIUS as f64);
            let on_edge = |k: &u32| close(exact(*k, p), limit);
            let missing = want.iter().filter(|k| got.binary_search(k).is_err());
            let extra = got.iter().filter(|k| want.binary_search(k).is_err());
            let edge_only = missing.chain(extra).all(on_edge);
            assert!(
                edge_only,
                "rstar sphere at point {i}: {got:?} against {want:?}"
            );
            rstar_sphere_ties += 1;
        }
    }
    let (near, sphere) = (ws.take_stats(), sphere_ws.take_stats());
    let per = |count: u64| count as f64 / POINTS as f64;
    eprintln!(
        "check ok in {:.1} s: {POINTS} points; nearest {K}: {neighbours} neighbours, rstar differed within f32 rounding on {rstar_near} points; \
         sphere {RADIUS} m: {:.1} entities per sphere, rstar differed on the edge on {rstar_sphere_ties} points; \
         bevy_rtree per query: nearest {:.1} nodes visited and {:.1} entries tested, sphere {:.1} and {:.1}",
        start.elapsed().as_secs_f64(),
        in_sphere as f64 / POINTS as f64,
        per(near.nodes_visited),
        per(near.entries_tested),
        per(sphere.nodes_visited),
        per(sphere.entries_tested),
    );
    (rstar_near, rstar_sphere_ties)
}

/// bevy_rtree's `K` nearest of every query point, their keys into `out`.
fn bevy_nearest_all(
    c: &Contenders,
    ws: &mut QueryWorkspace,
    neighbours: &mut Vec<Neighbor<u32>>,
    out: &mut Vec<u32>,
) {
    for &p in &c.points {
        let result = c.bevy.tree.nearest_into(p, K, None, ws, neighbours);
        result.expect("valid point");
        out.extend(neighbours.iter().map(|n| n.key));
    }
}

/// rstar's `K` nearest of every query point.
fn rstar_nearest_all(c: &Contenders, out: &mut Vec<u32>) {
    for &p in &c.points {
        rstar_nearest(&c.rstar, p, out);
    }
}

/// bevy_rtree's entries within `RADIUS` of every query point.
fn bevy_sphere_all(c: &Contenders, ws: &mut QueryWorkspace, out: &mut Vec<u32>) {
    for &p in &c.points {
        let result = c.bevy.tree.overlapping_sphere_into(p, RADIUS, ws, out);
        result.expect("valid sphere");
    }
}

/// parry3d's entries within `RADIUS` of every query point.
fn parry_sphere_all(c: &Contenders, out: &mut Vec<u32>) {
    for &p in &c.points {
        parry_sphere(&c.parry, p, out);
    }
}

fn bench_nearest(cr: &mut Criterion, c: &Contenders) {
    let mut group = cr.benchmark_group("proximity/nearest_8");
    let (mut ws, mut neighbours) = (QueryWorkspace::default(), Vec::new());
    bench_list(&mut group, "bevy_rtree", |out| {
        bevy_nearest_all(c, &mut ws, &mut neighbours, out)
    });
    bench_list(&mut group, "rstar", |out| rstar_nearest_all(c, out));
    // About 0.2 s per iteration: ten samples of one iteration each.
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let (mut scratch, mut best) = (Vec::new(), Vec::new());
    bench_list(&mut group, "brute_force", |out| {
        for &p in &c.points {
            c.soa.nearest(p, &mut scratch, &mut best);
            out.extend(best.iter().map(|&(_, key)| key));
        }
    });
    group.finish();
}

fn bench_sphere(cr: &mut Criterion, c: &Contenders) {
    let mut group = cr.benchmark_group("proximity/sphere_10m");
    let mut ws = QueryWorkspace::default();
    bench_list(&mut group, "bevy_rtree", |out| {
        bevy_sphere_all(c, &mut ws, out)
    });
    bench_list(&mut group, "parry3d", |out| parry_sphere_all(c, out));
    bench_list(&mut group, "rstar", |out| {
        for &p in &c.points {
            rstar_sphere(&c.rstar, p, out);
        }
    });
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let mut scratch = Vec::new();
    bench_list(&mut group, "brute_force", |out| {
        for &p in &c.points {
            c.soa.sphere(p, &mut scratch, out);
        }
    });
    group.finish();
}

fn bench_all(cr: &mut Criterion) {
    eprintln!(
        "proximity bench: one iteration = {POINTS} queries on the standard town scene ({} entities, \
         {WARM_FRAMES} frames of movement applied to every index first), single-threaded. Compare \
         contenders within a group only.",
        TownScene::STANDARD_COUNT
    );
    let contenders = setup();
    check(&contenders);
    cold_ratios(&contenders);
    bench_nearest(cr, &contenders);
    bench_sphere(cr, &contenders);
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_millis(500), Duration::from_secs(2));
    targets = bench_all
}
criterion_main!(benches);

/// The two queries with cold caches, as a game frame meets the tree:
/// before each timed call (1,000 queries) a buffer several times the
/// last-level cache is streamed through (`common::paired::paired_ratio_cold`),
/// bevy_rtree against rstar for the nearest and against parry3d for the
/// spheres. Printed and written to
/// `target/criterion/proximity_cold_ratios.md`.
fn cold_ratios(c: &Contenders) {
    use common::paired::paired_ratio_cold;
    const ROUNDS: usize = 31;
    let (mut ws, mut neighbours) = (QueryWorkspace::default(), Vec::new());
    let (mut out, mut peer_out) = (Vec::new(), Vec::new());
    let nearest = paired_ratio_cold(
        ROUNDS,
        |_| {
            out.clear();
            bevy_nearest_all(c, &mut ws, &mut neighbours, &mut out);
            out.len()
        },
        |_| {
            peer_out.clear();
            rstar_nearest_all(c, &mut peer_out);
            peer_out.len()
        },
    );
    let sphere = paired_ratio_cold(
        ROUNDS,
        |_| {
            out.clear();
            bevy_sphere_all(c, &mut ws, &mut out);
            out.len()
        },
        |_| {
            peer_out.clear();
            parry_sphere_all(c, &mut peer_out);
            peer_out.len()
        },
    );
    let mut table = format!(
        "cold caches (a 128 MB buffer streamed through before each call of {POINTS} queries): \
         bevy_rtree time ÷ the peer's, {ROUNDS} alternating rounds\n\n\
         | query | bevy_rtree cold (µs) | peer | peer cold (µs) | ratio, median | ratio, range |\n\
         |---|---:|---|---:|---:|---:|\n"
    );
    for (name, peer, r) in [
        ("nearest 8", "rstar", nearest),
        ("sphere 10 m", "parry3d", sphere),
    ] {
        table += &format!(
            "| {name} | {:.1} | {peer} | {:.1} | {:.3} | {:.3}–{:.3} |\n",
            r.a_us, r.b_us, r.median, r.low, r.high
        );
    }
    eprintln!("\n{table}");
    let path = std::path::Path::new("target/criterion/proximity_cold_ratios.md");
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}
