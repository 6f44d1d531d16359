//! The index of Bevy's renderables follows their `Aabb` and
//! `GlobalTransform`: changed rows are rescanned each frame, and observers
//! see entities leave (or come back to) the set Bevy's culling tests.

use bevy_camera::primitives::Aabb as BevyAabb;
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, ViewVisibility,
};
use bevy_ecs::component::{ComponentId, Components};
use bevy_ecs::entity::Entities;
use bevy_ecs::entity_disabling::{DefaultQueryFilters, Disabled};
use bevy_ecs::event::EventPattern;
use bevy_ecs::lifecycle::HookContext;
use bevy_ecs::observer::Observer;
use bevy_ecs::prelude::*;
use bevy_ecs::query::{ContiguousQueryData, QueryData};
use bevy_ecs::world::DeferredWorld;
use bevy_transform::prelude::GlobalTransform;
use bevy_utils::Parallel;
use glam::Vec3;

use super::columns::TABLES_SPLIT_ACROSS_THREADS;
use super::{BevyVisibilitySettings, Renderable};
use crate::geometry::Aabb;
use crate::plugin::change_scan::ChangeTest;
use crate::plugin::diagnostics::DiagnosticsSink;
use crate::plugin::index::{self, SpatialIndex, SyncScratch};
use crate::tree::ProxyId;
use crate::tree::prefetch::{prefetch_every_line, prefetch_lines};

/// The filter of the set Bevy's CPU culling tests, less the entities that
/// the index leaves to one-by-one tests (no `Aabb`, or `NoFrustumCulling`).
pub(super) type Indexable = (
    With<InheritedVisibility>,
    With<ViewVisibility>,
    Without<NoCpuCulling>,
    Without<NoFrustumCulling>,
);

/// Entities the next sync reads again although its scan would not find
/// them: their box and transform unchanged, their membership come back.
#[derive(Resource, Default)]
pub(super) struct Resync {
    /// Read again at the next sync (an opt-out marker removed, enabled).
    again: Vec<Entity>,
    /// Entities with a box but without `InheritedVisibility` or
    /// `ViewVisibility` (given the box first, or the components taken
    /// away): each sync reads again those that have both now, which the
    /// scan would not, their box and transform unchanged, and forgets the
    /// despawned. Usually none; at most each live entity once.
    waiting: Vec<Entity>,
}

/// The index's handle of a renderable, kept on the entity (every entity
/// with Bevy's `Aabb` gets one, as a required component, so keeping it
/// moves no entity between tables): a move then finds its entry without
/// looking the entity up. A stale or foreign handle is refused by the
/// index and costs only that look-up.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_camera::primitives::Aabb;
/// use bevy_camera::visibility::{InheritedVisibility, ViewVisibility};
/// use bevy_rtree::plugin::{
///     BevyVisibilityPlugin, Renderable, RenderableHandle, SpatialIndex, SpatialIndexPlugin,
/// };
/// use bevy_transform::prelude::*;
/// use bevy_rtree::glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins((TransformPlugin, SpatialIndexPlugin::default(), BevyVisibilityPlugin));
/// let mesh = app
///     .world_mut()
///     .spawn((
///         Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
///         Transform::default(),
///         InheritedVisibility::VISIBLE,
///         ViewVisibility::default(),
///     ))
///     .id();
/// app.update();
/// // Bevy's `Aabb` brought the handle along; the first sync filled it.
/// let handle = app.world().get::<RenderableHandle>(mesh).unwrap();
/// let index = app.world().resource::<SpatialIndex<Renderable>>();
/// let (entity, _) = index.tree().get(handle.id().unwrap()).unwrap();
/// assert_eq!(entity, mesh);
/// ```
#[derive(Component, Clone, Copy, Debug, Default)]
#[component(on_add = wait_if_invisible)]
pub struct RenderableHandle(Option<ProxyId>);

impl RenderableHandle {
    /// The entity's handle in `SpatialIndex<Renderable>`'s tree, once the
    /// plugin has indexed it.
    pub fn id(self) -> Option<ProxyId> {
        self.0
    }
}

/// Beyond this, a transform's column may overflow `f32` in Bevy's tests,
/// whose answer a world box then cannot give: a camera plane's product
/// with it (`f32::MAX / sqrt(3)` is the least that can) gives NaN, which
/// keeps the entity whatever its box; a light's sphere test takes the
/// product of the column with the vector from the light to the box, which
/// overflows to infinity and accepts the entity once that vector is long
/// enough (34 m for a column of 1e37). Up to 1e18, that vector would have
/// to be longer than the lights' sphere query ever lets it be
/// (`lights::FAR_FOR_BEVY_S_SPHERE_TEST`). No game scales an entity by
/// that much: such entities are left to Bevy's tests, one by one.
pub(super) const COLUMN_BEYOND_BEVY_S_TEST: f32 = 1e18;

/// The world box of a Bevy `Aabb` under a transform: the box around the
/// oriented box Bevy's tests see, rounded outward ([contract S1](crate::contract)). An
/// unusable one (NaN, a negative half extent, a collapsed axis, a column
/// too long for Bevy's own test to be decided by a box) is the unusable
/// box, which the index refuses and counts: Bevy's test decides such an
/// entity alone.
pub(super) fn world_box(aabb: &BevyAabb, transform: &GlobalTransform) -> Aabb {
    let affine = transform.affine();
    if crate::plugin::transform::collapses_an_axis(&affine.matrix3) {
        return Aabb::UNUSABLE;
    }
    // Bevy's tests may overflow on a column that long (see the constant):
    // the entity is left to them.
    let columns = affine.matrix3.to_cols_array();
    if columns.iter().any(|v| v.abs() > COLUMN_BEYOND_BEVY_S_TEST) {
        return Aabb::UNUSABLE;
    }
    let center = Vec3::from(aabb.center);
    let half = Vec3::from(aabb.half_extents);
    Aabb::from_oriented(center, half, &affine).unwrap_or(Aabb::UNUSABLE)
}

/// What the sync reads of a renderable, table by table: its change ticks
/// tell whether it changed.
type Scanned<'a> = (
    Entity,
    Ref<'a, BevyAabb>,
    Ref<'a, GlobalTransform>,
    Option<&'a RenderableHandle>,
);

/// A changed renderable's entity, world box and kept handle.
type ChangedBox = (Entity, Aabb, Option<ProxyId>);

/// What one thread's scan gathers: the changed rows of the table it
/// reads, then their entities, world boxes and handles.
#[derive(Default)]
struct ScannedRows {
    rows: Vec<u32>,
    boxes: Vec<ChangedBox>,
}

/// The sync's buffers, kept from frame to frame.
#[derive(Default)]
pub(super) struct Scratch {
    sync: SyncScratch,
    /// The changed renderables, gathered before the tree's writes (per
    /// thread where the scan runs in parallel).
    scan: ScannedRows,
    per_thread: Parallel<ScannedRows>,
}

/// Applies this frame's changed renderables (and those to read again) to
/// the index, in one batch.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn sync_renderables(
    mut index: ResMut<SpatialIndex<Renderable>>,
    mut renderables: ParamSet<(
        Query<Scanned<'_>, Indexable>,
        Query<&mut RenderableHandle, Indexable>,
    )>,
    changed: Query<(), (Indexable, Or<(Changed<GlobalTransform>, Changed<BevyAabb>)>)>,
    members: Query<(&BevyAabb, &GlobalTransform), Indexable>,
    mut resync: ResMut<Resync>,
    entities: &Entities,
    mut scratch: Local<Scratch>,
    settings: Res<BevyVisibilitySettings>,
    sink: Res<DiagnosticsSink>,
) {
    let mut again = std::mem::take(&mut resync.again);
    if !resync.waiting.is_empty() {
        resync.waiting.sort_unstable();
        resync.waiting.dedup();
        resync.waiting.retain(|&entity| {
            if members.contains(entity) {
                again.push(entity);
                return false;
            }
            entities.contains(entity)
        });
    }
    again.sort_unstable();
    again.dedup();
    // One box per entity: one that changed this frame comes from the scan.
    again.retain(|&entity| !changed.contains(entity));
    let again = again.into_iter().filter_map(|entity| {
        let (aabb, transform) = members.get(entity).ok()?;
        Some((entity, world_box(aabb, transform), None))
    });
    let Scratch {
        sync,
        scan,
        per_thread,
    } = &mut *scratch;
    scan.boxes.clear();
    let scanned = renderables.p0();
    // Read table by table where the query can be (every query of an app
    // that registers a disabling component stored in a sparse set cannot
    // be, and goes row by row through Bevy's iteration).
    if settings.on_several_threads() {
        // The scan of the change ticks and the world boxes on every thread;
        // the tree's writes stay on this one.
        let local = || per_thread.borrow_local_mut();
        let by_table = if TABLES_SPLIT_ACROSS_THREADS {
            scanned.contiguous_par_iter().ok()
        } else {
            None
        };
        match by_table {
            Some(tables) => tables.for_each_init(local, |local, table| scan_table(table, local)),
            None => scanned
                .par_iter()
                .for_each_init(local, |local, item| scan_row(item, local)),
        }
        per_thread
            .iter_mut()
            .for_each(|local| scan.boxes.append(&mut local.boxes));
    } else {
        match scanned.contiguous_iter() {
            Ok(tables) => tables.for_each(|table| scan_table(table, scan)),
            Err(_) => scanned.iter().for_each(|item| scan_row(item, scan)),
        }
    }
    let boxes = scan.boxes.drain(..).chain(again);
    index::apply_changes(&mut index, boxes, sync, &sink, true);
    let mut handles = renderables.p1();
    for &(entity, id) in &sync.inserted {
        if let Ok(mut handle) = handles.get_mut(entity) {
            handle.0 = Some(id);
        }
    }
}

/// How many changed rows ahead `scan_table` asks for a row's box,
/// transform, entity and handle.
const ROWS_AHEAD: usize = 8;

/// The changed rows of one table's run of renderables, with their world
/// boxes, pushed onto `out.boxes`: a row changed where its box's or its
/// transform's change tick is newer than the system's last run, as Bevy's
/// `Changed` filter decides.
///
/// The changed rows are gathered first and their boxes read afterwards,
/// each asked for eight rows ahead: a changed row's reads miss the caches
/// (its transform alone is a line or two, in columns of 64 MB on a map of
/// a million), and read as the scan found them they waited one after
/// another. On a 2-core Xeon, with the compares in SSE2, the million-tile
/// map's scan on two threads 3.5 → 2.5 ms a frame (medians of five
/// alternating pairs), the town's lower too. (An AMD EPYC measured the
/// opposite before, 0.66 → 0.84–0.89 ms, when the compares ran slowly
/// enough for the misses to overlap with them.)
fn scan_table(
    table: <Scanned<'_> as ContiguousQueryData>::Contiguous<'_, '_>,
    out: &mut ScannedRows,
) {
    let (ids, aabbs, transforms, handles) = table;
    let test = ChangeTest::new(transforms.last_run_tick(), transforms.this_run_tick());
    let columns = [
        transforms.changed_ticks_slice(),
        aabbs.changed_ticks_slice(),
    ];
    let ScannedRows { rows, boxes } = out;
    rows.clear();
    // Bevy's table rows are `u32`.
    test.for_each_changed(columns, |row| rows.push(row as u32));
    for (i, &row) in rows.iter().enumerate() {
        if let Some(&ahead) = rows.get(i + ROWS_AHEAD) {
            let ahead = ahead as usize;
            prefetch_every_line(&transforms[ahead]);
            prefetch_lines(&aabbs[ahead]);
            prefetch_lines(&ids[ahead]);
            if let Some(handles) = handles {
                prefetch_lines(&handles[ahead]);
            }
        }
        let row = row as usize;
        // Entities spawned before the plugin made the handle a required
        // component have none: their entries are looked up instead.
        let kept = handles.and_then(|h| h[row].0);
        boxes.push((ids[row], world_box(&aabbs[row], &transforms[row]), kept));
    }
}

/// [`scan_table`] for one row, through Bevy's iteration: its world box if
/// its box or transform changed since the system's last run.
fn scan_row(item: <Scanned<'_> as QueryData>::Item<'_, '_>, out: &mut ScannedRows) {
    let (entity, aabb, transform, handle) = item;
    if aabb.is_changed() || transform.is_changed() {
        out.boxes.push((
            entity,
            world_box(&aabb, &transform),
            handle.and_then(|h| h.0),
        ));
    }
}

/// Observers: an entity leaves the index when it loses what Bevy's culling
/// needs (its box, its transform, its visibility components), gains an
/// opt-out marker or is disabled (Bevy's `Disabled`), and is read again when
/// it loses the marker, is enabled, or gains its visibility components after
/// its box (the scan sees only a changed box or transform).
///
/// Where Bevy refused the handle as a required component of `Aabb`
/// (`handles_kept` false), observers of the visibility components' arrival
/// note what the handle's hook would have.
pub(super) fn add_observers(app: &mut bevy_app::App, handles_kept: bool) {
    if !handles_kept {
        app.add_observer(visible_now::<InheritedVisibility>)
            .add_observer(visible_now::<ViewVisibility>);
    }
    app.add_observer(leave::<Remove<BevyAabb>, true>)
        .add_observer(leave::<Remove<GlobalTransform>, true>)
        .add_observer(invisible::<InheritedVisibility>)
        .add_observer(invisible::<ViewVisibility>)
        .add_observer(leave::<Add<NoCpuCulling>, false>)
        .add_observer(leave::<Add<NoFrustumCulling>, false>)
        .add_observer(come_back::<Remove<NoCpuCulling>>)
        .add_observer(come_back::<Remove<NoFrustumCulling>>)
        .add_observer(leave_when_disabled)
        .add_observer(come_back::<Remove<Disabled>>);
}

/// Observer: the entity leaves the renderables' index. `BOX_LOST` when its
/// box is gone (its `Aabb` or its transform, a despawn too), which also
/// forgets a warning about that box.
fn leave<P: EventPattern, const BOX_LOST: bool>(
    event: On<P>,
    mut index: ResMut<SpatialIndex<Renderable>>,
    sink: Res<DiagnosticsSink>,
) where
    P::Event: EntityEvent,
{
    let entity = event.event_target();
    if BOX_LOST {
        index::remove_box(entity, &mut index, &sink);
    } else {
        index::remove_from_layer(entity, &mut index, &sink);
    }
}

/// Observer: a disabled entity leaves the index where Bevy's queries (its
/// culling's among them) leave it out, as they do unless the app took
/// `Disabled` out of `DefaultQueryFilters`.
fn leave_when_disabled(
    event: On<Add<Disabled>>,
    mut index: ResMut<SpatialIndex<Renderable>>,
    filters: Res<DefaultQueryFilters>,
    components: &Components,
    sink: Res<DiagnosticsSink>,
) {
    if crate::plugin::disabling::disabled_is_left_out(&filters, components) {
        index::remove_from_layer(event.entity, &mut index, &sink);
    }
}

/// The renderables' [`ComeBack`](crate::plugin::disabling::ComeBack): an
/// entity that loses a disabling component the app registered is read
/// again.
pub(super) fn come_back_on_enable(id: ComponentId) -> Observer {
    Observer::new(come_back::<Remove<()>>).with_component(id)
}

fn come_back<P: EventPattern>(event: On<P>, mut resync: ResMut<Resync>)
where
    P::Event: EntityEvent,
{
    resync.again.push(event.event_target());
}

/// Observer: an entity that loses a visibility component `C` leaves the
/// index, and waits to be read again once it has both again.
fn invisible<C: Component>(
    event: On<Remove<C>>,
    mut index: ResMut<SpatialIndex<Renderable>>,
    mut resync: ResMut<Resync>,
    sink: Res<DiagnosticsSink>,
) {
    index::remove_from_layer(event.entity, &mut index, &sink);
    resync.waiting.push(event.entity);
}

/// Observer, where entities do not get the handle: an entity that gains a
/// visibility component `C` with its box already there waits to be read
/// (one that gets its box later is found by the scan then).
fn visible_now<C: Component>(
    event: On<Add<C>>,
    boxes: Query<(), With<BevyAabb>>,
    mut resync: ResMut<Resync>,
) {
    if boxes.contains(event.entity) {
        resync.waiting.push(event.entity);
    }
}

/// Hook of [`RenderableHandle`], which comes with Bevy's `Aabb`: an
/// entity given its box before its visibility components waits for them
/// (see [`Resync`]). A hook rather than observers of the visibility
/// components' arrival, which every mesh has: with the observers a probe
/// spawning 200,000 meshes at once took 30-45 % longer (a noisy machine;
/// the hook's own cost was lost in that noise).
pub(super) fn wait_if_invisible(mut world: DeferredWorld, context: HookContext) {
    let entity = context.entity;
    let visible = world
        .get_entity(entity)
        .is_ok_and(|e| e.contains::<InheritedVisibility>() && e.contains::<ViewVisibility>());
    if !visible && let Some(mut resync) = world.get_resource_mut::<Resync>() {
        resync.waiting.push(entity);
    }
}
