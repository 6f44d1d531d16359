//! Disabling components an app registers besides Bevy's `Disabled`
//! (`World::register_disabling_component`): Bevy's queries leave an entity
//! that carries one out, and so does every index.
//!
//! `Disabled` itself is watched by observers the plugins add when they are
//! built. Other disabling components can be registered at any time, so each
//! index has a system that looks at Bevy's `DefaultQueryFilters` when it
//! changes and, for each component it has not seen, spawns an observer that
//! takes an entity out of the index when it gains the component, and takes
//! out the entities already indexed that carry it. An entity that loses the
//! component is read again by the index's next sync (if nothing else
//! disables it), as after `Disabled`.

use bevy_ecs::component::ComponentId;
use bevy_ecs::entity_disabling::{DefaultQueryFilters, Disabled};
use bevy_ecs::observer::Observer;
use bevy_ecs::prelude::*;

use super::diagnostics::DiagnosticsSink;
use super::index::{self, SpatialIndex};

/// Makes the observer that puts an entity back when it loses the
/// disabling component it is given.
pub(crate) type ComeBack = fn(ComponentId) -> Observer;

/// The system that keeps `SpatialIndex<L>` watching every disabling
/// component the app registers; `come_back`, where given, makes the
/// observer that puts an enabled entity back (one index per entity set
/// needs it: the main layer's, whose sync every layer follows). Run it
/// when `DefaultQueryFilters` changed.
pub(crate) fn watch_disabling<L: Component>(
    come_back: Option<ComeBack>,
) -> impl FnMut(Res<DefaultQueryFilters>, Res<SpatialIndex<L>>, Commands) {
    move |filters, index, mut commands| {
        let new: Vec<ComponentId> = filters
            .disabling_ids()
            .filter(|id| !index.watched_disabling.contains(id))
            .collect();
        if !new.is_empty() {
            commands.queue(move |world: &mut World| start_watching::<L>(world, &new, come_back));
        }
    }
}

/// Spawns the observers for `ids` (but `Disabled`, which has its own) and
/// takes out of the index the entities that already carry one of them.
fn start_watching<L: Component>(
    world: &mut World,
    ids: &[ComponentId],
    come_back: Option<ComeBack>,
) {
    let disabled = world.register_component::<Disabled>();
    world.resource_scope(|world, mut index: Mut<SpatialIndex<L>>| {
        for &id in ids {
            // Two systems (the startup sync's and the frame's) may have
            // asked for the same component before either request ran.
            if index.watched_disabling.contains(&id) {
                continue;
            }
            index.watched_disabling.push(id);
            if id == disabled {
                continue;
            }
            world.spawn(Observer::new(leave::<L>).with_component(id));
            if let Some(come_back) = come_back {
                world.spawn(come_back(id));
            }
            let carriers: Vec<Entity> = index
                .tree()
                .iter()
                .map(|(_, entity, _)| entity)
                .chain(index.unindexed())
                .filter(|&entity| world.get_entity(entity).is_ok_and(|e| e.contains_id(id)))
                .collect();
            let sink = world.resource::<DiagnosticsSink>();
            for entity in carriers {
                index::remove_from_layer(entity, &mut index, sink);
            }
        }
    });
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

/// The main layer's [`ComeBack`]: the entity's box is marked changed, so
/// that the next sync puts it back in every layer it belongs to.
pub(crate) fn mark_bounds_changed(id: ComponentId) -> Observer {
    Observer::new(bounds_changed_on_enable).with_component(id)
}

/// Observer: marks the box of an entity that loses a disabling component
/// as changed. The entity still carries the component while the observer
/// runs, which Bevy's queries would leave out: it is read directly.
fn bounds_changed_on_enable(event: On<Remove<()>>, mut world: bevy_ecs::world::DeferredWorld) {
    if let Some(mut bounds) = world.get_mut::<super::SpatialBounds>(event.entity) {
        bounds.set_changed();
    }
}
