//! `ecs/phases`: the plugin's phases timed by marks between its system
//! sets, the core path's by its calls, interleaved frame by frame, and the
//! sync probe that splits the plugin's sync into its parts.

use super::checks::{assert_same_frame, check_paths};
use super::core_town::CoreTown;
use super::town::{Barrel, Enemy, Town};
use super::{CHECK_FRAMES, PHASE_FRAMES, PHASE_WARM_FRAMES, SEED, town};
use bevy_app::prelude::{App, PostUpdate};
use bevy_ecs::entity::EntityHashMap;
use bevy_ecs::prelude::{
    Added, Changed, Component, Entity, IntoScheduleConfigs, Or, Query, Ref, ResMut, Resource, With,
    Without,
};
use bevy_rtree::plugin::{
    CullingCamera, NoSpatialIndex, RayCaster, SpatialBounds, SpatialDiagnostics, SpatialIndex,
    SpatialIndexSystems,
};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, CullMode, JoinMode, QueryWorkspace, Ray, RayMode, RayResults};
use criterion::Criterion;
use std::hint::black_box;
use std::time::{Duration, Instant};

// ecs/phases

/// When each of the plugin's phases ended this frame; written by `mark`.
#[derive(Resource, Default)]
pub(crate) struct PhaseMarks([Option<Instant>; 4]);

/// Records the end of phase `P` (0: the example's `Update` systems and
/// everything scheduled before `PostUpdate`; 1: sync; 2: maintain; 3:
/// queries).
pub(crate) fn mark<const P: usize>(mut marks: ResMut<PhaseMarks>) {
    marks.0[P] = Some(Instant::now());
}

pub(crate) const PHASES: [&str; 5] = [
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
pub(crate) struct SyncProbe {
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
pub(crate) type ChangedIn<L> = (
    With<L>,
    Without<NoSpatialIndex>,
    Or<(Changed<SpatialBounds>, Added<L>)>,
);

/// The rows the plugin's sync reads table by table for layer `L`.
pub(crate) type LayerRow<'a, L> = (Entity, Ref<'a, SpatialBounds>, Ref<'a, L>);

/// The changed rows of `L`'s tables as the plugin finds them: the change
/// ticks of the box and the added ticks of the marker, read as slices.
pub(crate) fn scan_tables<L: Component>(
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
pub(crate) fn probe_sync(
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
pub(crate) fn marked_app() -> App {
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
pub(crate) fn plugin_phases(app: &mut App) -> [Duration; 5] {
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
pub(crate) fn core_phases(core: &mut CoreTown) -> ([Duration; 5], [Duration; 3]) {
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
pub(crate) struct PluginTreeCalls {
    ws: QueryWorkspace,
    rays: Vec<Ray>,
    visible: Vec<Vec<Entity>>,
    hits: RayResults<Entity>,
    pairs: Vec<(Entity, Entity)>,
}

impl PluginTreeCalls {
    pub(crate) fn time(&mut self, app: &App) -> [Duration; 3] {
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

pub(crate) fn median(mut v: Vec<Duration>) -> Duration {
    v.sort_unstable();
    v[v.len() / 2]
}

pub(crate) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

pub(crate) fn ratio(a: Duration, b: Duration) -> String {
    if b.is_zero() {
        "-".to_string()
    } else {
        format!("{:.2}", a.as_secs_f64() / b.as_secs_f64())
    }
}

/// Median of column `p` of per-frame rows (`None`: of the rows' sums).
pub(crate) fn column<const N: usize>(rows: &[[Duration; N]], p: Option<usize>) -> Duration {
    median(
        rows.iter()
            .map(|r| p.map_or_else(|| r.iter().sum(), |p| r[p]))
            .collect(),
    )
}

/// Prints per-phase medians of interleaved plugin and core frames, and where
/// the plugin's extra time goes. Not a criterion group: criterion times one
/// closure, this splits one frame.
pub(crate) fn report_phases(_c: &mut Criterion) {
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
