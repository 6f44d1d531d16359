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

use std::time::{Duration, Instant};

use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, CullMode, Frustum, JoinMode, QueryWorkspace, Ray, RayMode, RayResults};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use parry3d::partitioning::BvhWorkspace;

mod common;
use common::indexes::{BevyIndex, ParryIndex, RstarIndex};
use common::{bench_answers, bench_list};

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

#[path = "queries/brute_force.rs"]
mod brute_force;
#[path = "queries/checks.rs"]
mod checks;
#[path = "queries/peers.rs"]
mod peers;
#[path = "queries/ratios.rs"]
mod ratios;
use brute_force::{SoaBoxes, Sweep};
use checks::check;
use peers::{
    Planes, RayPrep, parry_build_and_cross_join, parry_cross_join, parry_first_hit, parry_leaves,
    parry_self_join, parry_visible_into, rstar_cross_join, rstar_first_hit, rstar_self_join,
    rstar_visible_into,
};
use ratios::{cold_ratios, paired_ratios};

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

criterion_group! {
    name = benches;
    config = common::config(Duration::from_millis(500), Duration::from_secs(2));
    targets = bench_all
}
criterion_main!(benches);
