//! Disabling components an app registers besides Bevy's `Disabled`
//! (`World::register_disabling_component`): Bevy's queries leave an entity
//! that carries one out, and so does every index.
//!
//! `Disabled` itself is watched by observers the plugins add when they are
//! built. For the others, each index has a system that looks at Bevy's
//! `DefaultQueryFilters` when it changes and, for each component it has
//! not seen, takes out the entities already indexed that carry it and
//! spawns an observer that takes an entity out of the index when it gains
//! the component. An entity that loses it is read again by the index's next
//! sync (if nothing else disables it), as after `Disabled`.
//!
//! Register them as Bevy asks, before the app's first update (in a
//! plugin's `build`, say): a query leaves out only the disabling components
//! registered before it first ran, and the syncs' queries run from the
//! first frame on.

use bevy_ecs::archetype::Archetypes;
use bevy_ecs::component::{ComponentId, Components};
use bevy_ecs::entity::Entities;
use bevy_ecs::entity_disabling::{DefaultQueryFilters, Disabled};
use bevy_ecs::observer::Observer;
use bevy_ecs::prelude::*;
use bevy_ecs::world::DeferredWorld;

use super::SpatialBounds;
use super::diagnostics::DiagnosticsSink;
use super::index::{self, SpatialIndex};

/// Whether Bevy's queries leave out an entity with Bevy's `Disabled`: they
/// do unless the app took it out of `DefaultQueryFilters` (with
/// `DefaultQueryFilters::empty()`, say), and the indexes do as they do.
pub(crate) fn disabled_is_left_out(filters: &DefaultQueryFilters, components: &Components) -> bool {
    let disabled = components.component_id::<Disabled>();
    filters.disabling_ids().any(|id| Some(id) == disabled)
}

/// Makes the observer that puts an entity back when it loses the
/// disabling component it is given.
pub(crate) type ComeBack = fn(ComponentId) -> Observer;

/// What a watcher reads of the world to find the entities of its index
/// that carry a component.
type Carriers<'w> = (&'w Entities, &'w Archetypes, &'w Components);

/// The system that keeps `SpatialIndex<L>` watching every disabling
/// component the app registers; `come_back`, where given, makes the
/// observer that puts an enabled entity back (one index per entity set
/// needs it: the main layer's, whose sync every layer follows). Run it
/// when `DefaultQueryFilters` changed, before the index's sync: the
/// entities that carry a new one leave at once, and its observers are
/// spawned at the schedule's next sync point.
#[allow(clippy::type_complexity)]
pub(crate) fn watch_disabling<L: Component>(
    come_back: Option<ComeBack>,
) -> impl FnMut(
    Res<DefaultQueryFilters>,
    ResMut<SpatialIndex<L>>,
    Carriers<'_>,
    Res<DiagnosticsSink>,
    Commands,
) {
    move |filters, mut index, (entities, archetypes, components), sink, mut commands| {
        let disabled = components.component_id::<Disabled>();
        for id in filters.disabling_ids() {
            if index.watched_disabling.contains(&id) {
                continue;
            }
            index.watched_disabling.push(id);
            if Some(id) == disabled {
                continue;
            }
            commands.spawn(Observer::new(leave::<L>).with_component(id));
            if let Some(come_back) = come_back {
                commands.spawn(come_back(id));
            }
            let carries = |entity: Entity| {
                entities
                    .get_spawned(entity)
                    .ok()
                    .and_then(|at| archetypes.get(at.archetype_id))
                    .is_some_and(|archetype| archetype.contains(id))
            };
            let carriers: Vec<Entity> = index
                .tree()
                .iter()
                .map(|(_, entity, _)| entity)
                .chain(index.unindexed())
                .filter(|&entity| carries(entity))
                .collect();
            for entity in carriers {
                index::remove_from_layer(entity, &mut index, &sink);
            }
        }
    }
}

/// Observer: an entity gained a disabling component, so it leaves the
/// index.
fn leave<L: Component>(
    event: On<Add<()>>,
    mut index: ResMut<SpatialIndex<L>>,
    sink: Res<DiagnosticsSink>,
) {
    index::remove_from_layer(event.entity, &mut index, &sink);
}

/// The main layer's [`ComeBack`]: the entity is read again by the next
/// sync, and so put back in every layer it belongs to.
pub(crate) fn read_again_when_enabled(id: ComponentId) -> Observer {
    Observer::new(read_again_on_enable).with_component(id)
}

/// Observer: an entity loses a disabling component.
fn read_again_on_enable(event: On<Remove<()>>, mut world: DeferredWorld) {
    read_again(&mut world, event.entity);
}

/// Marks what the syncs read of an entity coming back (enabled again, or
/// opted back in) as changed: its box, and where the plugin computes that
/// from a local box, the local box, which may have changed while the
/// entity was left out of every query. Read through the world, not a
/// query, as the entity may still carry the component that leaves it out.
pub(crate) fn read_again(world: &mut DeferredWorld, entity: Entity) {
    #[cfg(feature = "bevy")]
    if let Some(mut local) = world.get_mut::<super::LocalBounds>(entity) {
        local.set_changed();
    }
    if let Some(mut bounds) = world.get_mut::<SpatialBounds>(entity) {
        bounds.set_changed();
    }
}
