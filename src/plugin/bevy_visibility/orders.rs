//! The orders an app gave its own systems against Bevy's systems that the
//! index replaces, carried over to the replacements.
//!
//! A system taken out of a schedule leaves its system set behind, empty.
//! An app's `probe.after(check_point_light_mesh_visibility)` then orders
//! `probe` after nothing: it may run before the index fills the lists it
//! reads, where with Bevy's system it always ran after. So before Bevy's
//! system goes, each order of a system against its set is copied onto the
//! set of the system that takes its place.
//!
//! Each of Bevy's systems has a replacement of its own, so an order
//! against one carries over to it alone and closes no cycle that Bevy's
//! system did not.
//!
//! Not carried over (each logged at debug level): an order of a whole set
//! of the app (the schedule hands out its sets only by reference), and of
//! a function added more than once (which cannot be ordered against by
//! name). Nor what the schedule keeps to itself: an order's opt-out of
//! sync points (`after_ignore_deferred`, carried as a plain order, which
//! may add a sync point Bevy's system did not have), and an exemption from
//! ambiguity against Bevy's system (`ambiguous_with`, `ignore_ambiguity`),
//! which does not cover the replacement.

use bevy_ecs::schedule::graph::Direction;
use bevy_ecs::schedule::{InternedSystemSet, IntoScheduleConfigs, NodeId, Schedule, SystemSet};

/// The set of the index's system that serves Bevy's camera culling.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct ServesCameraVisibility;

/// The set of the index's system that serves bevy_light's point and spot
/// light shadow visibility.
#[cfg(feature = "bevy_light")]
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct ServesPointLightVisibility;

/// The set of the index's system that serves bevy_light's directional
/// light shadow visibility.
#[cfg(feature = "bevy_light")]
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct ServesDirectionalLightVisibility;

/// The systems `schedule` orders before and after the set `replaced` (a
/// system of Bevy's, still in it), each named by its function's set:
/// `(before, after)`. Left out: the systems of `ours` (the replacement
/// itself), what the module's docs list, and a system found on both sides.
/// Read before Bevy's system is taken out (see `take_out_bevy_systems`).
pub(super) fn orders_against(
    schedule: &Schedule,
    replaced: InternedSystemSet,
    ours: InternedSystemSet,
) -> (Vec<InternedSystemSet>, Vec<InternedSystemSet>) {
    let graph = schedule.graph();
    let ours = graph.system_sets.get_key(ours).map(NodeId::Set);
    let hierarchy = graph.hierarchy().graph();
    // A system is held by the graph until the schedule is first built, and
    // by its executable afterwards.
    let system = |key| {
        graph
            .systems
            .get(key)
            .map(|held| held.system())
            .or_else(|| {
                let mut built = schedule.systems().ok()?;
                built
                    .find(|(built, _)| *built == key)
                    .map(|(_, system)| system)
            })
    };
    let label = |node: NodeId| -> Option<InternedSystemSet> {
        if ours.is_some_and(|ours| hierarchy.contains_edge(ours, node)) {
            return None;
        }
        let NodeId::System(key) = node else {
            log::debug!(
                "an order of a set against a system the index replaces is not carried over"
            );
            return None;
        };
        let function = *system(key)?.default_system_sets().first()?;
        let function_key = graph.system_sets.get_key(function)?;
        let instances = hierarchy
            .neighbors_directed(NodeId::Set(function_key), Direction::Outgoing)
            .count();
        if instances != 1 {
            log::debug!("an order of {function:?}, added {instances} times, is not carried over");
            return None;
        }
        Some(function)
    };
    let dependency = graph.dependency().graph();
    let Some(key) = graph.system_sets.get_key(replaced) else {
        return (Vec::new(), Vec::new());
    };
    let node = NodeId::Set(key);
    let mut before: Vec<InternedSystemSet> = dependency
        .neighbors_directed(node, Direction::Incoming)
        .filter_map(label)
        .collect();
    let mut after: Vec<InternedSystemSet> = dependency
        .neighbors_directed(node, Direction::Outgoing)
        .filter_map(label)
        .collect();
    let both: Vec<InternedSystemSet> = before
        .iter()
        .filter(|set| after.contains(set))
        .copied()
        .collect();
    if !both.is_empty() {
        log::debug!("orders on both sides of the systems the index replaces are not carried over");
    }
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
