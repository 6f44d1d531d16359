//! ECS overhead: one frame of the standard "town" scene through
//! `SpatialIndexPlugin` against the same work done on the core trees directly.
//!
//! The plugin side is the town example itself (`examples/town.rs`, included
//! below as a module), so the bench times exactly the App a user would run:
//! 100,000 entities with `SpatialBounds`, `Enemy` / `Barrel` layers, one
//! `CullingCamera`, 2,000 `RayCaster`s (first hit) and the enemy-barrel join
//! at 5 m (Euclidean).
//!
//! The core side keeps an `RTree<u32>` of all entities plus one tree of
//! enemies and one of barrels from frame to frame, keyed by scene index. Per
//! frame it does what the example's systems and the plugin do, in the same
//! order: advance the scene and re-aim the camera and the rays; update each
//! moved box in every tree it belongs to; `optimize` every tree with the
//! plugin's budget; `visible_into` the frustum (conservative); `cast_rays`
//! the same 2,000 rays (first hit); `cross_join_into` enemies x barrels;
//! then sort the visible list and the pairs, as the plugin does.
//!
//! Groups:
//! - `ecs/frame`: `plugin` is one `app.update()`, `core` one core frame; the
//!   ratio of their medians is the overhead of the ECS.
//! - `ecs/phases` (printed, not a criterion group): the two paths run
//!   interleaved frame by frame, the plugin's frame split into phases by
//!   marker systems around its system sets. Printed: medians per phase, the
//!   median of per-frame ratios (neighbouring frames share the machine's
//!   load, so this ratio drifts least on a busy machine; interleaving also
//!   costs both paths their warm caches), the core's query calls repeated on
//!   the plugin's own `Entity`-keyed trees (what the queries cost without
//!   the ECS around them), and a probe that repeats the ECS side of the
//!   plugin's sync (change-detection scans, entity-to-handle lookups).
//!
//! Before any timing, `CHECK_FRAMES` frames of both paths are compared: the
//! visible list, every ray's first hit and the pairs must be equal (core keys
//! mapped to entities through `Town::entities`; a first hit tied in `t` is
//! resolved by `Entity` order, as the plugin's tree does), and the plugin's
//! last frame must agree with brute force (the example's own oracle check).
//! A disagreement panics.
//!
//! With the default features bevy_ecs runs every schedule single-threaded;
//! `--features multi_threaded` switches to its multi-threaded executor (the
//! core side stays single-threaded either way).

use std::hint::black_box;
use std::time::Duration;

use bevy_rtree::scene::TownScene;
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};

// The example is included rather than copied so that the plugin side is, by
// construction, the scene and systems the example runs. Its `main` and
// argument parsing are unused here.
#[path = "../examples/town.rs"]
#[allow(dead_code)]
mod town;

mod common;

/// The example's seed.
const SEED: u64 = 2024;
/// Frames of both paths compared before timing.
const CHECK_FRAMES: usize = 3;
/// Untimed frames before `ecs/phases` records, so both paths start from
/// churned trees, as in the criterion group after its warm-up.
const PHASE_WARM_FRAMES: usize = 30;
/// Interleaved frames recorded by `ecs/phases`: three turns of the camera.
const PHASE_FRAMES: usize = 180;
/// Rays per frame: 1,000 incoherent, then 1,000 coherent (the example's).
const INCOHERENT_RAYS: usize = 1_000;

#[path = "ecs/core_town.rs"]
mod core_town;
use core_town::CoreTown;
#[path = "ecs/checks.rs"]
mod checks;
use checks::check_paths;
#[path = "ecs/phases.rs"]
mod phases;
use phases::report_phases;

// ---------------------------------------------------------------------------
// ecs/frame

fn bench_frame(c: &mut Criterion) {
    let mut app = town::build(TownScene::STANDARD_COUNT, SEED);
    let mut core = CoreTown::new(TownScene::STANDARD_COUNT, SEED);
    check_paths(&mut app, &mut core);

    let mut group = c.benchmark_group("ecs/frame");
    // One iteration is a whole frame (milliseconds): flat sampling keeps the
    // iteration count per sample equal and the total time bounded.
    group.sampling_mode(SamplingMode::Flat);
    group.bench_function("plugin", |b| b.iter(|| app.update()));
    group.bench_function("core", |b| {
        b.iter(|| {
            core.frame();
            black_box(core.pairs.len())
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_secs(2), Duration::from_secs(8));
    targets = bench_frame, report_phases
}
criterion_main!(benches);
