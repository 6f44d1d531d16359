//! What each precision-for-speed knob costs, measured in one run on the
//! standard "town" scene (`bevy_rtree::scene::TownScene`):
//!
//! 1. enlarged bounds (`TreeSettings`): absolute margins, margins as a
//!    fraction of the extent, and the displacement factor: update time
//!    against the extra candidates box queries then test, and the extra
//!    nodes a self join and incoherent rays then visit;
//! 2. conservative against exact frustum culling: time against false
//!    positives;
//! 3. Chebyshev against Euclidean joins: time against extra pairs;
//! 4. node width 4, 8 and 16: build, update, box query, cull, ray and join
//!    times;
//! 5. batched `cast_rays` against a loop of `cast_ray`: time, same answers;
//! 6. a long session with teleports: the jump limit and the rebuild
//!    (in slices, or on another thread as the plugin runs it), maintenance
//!    time against the work queries then do;
//! 7. with feature `bevy_camera`, Bevy's camera visibility from the index:
//!    the world boxes alone, Bevy's tests on every candidate, the inside
//!    proof, in time and in work.
//!
//! Every tree lives through the same frames: one scene advances, and every
//! contender is updated with the same moved boxes, in an order that rotates
//! from frame to frame so that none is always the first to touch a cold
//! cache. Every accuracy figure is counted against the brute-force oracle on
//! the frames it describes, and the answers are asserted equal to the
//! oracle's (the rays of every tenth frame and the last; the batched rays
//! equal to single rays in every frame), so the price of imprecision shows
//! as work and time, never as a wrong answer. Times are medians of single
//! runs timed with `std::time::Instant`.
//!
//! Run with `cargo run --release --example accuracy_cost --features
//! bevy_camera` (a few minutes). Options: `--count N` (entities) and
//! `--frames N` for a quicker run, `--warmup N` untimed frames of movement
//! before the measured ones (540 by default: the steady state of a
//! long-running game), `--no-docs` to print without writing. The tables go
//! to stdout and, from a run with feature `bevy_camera` (every section) at
//! the documented size (no `--count`, `--frames` or `--warmup` of another
//! value), to `docs/accuracy_cost.md`, the plots to
//! `docs/accuracy_cost_*.svg`.

#[cfg(feature = "bevy_camera")]
mod bevy_visibility;
mod contenders;
mod long_session;
mod measure;
mod modes;
mod report;
mod svg;

use std::path::Path;
use std::time::Instant;

use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_rtree::{JoinMode, RTree, TreeSettings};

use contenders::{Contender, Joined, Knob, contenders, join_trees};
use measure::{
    box_queries, mean, measure_box_queries, measure_builds, measure_churned_culls,
    measure_churned_joins_and_rays, measure_width_queries, median, min_max, oracle_of,
};
use modes::{FrameFigures, frame_modes};

/// The scene's seed, the same as the `town` example's.
const SEED: u64 = 2024;
/// Untimed frames of movement before the measured ones, by default: the
/// trees have lived through 600 frames when the measuring ends, the steady
/// state of a long-running game rather than a fresh load.
const WARMUP_FRAMES: usize = 540;
/// Box queries per set: a frame's worth of gameplay queries.
const BOX_QUERIES: usize = 1_000;
/// Half extent of a box query, in metres: a neighbourhood around an entity.
const BOX_QUERY_HALF: f32 = 5.0;
/// Timed runs of the box-query set per tree.
const QUERY_REPS: usize = 15;
/// Timed culls per frame and mode on the default tree.
const CULL_REPS: usize = 3;
/// Passes over the recorded frustums when timing culls on churned trees.
const CHURNED_CULL_REPS: usize = 2;
/// Bulk builds per node width.
const BUILD_REPS: usize = 9;
/// Timed runs of each ray set and of the join per node width.
const WIDTH_REPS: usize = 15;
/// Rays per ray set.
const RAY_COUNT: usize = 1_000;
/// Timed runs of the self join and the incoherent rays per churned tree.
const JOIN_RAY_REPS: usize = 5;
/// Timed runs per frame of each ray set, batched and single, interleaved.
const RAY_REPS: usize = 3;
/// The ray oracle tests 2,000 rays against every box; doing so every frame
/// would dominate the run, so it checks every tenth frame and the last.
const RAY_ORACLE_EVERY: usize = 10;
/// How much churn `optimize` may repair per frame: all of it, as the
/// benchmarks do, so update times include the full repair cost.
const OPTIMIZE_BUDGET: usize = usize::MAX;
/// The node widths compared.
const WIDTHS: [usize; 3] = [4, 8, 16];
/// The crate's default node width: the bounds policies and the modes are
/// measured at it.
const DEFAULT_WIDTH: usize = RTree::<u32>::WIDTH;

/// What the node widths cost beyond the contenders' figures.
#[derive(Default)]
struct WidthFigures {
    build_ms: [f64; 3],
    /// `[incoherent, coherent]` batched, on the churned trees.
    rays_ms: [[f64; 2]; 3],
    /// Euclidean cross join on the kept enemy and barrel trees.
    join_ms: [f64; 3],
}

/// The number after `name` on the command line, or `default` without one;
/// a value that is not a number stops the run with a message.
fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    let Some(i) = args.iter().position(|a| a == name) else {
        return default;
    };
    match args.get(i + 1).map(|v| v.parse()) {
        Some(Ok(value)) => value,
        _ => {
            eprintln!("{name} takes a number");
            std::process::exit(2);
        }
    }
}

struct Progress(Instant);

impl Progress {
    fn say(&self, what: &str) {
        eprintln!("[{:6.1} s] {what}", self.0.elapsed().as_secs_f64());
    }
}

fn main() {
    let count = arg("--count", TownScene::STANDARD_COUNT).max(100);
    let frames = arg("--frames", 60).max(1);
    let warmup = arg("--warmup", WARMUP_FRAMES);
    // The docs hold every section at the documented size: written only by
    // a run that has them all, at that size.
    let documented_size =
        count == TownScene::STANDARD_COUNT && frames == 60 && warmup == WARMUP_FRAMES;
    let write_docs = !std::env::args().any(|a| a == "--no-docs")
        && cfg!(feature = "bevy_camera")
        && documented_size;
    if !documented_size {
        eprintln!("a run of another size prints its tables and leaves docs/ as it is");
    }
    if !cfg!(feature = "bevy_camera") {
        eprintln!(
            "without feature bevy_camera section 7 is left out and docs/ is not written \
             (--features bevy_camera writes it)"
        );
    }
    let progress = Progress(Instant::now());
    let load_before = report::load_average();

    let mut scene = TownScene::new(count, SEED);
    let ranges = (
        TownScene::ENEMIES.start..TownScene::ENEMIES.end.min(count),
        TownScene::BARRELS.start.min(count)..TownScene::BARRELS.end.min(count),
    );
    progress.say(&format!(
        "town: {count} entities, {warmup} warm-up and {frames} measured frames; timing bulk builds"
    ));
    let mut widths = WidthFigures {
        build_ms: measure_builds(scene.boxes()),
        ..WidthFigures::default()
    };

    progress.say("loading the contenders");
    let mut contenders = contenders(scene.boxes());
    let default = contenders
        .iter()
        .position(Contender::is_default)
        .expect("the default settings are a contender");
    let default_join = WIDTHS
        .iter()
        .position(|&w| w == DEFAULT_WIDTH)
        .expect("the default width is compared");
    let mut joins: Vec<Box<dyn Joined>> = WIDTHS
        .iter()
        .map(|&w| join_trees(scene.boxes(), w, &ranges))
        .collect();

    // Box queries on the freshly loaded trees: the cost of the enlarged
    // bounds alone, before churn adds its own.
    let mut query_rng = SceneRng::new(SEED ^ 0xB0E5_B0E5);
    let around: Vec<usize> = (0..BOX_QUERIES).map(|_| query_rng.below(count)).collect();
    let queries = box_queries(scene.boxes(), &around);
    let oracle = oracle_of(scene.boxes(), 0..count);
    let truth: Vec<Vec<u32>> = queries.iter().map(|q| oracle.overlapping(q)).collect();
    progress.say("box queries on the fresh trees");
    let costs = measure_box_queries(&contenders, &queries, &truth);
    for (c, cost) in contenders.iter_mut().zip(costs) {
        c.fresh = cost;
    }

    for frame in 0..warmup {
        scene.advance_frame();
        for c in &mut contenders {
            c.index.apply(scene.moved(), scene.boxes());
        }
        for join in &mut joins {
            join.apply(scene.moved(), scene.boxes());
        }
        if (frame + 1) % 100 == 0 {
            progress.say(&format!("warm-up frame {}/{warmup}", frame + 1));
        }
    }
    for c in &mut contenders {
        c.index.take_maintenance();
    }

    let mut figures = FrameFigures::default();
    let mut frustums = Vec::with_capacity(frames);
    for frame in 0..frames {
        scene.advance_frame();
        let moved = scene.moved().to_vec();
        let n = contenders.len();
        for k in 0..n {
            let c = &mut contenders[(k + frame) % n];
            let (update, optimize) = c.index.apply(&moved, scene.boxes());
            c.update_ms.push(update + optimize);
            c.optimize_ms.push(optimize);
        }
        for join in &mut joins {
            join.apply(&moved, scene.boxes());
        }
        frustums.push(scene.frustum());

        let oracle = oracle_of(scene.boxes(), 0..count);
        let enemy_oracle = oracle_of(scene.boxes(), ranges.0.clone());
        let barrel_oracle = oracle_of(scene.boxes(), ranges.1.clone());
        frame_modes(
            frame,
            frame + 1 == frames,
            contenders[default].index.as_ref(),
            joins[default_join].as_ref(),
            &mut scene,
            [&oracle, &enemy_oracle, &barrel_oracle],
            &mut figures,
        );
        if (frame + 1) % 10 == 0 || frame + 1 == frames {
            progress.say(&format!(
                "frame {}/{frames}: default update + optimize {} ms, {} visible",
                frame + 1,
                report::ms(*contenders[default].update_ms.last().expect("timed")),
                figures.visible_exact.last().expect("counted"),
            ));
        }
    }
    for c in &mut contenders {
        c.moves = c.index.take_maintenance();
        if let Err(e) = c.index.validate() {
            panic!("{}: invalid tree after churn: {e}", c.label);
        }
    }

    progress.say("box queries and culls on the churned trees");
    let oracle = oracle_of(scene.boxes(), 0..count);
    let queries = box_queries(scene.boxes(), &around);
    let truth: Vec<Vec<u32>> = queries.iter().map(|q| oracle.overlapping(q)).collect();
    let true_answers = truth.iter().map(Vec::len).sum::<usize>() as f64 / queries.len() as f64;
    let costs = measure_box_queries(&contenders, &queries, &truth);
    for (c, cost) in contenders.iter_mut().zip(costs) {
        c.churned = cost;
    }
    let culls = measure_churned_culls(&contenders, &frustums, &oracle);
    for (c, ms) in contenders.iter_mut().zip(culls) {
        c.churned_cull_ms = ms;
    }

    progress.say("self joins and incoherent rays on the churned trees");
    let ray_sets = [scene.incoherent_rays(RAY_COUNT), scene.coherent_rays()];
    // The oracle's first hits, once for both measurements below.
    let ray_truth = ray_sets.each_ref().map(|rays| {
        rays.iter()
            .map(|r| oracle.ray_first(r).expect("valid ray"))
            .collect::<Vec<_>>()
    });
    let work = measure_churned_joins_and_rays(&contenders, &ray_sets[0], &ray_truth[0], &oracle);
    for (c, [join, rays]) in contenders.iter_mut().zip(work) {
        c.churned_self_join = join;
        c.churned_rays = rays;
    }

    progress.say("rays and joins per node width");
    let width_trees = WIDTHS.map(|w| {
        contenders
            .iter()
            .find(|c| c.width == w && c.settings == TreeSettings::default())
            .expect("a contender per width")
            .index
            .as_ref()
    });
    let pairs = oracle_of(scene.boxes(), ranges.0.clone())
        .cross_join(
            &oracle_of(scene.boxes(), ranges.1.clone()),
            TownScene::JOIN_DISTANCE,
            JoinMode::Euclidean,
        )
        .expect("a valid distance");
    (widths.rays_ms, widths.join_ms) =
        measure_width_queries(width_trees, &joins, &ray_sets, &ray_truth, &pairs);

    progress.say("a long session with teleports");
    let sessions = long_session::measure(count);
    #[cfg(feature = "bevy_camera")]
    let bevy_section = {
        progress.say("Bevy's visibility three ways");
        let mut s = String::new();
        bevy_visibility::markdown(&bevy_visibility::measure(), &mut s);
        s
    };
    #[cfg(not(feature = "bevy_camera"))]
    let bevy_section = String::new();

    let report = report::Report {
        sessions: &sessions,
        bevy_section,
        count,
        frames,
        warmup,
        contenders: &contenders,
        default,
        widths: &widths,
        figures: &figures,
        true_answers,
        run_seconds: progress.0.elapsed().as_secs_f64(),
        load: (load_before, report::load_average()),
    };
    let markdown = report.markdown();
    println!("{markdown}");
    if write_docs {
        let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs");
        std::fs::create_dir_all(&docs).expect("create docs/");
        std::fs::write(docs.join("accuracy_cost.md"), &markdown).expect("write the report");
        for (name, figure) in report.figures() {
            std::fs::write(docs.join(name), figure.to_svg()).expect("write a plot");
        }
        progress.say("wrote docs/accuracy_cost.md and docs/accuracy_cost_*.svg");
    }
}
