//! The tree's proven candidates decided through their table rows: each
//! candidate's location is looked up in Bevy's `Entities`, and its
//! components are read from the column slices of its table, which a
//! contiguous query hands over once per table.
//!
//! A `Query::get` per candidate binds every term of the query to the
//! entity's table again; on a map of a million entities with twenty
//! thousand candidates that binding, and the loads it waits on one after
//! another, were most of the camera's step. Here the locations are looked
//! up in one pass of independent loads (the processor overlaps them), and
//! each candidate's rows are asked for a few candidates ahead of its turn.
//! Where Bevy's queries cannot be read by table (an app that registers a
//! disabling component stored in a sparse set), the candidates go through
//! `Query::get` as before.

use std::panic::Location;

use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, RenderLayers, SetViewVisibility, ViewVisibility,
    VisibilityClass, VisibleEntityRanges,
};
use bevy_ecs::change_detection::{ContiguousComponentTicksMut, ContiguousMut, MaybeLocation, Tick};
use bevy_ecs::entity::Entities;
use bevy_ecs::prelude::*;
use bevy_ecs::storage::TableId;

use super::cameras::{Culled, Seen, Sight, decide, may_be_seen};
use crate::tree::prefetch::prefetch_lines;

/// How many candidates ahead of the one decided its rows are asked for.
const LOOK_AHEAD: usize = 8;

/// One table's columns of what a proven candidate's decision reads and
/// writes (of Bevy's culling query, [`Culled`]).
struct TableRows<'w> {
    table: TableId,
    inherited: &'w [InheritedVisibility],
    view: &'w mut [ViewVisibility],
    ticks: ContiguousComponentTicksMut<'w>,
    class: Option<&'w [VisibilityClass]>,
    layers: Option<&'w [RenderLayers]>,
    has_range: bool,
}

/// Where a candidate's components are: its table among the query's, and
/// its row.
#[derive(Clone, Copy)]
struct RowAt {
    table: u32,
    row: u32,
}

/// The look-ups' buffers, kept from frame to frame.
#[derive(Default)]
pub(super) struct RowScratch {
    /// Per candidate, where its components are.
    located: Vec<RowAt>,
    /// Per `TableId`, the table's place among the query's tables (`NONE`
    /// for tables the query does not read); reset after each use.
    slots: Vec<u32>,
}

/// No table: a candidate that is not decided here.
const NONE: u32 = u32::MAX;

/// Decides the proven candidates among `candidates` (entity, proven) for
/// one view through their rows: Bevy's checks other than the frustum tests
/// (visible in the hierarchy, on a layer the camera renders, within its
/// visibility range), then `set_visible` and the view's lists, as Bevy's
/// loop does for an entity that passes its tests. A candidate that is no
/// longer spawned, or not in the query's tables, is skipped, as a failed
/// `Query::get` skips it.
pub(super) fn decide_proven_by_rows(
    query: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    entities: &Entities,
    sight: &Sight,
    seen: &mut Seen,
    candidates: &[(Entity, bool)],
    scratch: &mut RowScratch,
    ranges: Option<&VisibleEntityRanges>,
) {
    let Ok(chunks) = query.contiguous_iter_mut() else {
        // Every query of an app that registers a disabling component stored
        // in a sparse set is sparse: the candidates go one by one.
        decide_proven_one_by_one(query, sight, seen, candidates, ranges);
        return;
    };
    let RowScratch { located, slots } = scratch;
    let mut tables: Vec<TableRows<'_>> = Vec::new();
    for (ids, inherited, view, class, layers, .., has_range) in chunks {
        let Some(&first) = ids.first() else { continue };
        let Ok(at) = entities.get_spawned(first) else {
            continue;
        };
        let id = at.table_id.as_u32() as usize;
        if slots.len() <= id {
            slots.resize(id + 1, NONE);
        }
        slots[id] = tables.len() as u32;
        let (view, ticks) = ContiguousMut::bypass_change_detection_split(view);
        tables.push(TableRows {
            table: at.table_id,
            inherited,
            view,
            ticks,
            class,
            layers,
            has_range,
        });
    }
    // The locations first, in a loop whose loads do not wait on each other.
    located.clear();
    located.extend(candidates.iter().map(|&(entity, proven)| {
        let at = proven.then(|| entities.get_spawned(entity).ok()).flatten();
        at.map_or(
            RowAt {
                table: NONE,
                row: 0,
            },
            |at| RowAt {
                table: slots
                    .get(at.table_id.as_u32() as usize)
                    .copied()
                    .unwrap_or(NONE),
                row: at.table_row.index_u32(),
            },
        )
    }));
    for table in &tables {
        slots[table.table.as_u32() as usize] = NONE;
    }
    for (i, (&(entity, _), &at)) in candidates.iter().zip(located.iter()).enumerate() {
        if let Some(&ahead) = located.get(i + LOOK_AHEAD)
            && let Some(table) = tables.get(ahead.table as usize)
        {
            let row = ahead.row as usize;
            prefetch_lines(&table.inherited[row]);
            prefetch_lines(&table.view[row]);
            if let Some(class) = table.class {
                prefetch_lines(&class[row]);
            }
        }
        let Some(table) = tables.get_mut(at.table as usize) else {
            continue;
        };
        let row = at.row as usize;
        let mask = table.layers.map(|layers| &layers[row]);
        if !may_be_seen(
            sight,
            entity,
            &table.inherited[row],
            mask,
            table.has_range,
            ranges,
        ) {
            continue;
        }
        set_visible(table.view, &mut table.ticks, row);
        if let Some(class) = table.class {
            for &id in class[row].iter() {
                seen.push(entity, id);
            }
        }
    }
}

/// [`decide_proven_by_rows`] through `Query::get`, for a query that cannot
/// be read by table.
fn decide_proven_one_by_one(
    query: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    sight: &Sight,
    seen: &mut Seen,
    candidates: &[(Entity, bool)],
    ranges: Option<&VisibleEntityRanges>,
) {
    for &(entity, proven) in candidates {
        if proven && let Ok(mut item) = query.get_mut(entity) {
            decide(sight, seen, &mut item, true, ranges);
        }
    }
}

/// Bevy's `set_visible` on one row of a `ViewVisibility` column: the value
/// changed as Bevy changes it, and the row's change tick (and caller, where
/// Bevy tracks it) written exactly when Bevy's would be.
pub(super) fn set_visible(
    view: &mut [ViewVisibility],
    ticks: &mut ContiguousComponentTicksMut<'_>,
    row: usize,
) {
    let (last_run, this_run) = (ticks.last_run(), ticks.this_run());
    let mut value = view[row];
    // `set_visible` reads neither tick; the copy's changed tick becomes
    // `this_run` exactly when it marks the value changed. (The column has
    // no summary tick for it to update: `ViewVisibility` keeps none, which
    // a test checks.)
    let mut added = this_run;
    let mut changed = Tick::new(this_run.get().wrapping_sub(1));
    let mut caller = Location::caller();
    let mut visibility = Mut::new(
        &mut value,
        &mut added,
        &mut changed,
        None,
        last_run,
        this_run,
        MaybeLocation::new_with(|| &mut caller),
    );
    visibility.set_visible();
    let marked = changed == this_run;
    view[row] = value;
    if marked {
        ticks.changed_mut()[row] = this_run;
        ticks.changed_by_mut().map(|by| by[row] = caller);
    }
}
