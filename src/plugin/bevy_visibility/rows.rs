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

use bevy_camera::visibility::{NoCpuCulling, VisibleEntityRanges};
use bevy_ecs::entity::Entities;
use bevy_ecs::prelude::*;
use bevy_ecs::storage::TableId;

use super::cameras::{Culled, Sight, decide};
use super::columns::CulledColumns;
use super::seen::Seen;

/// How many candidates ahead of the one decided its rows are asked for.
const LOOK_AHEAD: usize = 8;

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
    let mut tables: Vec<(TableId, CulledColumns<'_>)> = Vec::new();
    for columns in chunks {
        let columns = CulledColumns::new(columns);
        let Some(&first) = columns.ids.first() else {
            continue;
        };
        let Ok(at) = entities.get_spawned(first) else {
            continue;
        };
        let id = at.table_id.as_u32() as usize;
        if slots.len() <= id {
            slots.resize(id + 1, NONE);
        }
        slots[id] = tables.len() as u32;
        tables.push((at.table_id, columns));
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
    for (id, _) in &tables {
        slots[id.as_u32() as usize] = NONE;
    }
    for (i, (&(entity, _), &at)) in candidates.iter().zip(located.iter()).enumerate() {
        if let Some(&ahead) = located.get(i + LOOK_AHEAD)
            && let Some((_, columns)) = tables.get(ahead.table as usize)
        {
            columns.prefetch_proven(ahead.row as usize);
        }
        if let Some((_, columns)) = tables.get_mut(at.table as usize) {
            columns.decide(at.row as usize, entity, sight, seen, true, ranges);
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
