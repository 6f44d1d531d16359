//! One index per layer: the tree of the entities that carry the layer's
//! marker, and the systems and observers that keep it equal to their boxes.

use std::marker::PhantomData;

use bevy_ecs::change_detection::{CheckChangeTicks, Tick};
use bevy_ecs::component::ComponentId;
use bevy_ecs::entity::{EntityHashMap, EntityHashSet};
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemChangeTick;

use super::bounds::{NoSpatialIndex, SpatialBounds, SpatialHandle};
use super::change_scan::ChangeTest;
use super::diagnostics::DiagnosticsSink;
use super::move_order::{BucketSpace, bucket_by_slot};
use crate::geometry::Aabb;
use crate::tree::{InvariantViolation, ProxyId, RTree, TreeSettings};

/// The index of one layer: every entity with [`SpatialBounds`], the marker
/// `L` and no [`NoSpatialIndex`], keyed by [`Entity`].
///
/// `SpatialIndex` (with the default `L = SpatialBounds`) holds every indexed
/// entity; [`add_spatial_layer::<L>`](super::SpatialAppExt::add_spatial_layer)
/// adds a separate tree for the entities marked `L`, so that queries and joins
/// limited to that layer visit nothing else.
///
/// Read it from any system with `Res<SpatialIndex<L>>` (or through
/// [`SpatialQuery`](super::SpatialQuery)); it is current after
/// [`SpatialIndexSystems::Sync`](super::SpatialIndexSystems::Sync).
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::Aabb;
/// use bevy_rtree::plugin::{SpatialBounds, SpatialIndex, SpatialIndexPlugin};
/// use bevy_rtree::glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let e = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?)).id();
/// app.update();
/// let index = app.world().resource::<SpatialIndex>();
/// assert_eq!(index.get(e), Some(Aabb::new(Vec3::ZERO, Vec3::ONE)?));
/// assert_eq!(index.tree().overlapping(&Aabb::new(Vec3::splat(0.5), Vec3::ONE)?), vec![e]);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Resource)]
pub struct SpatialIndex<L: Component = SpatialBounds> {
    pub(super) tree: RTree<Entity>,
    proxies: EntityHashMap<ProxyId>,
    /// Entities already warned about an invalid box (one warning each).
    warned: EntityHashSet,
    /// Entities of the layer left out for an invalid box, until it is valid
    /// again (those that answer by other means, like Bevy's renderables, are
    /// tested one by one).
    unindexed: EntityHashSet,
    /// Bumped by every change of the indexed set or of a box, so that joins
    /// can skip frames where neither of their layers changed.
    generation: u64,
    /// The disabling components whose observers serve this index.
    pub(crate) watched_disabling: Vec<ComponentId>,
    /// When a sync of this index last ran. Its sync runs as two systems
    /// (in `PostStartup` and in the plugin's schedule), each with a change
    /// tick of its own; the index's own tick lets the second start where
    /// the first ended, instead of reading every startup box again.
    synced_at: Option<Tick>,
    /// Whether a rebuild's work is out on the task pool: the maintenance
    /// runs until it is back (or let go), whatever else it has to do, so
    /// that no finished work waits in it with a whole second structure.
    pub(crate) rebuild_away: bool,
    _layer: PhantomData<fn() -> L>,
}

impl<L: Component> SpatialIndex<L> {
    pub(crate) fn new(settings: TreeSettings) -> Self {
        let tree = RTree::with_settings(settings).unwrap_or_default();
        SpatialIndex {
            tree,
            proxies: EntityHashMap::default(),
            warned: EntityHashSet::default(),
            unindexed: EntityHashSet::default(),
            generation: 0,
            watched_disabling: Vec::new(),
            synced_at: None,
            rebuild_away: false,
            _layer: PhantomData,
        }
    }

    /// The tree, for every query of the core API.
    pub fn tree(&self) -> &RTree<Entity> {
        &self.tree
    }

    /// Number of indexed entities.
    pub fn len(&self) -> usize {
        self.tree.len()
    }

    /// Whether no entity is indexed.
    pub fn is_empty(&self) -> bool {
        self.tree.is_empty()
    }

    /// Whether `entity` is indexed.
    pub fn contains(&self, entity: Entity) -> bool {
        self.proxies.contains_key(&entity)
    }

    /// The box the index holds for `entity`, if it is indexed.
    pub fn get(&self, entity: Entity) -> Option<Aabb> {
        let id = *self.proxies.get(&entity)?;
        self.tree.get(id).ok().map(|(_, aabb)| aabb)
    }

    /// Checks the tree's invariants ([contract S10](crate::contract)) and that the entity map
    /// and the tree agree.
    pub fn validate(&self) -> Result<(), InvariantViolation> {
        self.tree.validate()?;
        if self.proxies.len() != self.tree.len() {
            return Err(InvariantViolation(format!(
                "{} entities mapped, {} entries in the tree",
                self.proxies.len(),
                self.tree.len()
            )));
        }
        for (entity, id) in &self.proxies {
            match self.tree.get(*id) {
                Ok((key, _)) if key == *entity => {}
                _ => {
                    return Err(InvariantViolation(format!(
                        "{entity} maps to a handle the tree does not hold for it"
                    )));
                }
            }
        }
        Ok(())
    }

    /// A counter that changes whenever the indexed set or a box changes.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The entities of the layer that are left out of the index for an
    /// invalid box, until they get a valid one.
    pub fn unindexed(&self) -> impl ExactSizeIterator<Item = Entity> + '_ {
        self.unindexed.iter().copied()
    }

    /// The change test of a sync of this index running with `ticks`: the
    /// changes since the last sync of the index by any system, and this
    /// run noted as the next one's start.
    fn sync_test(&mut self, ticks: &SystemChangeTick) -> ChangeTest {
        let since = self.synced_at.unwrap_or(ticks.last_run());
        self.synced_at = Some(ticks.this_run());
        ChangeTest::new(since, ticks.this_run())
    }

    /// Keeps the last sync's tick from growing so old that it wraps, as
    /// Bevy keeps its systems' ticks (on [`CheckChangeTicks`]).
    pub(crate) fn check_ticks(&mut self, check: CheckChangeTicks) {
        if let Some(tick) = &mut self.synced_at {
            tick.check_tick(check);
        }
    }

    /// Takes `entity` out of the index if it is there.
    pub(crate) fn remove(&mut self, entity: Entity) -> bool {
        match self.proxies.remove(&entity) {
            Some(id) => {
                // The handle came from this tree, so removal cannot fail.
                let _ = self.tree.remove(id);
                self.generation += 1;
                true
            }
            None => false,
        }
    }
}

/// Whether `L` is the layer of all indexed entities.
pub(crate) fn is_main_layer<L: Component>() -> bool {
    std::any::TypeId::of::<L>() == std::any::TypeId::of::<SpatialBounds>()
}

/// What one sync pass did to one index.
#[derive(Default)]
pub(crate) struct SyncCount {
    pub inserted: u64,
    pub updated: u64,
    pub removed: u64,
    pub invalid: u64,
}

/// What a layer's sync reads of an entity, table by table: the change
/// ticks of its box, and the added ticks of the layer's marker.
type LayerRow<'a, L> = (Entity, Ref<'a, SpatialBounds>, Ref<'a, L>);

/// Applies the changed boxes of this frame to the index of a layer `L`
/// other than the main one: an entity also enters when it gains `L`.
pub(crate) fn sync_layer<L: Component>(
    mut index: ResMut<SpatialIndex<L>>,
    members: Query<LayerRow<'_, L>, Without<NoSpatialIndex>>,
    mut scratch: Local<SyncScratch>,
    sink: Res<DiagnosticsSink>,
    ticks: SystemChangeTick,
) {
    let scratch = &mut *scratch;
    let mut changed = std::mem::take(&mut scratch.changed);
    changed.clear();
    let test = index.sync_test(&ticks);
    // Table by table where the query can be read so (a marker or a
    // disabling component stored in a sparse set makes it row by row).
    match members.contiguous_iter() {
        Ok(tables) => tables.for_each(|(entities, bounds, marker)| {
            let columns = [bounds.changed_ticks_slice(), marker.added_ticks_slice()];
            test.for_each_changed(columns, |row| {
                changed.push((entities[row], bounds[row].0, None));
            });
        }),
        Err(_) => changed.extend(
            members
                .iter()
                .filter(|(_, bounds, marker)| {
                    test.newer(&bounds.last_changed()) || test.newer(&marker.added())
                })
                .map(|(entity, bounds, _)| (entity, bounds.0, None)),
        ),
    }
    // Every entity of a layer is in the main layer too: one bad box is
    // reported there only, one warning and one count.
    apply_changes(&mut index, changed.drain(..), scratch, &sink, false);
    scratch.changed = changed;
}

/// What the main sync reads of an entity, table by table.
type MainRow<'a> = (Entity, Ref<'a, SpatialBounds>, &'a SpatialHandle);

/// Applies the changed boxes of this frame to the main index. Gaining the
/// component is a change of it, so one change test per entity suffices
/// (the scan over every entity is the plugin's main fixed cost).
#[allow(clippy::type_complexity)]
pub(crate) fn sync_main(
    mut index: ResMut<SpatialIndex>,
    mut members: ParamSet<(
        Query<MainRow<'_>, Without<NoSpatialIndex>>,
        Query<&mut SpatialHandle, Without<NoSpatialIndex>>,
    )>,
    mut scratch: Local<SyncScratch>,
    sink: Res<DiagnosticsSink>,
    ticks: SystemChangeTick,
) {
    let scratch = &mut *scratch;
    let mut changed = std::mem::take(&mut scratch.changed);
    changed.clear();
    let test = index.sync_test(&ticks);
    let scanned = members.p0();
    match scanned.contiguous_iter() {
        Ok(tables) => tables.for_each(|(entities, bounds, handles)| {
            test.for_each_changed([bounds.changed_ticks_slice()], |row| {
                changed.push((entities[row], bounds[row].0, handles[row].0));
            });
        }),
        Err(_) => changed.extend(
            scanned
                .iter()
                .filter(|(_, bounds, _)| test.newer(&bounds.last_changed()))
                .map(|(entity, bounds, handle)| (entity, bounds.0, handle.0)),
        ),
    }
    apply_changes(&mut index, changed.drain(..), scratch, &sink, true);
    scratch.changed = changed;
    // The handles of the entities just inserted, kept on them.
    let mut handles = members.p1();
    for &(entity, id) in &scratch.inserted {
        if let Ok(mut handle) = handles.get_mut(entity) {
            handle.0 = Some(id);
        }
    }
}

/// A sync system's buffers, kept from frame to frame so syncing does not
/// allocate.
#[derive(Default)]
pub(crate) struct SyncScratch {
    /// Entities seen for the first time, inserted together.
    fresh: Vec<(Entity, Aabb)>,
    /// Indexed entities that moved, found by look-up, applied as one batch.
    moves: Vec<(ProxyId, Aabb)>,
    /// Moves by the handles the entities keep, checked as they apply.
    kept_moves: Vec<(ProxyId, Entity, Aabb)>,
    /// Indices into `kept_moves` whose handle was not the entity's entry.
    refused: Vec<usize>,
    /// Working space for putting the moves in slot order.
    kept_order: BucketSpace<(ProxyId, Entity, Aabb)>,
    moves_order: BucketSpace<(ProxyId, Aabb)>,
    /// The handles of the entities the last sync inserted, for callers that
    /// keep them on the entities.
    pub inserted: Vec<(Entity, ProxyId)>,
    /// The changed entities a sync system found, before they are applied.
    changed: Vec<(Entity, Aabb, Option<ProxyId>)>,
}

/// Updates, inserts or (for invalid boxes) removes each changed entity,
/// warning once per entity about an invalid box and counting it where
/// `report` says this layer reports them. An entity appears at most once in
/// `changed`, with the handle its caller keeps for it, if any: a live handle
/// of the entity saves the look-up of its entry. The handles of inserted
/// entities are left in `scratch.inserted`.
///
/// Moves are gathered and applied as one [`RTree::update_batch`](crate::RTree::update_batch).
/// New entities are gathered and inserted together: when they outnumber the
/// entities already indexed (the first frame of a scene) the tree is bulk
/// loaded, which is several times faster and gives a better tree, with room
/// in its leaves for the entities that will move
/// ([`RTree::insert_bulk_with_room`](crate::RTree::insert_bulk_with_room)).
pub(crate) fn apply_changes<L: Component>(
    index: &mut SpatialIndex<L>,
    changed: impl Iterator<Item = (Entity, Aabb, Option<ProxyId>)>,
    scratch: &mut SyncScratch,
    sink: &DiagnosticsSink,
    report: bool,
) {
    let mut count = SyncCount::default();
    let SyncScratch {
        fresh,
        moves,
        kept_moves,
        refused,
        kept_order,
        moves_order,
        inserted,
        ..
    } = scratch;
    fresh.clear();
    moves.clear();
    kept_moves.clear();
    refused.clear();
    inserted.clear();
    for (entity, aabb, kept) in changed {
        if let Err(error) = aabb.validate() {
            if index.remove(entity) {
                count.removed += 1;
            }
            index.unindexed.insert(entity);
            // The default box is a placeholder, "no box yet" (spawned with
            // `SpatialBounds::default()`, or given `LocalBounds` after this
            // frame's world boxes were written): left out like any invalid
            // box, but nothing the user got wrong, so neither reported nor
            // counted. Boxes that could not be computed are `UNUSABLE`.
            if !report || aabb == Aabb::INVERTED {
                continue;
            }
            count.invalid += 1;
            if index.warned.insert(entity) {
                log::warn!(
                    "{entity} has an invalid box ({error}) for the spatial index of {}; it is left out until its box is valid",
                    std::any::type_name::<L>()
                );
            }
            continue;
        }
        if !index.unindexed.is_empty() {
            index.unindexed.remove(&entity);
        }
        if let Some(id) = kept {
            kept_moves.push((id, entity, aabb));
            continue;
        }
        match index.proxies.get(&entity) {
            Some(&id) => moves.push((id, aabb)),
            None => fresh.push((entity, aabb)),
        }
    }
    // Moves by the handles the entities keep, each checked as it is
    // applied, in the order of their entries' slots (see `move_order`);
    // an entity whose handle is not its entry's is looked up.
    let slots = index.tree.slot_count();
    bucket_by_slot(kept_moves, kept_order, slots, |m| m.0.index());
    index.tree.update_kept(kept_moves, refused);
    count.updated = (kept_moves.len() - refused.len()) as u64;
    for &i in refused.iter() {
        let (_, entity, aabb) = kept_moves[i];
        match index.proxies.get(&entity) {
            Some(&id) => moves.push((id, aabb)),
            None => fresh.push((entity, aabb)),
        }
    }
    // Every box was validated above and every handle is live, so the batch
    // is accepted whole; should it ever be refused, the moves go one by one
    // and only the refused ones are skipped. In slot order too: the layers'
    // syncs keep no handles, and find every entry here.
    bucket_by_slot(moves, moves_order, slots, |m| m.0.index());
    if index.tree.update_batch(moves).is_ok() {
        count.updated += moves.len() as u64;
    } else {
        for &(id, aabb) in moves.iter() {
            if index.tree.update(id, aabb).is_ok() {
                count.updated += 1;
            }
        }
    }
    if !fresh.is_empty() {
        // Many at once in bulk, with room in the leaves for the moves to
        // come; should the bulk load ever be refused (the boxes were
        // checked), one by one, as the moves above.
        let bulk = (fresh.len() > index.tree.len())
            .then(|| index.tree.insert_bulk_with_room(fresh.iter().copied()).ok())
            .flatten();
        if let Some(ids) = bulk {
            for (&(entity, _), id) in fresh.iter().zip(ids) {
                index.proxies.insert(entity, id);
                inserted.push((entity, id));
            }
        } else {
            for &(entity, aabb) in fresh.iter() {
                if let Ok(id) = index.tree.insert(entity, aabb) {
                    index.proxies.insert(entity, id);
                    inserted.push((entity, id));
                }
            }
        }
        count.inserted = inserted.len() as u64;
    }
    if count.inserted + count.updated + count.removed > 0 {
        index.generation += 1;
    }
    sink.add(|d| d.record_sync(&count));
}

/// Observer: an entity that loses its [`SpatialHandle`] but keeps its box
/// gets the handle back, naming its entry in the main index. The main sync
/// reads the handle with the box, so without one the entity would keep its
/// last box there for good.
pub(crate) fn put_handle_back(event: On<Remove<SpatialHandle>>, mut commands: Commands) {
    let entity = event.entity;
    // Decided once the removal is done (observers of `Remove` run before
    // it): a despawn, or a removal that takes the box too (`clear`,
    // `retain`), leaves nothing to put the handle on.
    commands.queue(move |world: &mut World| {
        let id = world
            .get_resource::<SpatialIndex>()
            .and_then(|index| index.proxies.get(&entity).copied());
        if let Ok(mut kept) = world.get_entity_mut(entity)
            && kept.contains::<SpatialBounds>()
            && !kept.contains::<SpatialHandle>()
        {
            kept.insert(SpatialHandle(id));
        }
    });
}

/// Observer: an entity lost its layer marker or its place (opt-out,
/// disabled), so it leaves the index at once. A warning about its box
/// stands: the same box read again when it comes back is not warned about
/// twice.
pub(crate) fn remove_from_layer<L: Component>(
    entity: Entity,
    index: &mut SpatialIndex<L>,
    sink: &DiagnosticsSink,
) {
    index.unindexed.remove(&entity);
    if index.remove(entity) {
        sink.add(|d| d.sync.removed += 1);
    }
}

/// Observer: an entity lost its box (a despawn too), so it leaves the
/// index at once; a box it gets later is a new one, warned about if it is
/// invalid. Forgetting here keeps the warned set as small as the entities
/// that hold a bad box.
pub(crate) fn remove_box<L: Component>(
    entity: Entity,
    index: &mut SpatialIndex<L>,
    sink: &DiagnosticsSink,
) {
    index.warned.remove(&entity);
    remove_from_layer(entity, index, sink);
}
