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
use std::ops::Range;
use std::time::{Duration, Instant};

use bevy_app::prelude::*;
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::{
    CullingCamera, NoSpatialIndex, RayCaster, RayCasterHits, SpatialBounds, SpatialDiagnostics,
    SpatialIndex, SpatialIndexPlugin, SpatialIndexSystems, SpatialJoin, VisibleEntityList,
};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, ProxyId, QueryWorkspace, RTree, Ray, RayHit, RayMode,
    RayResults,
};
use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};

// The example is included rather than copied so that the plugin side is, by
// construction, the scene and systems the example runs. Its `main` and
// argument parsing are unused here.
#[path = "../examples/town.rs"]
#[allow(dead_code)]
mod town;

mod common;

use town::{Barrel, Enemy, Town};

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

// ---------------------------------------------------------------------------
// The core path.

/// The town frame on bare trees, with every buffer kept between frames (as
/// the plugin keeps its scratch in `Local`s and resources).
struct CoreTown {
    scene: TownScene,
    all: RTree<u32>,
    all_ids: Vec<ProxyId>,
    enemies: RTree<u32>,
    enemy_ids: Vec<ProxyId>,
    barrels: RTree<u32>,
    barrel_ids: Vec<ProxyId>,
    optimize_budget: usize,
    /// Nodes repacked by `optimize` so far, to compare with the plugin's.
    repacked: u64,
    frustum: Frustum,
    rays: Vec<Ray>,
    cull_ws: QueryWorkspace,
    ray_ws: QueryWorkspace,
    join_ws: QueryWorkspace,
    visible: Vec<Vec<u32>>,
    hits: RayResults<u32>,
    pairs: Vec<(u32, u32)>,
    /// A frame's moves per tree (all, enemies, barrels), for `update_batch`.
    moves: [Vec<(ProxyId, Aabb)>; 3],
}

/// A tree of the scene's entities in `range`, keyed by scene index, and the
/// handle of each (`ids[i - range.start]`).
fn layer_tree(scene: &TownScene, range: Range<usize>) -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::new();
    let ids = tree
        .insert_bulk(range.map(|i| (i as u32, scene.boxes()[i])))
        .expect("scene boxes are valid");
    (tree, ids)
}

impl CoreTown {
    /// The scene of `town::build(count, seed)`, bulk loaded before its first
    /// frame (the plugin bulk loads on its first frame, after the first moves;
    /// answers depend only on the boxes, and both are churned before timing).
    fn new(count: usize, seed: u64) -> Self {
        let scene = TownScene::new(count, seed);
        let (all, all_ids) = scene.bulk_loaded_tree();
        let (enemies, enemy_ids) = layer_tree(&scene, TownScene::ENEMIES);
        let (barrels, barrel_ids) = layer_tree(&scene, TownScene::BARRELS);
        let frustum = scene.frustum();
        CoreTown {
            scene,
            all,
            all_ids,
            enemies,
            enemy_ids,
            barrels,
            barrel_ids,
            optimize_budget: SpatialIndexPlugin::default().optimize_budget,
            repacked: 0,
            frustum,
            rays: Vec::new(),
            cull_ws: QueryWorkspace::default(),
            ray_ws: QueryWorkspace::default(),
            join_ws: QueryWorkspace::default(),
            visible: vec![Vec::new()],
            hits: RayResults::default(),
            pairs: Vec::new(),
            moves: Default::default(),
        }
    }

    /// The example's `Update` systems: the scene moves, the camera turns and
    /// the rays are re-aimed (same calls, same order, so the scene's random
    /// stream stays in step with the App's).
    fn move_and_aim(&mut self) {
        self.scene.advance_frame();
        self.frustum = self.scene.frustum();
        self.rays = self.scene.incoherent_rays(INCOHERENT_RAYS);
        self.rays.extend(self.scene.coherent_rays());
    }

    /// The plugin's sync: every moved box into every tree that holds it,
    /// as one `update_batch` per tree.
    fn sync(&mut self) {
        let CoreTown {
            scene,
            all,
            all_ids,
            enemies,
            enemy_ids,
            barrels,
            barrel_ids,
            moves: [all_moves, enemy_moves, barrel_moves],
            ..
        } = self;
        let boxes = scene.boxes();
        for batch in [&mut *all_moves, &mut *enemy_moves, &mut *barrel_moves] {
            batch.clear();
        }
        for &index in scene.moved() {
            let i = index as usize;
            let aabb = boxes[i];
            all_moves.push((all_ids[i], aabb));
            if TownScene::ENEMIES.contains(&i) {
                enemy_moves.push((enemy_ids[i - TownScene::ENEMIES.start], aabb));
            } else if TownScene::BARRELS.contains(&i) {
                barrel_moves.push((barrel_ids[i - TownScene::BARRELS.start], aabb));
            }
        }
        for (tree, batch) in [
            (all, all_moves),
            (enemies, enemy_moves),
            (barrels, barrel_moves),
        ] {
            tree.update_batch(batch).expect("live handles, valid boxes");
        }
    }

    /// The plugin's maintenance: it runs only where repairs are pending.
    fn maintain(&mut self) {
        for tree in [&mut self.all, &mut self.enemies, &mut self.barrels] {
            if tree.pending_repairs() > 0 {
                self.repacked += tree.optimize(self.optimize_budget) as u64;
            }
        }
    }

    /// Culling, with the plugin's sorting of the visible list.
    fn cull(&mut self) {
        self.visible[0].clear();
        self.all.visible_into(
            std::slice::from_ref(&self.frustum),
            CullMode::Conservative,
            &mut self.cull_ws,
            &mut self.visible,
        );
        self.visible[0].sort_unstable();
    }

    /// The frame's rays, one batch, first hit.
    fn cast(&mut self) {
        self.all
            .cast_rays(&self.rays, RayMode::First, &mut self.ray_ws, &mut self.hits);
    }

    /// The enemy-barrel join, with the plugin's sorting of the pairs.
    fn join(&mut self) {
        self.pairs.clear();
        self.enemies
            .cross_join_into(
                &self.barrels,
                TownScene::JOIN_DISTANCE,
                JoinMode::Euclidean,
                &mut self.join_ws,
                &mut self.pairs,
            )
            .expect("the join distance is valid");
        self.pairs.sort_unstable();
    }

    fn queries(&mut self) {
        self.cull();
        self.cast();
        self.join();
    }

    fn frame(&mut self) {
        self.move_and_aim();
        self.sync();
        self.maintain();
        self.queries();
    }
}

// ---------------------------------------------------------------------------
// Correctness: the core path's answers equal the plugin's.

/// Panics unless this frame's visible list, first hits and pairs of the App
/// and of the core path are equal.
fn assert_same_frame(app: &App, core: &CoreTown, frame: usize) {
    let world = app.world();
    let town = world.resource::<Town>();
    assert!(
        town.scene.boxes() == core.scene.boxes(),
        "frame {frame}: the two scenes are out of step"
    );
    let entity = |i: u32| town.entities[i as usize];

    let visible = world
        .get::<VisibleEntityList>(town.camera)
        .expect("the camera has its list")
        .entities();
    // Sorted again after mapping: the check must not rely on the entity ids
    // growing with the scene index.
    let mut core_visible: Vec<Entity> = core.visible[0].iter().map(|&i| entity(i)).collect();
    core_visible.sort_unstable();
    assert!(!visible.is_empty(), "frame {frame}: nothing visible");
    assert!(
        visible == core_visible.as_slice(),
        "frame {frame}: visible lists differ ({} vs {} entities)",
        visible.len(),
        core_visible.len()
    );

    // First hit is the smallest `(t, key)`, and `Entity` order is not scene
    // order (bevy_ecs stores the index inverted, so later spawns sort
    // first): on a tie in `t` the two paths rightly pick different boxes.
    // So the core's first hit is re-derived under `Entity` order from all of
    // the ray's hits at the core's best `t`.
    let mut ws = QueryWorkspace::default();
    let mut all_hits = Vec::new();
    let mut hits = 0;
    for (k, &caster) in town.casters.iter().enumerate() {
        let plugin = world
            .get::<RayCasterHits>(caster)
            .expect("every caster has hits")
            .first();
        let core_first = core.hits.first(k).expect("the scene's rays are valid");
        let core = core_first.map(|best| {
            core.all
                .cast_ray_all(&core.rays[k], None, &mut ws, &mut all_hits)
                .expect("the scene's rays are valid");
            let key = all_hits
                .iter()
                .filter(|h| h.t == best.t)
                .map(|h| entity(h.key))
                .min()
                .expect("the best hit is among all hits");
            RayHit { key, t: best.t }
        });
        assert_eq!(plugin, core, "frame {frame}: ray {k} differs");
        hits += usize::from(plugin.is_some());
    }
    assert!(hits > 0, "frame {frame}: no ray hit anything");

    let pairs = world.resource::<SpatialJoin<Enemy, Barrel>>().pairs();
    let mut core_pairs: Vec<(Entity, Entity)> = core
        .pairs
        .iter()
        .map(|&(a, b)| (entity(a), entity(b)))
        .collect();
    core_pairs.sort_unstable();
    assert!(!pairs.is_empty(), "frame {frame}: no pairs");
    assert!(
        pairs == core_pairs.as_slice(),
        "frame {frame}: pairs differ ({} vs {})",
        pairs.len(),
        core_pairs.len()
    );
}

/// Runs `CHECK_FRAMES` frames of both paths, comparing each, then checks the
/// plugin against brute force.
fn check_paths(app: &mut App, core: &mut CoreTown) {
    for frame in 0..CHECK_FRAMES {
        app.update();
        core.frame();
        assert_same_frame(app, core, frame);
    }
    assert!(
        town::agrees_with_oracle(app),
        "the plugin disagrees with brute force"
    );
    let (visible, hits, pairs) = town::counts(app);
    eprintln!(
        "ecs check ok over {CHECK_FRAMES} frames: {visible} visible, {hits} of {} rays hit, \
         {pairs} pairs; executor: {}",
        app.world().resource::<Town>().casters.len(),
        if cfg!(feature = "multi_threaded") {
            "bevy_ecs multi_threaded"
        } else {
            "single-threaded"
        }
    );
}

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

// ---------------------------------------------------------------------------
// ecs/phases

/// When each of the plugin's phases ended this frame; written by `mark`.
#[derive(Resource, Default)]
struct PhaseMarks([Option<Instant>; 4]);

/// Records the end of phase `P` (0: the example's `Update` systems and
/// everything scheduled before `PostUpdate`; 1: sync; 2: maintain; 3:
/// queries).
fn mark<const P: usize>(mut marks: ResMut<PhaseMarks>) {
    marks.0[P] = Some(Instant::now());
}

const PHASES: [&str; 5] = [
    "move + aim (Update)",
    "sync",
    "maintain",
    "queries",
    "rest of app.update",
];

/// The ECS side of the plugin's sync, repeated by `probe_sync`: the three
/// layers' change-detection scans, and, for the two marker layers (the
/// main layer's handles are kept on the entities), one entity-to-handle
/// lookup per changed entity in maps shaped like the plugin's (its own are
/// private).
#[derive(Resource, Default)]
struct SyncProbe {
    maps: [EntityHashMap<u32>; 3],
    changed: [Vec<(Entity, Aabb)>; 3],
    scratch: Vec<(Entity, Aabb)>,
    /// The main layer's scan as the plugin reads it (table by table), the
    /// same through Bevy's row-by-row filter, and the two marker layers'
    /// scans.
    scans: [Duration; 3],
    lookup: Duration,
    /// The probe's whole run, taken off the plugin's last phase.
    total: Duration,
    frame: u64,
}

/// The filter of the plugin's sync for layer `L`, as Bevy's row-by-row
/// iteration applies it.
type ChangedIn<L> = (
    With<L>,
    Without<NoSpatialIndex>,
    Or<(Changed<SpatialBounds>, Added<L>)>,
);

/// The rows the plugin's sync reads table by table for layer `L`.
type LayerRow<'a, L> = (Entity, Ref<'a, SpatialBounds>, Ref<'a, L>);

/// The changed rows of `L`'s tables as the plugin finds them: the change
/// ticks of the box and the added ticks of the marker, read as slices.
fn scan_tables<L: Component>(
    members: &Query<LayerRow<'_, L>, Without<NoSpatialIndex>>,
    out: &mut Vec<(Entity, Aabb)>,
) {
    out.clear();
    let tables = members.contiguous_iter().expect("dense tables");
    for (entities, bounds, marker) in tables {
        let (last, now) = (bounds.last_run_tick(), bounds.this_run_tick());
        let changed = bounds.changed_ticks_slice().iter();
        let added = marker.added_ticks_slice().iter();
        for (row, (c, a)) in changed.zip(added).enumerate() {
            if c.is_newer_than(last, now) || a.is_newer_than(last, now) {
                out.push((entities[row], bounds[row].0));
            }
        }
    }
}

/// Runs after the queries, so that it does not warm the caches for the sync
/// it stands for; its own change ticks see the same moves as the sync did.
#[allow(clippy::type_complexity)]
fn probe_sync(
    mut probe: ResMut<SyncProbe>,
    all: Query<LayerRow<'_, SpatialBounds>, Without<NoSpatialIndex>>,
    all_filtered: Query<(Entity, &SpatialBounds), ChangedIn<SpatialBounds>>,
    enemies: Query<LayerRow<'_, Enemy>, Without<NoSpatialIndex>>,
    barrels: Query<LayerRow<'_, Barrel>, Without<NoSpatialIndex>>,
) {
    let probe = &mut *probe;
    let start = Instant::now();
    probe.frame += 1;
    // The second scan of the main layer finds its columns in cache: the two
    // take turns going first.
    let tables_first = probe.frame.is_multiple_of(2);
    for round in 0..2 {
        let t = Instant::now();
        if (round == 0) == tables_first {
            scan_tables(&all, &mut probe.changed[0]);
            probe.scans[0] = t.elapsed();
        } else {
            probe.scratch.clear();
            probe
                .scratch
                .extend(all_filtered.iter().map(|(e, b)| (e, b.0)));
            probe.scans[1] = t.elapsed();
        }
    }
    assert_eq!(probe.changed[0].len(), probe.scratch.len());
    let t = Instant::now();
    let [_, enemies_out, barrels_out] = &mut probe.changed;
    scan_tables(&enemies, enemies_out);
    scan_tables(&barrels, barrels_out);
    probe.scans[2] = t.elapsed();
    let t = Instant::now();
    let mut found = 0usize;
    // The main layer's handles are kept on the entities: only the two
    // marker layers look their entities up.
    for (map, changed) in probe.maps.iter().zip(&probe.changed).skip(1) {
        for (entity, _) in changed {
            found += usize::from(map.get(entity).is_some());
        }
    }
    black_box(found);
    probe.lookup = t.elapsed();
    probe.total = start.elapsed();
}

/// The App with marker systems between the plugin's sets (they only read the
/// clock, so they leave the frame's work unchanged) and the sync probe.
fn marked_app() -> App {
    let mut app = town::build(TownScene::STANDARD_COUNT, SEED);
    let mut probe = SyncProbe::default();
    {
        let town = app.world().resource::<Town>();
        for (i, &entity) in town.entities.iter().enumerate() {
            probe.maps[0].insert(entity, i as u32);
            if TownScene::ENEMIES.contains(&i) {
                probe.maps[1].insert(entity, i as u32);
            } else if TownScene::BARRELS.contains(&i) {
                probe.maps[2].insert(entity, i as u32);
            }
        }
    }
    app.init_resource::<PhaseMarks>()
        .insert_resource(probe)
        .add_systems(
            PostUpdate,
            (
                mark::<0>.before(SpatialIndexSystems::Bounds),
                mark::<1>
                    .after(SpatialIndexSystems::Sync)
                    .before(SpatialIndexSystems::Maintain),
                mark::<2>
                    .after(SpatialIndexSystems::Maintain)
                    .before(SpatialIndexSystems::Queries),
                mark::<3>.after(SpatialIndexSystems::Queries),
                probe_sync.after(mark::<3>),
            ),
        );
    app
}

/// Phase durations of one plugin frame (the probe taken off the last).
fn plugin_phases(app: &mut App) -> [Duration; 5] {
    let start = Instant::now();
    app.update();
    let end = Instant::now();
    let marks = app.world().resource::<PhaseMarks>().0;
    let mut t = [start; 6];
    for (slot, mark) in t[1..5].iter_mut().zip(marks) {
        *slot = mark.expect("every marker ran");
    }
    t[5] = end;
    let mut phases: [Duration; 5] = std::array::from_fn(|p| t[p + 1] - t[p]);
    let probe = app.world().resource::<SyncProbe>().total;
    phases[4] = phases[4].saturating_sub(probe);
    phases
}

/// Phase durations of one core frame, and of its three query families.
fn core_phases(core: &mut CoreTown) -> ([Duration; 5], [Duration; 3]) {
    let t0 = Instant::now();
    core.move_and_aim();
    let t1 = Instant::now();
    core.sync();
    let t2 = Instant::now();
    core.maintain();
    let t3 = Instant::now();
    core.cull();
    let t4 = Instant::now();
    core.cast();
    let t5 = Instant::now();
    core.join();
    let t6 = Instant::now();
    black_box(core.pairs.len());
    (
        [t1 - t0, t2 - t1, t3 - t2, t6 - t3, Duration::ZERO],
        [t4 - t3, t5 - t4, t6 - t5],
    )
}

/// The core path's query calls made on the plugin's own trees (keyed by
/// `Entity`, loaded and churned by the plugin) with the plugin's inputs:
/// the queries phase without the ECS around it.
#[derive(Default)]
struct PluginTreeCalls {
    ws: QueryWorkspace,
    rays: Vec<Ray>,
    visible: Vec<Vec<Entity>>,
    hits: RayResults<Entity>,
    pairs: Vec<(Entity, Entity)>,
}

impl PluginTreeCalls {
    fn time(&mut self, app: &App) -> [Duration; 3] {
        let world = app.world();
        let town = world.resource::<Town>();
        let frustum = world
            .get::<CullingCamera>(town.camera)
            .expect("the camera")
            .frustum;
        self.rays.clear();
        self.rays.extend(
            town.casters
                .iter()
                .map(|&c| world.get::<RayCaster>(c).expect("a caster").ray),
        );
        let all = world.resource::<SpatialIndex>().tree();
        let enemies = world.resource::<SpatialIndex<Enemy>>().tree();
        let barrels = world.resource::<SpatialIndex<Barrel>>().tree();
        let t0 = Instant::now();
        self.visible.iter_mut().for_each(Vec::clear);
        all.visible_into(
            std::slice::from_ref(&frustum),
            CullMode::Conservative,
            &mut self.ws,
            &mut self.visible,
        );
        self.visible.iter_mut().for_each(|v| v.sort_unstable());
        let t1 = Instant::now();
        all.cast_rays(&self.rays, RayMode::First, &mut self.ws, &mut self.hits);
        let t2 = Instant::now();
        self.pairs.clear();
        enemies
            .cross_join_into(
                barrels,
                TownScene::JOIN_DISTANCE,
                JoinMode::Euclidean,
                &mut self.ws,
                &mut self.pairs,
            )
            .expect("the join distance is valid");
        self.pairs.sort_unstable();
        let t3 = Instant::now();
        black_box(self.hits.len());
        [t1 - t0, t2 - t1, t3 - t2]
    }
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort_unstable();
    v[v.len() / 2]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn ratio(a: Duration, b: Duration) -> String {
    if b.is_zero() {
        "-".to_string()
    } else {
        format!("{:.2}", a.as_secs_f64() / b.as_secs_f64())
    }
}

/// Median of column `p` of per-frame rows (`None`: of the rows' sums).
fn column<const N: usize>(rows: &[[Duration; N]], p: Option<usize>) -> Duration {
    median(
        rows.iter()
            .map(|r| p.map_or_else(|| r.iter().sum(), |p| r[p]))
            .collect(),
    )
}

/// Prints per-phase medians of interleaved plugin and core frames, and where
/// the plugin's extra time goes. Not a criterion group: criterion times one
/// closure, this splits one frame.
fn report_phases(_c: &mut Criterion) {
    let mut app = marked_app();
    let mut core = CoreTown::new(TownScene::STANDARD_COUNT, SEED);
    check_paths(&mut app, &mut core);
    for _ in 0..PHASE_WARM_FRAMES {
        app.update();
        core.frame();
    }
    let mut plugin: Vec<[Duration; 5]> = Vec::with_capacity(PHASE_FRAMES);
    let mut bare: Vec<[Duration; 5]> = Vec::with_capacity(PHASE_FRAMES);
    let mut bare_families: Vec<[Duration; 3]> = Vec::with_capacity(PHASE_FRAMES);
    let mut plugin_trees: Vec<[Duration; 3]> = Vec::with_capacity(PHASE_FRAMES);
    let mut probes: Vec<[Duration; 4]> = Vec::with_capacity(PHASE_FRAMES);
    let mut calls = PluginTreeCalls::default();
    let (mut synced, mut repacked) = (0, 0);
    let core_repacked_before = core.repacked;
    for _ in 0..PHASE_FRAMES {
        plugin.push(plugin_phases(&mut app));
        let (phases, families) = core_phases(&mut core);
        bare.push(phases);
        bare_families.push(families);
        plugin_trees.push(calls.time(&app));
        let world = app.world();
        let probe = world.resource::<SyncProbe>();
        probes.push([probe.scans[0], probe.scans[1], probe.scans[2], probe.lookup]);
        let d = world.resource::<SpatialDiagnostics>();
        synced += d.sync.updated;
        repacked += d.maintenance.nodes_repacked;
    }
    assert_same_frame(&app, &core, CHECK_FRAMES + PHASE_WARM_FRAMES + PHASE_FRAMES);

    eprintln!(
        "\necs/phases: medians of {PHASE_FRAMES} interleaved frames (ms); per frame the plugin \
         updated {:.0} boxes and repacked {:.1} nodes, the core repacked {:.1}",
        synced as f64 / PHASE_FRAMES as f64,
        repacked as f64 / PHASE_FRAMES as f64,
        (core.repacked - core_repacked_before) as f64 / PHASE_FRAMES as f64,
    );
    eprintln!(
        "{:<34} {:>8} {:>8} {:>8}",
        "phase", "plugin", "core", "ratio"
    );
    for p in (0..PHASES.len()).map(Some).chain([None]) {
        let (a, b) = (column(&plugin, p), column(&bare, p));
        let name = p.map_or("whole frame", |p| PHASES[p]);
        eprintln!(
            "{name:<34} {:>8.3} {:>8.3} {:>8}",
            ms(a),
            ms(b),
            ratio(a, b)
        );
    }
    // Neighbouring frames share the machine's load: the median of their
    // ratios is the steadiest figure on a busy machine.
    let mut per_frame: Vec<f64> = plugin
        .iter()
        .zip(&bare)
        .map(|(a, b)| {
            a.iter().sum::<Duration>().as_secs_f64() / b.iter().sum::<Duration>().as_secs_f64()
        })
        .collect();
    per_frame.sort_unstable_by(f64::total_cmp);
    eprintln!(
        "{:<34} {:>8} {:>8} {:>8.2}",
        "median of per-frame ratios",
        "",
        "",
        per_frame[per_frame.len() / 2]
    );

    eprintln!(
        "\n{:<34} {:>8} {:>8} {:>8}",
        "queries by family", "plugin's", "core", "ratio"
    );
    eprintln!(
        "{:<34} {:>8} {:>8}",
        "(same calls on ... trees)", "Entity", "u32"
    );
    let families = ["cull + sort", "rays (2,000, first)", "join + sort"];
    for f in (0..families.len()).map(Some).chain([None]) {
        let (a, b) = (column(&plugin_trees, f), column(&bare_families, f));
        let name = f.map_or("sum", |f| families[f]);
        eprintln!(
            "{name:<34} {:>8.3} {:>8.3} {:>8}",
            ms(a),
            ms(b),
            ratio(a, b)
        );
    }
    let queries_phase = column(&plugin, Some(3));
    let on_trees = column(&plugin_trees, None);
    eprintln!(
        "queries phase minus those calls (gathering casters, writing hits, pair messages): {:.3}",
        ms(queries_phase.saturating_sub(on_trees))
    );
    eprintln!(
        "sync's ECS side, repeated by a probe: change-detection scans {:.3} for all entities \
         table by table ({:.3} through Bevy's Changed filter row by row) + {:.3} for enemies \
         and barrels; the marker layers' entity-to-handle lookups {:.3}\n",
        ms(column(&probes, Some(0))),
        ms(column(&probes, Some(1))),
        ms(column(&probes, Some(2))),
        ms(column(&probes, Some(3))),
    );
}

criterion_group! {
    name = benches;
    config = common::config(Duration::from_secs(2), Duration::from_secs(8));
    targets = bench_frame, report_phases
}
criterion_main!(benches);
