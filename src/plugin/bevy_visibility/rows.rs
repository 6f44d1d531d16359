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
//!
//! On a task pool of several threads, with enough candidates, the reads
//! are split: each thread takes a contiguous share of the candidates (in
//! `Entity` order), looks them up and decides them on read-only columns,
//! noting the rows it saw; the calling thread then marks those rows
//! visible. The reads are nearly all cache misses, and several cores keep
//! more of them in flight than one.

use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, RenderLayers, ViewVisibility, VisibilityClass,
    VisibleEntityRanges,
};
use bevy_ecs::entity::Entities;
use bevy_ecs::prelude::*;
use bevy_ecs::storage::TableId;
use bevy_tasks::ComputeTaskPool;

use super::cameras::{Culled, Sight, decide, may_be_seen};
use super::columns::CulledColumns;
use super::seen::Seen;
use crate::tree::prefetch::prefetch_lines;

/// How many candidates ahead of the one decided its rows are asked for.
const LOOK_AHEAD: usize = 8;

/// The fewest candidates a thread's share of the split look-ups holds:
/// below it, the share's work would not pay for its task.
const CANDIDATES_PER_SHARE: usize = 256;

/// Where a candidate's components are: its table among the query's, and
/// its row.
#[derive(Clone, Copy)]
struct RowAt {
    table: u32,
    row: u32,
}

/// No table: a candidate that is not decided here.
const NONE: u32 = u32::MAX;

/// One thread's share of the split look-ups, kept from frame to frame.
#[derive(Default)]
struct Share {
    /// Per candidate of the share, where its components are.
    located: Vec<RowAt>,
    /// The rows the share found visible, for the calling thread to mark.
    visible: Vec<RowAt>,
    /// The share's lists.
    seen: Seen,
}

/// The look-ups' buffers, kept from frame to frame.
#[derive(Default)]
pub(super) struct RowScratch {
    /// Per candidate, where its components are.
    located: Vec<RowAt>,
    /// Per `TableId`, the table's place among the query's tables (`NONE`
    /// for tables the query does not read); reset after each use.
    slots: Vec<u32>,
    /// The threads' shares, where the look-ups are split.
    shares: Vec<Share>,
    /// The split look-ups' tables, by their place in the read-only pass.
    read_tables: Vec<TableId>,
}

/// The columns of [`Culled`] a decision on a proven candidate reads, for
/// a run of rows (read-only, so that several threads may read them).
struct ReadColumns<'w> {
    ids: &'w [Entity],
    inherited: &'w [InheritedVisibility],
    view: &'w [ViewVisibility],
    class: Option<&'w [VisibilityClass]>,
    layers: Option<&'w [RenderLayers]>,
    has_range: bool,
}

/// The query's tables in its order, each with its columns, and `slots`
/// filled with each table's place (tables whose first entity is not
/// spawned are left out, as no candidate can be in them).
fn tables_of<C>(
    chunks: impl Iterator<Item = C>,
    ids: impl Fn(&C) -> &[Entity],
    entities: &Entities,
    slots: &mut Vec<u32>,
) -> Vec<(TableId, C)> {
    let mut tables = Vec::new();
    for columns in chunks {
        let Some(&first) = ids(&columns).first() else {
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
    tables
}

/// Each proven candidate's table place and row (`NONE` for the others and
/// for those no longer spawned), in a loop whose loads do not wait on each
/// other.
fn locate(
    candidates: &[(Entity, bool)],
    entities: &Entities,
    slots: &[u32],
    located: &mut Vec<RowAt>,
) {
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
}

/// Decides the proven candidates among `candidates` (entity, proven) for
/// one view through their rows: Bevy's checks other than the frustum tests
/// (visible in the hierarchy, on a layer the camera renders, within its
/// visibility range), then `set_visible` and the view's lists, as Bevy's
/// loop does for an entity that passes its tests. A candidate that is no
/// longer spawned, or not in the query's tables, is skipped, as a failed
/// `Query::get` skips it. With `parallel` (and a pool of several threads)
/// the reads are split over the pool (see the module docs).
#[allow(clippy::too_many_arguments)]
pub(super) fn decide_proven_by_rows(
    query: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    entities: &Entities,
    sight: &Sight,
    seen: &mut Seen,
    candidates: &[(Entity, bool)],
    scratch: &mut RowScratch,
    ranges: Option<&VisibleEntityRanges>,
    parallel: bool,
) {
    let threads = if parallel {
        ComputeTaskPool::try_get().map_or(1, |pool| pool.thread_num())
    } else {
        1
    };
    let shares = threads.min(candidates.len() / CANDIDATES_PER_SHARE);
    if shares > 1 {
        decide_split(
            query, entities, sight, seen, candidates, scratch, ranges, shares,
        );
        return;
    }
    let Ok(chunks) = query.contiguous_iter_mut() else {
        // Every query of an app that registers a disabling component stored
        // in a sparse set is sparse: the candidates go one by one.
        decide_proven_one_by_one(query, sight, seen, candidates, ranges);
        return;
    };
    let RowScratch { located, slots, .. } = scratch;
    let chunks = chunks.map(CulledColumns::new);
    let mut tables = tables_of(chunks, |c| c.ids, entities, slots);
    locate(candidates, entities, slots, located);
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

/// [`decide_proven_by_rows`] split into `shares` contiguous shares of the
/// candidates, one task each, deciding on read-only columns; the rows they
/// saw are then marked visible here, and their lists appended in share
/// order (the lists are sorted before they are handed to Bevy).
#[allow(clippy::too_many_arguments)]
fn decide_split(
    query: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    entities: &Entities,
    sight: &Sight,
    seen: &mut Seen,
    candidates: &[(Entity, bool)],
    scratch: &mut RowScratch,
    ranges: Option<&VisibleEntityRanges>,
    shares: usize,
) {
    let RowScratch {
        slots,
        shares: all_shares,
        read_tables,
        ..
    } = scratch;
    if all_shares.len() < shares {
        all_shares.resize_with(shares, Share::default);
    }
    let share_len = candidates.len().div_ceil(shares);
    {
        // Every query of an app that registers a disabling component
        // stored in a sparse set is sparse: the candidates go one by one.
        let Ok(chunks) = query.contiguous_iter() else {
            decide_proven_one_by_one(query, sight, seen, candidates, ranges);
            return;
        };
        let chunks = chunks.map(|columns| {
            let (ids, inherited, view, class, layers, _, _, _, _, has_range) = columns;
            ReadColumns {
                ids,
                inherited,
                view,
                class,
                layers,
                has_range,
            }
        });
        let tables = tables_of(chunks, |c| c.ids, entities, slots);
        let (read, slots_read) = (&tables[..], &slots[..]);
        ComputeTaskPool::get().scope(|scope| {
            for (part, share) in candidates.chunks(share_len).zip(all_shares.iter_mut()) {
                scope.spawn(async move {
                    // Worked on as the task's own local: the shares lie
                    // side by side, and their lists' lengths written
                    // candidate by candidate from several cores could
                    // share cache lines.
                    let mut mine = std::mem::take(share);
                    decide_share(read, slots_read, entities, sight, part, ranges, &mut mine);
                    *share = mine;
                });
            }
        });
        for (id, _) in &tables {
            slots[id.as_u32() as usize] = NONE;
        }
        // The read's tables, in the order the shares' rows name them.
        read_tables.clear();
        read_tables.extend(tables.iter().map(|(id, _)| *id));
    }
    let Ok(chunks) = query.contiguous_iter_mut() else {
        for share in all_shares.iter_mut() {
            share.visible.clear();
            share.seen.clear();
        }
        decide_proven_one_by_one(query, sight, seen, candidates, ranges);
        return;
    };
    let chunks = chunks.map(CulledColumns::new);
    // `slots` now gives each table's place in this second list: a share's
    // row names its table by its place in the first, translated by id.
    let mut tables = tables_of(chunks, |c| c.ids, entities, slots);
    for share in all_shares.iter_mut().take(shares) {
        for at in share.visible.drain(..) {
            let id = read_tables[at.table as usize].as_u32() as usize;
            let place = slots.get(id).copied().unwrap_or(NONE);
            if let Some((_, columns)) = tables.get_mut(place as usize) {
                columns.set_visible(at.row as usize);
            }
        }
        seen.take_from(&mut share.seen);
    }
    for (id, _) in &tables {
        slots[id.as_u32() as usize] = NONE;
    }
}

/// One share of the split look-ups: its candidates located and decided on
/// read-only columns, the rows seen noted in `share.visible` and listed in
/// `share.seen`.
fn decide_share(
    tables: &[(TableId, ReadColumns<'_>)],
    slots: &[u32],
    entities: &Entities,
    sight: &Sight,
    candidates: &[(Entity, bool)],
    ranges: Option<&VisibleEntityRanges>,
    share: &mut Share,
) {
    let Share {
        located,
        visible,
        seen,
    } = share;
    locate(candidates, entities, slots, located);
    visible.clear();
    seen.clear();
    for (i, (&(entity, _), &at)) in candidates.iter().zip(located.iter()).enumerate() {
        if let Some(&ahead) = located.get(i + LOOK_AHEAD)
            && let Some((_, columns)) = tables.get(ahead.table as usize)
        {
            let row = ahead.row as usize;
            prefetch_lines(&columns.inherited[row]);
            // Not read here: asked for so that the marking, on the
            // calling thread, may find it in a cache the cores share (not
            // measured apart from the rest of the split).
            prefetch_lines(&columns.view[row]);
            if let Some(class) = columns.class {
                prefetch_lines(&class[row]);
            }
        }
        let Some((_, columns)) = tables.get(at.table as usize) else {
            continue;
        };
        let row = at.row as usize;
        let mask = columns.layers.map(|layers| &layers[row]);
        let inherited = &columns.inherited[row];
        if !may_be_seen(sight, entity, inherited, mask, columns.has_range, ranges) {
            continue;
        }
        visible.push(at);
        seen.push_classes(entity, columns.class.map(|class| &class[row]));
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
