//! Side-by-side benchmark of `bevy_rtree` against its peers on the standard
//! "town" scene (`bevy_rtree::scene::TownScene`): rstar 0.14, parry3d 0.31's
//! `Bvh`, and the flat / brute-force lower and upper limits.
//!
//! Groups:
//! - `build/bulk_load_100k`, `build/insert_100k`: building an index of the
//!   scene from scratch;
//! - `frame/moves_10k`: applying one frame's 10,000 moves to a persistent
//!   index (the scene is advanced untimed before each timed frame);
//!   `bevy_rtree` gathers them into one `update_batch`, as the plugin does,
//!   then runs the churn repair (`optimize`); `bevy_rtree_repair_untimed`
//!   is the same with the repair run but not counted (the counterpart of
//!   parry3d's update path, which repairs nothing), and
//!   `bevy_rtree_one_by_one` calls `update` per move. parry3d runs
//!   `insert_or_update_partially` per move and `refit`, with a margin of 0
//!   or 0.1, and once more with `optimize_incremental` after each frame
//!   (its own repair);
//! - `query/boxes`: 1,000 box-overlap queries against a fresh and a churned
//!   tree and the peers, all over the same boxes;
//! - `split/insert_100k`, `split/moves_10k`, `split/boxes_churned`: the node
//!   split strategies (`TreeSettings::split`) side by side: 100,000 single
//!   inserts, a frame's moves, and the `query/boxes` queries on each
//!   strategy's tree after `CHURN_FRAMES` frames of moves (with a tree bulk
//!   loaded from the same boxes for reference).
//!
//! Every contender's answers are checked against the oracle
//! (`bevy_rtree::oracle::BruteForce`) before any timing; a disagreement
//! panics.

use std::hint::black_box;
use std::time::{Duration, Instant};

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::{SceneRng, TownScene, WORLD_MAX};
use bevy_rtree::{Aabb, ProxyId, QueryWorkspace, RTree, SplitStrategy, TreeSettings};
use criterion::{BatchSize, Criterion, SamplingMode, criterion_group, criterion_main};
use glam::Vec3;
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};
use rstar::AABB as RstarEnvelope;

mod common;
use common::{RstarBox, sorted, to_parry, to_rstar};

/// The scene's seed; every contender sees the same boxes and frames.
const SEED: u64 = 0x5EED_2024;
/// Frames of churn applied to the tree queried as "bevy_rtree_churned".
const CHURN_FRAMES: usize = 600;
/// Query boxes per `query/boxes` iteration.
const QUERY_COUNT: usize = 1_000;
/// Half extent of a query box (a cube, clamped to the world in y).
const QUERY_HALF_EXTENT: f32 = 10.0;
/// Frames applied to each moves contender before its answers are checked.
const CHECK_FRAMES: usize = 5;
/// Query boxes used by the moves group's correctness checks.
const MOVE_CHECK_QUERIES: usize = 200;

// ---------------------------------------------------------------------------
// Conversions and inputs.

fn rstar_envelope(aabb: &Aabb) -> RstarEnvelope<[f32; 3]> {
    RstarEnvelope::from_corners(aabb.min.to_array(), aabb.max.to_array())
}

fn keyed(boxes: &[Aabb]) -> Vec<(u32, Aabb)> {
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| (i as u32, *b))
        .collect()
}

fn rstar_items(boxes: &[Aabb]) -> Vec<RstarBox> {
    boxes
        .iter()
        .enumerate()
        .map(|(i, b)| to_rstar(b, i as u32))
        .collect()
}

fn parry_leaves(boxes: &[Aabb]) -> Vec<ParryAabb> {
    boxes.iter().map(to_parry).collect()
}

fn oracle_of(boxes: &[Aabb]) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    oracle
}

/// Deterministic query boxes: centres uniform in the world volume, a
/// `QUERY_HALF_EXTENT` cube around each, clamped to the world in y.
fn query_boxes(count: usize, seed: u64) -> Vec<Aabb> {
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

fn bulk_tree(boxes: &[Aabb]) -> (RTree<u32>, Vec<ProxyId>) {
    bulk_tree_with(boxes, TreeSettings::default())
}

fn bulk_tree_with(boxes: &[Aabb], settings: TreeSettings) -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::with_settings(settings).expect("valid settings");
    let ids = tree
        .insert_bulk(keyed(boxes))
        .expect("scene boxes are valid");
    (tree, ids)
}

// ---------------------------------------------------------------------------
// The brute-force contender: a structure-of-arrays box list, tested 16 boxes
// at a time into a bit mask (a loop the compiler vectorises).

struct SoaBoxes {
    min: [Vec<f32>; 3],
    max: [Vec<f32>; 3],
}

impl SoaBoxes {
    const LANES: usize = 16;

    fn new(boxes: &[Aabb]) -> Self {
        let axis = |f: &dyn Fn(&Aabb) -> f32| boxes.iter().map(f).collect::<Vec<f32>>();
        SoaBoxes {
            min: [axis(&|b| b.min.x), axis(&|b| b.min.y), axis(&|b| b.min.z)],
            max: [axis(&|b| b.max.x), axis(&|b| b.max.y), axis(&|b| b.max.z)],
        }
    }

    /// Appends the indices of all boxes overlapping `q` (closed boxes).
    fn overlapping_into(&self, q: &Aabb, out: &mut Vec<u32>) {
        let n = self.min[0].len();
        let (qmin, qmax) = (q.min.to_array(), q.max.to_array());
        let full = n / Self::LANES * Self::LANES;
        for base in (0..full).step_by(Self::LANES) {
            let end = base + Self::LANES;
            let (x0, y0, z0) = (
                &self.min[0][base..end],
                &self.min[1][base..end],
                &self.min[2][base..end],
            );
            let (x1, y1, z1) = (
                &self.max[0][base..end],
                &self.max[1][base..end],
                &self.max[2][base..end],
            );
            let mut mask = 0u32;
            for j in 0..Self::LANES {
                let hit = (x0[j] <= qmax[0])
                    & (x1[j] >= qmin[0])
                    & (y0[j] <= qmax[1])
                    & (y1[j] >= qmin[1])
                    & (z0[j] <= qmax[2])
                    & (z1[j] >= qmin[2]);
                mask |= (hit as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out.push((base + j) as u32);
            }
        }
        for i in full..n {
            let hit = (0..3).all(|a| self.min[a][i] <= qmax[a] && self.max[a][i] >= qmin[a]);
            if hit {
                out.push(i as u32);
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Correctness helpers: sorted answers of each contender.

fn answer_rstar(tree: &rstar::RTree<RstarBox>, q: &Aabb) -> Vec<u32> {
    sorted(
        tree.locate_in_envelope_intersecting(rstar_envelope(q))
            .map(|g| g.data)
            .collect(),
    )
}

fn answer_parry(bvh: &Bvh, q: &Aabb) -> Vec<u32> {
    let pq = to_parry(q);
    sorted(bvh.intersect_aabb(&pq).collect())
}

/// Panics with a readable message when `got` differs from the oracle.
fn assert_same(who: &str, q: &Aabb, got: &[u32], want: &[u32]) {
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

// ---------------------------------------------------------------------------
// build/*

fn bench_build(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let boxes = scene.boxes().to_vec();
    let parry = parry_leaves(&boxes);
    let rstar = rstar_items(&boxes);

    // Check every builder's output before timing.
    let oracle = oracle_of(&boxes);
    let checks = query_boxes(MOVE_CHECK_QUERIES, SEED ^ 0xB11D);
    {
        let (bulk, _) = bulk_tree(&boxes);
        bulk.validate().unwrap();
        let mut inserted = RTree::<u32>::new();
        for (i, b) in boxes.iter().enumerate() {
            inserted.insert(i as u32, *b).unwrap();
        }
        inserted.validate().unwrap();
        let rstar_bulk = rstar::RTree::bulk_load(rstar.clone());
        let mut rstar_ins = rstar::RTree::new();
        for item in &rstar {
            rstar_ins.insert(*item);
        }
        let parry_bulk = Bvh::from_leaves(BvhBuildStrategy::Binned, &parry);
        let mut parry_ins = Bvh::new();
        for (i, b) in parry.iter().enumerate() {
            parry_ins.insert(*b, i as u32);
        }
        for q in &checks {
            let want = oracle.overlapping(q);
            assert_same("bevy_rtree bulk", q, &bulk.overlapping(q), &want);
            assert_same("bevy_rtree insert", q, &inserted.overlapping(q), &want);
            assert_same("rstar bulk", q, &answer_rstar(&rstar_bulk, q), &want);
            assert_same("rstar insert", q, &answer_rstar(&rstar_ins, q), &want);
            assert_same("parry3d bulk", q, &answer_parry(&parry_bulk, q), &want);
            assert_same("parry3d insert", q, &answer_parry(&parry_ins, q), &want);
        }
        eprintln!(
            "build check ok: bevy_rtree height bulk {} / inserted {}, nodes {} / {}",
            bulk.height(),
            inserted.height(),
            bulk.node_count(),
            inserted.node_count()
        );
    }

    let mut group = c.benchmark_group("build/bulk_load_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    group.bench_function("bevy_rtree", |b| {
        b.iter_batched(
            || keyed(&boxes),
            |input| {
                let mut tree = RTree::<u32>::new();
                let ids = tree.insert_bulk(input).unwrap();
                (tree, ids)
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("rstar", |b| {
        b.iter_batched(
            || rstar.clone(),
            rstar::RTree::bulk_load,
            BatchSize::LargeInput,
        )
    });
    group.bench_function("parry3d", |b| {
        b.iter_batched(
            || (),
            |()| Bvh::from_leaves(BvhBuildStrategy::Binned, black_box(&parry)),
            BatchSize::LargeInput,
        )
    });
    group.finish();

    let mut group = c.benchmark_group("build/insert_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    group.bench_function("bevy_rtree", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut tree = RTree::<u32>::new();
                for (i, aabb) in boxes.iter().enumerate() {
                    tree.insert(i as u32, *aabb).unwrap();
                }
                tree
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("rstar", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut tree = rstar::RTree::new();
                for item in &rstar {
                    tree.insert(*item);
                }
                tree
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("parry3d", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut bvh = Bvh::new();
                for (i, aabb) in parry.iter().enumerate() {
                    bvh.insert(*aabb, i as u32);
                }
                bvh
            },
            BatchSize::LargeInput,
        )
    });
    group.finish();
}

// ---------------------------------------------------------------------------
// frame/moves_10k
//
// Each contender owns a persistent index and its own clone of the scene. One
// iteration advances its scene by a frame (untimed) and times only applying
// that frame's moved boxes.

/// Times `apply` on `iters` consecutive frames of `scene`, advancing the
/// scene untimed before each.
fn time_frames(
    scene: &mut TownScene,
    iters: u64,
    mut apply: impl FnMut(&[u32], &[Aabb]),
) -> Duration {
    time_frames_excluding(scene, iters, |moved, boxes| {
        apply(moved, boxes);
        Duration::ZERO
    })
}

/// [`time_frames`] for an `apply` that returns how long a part of its work
/// took that is not to be counted.
fn time_frames_excluding(
    scene: &mut TownScene,
    iters: u64,
    mut apply: impl FnMut(&[u32], &[Aabb]) -> Duration,
) -> Duration {
    let mut total = Duration::ZERO;
    for _ in 0..iters {
        scene.advance_frame();
        let (moved, boxes) = (scene.moved(), scene.boxes());
        let start = Instant::now();
        let excluded = apply(moved, boxes);
        total += start.elapsed().saturating_sub(excluded);
    }
    total
}

struct BevyMoves {
    scene: TownScene,
    tree: RTree<u32>,
    ids: Vec<ProxyId>,
    /// One `update_batch` per frame, or one `update` per move.
    batched: bool,
    /// Whether the frame's churn repair (`optimize`) counts in the time; it
    /// runs every frame either way, so the tree is the same.
    repair_timed: bool,
    /// The frame's moves, for `update_batch` (kept to avoid reallocating).
    moves: Vec<(ProxyId, Aabb)>,
}

impl BevyMoves {
    fn new(scene: &TownScene, batched: bool) -> Self {
        Self::with_settings(scene, batched, TreeSettings::default())
    }

    fn with_settings(scene: &TownScene, batched: bool, settings: TreeSettings) -> Self {
        let (tree, ids) = bulk_tree_with(scene.boxes(), settings);
        BevyMoves {
            scene: scene.clone(),
            tree,
            ids,
            batched,
            repair_timed: true,
            moves: Vec::new(),
        }
    }

    /// A contender that times the moves alone, with the churn repair run
    /// every frame but not counted: the counterpart of parry3d's update
    /// path, which repairs nothing.
    fn repair_untimed(mut self) -> Self {
        self.repair_timed = false;
        self
    }

    fn frame(&mut self, iters: u64) -> Duration {
        let (tree, ids, moves, batched, repair_timed) = (
            &mut self.tree,
            &self.ids,
            &mut self.moves,
            self.batched,
            self.repair_timed,
        );
        time_frames_excluding(&mut self.scene, iters, |moved, boxes| {
            if batched {
                moves.clear();
                moves.extend(moved.iter().map(|&i| (ids[i as usize], boxes[i as usize])));
                tree.update_batch(moves).unwrap();
            } else {
                for &i in moved {
                    tree.update(ids[i as usize], boxes[i as usize]).unwrap();
                }
            }
            let repair = Instant::now();
            black_box(tree.optimize(usize::MAX));
            if repair_timed {
                Duration::ZERO
            } else {
                repair.elapsed()
            }
        })
    }
    fn check(&self, queries: &[Aabb]) {
        self.tree.validate().unwrap();
        let oracle = oracle_of(self.scene.boxes());
        for q in queries {
            assert_same(
                "bevy_rtree (moves)",
                q,
                &self.tree.overlapping(q),
                &oracle.overlapping(q),
            );
        }
    }
}

struct RstarMoves {
    scene: TownScene,
    tree: rstar::RTree<RstarBox>,
    /// The item each entity currently has in the tree (to remove it).
    current: Vec<RstarBox>,
}

impl RstarMoves {
    fn new(scene: &TownScene) -> Self {
        let current = rstar_items(scene.boxes());
        RstarMoves {
            scene: scene.clone(),
            tree: rstar::RTree::bulk_load(current.clone()),
            current,
        }
    }

    fn apply(
        tree: &mut rstar::RTree<RstarBox>,
        current: &mut [RstarBox],
        moved: &[u32],
        boxes: &[Aabb],
    ) {
        for &i in moved {
            let new = to_rstar(&boxes[i as usize], i);
            let old = std::mem::replace(&mut current[i as usize], new);
            let removed = tree.remove(&old);
            assert!(removed.is_some(), "rstar lost entity {i}");
            tree.insert(new);
        }
    }

    fn frame(&mut self, iters: u64) -> Duration {
        let (tree, current) = (&mut self.tree, &mut self.current);
        time_frames(&mut self.scene, iters, |moved, boxes| {
            Self::apply(tree, current, moved, boxes)
        })
    }

    fn check(&self, queries: &[Aabb]) {
        assert_eq!(self.tree.size(), self.scene.len());
        let oracle = oracle_of(self.scene.boxes());
        for q in queries {
            assert_same(
                "rstar (moves)",
                q,
                &answer_rstar(&self.tree, q),
                &oracle.overlapping(q),
            );
        }
    }
}

struct ParryMoves {
    scene: TownScene,
    bvh: Bvh,
    workspace: BvhWorkspace,
    margin: f32,
    /// Whether each frame ends with `optimize_incremental`, parry3d's
    /// counterpart of bevy_rtree's churn repair.
    optimize: bool,
}

impl ParryMoves {
    fn new(scene: &TownScene, margin: f32) -> Self {
        ParryMoves {
            scene: scene.clone(),
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &parry_leaves(scene.boxes())),
            workspace: BvhWorkspace::default(),
            margin,
            optimize: false,
        }
    }

    /// The same update path followed by `optimize_incremental` each frame.
    fn optimized(mut self) -> Self {
        self.optimize = true;
        self
    }

    fn apply(bvh: &mut Bvh, ws: &mut BvhWorkspace, margin: f32, moved: &[u32], boxes: &[Aabb]) {
        for &i in moved {
            bvh.insert_or_update_partially(to_parry(&boxes[i as usize]), i, margin);
        }
        bvh.refit(ws);
    }

    fn frame(&mut self, iters: u64) -> Duration {
        let (bvh, ws, margin, optimize) = (
            &mut self.bvh,
            &mut self.workspace,
            self.margin,
            self.optimize,
        );
        time_frames(&mut self.scene, iters, |moved, boxes| {
            Self::apply(bvh, ws, margin, moved, boxes);
            if optimize {
                bvh.optimize_incremental(ws);
            }
        })
    }

    /// With a margin the leaves hold enlarged boxes, so the BVH answers a
    /// superset; filtered by the exact boxes it must equal the oracle.
    fn check(&self, queries: &[Aabb]) {
        assert_eq!(self.bvh.leaf_count() as usize, self.scene.len());
        let boxes = self.scene.boxes();
        let oracle = oracle_of(boxes);
        let who = format!("parry3d margin {} (moves)", self.margin);
        for q in queries {
            let want = oracle.overlapping(q);
            let candidates = answer_parry(&self.bvh, q);
            let exact: Vec<u32> = candidates
                .iter()
                .copied()
                .filter(|&i| boxes[i as usize].intersects(q))
                .collect();
            assert_same(&who, q, &exact, &want);
            if self.margin == 0.0 {
                assert_same(&who, q, &candidates, &want);
            }
        }
    }
}

struct FlatMoves {
    scene: TownScene,
    flat: Vec<Aabb>,
}

impl FlatMoves {
    fn frame(&mut self, iters: u64) -> Duration {
        let flat = &mut self.flat;
        time_frames(&mut self.scene, iters, |moved, boxes| {
            for &i in moved {
                flat[i as usize] = boxes[i as usize];
            }
            black_box(&mut *flat);
        })
    }

    fn check(&self) {
        assert_eq!(self.flat, self.scene.boxes(), "flat array out of date");
    }
}

fn bench_moves(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let checks = query_boxes(MOVE_CHECK_QUERIES, SEED ^ 0x3073);

    let mut bevy = BevyMoves::new(&scene, true);
    let mut bevy_moves_alone = BevyMoves::new(&scene, true).repair_untimed();
    let mut bevy_single = BevyMoves::new(&scene, false);
    let mut rstar = RstarMoves::new(&scene);
    let mut parry0 = ParryMoves::new(&scene, 0.0);
    let mut parry01 = ParryMoves::new(&scene, 0.1);
    let mut parry0_optimized = ParryMoves::new(&scene, 0.0).optimized();
    let mut flat = FlatMoves {
        scene: scene.clone(),
        flat: scene.boxes().to_vec(),
    };

    // A few frames, then check every contender against the oracle.
    bevy.frame(CHECK_FRAMES as u64);
    bevy_moves_alone.frame(CHECK_FRAMES as u64);
    bevy_single.frame(CHECK_FRAMES as u64);
    rstar.frame(CHECK_FRAMES as u64);
    parry0.frame(CHECK_FRAMES as u64);
    parry01.frame(CHECK_FRAMES as u64);
    parry0_optimized.frame(CHECK_FRAMES as u64);
    flat.frame(CHECK_FRAMES as u64);
    bevy.check(&checks);
    bevy_moves_alone.check(&checks);
    bevy_single.check(&checks);
    rstar.check(&checks);
    parry0.check(&checks);
    parry01.check(&checks);
    parry0_optimized.check(&checks);
    flat.check();
    eprintln!("moves check ok after {CHECK_FRAMES} frames");
    bevy.tree.take_maintenance_stats();
    let frames_before = bevy.scene.frame();

    let mut group = c.benchmark_group("frame/moves_10k");
    group.bench_function("bevy_rtree", |b| b.iter_custom(|iters| bevy.frame(iters)));
    group.bench_function("bevy_rtree_repair_untimed", |b| {
        b.iter_custom(|iters| bevy_moves_alone.frame(iters))
    });
    group.bench_function("bevy_rtree_one_by_one", |b| {
        b.iter_custom(|iters| bevy_single.frame(iters))
    });
    group.bench_function("rstar", |b| b.iter_custom(|iters| rstar.frame(iters)));
    group.bench_function("parry3d_margin0", |b| {
        b.iter_custom(|iters| parry0.frame(iters))
    });
    group.bench_function("parry3d_margin0.1", |b| {
        b.iter_custom(|iters| parry01.frame(iters))
    });
    group.bench_function("parry3d_margin0_optimize_incremental", |b| {
        b.iter_custom(|iters| parry0_optimized.frame(iters))
    });
    group.bench_function("flat_array", |b| b.iter_custom(|iters| flat.frame(iters)));
    group.finish();

    // The indexes went through many more frames while timed: check again.
    bevy.check(&checks);
    bevy_moves_alone.check(&checks);
    bevy_single.check(&checks);
    rstar.check(&checks);
    parry0.check(&checks);
    parry01.check(&checks);
    parry0_optimized.check(&checks);
    flat.check();
    let frames = (bevy.scene.frame() - frames_before).max(1);
    let stats = bevy.tree.take_maintenance_stats();
    eprintln!(
        "moves bench: bevy_rtree ran {frames} timed/warm-up frames; per frame: in place {:.0}, in leaf {:.0}, leaf grown {:.0}, reinserted {:.0}, splits {:.1}, condensed {:.1}, repacks {:.1}; height {}; post-check ok",
        stats.moves_in_place as f64 / frames as f64,
        stats.moves_in_leaf as f64 / frames as f64,
        stats.moves_leaf_grown as f64 / frames as f64,
        stats.moves_reinserted as f64 / frames as f64,
        stats.splits as f64 / frames as f64,
        stats.condensed_nodes as f64 / frames as f64,
        stats.repacks as f64 / frames as f64,
        bevy.tree.height()
    );
}

// ---------------------------------------------------------------------------
// query/boxes

/// Times one `query/boxes`-style iteration under `name`: every query of
/// `queries` answered by `answer` into a cleared, reused list.
fn bench_box_queries<Q>(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    queries: &[Q],
    mut answer: impl FnMut(&Q, &mut Vec<u32>),
) {
    group.bench_function(name, |b| {
        let mut out = Vec::new();
        b.iter(|| {
            let mut total = 0;
            for q in queries {
                out.clear();
                answer(q, &mut out);
                total += out.len();
            }
            black_box(total)
        })
    });
}

/// [`bench_box_queries`] on one of our trees.
fn bench_tree_boxes(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    tree: &RTree<u32>,
    queries: &[Aabb],
) {
    let mut ws = QueryWorkspace::default();
    bench_box_queries(group, name, queries, |q, out| {
        tree.overlapping_into(q, &mut ws, out)
    });
}

fn bench_queries(c: &mut Criterion) {
    // The churned tree: 600 frames of moves + optimize on the standard scene.
    let mut churn = BevyMoves::new(&TownScene::new(TownScene::STANDARD_COUNT, SEED), true);
    churn.tree.take_maintenance_stats();
    let start = Instant::now();
    churn.frame(CHURN_FRAMES as u64);
    let BevyMoves {
        scene,
        tree: mut churned,
        ..
    } = churn;
    churned.validate().unwrap();
    let s = churned.take_maintenance_stats();
    eprintln!(
        "churn {CHURN_FRAMES} frames ({:.1} s): moves in place {}, in leaf {}, reinserted {}; splits {}, condensed {}, repacks {}; height {}, nodes {}",
        start.elapsed().as_secs_f64(),
        s.moves_in_place,
        s.moves_in_leaf,
        s.moves_reinserted,
        s.splits,
        s.condensed_nodes,
        s.repacks,
        churned.height(),
        churned.node_count()
    );

    // Every other contender indexes the churned scene's current boxes.
    let boxes = scene.boxes().to_vec();
    let (fresh, _) = bulk_tree(&boxes);
    let rstar = rstar::RTree::bulk_load(rstar_items(&boxes));
    let parry = Bvh::from_leaves(BvhBuildStrategy::Binned, &parry_leaves(&boxes));
    let soa = SoaBoxes::new(&boxes);
    let queries = query_boxes(QUERY_COUNT, SEED ^ 0x0E17);
    let rstar_queries: Vec<_> = queries.iter().map(rstar_envelope).collect();
    let parry_queries: Vec<_> = queries.iter().map(to_parry).collect();

    // Check every contender on every query box. rstar and parry use closed
    // boxes like the oracle, with the same f32 comparisons, so the answers
    // must be identical (no tolerance for touching boxes is needed).
    let oracle = oracle_of(&boxes);
    let mut hits = 0usize;
    let mut ws_fresh = QueryWorkspace::default();
    let mut ws_churned = QueryWorkspace::default();
    for q in &queries {
        let want = oracle.overlapping(q);
        hits += want.len();
        let mut got = Vec::new();
        fresh.overlapping_into(q, &mut ws_fresh, &mut got);
        assert_same("bevy_rtree_fresh", q, &sorted(got), &want);
        let mut got = Vec::new();
        churned.overlapping_into(q, &mut ws_churned, &mut got);
        assert_same("bevy_rtree_churned", q, &sorted(got), &want);
        assert_same("rstar", q, &answer_rstar(&rstar, q), &want);
        assert_same("parry3d", q, &answer_parry(&parry, q), &want);
        let mut got = Vec::new();
        soa.overlapping_into(q, &mut got);
        assert_same("brute_force", q, &got, &want);
    }
    let per_query = |ws: &mut QueryWorkspace| {
        let s = ws.take_stats();
        (
            s.nodes_visited as f64 / QUERY_COUNT as f64,
            s.entries_tested as f64 / QUERY_COUNT as f64,
        )
    };
    let (fresh_nodes, fresh_entries) = per_query(&mut ws_fresh);
    let (churned_nodes, churned_entries) = per_query(&mut ws_churned);
    eprintln!(
        "query check ok: {QUERY_COUNT} boxes, {:.1} hits/query; per query fresh: {fresh_nodes:.1} nodes, {fresh_entries:.1} entries tested (height {}); churned: {churned_nodes:.1} nodes, {churned_entries:.1} entries (height {})",
        hits as f64 / QUERY_COUNT as f64,
        fresh.height(),
        churned.height()
    );

    let mut group = c.benchmark_group("query/boxes");
    for (name, tree) in [
        ("bevy_rtree_fresh", &fresh),
        ("bevy_rtree_churned", &churned),
    ] {
        bench_tree_boxes(&mut group, name, tree, &queries);
    }
    bench_box_queries(&mut group, "rstar", &rstar_queries, |q, out| {
        out.extend(rstar.locate_in_envelope_intersecting(*q).map(|g| g.data))
    });
    bench_box_queries(&mut group, "parry3d", &parry_queries, |q, out| {
        out.extend(parry.intersect_aabb(q))
    });
    bench_box_queries(&mut group, "brute_force", &queries, |q, out| {
        soa.overlapping_into(q, out)
    });
    group.finish();
}

// ---------------------------------------------------------------------------
// split/*: the node split strategies (`TreeSettings::split`) side by side on
// what a split decides: the cost of single inserts and of a frame's moves,
// and the quality of the tree those leave behind.

const SPLITS: [(&str, SplitStrategy); 3] = [
    ("rstar", SplitStrategy::RStar),
    ("quadratic", SplitStrategy::Quadratic),
    ("median", SplitStrategy::Median),
];

fn split_settings(split: SplitStrategy) -> TreeSettings {
    TreeSettings {
        split,
        ..TreeSettings::default()
    }
}

fn inserted_tree(boxes: &[Aabb], settings: TreeSettings) -> RTree<u32> {
    let mut tree = RTree::with_settings(settings).expect("valid settings");
    for (i, aabb) in boxes.iter().enumerate() {
        tree.insert(i as u32, *aabb).unwrap();
    }
    tree
}

/// Average nodes visited and entries tested per query of `queries`, after
/// checking every answer against `oracle`.
fn checked_query_work(
    who: &str,
    tree: &RTree<u32>,
    oracle: &BruteForce<u32>,
    queries: &[Aabb],
) -> (f64, f64) {
    let mut ws = QueryWorkspace::default();
    for q in queries {
        let mut got = Vec::new();
        tree.overlapping_into(q, &mut ws, &mut got);
        assert_same(who, q, &sorted(got), &oracle.overlapping(q));
    }
    let s = ws.take_stats();
    let n = queries.len() as f64;
    (s.nodes_visited as f64 / n, s.entries_tested as f64 / n)
}

fn bench_splits(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let boxes = scene.boxes().to_vec();
    let queries = query_boxes(QUERY_COUNT, SEED ^ 0x0E17);

    let oracle = oracle_of(&boxes);
    for (name, split) in SPLITS {
        let tree = inserted_tree(&boxes, split_settings(split));
        tree.validate().unwrap();
        let (nodes, entries) = checked_query_work(name, &tree, &oracle, &queries);
        eprintln!(
            "split check ok: {name} after 100,000 inserts: height {}, {} nodes; per query {nodes:.1} nodes, {entries:.1} entries tested",
            tree.height(),
            tree.node_count()
        );
    }
    let mut group = c.benchmark_group("split/insert_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    for (name, split) in SPLITS {
        group.bench_function(name, |b| {
            b.iter_batched(
                || (),
                |()| inserted_tree(&boxes, split_settings(split)),
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();

    // Each strategy's tree goes through the same frames: first the moves
    // group's (timed, as many as criterion runs), then untimed ones until all
    // trees reach the same frame, at least `CHURN_FRAMES`; the queries are
    // timed on the boxes of that frame.
    let mut churned = Vec::new();
    let mut group = c.benchmark_group("split/moves_10k");
    for (name, split) in SPLITS {
        let mut moves = BevyMoves::with_settings(&scene, true, split_settings(split));
        group.bench_function(name, |b| b.iter_custom(|iters| moves.frame(iters)));
        churned.push(moves);
    }
    group.finish();
    let last_frame = churned
        .iter()
        .map(|m| m.scene.frame())
        .max()
        .unwrap_or(0)
        .max(CHURN_FRAMES as u64);
    for moves in &mut churned {
        let left = last_frame - moves.scene.frame();
        moves.frame(left);
    }
    let oracle = oracle_of(churned[0].scene.boxes());
    let (fresh, _) = bulk_tree(churned[0].scene.boxes());
    let (fresh_nodes, fresh_entries) = checked_query_work("fresh", &fresh, &oracle, &queries);
    eprintln!(
        "split check ok: bulk loaded at frame {last_frame}: height {}, {} nodes; per query {fresh_nodes:.1} nodes, {fresh_entries:.1} entries tested",
        fresh.height(),
        fresh.node_count()
    );
    for ((name, _), moves) in SPLITS.iter().zip(&churned) {
        moves.tree.validate().unwrap();
        let (nodes, entries) = checked_query_work(name, &moves.tree, &oracle, &queries);
        eprintln!(
            "split check ok: {name} churned to frame {last_frame}: height {}, {} nodes; per query {nodes:.1} nodes, {entries:.1} entries tested",
            moves.tree.height(),
            moves.tree.node_count()
        );
    }
    let mut group = c.benchmark_group("split/boxes_churned");
    let trees = std::iter::once(("bulk_loaded", &fresh)).chain(
        SPLITS
            .iter()
            .zip(&churned)
            .map(|((name, _), m)| (*name, &m.tree)),
    );
    for (name, tree) in trees {
        bench_tree_boxes(&mut group, name, tree, &queries);
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_secs(1), Duration::from_secs(3));
    targets = bench_build, bench_moves, bench_queries, bench_splits
}
criterion_main!(benches);
