//! What each precision-for-speed knob costs, measured in one run on the
//! standard "town" scene (BENCHMARK.md, "Accuracy against time"):
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
//! the frames it describes, and every answer is asserted equal to the
//! oracle's, so the price of imprecision shows as work and time, never as a
//! wrong answer. Times are medians of single runs timed with
//! `std::time::Instant`.
//!
//! Run with `cargo run --release --example accuracy_cost`. Options:
//! `--count N` (entities) and `--frames N` for a quicker run, `--warmup N`
//! untimed frames of movement before the measured ones (for the steady
//! state of a long-running game), `--no-docs` to print without writing. The
//! tables go to stdout and, with feature `bevy_camera` (every section), to
//! `docs/accuracy_cost.md`, the plots to `docs/accuracy_cost_*.svg`.

#[cfg(feature = "bevy_camera")]
mod bevy_visibility;
mod long_session;
mod report;
mod svg;

use std::ops::Range;
use std::path::Path;
use std::time::Instant;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, MaintenanceStats, ProxyId, QueryWorkspace, RTree, Ray,
    RayHit, RayMode, RayResults, TreeSettings,
};
use glam::Vec3;

/// The scene's seed, the same as the `town` example's.
const SEED: u64 = 2024;
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

/// One kept tree of any node width, so the frame loop can treat every
/// contender alike.
trait Kept {
    /// Moves the scene's moved entities, then repairs churn; returns the
    /// milliseconds of each half.
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) -> (f64, f64);
    fn take_maintenance(&mut self) -> MaintenanceStats;
    fn overlapping_into(&self, query: &Aabb, ws: &mut QueryWorkspace, out: &mut Vec<u32>);
    fn cull_into(
        &self,
        frustum: &Frustum,
        mode: CullMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<u32>,
    );
    fn cast_rays_first(&self, rays: &[Ray], ws: &mut QueryWorkspace, out: &mut RayResults<u32>);
    fn cast_ray_first(&self, ray: &Ray, ws: &mut QueryWorkspace) -> Option<RayHit<u32>>;
    /// All touching or overlapping pairs (d = 0), unsorted.
    fn self_join_into(&self, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>);
    /// Height and node count.
    fn shape(&self) -> (usize, usize);
    fn validate(&self) -> Result<(), String>;
}

/// A tree keyed by entity index, and the handle of each of its entities.
struct Index<const W: usize> {
    tree: RTree<u32, W>,
    ids: Vec<ProxyId>,
    /// The first entity of the range the tree holds.
    start: usize,
    /// A frame's moves, kept to avoid reallocating.
    moves: Vec<(ProxyId, Aabb)>,
}

impl<const W: usize> Index<W> {
    fn load(boxes: &[Aabb], range: Range<usize>, settings: TreeSettings) -> Self {
        let mut tree = RTree::<u32, W>::with_settings(settings).expect("settings in range");
        let start = range.start;
        let ids = tree
            .insert_bulk(range.map(|i| (i as u32, boxes[i])))
            .expect("scene boxes are valid");
        Index {
            tree,
            ids,
            start,
            moves: Vec::new(),
        }
    }
}

impl<const W: usize> Kept for Index<W> {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) -> (f64, f64) {
        // One batch per frame, as the plugin applies a frame's moves.
        let start = Instant::now();
        self.moves.clear();
        self.moves.extend(moved.iter().filter_map(|&i| {
            let i = i as usize;
            let id = i.checked_sub(self.start).and_then(|k| self.ids.get(k))?;
            Some((*id, boxes[i]))
        }));
        self.tree
            .update_batch(&self.moves)
            .expect("scene boxes are valid");
        let updated = Instant::now();
        self.tree.optimize(OPTIMIZE_BUDGET);
        (ms_between(start, updated), ms_since(updated))
    }

    fn take_maintenance(&mut self) -> MaintenanceStats {
        self.tree.take_maintenance_stats()
    }

    fn overlapping_into(&self, query: &Aabb, ws: &mut QueryWorkspace, out: &mut Vec<u32>) {
        self.tree.overlapping_into(query, ws, out);
    }

    fn cull_into(
        &self,
        frustum: &Frustum,
        mode: CullMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<u32>,
    ) {
        self.tree
            .visit_visible(std::slice::from_ref(frustum), mode, ws, |_, key, _| {
                out.push(key);
                std::ops::ControlFlow::Continue(())
            });
    }

    fn cast_rays_first(&self, rays: &[Ray], ws: &mut QueryWorkspace, out: &mut RayResults<u32>) {
        self.tree.cast_rays(rays, RayMode::First, ws, out);
    }

    fn cast_ray_first(&self, ray: &Ray, ws: &mut QueryWorkspace) -> Option<RayHit<u32>> {
        self.tree.cast_ray(ray, ws).expect("scene rays are valid")
    }

    fn self_join_into(&self, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>) {
        self.tree
            .self_join_into(0.0, JoinMode::Euclidean, ws, out)
            .expect("a valid distance");
    }

    fn shape(&self) -> (usize, usize) {
        (self.tree.height(), self.tree.node_count())
    }

    fn validate(&self) -> Result<(), String> {
        self.tree.validate().map_err(|e| e.0)
    }
}

/// The kept enemy and barrel trees of one node width: joins need both sides
/// of the same width, which a trait object hides.
trait Joined {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]);
    fn cross_join_into(&self, mode: JoinMode, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>);
}

struct JoinTrees<const W: usize> {
    enemies: Index<W>,
    barrels: Index<W>,
}

impl<const W: usize> Joined for JoinTrees<W> {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) {
        self.enemies.apply(moved, boxes);
        self.barrels.apply(moved, boxes);
    }

    fn cross_join_into(&self, mode: JoinMode, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>) {
        self.enemies
            .tree
            .cross_join_into(&self.barrels.tree, TownScene::JOIN_DISTANCE, mode, ws, out)
            .expect("a valid distance");
    }
}

fn join_trees(
    boxes: &[Aabb],
    width: usize,
    ranges: &(Range<usize>, Range<usize>),
) -> Box<dyn Joined> {
    let d = TreeSettings::default();
    let (e, b) = ranges.clone();
    match width {
        4 => Box::new(JoinTrees::<4> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
        16 => Box::new(JoinTrees::<16> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
        _ => Box::new(JoinTrees::<8> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
    }
}

/// Which knob a contender varies.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Knob {
    Margin,
    Fraction,
    Displacement,
    /// How much churn a level-1 node absorbs before `optimize` repacks it.
    Repack,
    Width,
}

/// Time and traversal work of one query on one tree.
#[derive(Clone, Copy, Default)]
struct WorkCost {
    /// Median time.
    ms: f64,
    /// Nodes (node pairs, for a join) visited.
    nodes: u64,
}

/// Cost of the box-query set on one tree.
#[derive(Clone, Copy, Default)]
struct BoxCost {
    /// Median time of the whole set.
    ms: f64,
    /// Entries tested per query beyond the oracle's answer count.
    extra_per_query: f64,
    /// Nodes visited per query: the other half of the traversal's work.
    nodes_per_query: f64,
}

struct Contender {
    knob: Knob,
    /// Row label in the tables.
    label: String,
    /// Tick label in the plots.
    tick: String,
    width: usize,
    settings: TreeSettings,
    index: Box<dyn Kept>,
    /// Update plus optimize, per measured frame.
    update_ms: Vec<f64>,
    /// The optimize part alone, per measured frame.
    optimize_ms: Vec<f64>,
    /// Maintenance over the measured frames.
    moves: MaintenanceStats,
    fresh: BoxCost,
    churned: BoxCost,
    churned_cull_ms: f64,
    /// Self join (d = 0) on the churned tree.
    churned_self_join: WorkCost,
    /// The incoherent ray set on the churned tree.
    churned_rays: WorkCost,
}

impl Contender {
    fn is_default(&self) -> bool {
        self.width == DEFAULT_WIDTH && self.settings == TreeSettings::default()
    }
}

/// Restructuring moves a level-1 node absorbs before it is repacked, at
/// the default width (`TreeSettings::repack_fraction` of its capacity).
fn repack_moves(settings: &TreeSettings) -> u32 {
    (settings.repack_fraction * (DEFAULT_WIDTH * DEFAULT_WIDTH) as f32).ceil() as u32
}

/// The contenders: every bounds policy at the default width, then the other
/// widths with default settings (the default width with default settings is
/// the margin 0.1 row).
fn contenders(boxes: &[Aabb]) -> Vec<Contender> {
    let d = TreeSettings::default();
    let mut specs: Vec<(Knob, String, String, usize, TreeSettings)> = Vec::new();
    for margin in [0.0f32, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0] {
        let settings = TreeSettings {
            margin,
            margin_fraction: 0.0,
            ..d
        };
        let (label, tick) = (format!("margin {margin} m"), format!("{margin}"));
        specs.push((Knob::Margin, label, tick, DEFAULT_WIDTH, settings));
    }
    for fraction in [0.05f32, 0.1, 0.25] {
        let settings = TreeSettings {
            margin: 0.0,
            margin_fraction: fraction,
            ..d
        };
        let percent = fraction * 100.0;
        let label = format!("margin 0, {percent:.0} % of extent");
        specs.push((
            Knob::Fraction,
            label,
            format!("{percent:.0} %"),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for factor in [0.0f32, 1.0, 8.0, 16.0, 32.0] {
        let settings = TreeSettings {
            displacement_factor: factor,
            ..d
        };
        let label = format!("margin 0.1 m, displacement x{factor}");
        specs.push((
            Knob::Displacement,
            label,
            format!("x{factor}"),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for fraction in [0.0625f32, 1.0] {
        let settings = TreeSettings {
            repack_fraction: fraction,
            ..d
        };
        let moves = repack_moves(&settings);
        specs.push((
            Knob::Repack,
            format!("margin 0.1 m, repack after {moves} moves"),
            moves.to_string(),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for width in WIDTHS.into_iter().filter(|&w| w != DEFAULT_WIDTH) {
        specs.push((
            Knob::Width,
            format!("width {width}"),
            width.to_string(),
            width,
            d,
        ));
    }
    specs
        .into_iter()
        .map(|(knob, label, tick, width, settings)| {
            let all = 0..boxes.len();
            let index: Box<dyn Kept> = match width {
                4 => Box::new(Index::<4>::load(boxes, all, settings)),
                16 => Box::new(Index::<16>::load(boxes, all, settings)),
                _ => Box::new(Index::<8>::load(boxes, all, settings)),
            };
            Contender {
                knob,
                label,
                tick,
                width,
                settings,
                index,
                update_ms: Vec::new(),
                optimize_ms: Vec::new(),
                moves: MaintenanceStats::default(),
                fresh: BoxCost::default(),
                churned: BoxCost::default(),
                churned_cull_ms: 0.0,
                churned_self_join: WorkCost::default(),
                churned_rays: WorkCost::default(),
            }
        })
        .collect()
}

/// The per-frame figures of the mode comparisons on the default tree.
#[derive(Default)]
struct FrameFigures {
    /// `[conservative, exact]`.
    cull_ms: [Vec<f64>; 2],
    visible_exact: Vec<f64>,
    cull_false_positives: Vec<f64>,
    cull_false_share: Vec<f64>,
    /// `[Chebyshev, Euclidean]`.
    join_ms: [Vec<f64>; 2],
    pairs_euclidean: Vec<f64>,
    join_extra: Vec<f64>,
    join_extra_share: Vec<f64>,
    /// `[incoherent, coherent]` x `[batched, single]`.
    ray_ms: [[Vec<f64>; 2]; 2],
    ray_hits: [Vec<f64>; 2],
    ray_frames_compared: usize,
    ray_frames_oracle: usize,
}

/// What the node widths cost beyond the contenders' figures.
#[derive(Default)]
struct WidthFigures {
    build_ms: [f64; 3],
    /// `[incoherent, coherent]` batched, on the churned trees.
    rays_ms: [[f64; 2]; 3],
    /// Euclidean cross join on the kept enemy and barrel trees.
    join_ms: [f64; 3],
}

const CULL_MODES: [CullMode; 2] = [CullMode::Conservative, CullMode::Exact];
const JOIN_MODES: [JoinMode; 2] = [JoinMode::Chebyshev, JoinMode::Euclidean];

fn ms_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

fn ms_between(start: Instant, end: Instant) -> f64 {
    (end - start).as_secs_f64() * 1e3
}

fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let mid = v.len() / 2;
    if v.len() % 2 == 1 {
        v[mid]
    } else {
        (v[mid - 1] + v[mid]) / 2.0
    }
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len().max(1) as f64
}

fn min_max(values: &[f64]) -> (f64, f64) {
    values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        })
}

fn oracle_of(boxes: &[Aabb], range: Range<usize>) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for i in range {
        oracle.insert(i as u32, boxes[i]);
    }
    oracle
}

/// Boxes of half extent `BOX_QUERY_HALF` around the current centres of the
/// `around` entities, so queries land where the entities are, as gameplay
/// queries do. The same entities serve before and after the churn, so the
/// two measurements differ by the trees, not by a new sample of queries.
fn box_queries(boxes: &[Aabb], around: &[usize]) -> Vec<Aabb> {
    around
        .iter()
        .map(|&i| {
            let b = boxes[i];
            Aabb::from_center_half_extents((b.min + b.max) * 0.5, Vec3::splat(BOX_QUERY_HALF))
                .expect("a valid query box")
        })
        .collect()
}

/// Checks every contender's answers to `queries` against `truth`, counts
/// its work, then times the set `QUERY_REPS` times per tree, round robin
/// across trees.
fn measure_box_queries(
    contenders: &[Contender],
    queries: &[Aabb],
    truth: &[Vec<u32>],
) -> Vec<BoxCost> {
    let answers: usize = truth.iter().map(Vec::len).sum();
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    let mut costs: Vec<BoxCost> = contenders
        .iter()
        .map(|c| {
            ws.take_stats();
            for (query, expected) in queries.iter().zip(truth) {
                out.clear();
                c.index.overlapping_into(query, &mut ws, &mut out);
                out.sort_unstable();
                assert_eq!(
                    &out, expected,
                    "{}: box query differs from the oracle",
                    c.label
                );
            }
            let stats = ws.take_stats();
            BoxCost {
                ms: 0.0,
                extra_per_query: (stats.entries_tested as usize - answers) as f64
                    / queries.len() as f64,
                nodes_per_query: stats.nodes_visited as f64 / queries.len() as f64,
            }
        })
        .collect();
    let n = contenders.len();
    let mut times = vec![Vec::with_capacity(QUERY_REPS); n];
    for rep in 0..QUERY_REPS {
        for k in 0..n {
            let i = (k + rep) % n;
            let start = Instant::now();
            for query in queries {
                out.clear();
                contenders[i]
                    .index
                    .overlapping_into(query, &mut ws, &mut out);
            }
            times[i].push(ms_since(start));
        }
    }
    for (cost, t) in costs.iter_mut().zip(&times) {
        cost.ms = median(t);
    }
    costs
}

/// Checks every contender's self join (d = 0) against the oracle and its
/// first hits of `rays` against `hits` (the oracle's), counts the nodes they visit, then times both
/// `JOIN_RAY_REPS` times per tree, round robin across trees. These are the
/// queries that descend the most internal nodes, where fat bounds cost.
fn measure_churned_joins_and_rays(
    contenders: &[Contender],
    rays: &[Ray],
    hits: &[Option<RayHit<u32>>],
    oracle: &BruteForce<u32>,
) -> Vec<[WorkCost; 2]> {
    let pairs = oracle
        .self_join(0.0, JoinMode::Euclidean)
        .expect("a valid distance");
    let mut ws = QueryWorkspace::default();
    let mut results = RayResults::default();
    let mut out = Vec::new();
    let mut costs: Vec<[WorkCost; 2]> = contenders
        .iter()
        .map(|c| {
            ws.take_stats();
            out.clear();
            c.index.self_join_into(&mut ws, &mut out);
            let join = ws.take_stats();
            out.sort_unstable();
            assert!(
                out == pairs,
                "{}: self join differs from the oracle",
                c.label
            );
            c.index.cast_rays_first(rays, &mut ws, &mut results);
            let ray = ws.take_stats();
            for (i, hit) in hits.iter().enumerate() {
                assert_eq!(
                    results.first(i).expect("valid ray"),
                    *hit,
                    "{}: ray differs from the oracle",
                    c.label
                );
            }
            [join.nodes_visited, ray.nodes_visited].map(|nodes| WorkCost { ms: 0.0, nodes })
        })
        .collect();
    let n = contenders.len();
    let mut times = vec![[Vec::new(), Vec::new()]; n];
    for rep in 0..JOIN_RAY_REPS {
        for k in 0..n {
            let i = (k + rep) % n;
            out.clear();
            let start = Instant::now();
            contenders[i].index.self_join_into(&mut ws, &mut out);
            times[i][0].push(ms_since(start));
            let start = Instant::now();
            contenders[i]
                .index
                .cast_rays_first(rays, &mut ws, &mut results);
            times[i][1].push(ms_since(start));
        }
    }
    for (cost, t) in costs.iter_mut().zip(&times) {
        cost[0].ms = median(&t[0]);
        cost[1].ms = median(&t[1]);
    }
    costs
}

/// Checks every contender's conservative culls of the recorded frustums
/// against the oracle, then times them, round robin across trees.
fn measure_churned_culls(
    contenders: &[Contender],
    frustums: &[Frustum],
    oracle: &BruteForce<u32>,
) -> Vec<f64> {
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    for frustum in frustums {
        let expected = oracle.visible(frustum, CullMode::Conservative);
        for c in contenders {
            out.clear();
            c.index
                .cull_into(frustum, CullMode::Conservative, &mut ws, &mut out);
            out.sort_unstable();
            assert_eq!(out, expected, "{}: cull differs from the oracle", c.label);
        }
    }
    let n = contenders.len();
    let mut times = vec![Vec::new(); n];
    for rep in 0..CHURNED_CULL_REPS {
        for (f, frustum) in frustums.iter().enumerate() {
            for k in 0..n {
                let i = (k + f + rep) % n;
                out.clear();
                let start = Instant::now();
                contenders[i]
                    .index
                    .cull_into(frustum, CullMode::Conservative, &mut ws, &mut out);
                times[i].push(ms_since(start));
            }
        }
    }
    times.iter().map(|t| median(t)).collect()
}

/// Median bulk-load time of the whole scene per node width, builds
/// interleaved across widths.
fn measure_builds(boxes: &[Aabb]) -> [f64; 3] {
    let mut times: [Vec<f64>; 3] = Default::default();
    let settings = TreeSettings::default();
    let all = || 0..boxes.len();
    for rep in 0..BUILD_REPS {
        for k in 0..3 {
            let w = (k + rep) % 3;
            let start = Instant::now();
            let height = match WIDTHS[w] {
                4 => Index::<4>::load(boxes, all(), settings).tree.height(),
                8 => Index::<8>::load(boxes, all(), settings).tree.height(),
                _ => Index::<16>::load(boxes, all(), settings).tree.height(),
            };
            // Includes dropping the tree, as a rebuild would.
            times[w].push(ms_since(start));
            std::hint::black_box(height);
        }
    }
    times.map(|t| median(&t))
}

/// Batched rays and the Euclidean join per node width on the final state,
/// each checked against the oracle, timed round robin across widths.
fn measure_width_queries(
    trees: [&dyn Kept; 3],
    joins: &[Box<dyn Joined>],
    ray_sets: &[Vec<Ray>; 2],
    ray_truth: &[Vec<Option<RayHit<u32>>>; 2],
    pairs: &[(u32, u32)],
) -> ([[f64; 2]; 3], [f64; 3]) {
    let mut ws = QueryWorkspace::default();
    let mut results = RayResults::default();
    let mut out = Vec::new();
    for (rays, expected) in ray_sets.iter().zip(ray_truth) {
        for tree in trees {
            tree.cast_rays_first(rays, &mut ws, &mut results);
            for (i, hit) in expected.iter().enumerate() {
                assert_eq!(
                    results.first(i).expect("valid ray"),
                    *hit,
                    "ray differs from the oracle"
                );
            }
        }
    }
    for join in joins {
        out.clear();
        join.cross_join_into(JoinMode::Euclidean, &mut ws, &mut out);
        out.sort_unstable();
        assert_eq!(out, pairs, "join differs from the oracle");
    }
    let mut ray_times: [[Vec<f64>; 2]; 3] = Default::default();
    let mut join_times: [Vec<f64>; 3] = Default::default();
    for rep in 0..WIDTH_REPS {
        for k in 0..3 {
            let w = (k + rep) % 3;
            for (r, rays) in ray_sets.iter().enumerate() {
                let start = Instant::now();
                trees[w].cast_rays_first(rays, &mut ws, &mut results);
                ray_times[w][r].push(ms_since(start));
            }
            out.clear();
            let start = Instant::now();
            joins[w].cross_join_into(JoinMode::Euclidean, &mut ws, &mut out);
            join_times[w].push(ms_since(start));
        }
    }
    (
        ray_times.map(|[a, b]| [median(&a), median(&b)]),
        join_times.map(|t| median(&t)),
    )
}

/// Culls, rays and joins of one frame on the default tree and the kept
/// enemy and barrel trees, each checked against the oracle.
fn frame_modes(
    frame: usize,
    last: bool,
    default: &dyn Kept,
    joined: &dyn Joined,
    scene: &mut TownScene,
    oracles: [&BruteForce<u32>; 3],
    figures: &mut FrameFigures,
) {
    let [oracle, enemy_oracle, barrel_oracle] = oracles;
    let mut ws = QueryWorkspace::default();

    // Culling: both modes, interleaved, the first mode alternating.
    let frustum = scene.frustum();
    let mut visible: [Vec<u32>; 2] = Default::default();
    for rep in 0..CULL_REPS {
        for k in 0..2 {
            let m = (k + rep + frame) % 2;
            visible[m].clear();
            let start = Instant::now();
            default.cull_into(&frustum, CULL_MODES[m], &mut ws, &mut visible[m]);
            figures.cull_ms[m].push(ms_since(start));
        }
    }
    for (m, list) in visible.iter_mut().enumerate() {
        list.sort_unstable();
        let expected = oracle.visible(&frustum, CULL_MODES[m]);
        assert_eq!(
            *list, expected,
            "{:?} cull differs from the oracle",
            CULL_MODES[m]
        );
    }
    // Exact is conservative plus a separating-axis test: a subset.
    let exact = visible[1].len() as f64;
    let false_positives = (visible[0].len() - visible[1].len()) as f64;
    figures.visible_exact.push(exact);
    figures.cull_false_positives.push(false_positives);
    figures
        .cull_false_share
        .push(false_positives / exact.max(1.0));

    // Rays: batched and single, incoherent then coherent, order alternating.
    let ray_sets = [scene.incoherent_rays(RAY_COUNT), scene.coherent_rays()];
    let check_oracle = frame.is_multiple_of(RAY_ORACLE_EVERY) || last;
    for (r, rays) in ray_sets.iter().enumerate() {
        let mut batched = RayResults::default();
        let mut single: Vec<Option<RayHit<u32>>> = Vec::with_capacity(rays.len());
        for k in 0..2 * RAY_REPS {
            let start = Instant::now();
            if (k + frame).is_multiple_of(2) {
                default.cast_rays_first(rays, &mut ws, &mut batched);
                figures.ray_ms[r][0].push(ms_since(start));
            } else {
                single.clear();
                single.extend(rays.iter().map(|ray| default.cast_ray_first(ray, &mut ws)));
                figures.ray_ms[r][1].push(ms_since(start));
            }
        }
        for (i, hit) in single.iter().enumerate() {
            assert_eq!(
                batched.first(i).expect("valid ray"),
                *hit,
                "batched and single rays differ"
            );
        }
        if check_oracle {
            for (ray, hit) in rays.iter().zip(&single) {
                assert_eq!(
                    oracle.ray_first(ray).expect("valid ray"),
                    *hit,
                    "ray differs from the oracle"
                );
            }
        }
        figures.ray_hits[r].push(single.iter().flatten().count() as f64);
    }
    figures.ray_frames_compared += 1;
    figures.ray_frames_oracle += usize::from(check_oracle);

    // Joins on the kept enemy and barrel trees, the first mode alternating.
    let mut pairs: [Vec<(u32, u32)>; 2] = Default::default();
    for k in 0..2 {
        let m = (k + frame) % 2;
        pairs[m].clear();
        let start = Instant::now();
        joined.cross_join_into(JOIN_MODES[m], &mut ws, &mut pairs[m]);
        figures.join_ms[m].push(ms_since(start));
    }
    for (m, list) in pairs.iter_mut().enumerate() {
        list.sort_unstable();
        let expected = enemy_oracle
            .cross_join(barrel_oracle, TownScene::JOIN_DISTANCE, JOIN_MODES[m])
            .expect("a valid distance");
        assert_eq!(
            *list, expected,
            "{:?} join differs from the oracle",
            JOIN_MODES[m]
        );
    }
    // Chebyshev accepts every Euclidean pair, so the difference is extra.
    let euclidean = pairs[1].len() as f64;
    let extra = (pairs[0].len() - pairs[1].len()) as f64;
    figures.pairs_euclidean.push(euclidean);
    figures.join_extra.push(extra);
    figures.join_extra_share.push(extra / euclidean.max(1.0));
}

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
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
    let warmup = arg("--warmup", 0);
    // The docs hold every section: written only by a run that has them all.
    let write_docs = !std::env::args().any(|a| a == "--no-docs") && cfg!(feature = "bevy_camera");
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
