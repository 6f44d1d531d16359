//! The parallel queries (feature `parallel`) against the same queries on one
//! thread, on the standard town scene maintained through `WARM_FRAMES`
//! frames of movement, as in `benches/queries.rs`.
//!
//! Run with `cargo bench --features parallel --bench parallel`. Each group
//! has `single` (the ordinary call) and `parallel` (the `par_` call on
//! bevy_tasks' `ComputeTaskPool`, one thread per core); the speed-up is
//! single / parallel. Before any timing the two answers are compared on
//! every timed input and must be identical.
//!
//! Groups (one iteration = one operation of one frame):
//! - `parallel/rays_incoherent`, `parallel/rays_coherent`,
//!   `parallel/rays_coherent_clear_eye`: 1,000 rays, first hit, as in the
//!   queries bench (from the standard eye, inside boxes, one point query
//!   answers every coherent ray; from the clear eye every ray walks);
//! - `parallel/rays_incoherent_4000`: 4,000 incoherent rays in one batch
//!   (a frame with four times the standard scene's rays), to show how the
//!   speed-up grows once the work outweighs a pool thread's start;
//! - `parallel/rays_incoherent_after_idle`: the 1,000 incoherent rays
//!   again, but each timed call comes after `IDLE_GAP` of sleep (untimed),
//!   as a game's once-per-frame call does: the pool threads have gone to
//!   sleep by then, and this shows what waking one costs;
//! - `parallel/frustum`: the standard camera, conservative;
//! - `parallel/frustum_4_views`: the camera and three more yaws in one call
//!   (a frame's cameras and shadow views);
//! - `parallel/cross_join`: enemies x barrels within 5 m, Euclidean;
//! - `parallel/self_join`: all touching or overlapping pairs (d = 0).
//!
//! With `BEVY_RTREE_THREADS=n` the pool has exactly `n` threads; with
//! `BEVY_RTREE_PAIRED_ONLY=1` only the paired blocks below run (what
//! `scripts/scaling.sh` does for 1 to 16 threads).
//!
//! After the groups, `paired_speed_ups` times the single and the parallel
//! call again in alternating short blocks (`common/paired.rs`) and prints
//! the speed-up's median and range; the table is also written to
//! `target/criterion/parallel_paired_speed_ups.md`.

use std::hint::black_box;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    CullMode, Frustum, JoinMode, ParallelWorkspace, ProxyId, QueryWorkspace, RTree, Ray, RayMode,
    RayResults,
};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};

mod common;
use common::{bench_answers, bench_list};

const SEED: u64 = 0x5EED_2024;
const WARM_FRAMES: usize = 60;
/// The untimed pause before each call of `parallel/rays_incoherent_after_idle`:
/// about what the rest of a 60 Hz frame leaves between two calls.
const IDLE_GAP: Duration = Duration::from_millis(2);

struct Trees {
    all: RTree<u32>,
    enemies: RTree<u32>,
    barrels: RTree<u32>,
}

struct Inputs {
    frustums: Vec<Frustum>,
    incoherent: Vec<Ray>,
    incoherent_4000: Vec<Ray>,
    coherent: Vec<Ray>,
    coherent_clear_eye: Vec<Ray>,
}

fn maintained(scene: &TownScene, range: std::ops::Range<usize>) -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::new();
    let boxes = scene.boxes();
    let ids = tree
        .insert_bulk(range.map(|i| (i as u32, boxes[i])))
        .expect("scene boxes are valid");
    (tree, ids)
}

fn setup() -> (Trees, Inputs) {
    let mut scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let mut trees = [
        (0..scene.len(), maintained(&scene, 0..scene.len())),
        (TownScene::ENEMIES, maintained(&scene, TownScene::ENEMIES)),
        (TownScene::BARRELS, maintained(&scene, TownScene::BARRELS)),
    ];
    for _ in 0..WARM_FRAMES {
        scene.advance_frame();
        for (range, (tree, ids)) in &mut trees {
            for &i in scene.moved() {
                let i = i as usize;
                if range.contains(&i) {
                    let id = ids[i - range.start];
                    tree.update(id, scene.boxes()[i]).expect("valid box");
                }
            }
            tree.optimize(usize::MAX);
        }
    }
    let frustums = (0..4)
        .map(|_| {
            let f = scene.frustum();
            scene.advance_frame();
            f
        })
        .collect();
    let coherent = scene.coherent_rays();
    let coherent_clear_eye = scene.coherent_rays_from(scene.clear_eye());
    let incoherent = scene.incoherent_rays(1_000);
    let incoherent_4000 = scene.incoherent_rays(4_000);
    let [(_, (all, _)), (_, (enemies, _)), (_, (barrels, _))] = trees;
    (
        Trees {
            all,
            enemies,
            barrels,
        },
        Inputs {
            frustums,
            incoherent,
            incoherent_4000,
            coherent,
            coherent_clear_eye,
        },
    )
}

/// Slot by slot, the two batches answered the same.
fn same_rays(a: &RayResults<u32>, b: &RayResults<u32>) -> bool {
    a.len() == b.len() && (0..a.len()).all(|i| a.hits(i) == b.hits(i) && a.any(i) == b.any(i))
}

fn check(trees: &Trees, inputs: &Inputs, pws: &mut ParallelWorkspace<u32>) {
    let mut ws = QueryWorkspace::default();
    for rays in [
        &inputs.incoherent,
        &inputs.incoherent_4000,
        &inputs.coherent,
        &inputs.coherent_clear_eye,
    ] {
        let (mut single, mut parallel) = (RayResults::default(), RayResults::default());
        trees
            .all
            .cast_rays(rays, RayMode::First, &mut ws, &mut single);
        trees
            .all
            .par_cast_rays(rays, RayMode::First, pws, &mut parallel);
        assert!(same_rays(&single, &parallel), "rays differ");
    }
    for views in [&inputs.frustums[..1], &inputs.frustums[..]] {
        let mut single = vec![Vec::new(); views.len()];
        let mut parallel = vec![Vec::new(); views.len()];
        let mode = CullMode::Conservative;
        trees.all.visible_into(views, mode, &mut ws, &mut single);
        trees.all.par_visible_into(views, mode, pws, &mut parallel);
        assert_eq!(single, parallel, "culling differs");
    }
    let (d, mode) = (TownScene::JOIN_DISTANCE, JoinMode::Euclidean);
    let (mut single, mut parallel) = (Vec::new(), Vec::new());
    let (enemies, barrels) = (&trees.enemies, &trees.barrels);
    enemies
        .cross_join_into(barrels, d, mode, &mut ws, &mut single)
        .expect("valid distance");
    enemies
        .par_cross_join_into(barrels, d, mode, pws, &mut parallel)
        .expect("valid distance");
    assert_eq!(single, parallel, "cross joins differ");
    let (mut single, mut parallel) = (Vec::new(), Vec::new());
    trees
        .all
        .self_join_into(0.0, mode, &mut ws, &mut single)
        .expect("valid distance");
    trees
        .all
        .par_self_join_into(0.0, mode, pws, &mut parallel)
        .expect("valid distance");
    assert_eq!(single, parallel, "self joins differ");
    eprintln!(
        "check: parallel answers equal single-threaded answers; last split {} tasks on {} pool threads",
        pws.last_split(),
        bevy_tasks::ComputeTaskPool::get().thread_num()
    );
}

fn bench_rays(cr: &mut Criterion, trees: &Trees, name: &str, rays: &[Ray]) {
    let mut group = cr.benchmark_group(name);
    let mut ws = QueryWorkspace::default();
    bench_answers(&mut group, "single", RayResults::default(), |out| {
        trees.all.cast_rays(rays, RayMode::First, &mut ws, out);
    });
    let mut pws = ParallelWorkspace::default();
    bench_answers(&mut group, "parallel", RayResults::default(), |out| {
        trees.all.par_cast_rays(rays, RayMode::First, &mut pws, out);
    });
    group.finish();
}

/// [`bench_rays`] with `IDLE_GAP` of sleep before each timed call.
fn bench_rays_after_idle(cr: &mut Criterion, trees: &Trees, name: &str, rays: &[Ray]) {
    let mut group = cr.benchmark_group(name);
    // Every iteration sleeps, so few samples keep the wall time short.
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let mut after_idle = |name: &str, cast: &mut dyn FnMut(&mut RayResults<u32>)| {
        let mut out = RayResults::default();
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    std::thread::sleep(IDLE_GAP);
                    let start = Instant::now();
                    cast(&mut out);
                    total += start.elapsed();
                    black_box(&out);
                }
                total
            })
        });
    };
    let mut ws = QueryWorkspace::default();
    after_idle("single", &mut |out| {
        trees.all.cast_rays(rays, RayMode::First, &mut ws, out);
    });
    let mut pws = ParallelWorkspace::default();
    after_idle("parallel", &mut |out| {
        trees.all.par_cast_rays(rays, RayMode::First, &mut pws, out);
    });
    group.finish();
}

fn bench_frustum(cr: &mut Criterion, trees: &Trees, name: &str, views: &[Frustum]) {
    let mut group = cr.benchmark_group(name);
    let mode = CullMode::Conservative;
    let lists = || vec![Vec::new(); views.len()];
    let mut ws = QueryWorkspace::default();
    bench_answers(&mut group, "single", lists(), |out| {
        out.iter_mut().for_each(Vec::clear);
        trees.all.visible_into(views, mode, &mut ws, out);
    });
    let mut pws = ParallelWorkspace::default();
    bench_answers(&mut group, "parallel", lists(), |out| {
        out.iter_mut().for_each(Vec::clear);
        trees.all.par_visible_into(views, mode, &mut pws, out);
    });
    group.finish();
}

fn bench_joins(cr: &mut Criterion, trees: &Trees) {
    let (d, mode) = (TownScene::JOIN_DISTANCE, JoinMode::Euclidean);
    let (enemies, barrels) = (&trees.enemies, &trees.barrels);
    let mut group = cr.benchmark_group("parallel/cross_join");
    let mut ws = QueryWorkspace::default();
    bench_list(&mut group, "single", |out| {
        let result = enemies.cross_join_into(barrels, d, mode, &mut ws, out);
        result.expect("valid distance");
    });
    let mut pws = ParallelWorkspace::default();
    bench_list(&mut group, "parallel", |out| {
        let result = enemies.par_cross_join_into(barrels, d, mode, &mut pws, out);
        result.expect("valid distance");
    });
    group.finish();

    let mut group = cr.benchmark_group("parallel/self_join");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    let mut ws = QueryWorkspace::default();
    bench_list(&mut group, "single", |out| {
        let result = trees.all.self_join_into(0.0, mode, &mut ws, out);
        result.expect("valid distance");
    });
    let mut pws = ParallelWorkspace::default();
    bench_list(&mut group, "parallel", |out| {
        let result = trees.all.par_self_join_into(0.0, mode, &mut pws, out);
        result.expect("valid distance");
    });
    group.finish();
}

fn bench_all(cr: &mut Criterion) {
    let threads = pool_threads();
    let (trees, inputs) = setup();
    check(&trees, &inputs, &mut ParallelWorkspace::default());
    if std::env::var_os("BEVY_RTREE_PAIRED_ONLY").is_some() {
        paired_speed_ups(&trees, &inputs, threads);
        return;
    }
    bench_rays(cr, &trees, "parallel/rays_incoherent", &inputs.incoherent);
    let many = &inputs.incoherent_4000;
    bench_rays(cr, &trees, "parallel/rays_incoherent_4000", many);
    let name = "parallel/rays_incoherent_after_idle";
    bench_rays_after_idle(cr, &trees, name, &inputs.incoherent);
    bench_rays(cr, &trees, "parallel/rays_coherent", &inputs.coherent);
    let clear = &inputs.coherent_clear_eye;
    bench_rays(cr, &trees, "parallel/rays_coherent_clear_eye", clear);
    bench_frustum(cr, &trees, "parallel/frustum", &inputs.frustums[..1]);
    bench_frustum(cr, &trees, "parallel/frustum_4_views", &inputs.frustums);
    bench_joins(cr, &trees);
    paired_speed_ups(&trees, &inputs, threads);
}

/// The task pool's size: `BEVY_RTREE_THREADS` threads if set (so that a
/// scaling run means the same on any machine: `scripts/scaling.sh`), else
/// one per core.
fn pool_threads() -> usize {
    let pool =
        bevy_tasks::ComputeTaskPool::get_or_init(|| match common::threads::threads_wanted() {
            Some(n) => bevy_tasks::TaskPoolBuilder::new().num_threads(n).build(),
            None => bevy_tasks::TaskPool::default(),
        });
    pool.thread_num()
}

/// The speed-ups again, with the single and the parallel call timed in
/// alternating short blocks (`common/paired.rs`), so that both see the same
/// state of the shared machine; criterion times them seconds apart. Prints
/// the median speed-up and its range over the rounds, and writes the table
/// to `target/criterion/parallel_paired_speed_ups.md`.
fn paired_speed_ups(trees: &Trees, inputs: &Inputs, threads: usize) {
    const ROUNDS: usize = 31;
    let mut rows = Vec::new();
    let mut ws = QueryWorkspace::default();
    let mut pws = ParallelWorkspace::default();
    let (mut single, mut parallel) = (RayResults::default(), RayResults::default());
    for (name, rays, per_block) in [
        ("1,000 incoherent rays", &inputs.incoherent, 10),
        ("4,000 incoherent rays", &inputs.incoherent_4000, 4),
        (
            "1,000 coherent rays, clear eye",
            &inputs.coherent_clear_eye,
            10,
        ),
    ] {
        let ratio = common::paired::paired_ratio(
            ROUNDS,
            per_block,
            || {
                let all = &trees.all;
                all.cast_rays(rays, RayMode::First, &mut ws, &mut single);
                single.len()
            },
            || {
                let all = &trees.all;
                all.par_cast_rays(rays, RayMode::First, &mut pws, &mut parallel);
                parallel.len()
            },
        );
        rows.push((name, ratio));
    }
    let mode = CullMode::Conservative;
    let views = &inputs.frustums;
    let (mut single, mut parallel) = (vec![Vec::new(); views.len()], vec![Vec::new(); views.len()]);
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        10,
        || {
            single.iter_mut().for_each(Vec::clear);
            trees.all.visible_into(views, mode, &mut ws, &mut single);
            single.iter().map(Vec::len).sum::<usize>()
        },
        || {
            parallel.iter_mut().for_each(Vec::clear);
            trees
                .all
                .par_visible_into(views, mode, &mut pws, &mut parallel);
            parallel.iter().map(Vec::len).sum::<usize>()
        },
    );
    rows.push(("frustum cull, four views", ratio));
    let (d, mode) = (TownScene::JOIN_DISTANCE, JoinMode::Euclidean);
    let (enemies, barrels) = (&trees.enemies, &trees.barrels);
    let (mut single, mut parallel) = (Vec::new(), Vec::new());
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        20,
        || {
            single.clear();
            let result = enemies.cross_join_into(barrels, d, mode, &mut ws, &mut single);
            result.expect("valid distance");
            single.len()
        },
        || {
            parallel.clear();
            let result = enemies.par_cross_join_into(barrels, d, mode, &mut pws, &mut parallel);
            result.expect("valid distance");
            parallel.len()
        },
    );
    rows.push(("cross join", ratio));
    let ratio = common::paired::paired_ratio(
        ROUNDS,
        3,
        || {
            single.clear();
            let result = trees.all.self_join_into(0.0, mode, &mut ws, &mut single);
            result.expect("valid distance");
            single.len()
        },
        || {
            parallel.clear();
            let result = trees
                .all
                .par_self_join_into(0.0, mode, &mut pws, &mut parallel);
            result.expect("valid distance");
            parallel.len()
        },
    );
    rows.push(("self join", ratio));

    // The paired ratio is single ÷ parallel here: the speed-up.
    let mut table = pool_start_times(threads);
    table += &format!(
        "speed-up on a pool of {threads} threads = one thread's time ÷ the `par_` call's, \
         alternating blocks, {ROUNDS} rounds\n\n\
         | query | one thread (µs) | `par_` (µs) | speed-up, median | speed-up, range |\n\
         |---|---:|---:|---:|---:|\n"
    );
    for (name, r) in &rows {
        table += &format!(
            "| {name} | {:.1} | {:.1} | {:.2} | {:.2}–{:.2} |\n",
            r.a_us, r.b_us, r.median, r.low, r.high
        );
    }
    eprintln!("\n{table}");
    let path = std::env::var("BEVY_RTREE_OUT")
        .unwrap_or_else(|_| "target/criterion/parallel_paired_speed_ups.md".to_string());
    let path = std::path::Path::new(&path);
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}

/// How long the pool's threads take to start on a call's tasks, the floor
/// under every split: the calling thread spawns one task per other pool
/// thread and spins until all have started (or 2 ms have passed). Returns a
/// line for the report with the medians, over `REPEATS` calls made 50 µs
/// apart (as a frame's back-to-back queries are), of the time until the
/// first, the middle and the last task started.
fn pool_start_times(threads: usize) -> String {
    const REPEATS: usize = 200;
    if threads < 2 {
        return String::new();
    }
    let pool = bevy_tasks::ComputeTaskPool::get();
    let tasks = threads - 1;
    let mut starts: Vec<Vec<f64>> = vec![Vec::with_capacity(REPEATS); tasks];
    for _ in 0..REPEATS {
        let pause = Instant::now();
        while pause.elapsed() < Duration::from_micros(50) {
            std::hint::spin_loop();
        }
        let started: Vec<AtomicU64> = (0..tasks).map(|_| Default::default()).collect();
        let count = AtomicUsize::new(0);
        let t0 = Instant::now();
        pool.scope(|scope| {
            for _ in 0..tasks {
                let (started, count) = (&started, &count);
                scope.spawn(async move {
                    let ns = t0.elapsed().as_nanos() as u64;
                    let k = count.fetch_add(1, Ordering::AcqRel);
                    started[k].store(ns, Ordering::Release);
                });
            }
            while count.load(Ordering::Acquire) < tasks && t0.elapsed() < Duration::from_millis(2) {
                std::hint::spin_loop();
            }
        });
        let mut ns: Vec<u64> = started.iter().map(|a| a.load(Ordering::Acquire)).collect();
        ns.sort_unstable();
        for (k, ns) in ns.iter().enumerate() {
            starts[k].push(*ns as f64 / 1e3);
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    if tasks == 1 {
        return format!(
            "pool start: the calling thread spawns 1 task; median over {REPEATS} calls \
             of the time until it started {:.1} µs\n\n",
            median(&mut starts[0]),
        );
    }
    let (first, middle, last) = (0, tasks / 2, tasks - 1);
    format!(
        "pool start: the calling thread spawns {tasks} tasks; medians over {REPEATS} calls \
         of the time until the first started {:.1} µs, the {} {:.1} µs, the last {:.1} µs\n\n",
        median(&mut starts[first]),
        ordinal(middle + 1),
        median(&mut starts[middle]),
        median(&mut starts[last]),
    )
}

fn ordinal(n: usize) -> String {
    let suffix = match (n % 10, n % 100) {
        (1, 11) | (2, 12) | (3, 13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_millis(500), Duration::from_secs(2));
    targets = bench_all
}
criterion_main!(benches);
