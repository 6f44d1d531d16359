//! The orders an app gave its own systems against Bevy's systems that the
//! index replaces, carried over to the replacements.
//!
//! A system taken out of a schedule leaves its system set behind, empty.
//! An app's `probe.after(check_point_light_mesh_visibility)` then orders
//! `probe` after nothing: it may run before the index fills the lists it
//! reads, where with Bevy's system it always ran after. So before Bevy's
//! system goes, each order of a system against its set is copied onto the
//! set of the system that takes its place. (An order of a whole set of the
//! app cannot be: the schedule hands out its other sets only by reference.)

use bevy_ecs::schedule::graph::Direction;
use bevy_ecs::schedule::{InternedSystemSet, IntoScheduleConfigs, NodeId, Schedule, SystemSet};

/// The set of the index's system that serves Bevy's camera culling.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct ServesCameraVisibility;

/// The set of the index's system that serves bevy_light's shadow
/// visibility.
#[cfg(feature = "bevy_light")]
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct ServesLightVisibility;

/// The systems `schedule` orders before and after the sets `replaced`
/// (Bevy's systems, still in it), each named by its function's set:
/// `(before, after)`. Left out: the systems of `ours` (the replacement
/// itself), a function added more than once (which cannot be ordered
/// against by name), and a system found on both sides (before one of
/// Bevy's systems and after another: one replacement cannot sit between).
pub(super) fn orders_against(
    schedule: &Schedule,
    replaced: &[InternedSystemSet],
    ours: InternedSystemSet,
) -> (Vec<InternedSystemSet>, Vec<InternedSystemSet>) {
    let graph = schedule.graph();
    let ours = graph.system_sets.get_key(ours).map(NodeId::Set);
    let label = |node: NodeId| -> Option<InternedSystemSet> {
        if ours.is_some_and(|ours| graph.hierarchy().graph().contains_edge(ours, node)) {
            return None;
        }
        let NodeId::System(key) = node else {
            log::debug!(
                "an order of a system set against a system the index replaces is not carried over"
            );
            return None;
        };
        let function = *graph
            .systems
            .get(key)?
            .system()
            .default_system_sets()
            .first()?;
        let instances = graph
            .systems
            .iter()
            .filter(|(_, other, _)| other.default_system_sets().contains(&function))
            .count();
        (instances == 1).then_some(function)
    };
    let dependency = graph.dependency().graph();
    let (mut before, mut after) = (Vec::new(), Vec::new());
    for set in replaced {
        let Some(key) = graph.system_sets.get_key(*set) else {
            continue;
        };
        let node = NodeId::Set(key);
        before.extend(
            dependency
                .neighbors_directed(node, Direction::Incoming)
                .filter_map(label),
        );
        after.extend(
            dependency
                .neighbors_directed(node, Direction::Outgoing)
                .filter_map(label),
        );
    }
    let both: Vec<InternedSystemSet> = before
        .iter()
        .filter(|set| after.contains(set))
        .copied()
        .collect();
    before.retain(|set| !both.contains(set));
    after.retain(|set| !both.contains(set));
    (before, after)
}

/// Orders `ours` after every set of `before` and before every set of
/// `after`.
pub(super) fn order(
    schedule: &mut Schedule,
    ours: InternedSystemSet,
    (before, after): (Vec<InternedSystemSet>, Vec<InternedSystemSet>),
) {
    for set in before {
        schedule.configure_sets(ours.after(set));
    }
    for set in after {
        schedule.configure_sets(ours.before(set));
    }
}
