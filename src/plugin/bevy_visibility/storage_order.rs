//! The cameras decided together in one pass over the entities in storage
//! order, where their candidates are a large part of all entities: each
//! table's columns are walked row by row, and a row is decided for the
//! views that marked its entity as a candidate.
//!
//! The walk reads the columns a contiguous query hands over once per table
//! (or per batch, on several threads), so a row no view marked costs the
//! read of its entity and its marks, not a binding of every term of
//! Bevy's query to the row. Where Bevy's queries cannot be read by table
//! (an app that registers a disabling component stored in a sparse set),
//! the walk goes through Bevy's own iteration, row by row.

use std::ops::DerefMut;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::atomic::{AtomicU16, AtomicUsize};

use bevy_camera::visibility::{NoCpuCulling, VisibleEntityRanges};
use bevy_ecs::prelude::*;
use bevy_ecs::query::{ContiguousQueryData, QueryData};
use bevy_utils::Parallel;

use super::cameras::{Culled, Sight, View, decide};
use super::columns::{CulledColumns, TABLES_SPLIT_ACROSS_THREADS};
use super::seen::Seen;

/// One table's (or batch's) columns of [`Culled`].
type Columns<'w, 's> = <Culled<'static> as ContiguousQueryData>::Contiguous<'w, 's>;

/// One entity's row of [`Culled`].
type CulledItem<'w, 's> = <Culled<'static> as QueryData>::Item<'w, 's>;

/// An entity's mark for a view: the view has it as a candidate.
const CANDIDATE: u16 = 0b01;
/// An entity's mark for a view: the tree proved it inside every plane.
const PROVEN: u16 = 0b10;

/// One batch's hold on its thread's lists: when the batch ends, each list
/// notes the part the batch wrote, a run in storage order (see `seen.rs`).
struct BatchLists<L: DerefMut<Target = Vec<Seen>>> {
    lists: L,
}

impl<L: DerefMut<Target = Vec<Seen>>> BatchLists<L> {
    fn start(mut lists: L) -> Self {
        lists.iter_mut().for_each(Seen::start_batch);
        BatchLists { lists }
    }
}

impl<L: DerefMut<Target = Vec<Seen>>> Drop for BatchLists<L> {
    fn drop(&mut self) {
        self.lists.iter_mut().for_each(Seen::end_batch);
    }
}

/// The views of a pass marked in `bits` (two per view), each with whether
/// it proved the entity inside.
fn views_marked(mut bits: u16) -> impl Iterator<Item = (usize, bool)> {
    std::iter::from_fn(move || {
        (bits != 0).then(|| {
            let v = bits.trailing_zeros() as usize / 2;
            let proven = bits >> (2 * v) & PROVEN != 0;
            bits &= !(0b11 << (2 * v));
            (v, proven)
        })
    })
}

/// Decides the views of one pass together, walking the entities in
/// storage order and testing each against the views that have it as a
/// candidate (every view that culls nothing, and every view for the
/// entities outside the tree). `marks` is working space, per entity index,
/// two bits per view of the pass (candidate, proven inside), all clear
/// between calls (the walk clears those it reads, the rest are cleared
/// after it).
///
/// On a task pool of several threads the walk is split as Bevy splits its
/// own; each thread gathers what it saw in its own lists, merged afterwards
/// (the lists are sorted before they are handed to Bevy, so the order of
/// the merge does not show).
pub(super) fn decide_in_storage_order(
    views: &mut [View],
    one_by_one: &[Entity],
    culled: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    ranges: Option<&VisibleEntityRanges>,
    marks: &mut Vec<AtomicU16>,
    seen: &mut Parallel<Vec<Seen>>,
    parallel: bool,
) {
    // How many entities got a mark.
    let mut marked = 0usize;
    let mut mark = |entity: Entity, bits: u16| {
        let at = entity.index_u32() as usize;
        if marks.len() <= at {
            marks.resize_with(at + 1, AtomicU16::default);
        }
        let mark = marks[at].get_mut();
        marked += usize::from(*mark == 0);
        *mark |= bits;
    };
    let mut all = 0u16;
    for (v, view) in views.iter().enumerate() {
        let shift = 2 * v;
        if view.sight.no_culling {
            all |= CANDIDATE << shift;
        }
        for &(entity, proven) in &view.candidates {
            mark(
                entity,
                (CANDIDATE | if proven { PROVEN } else { 0 }) << shift,
            );
        }
        for &entity in one_by_one {
            mark(entity, CANDIDATE << shift);
        }
    }
    let mut visible: Vec<Seen> = views
        .iter_mut()
        .map(|v| std::mem::take(&mut v.visible))
        .collect();
    let sights: Vec<&Sight> = views.iter().map(|v| &v.sight).collect();
    let marks_read: &[AtomicU16] = marks;
    let marks_of = |entity: Entity| {
        all | marks_read
            .get(entity.index_u32() as usize)
            .map_or(0, |mark| mark.load(Relaxed))
    };
    // The walk by table clears each mark it finds set, on the thread that
    // reads it (each entity is one row, so no two threads write one mark;
    // relaxed loads and stores are plain moves), and counts them.
    let cleared = AtomicUsize::new(0);
    let walk = |lists: &mut Vec<Seen>, columns: Columns<'_, '_>| {
        let mut columns = CulledColumns::new(columns);
        let mut cleared_here = 0;
        for (row, &entity) in columns.ids.iter().enumerate() {
            let bits = match marks_read.get(entity.index_u32() as usize) {
                Some(mark) => {
                    let bits = mark.load(Relaxed);
                    if bits != 0 {
                        mark.store(0, Relaxed);
                        cleared_here += 1;
                    }
                    bits
                }
                None => 0,
            };
            for (v, proven) in views_marked(all | bits) {
                columns.decide(row, entity, sights[v], &mut lists[v], proven, ranges);
            }
        }
        cleared.fetch_add(cleared_here, Relaxed);
    };
    // Where the query cannot be read by table (a disabling component the
    // app registered is stored in a sparse set, which makes every query
    // sparse), the walk goes entity by entity through Bevy's iteration.
    let walk_items = |lists: &mut Vec<Seen>, mut item: CulledItem<'_, '_>| {
        for (v, proven) in views_marked(marks_of(item.0)) {
            decide(sights[v], &mut lists[v], &mut item, proven, ranges);
        }
    };
    if parallel {
        // Bevy calls this once per batch.
        let lists = || {
            let mut lists = seen.borrow_local_mut();
            lists.resize_with(sights.len(), Seen::default);
            BatchLists::start(lists)
        };
        let by_table = if TABLES_SPLIT_ACROSS_THREADS {
            culled.contiguous_par_iter_mut().ok()
        } else {
            None
        };
        match by_table {
            Some(batches) => {
                batches.for_each_init(lists, |batch, columns| walk(&mut batch.lists, columns))
            }
            None => culled
                .par_iter_mut()
                .for_each_init(lists, |batch, item| walk_items(&mut batch.lists, item)),
        }
        for local in seen.iter_mut() {
            for (mine, list) in visible.iter_mut().zip(local.iter_mut()) {
                mine.take_from(list);
            }
        }
    } else {
        // One thread: straight into the views' lists.
        match culled.contiguous_iter_mut() {
            Ok(tables) => tables.for_each(|columns| walk(&mut visible, columns)),
            Err(_) => culled
                .iter_mut()
                .for_each(|item| walk_items(&mut visible, item)),
        }
    }
    for (view, list) in views.iter_mut().zip(visible) {
        view.visible = list;
    }
    // Where the walk did not clear every mark (its count differs from the
    // entities marked: a marked entity it did not meet, or the walk row by
    // row), cleared mark by mark: no mark may be carried into the next
    // pass. (All marks are clear on entry, and the walk meets an entity at
    // most once, so equal counts mean every mark was cleared.)
    if cleared.into_inner() != marked {
        for view in views.iter() {
            for &(entity, _) in &view.candidates {
                *marks[entity.index_u32() as usize].get_mut() = 0;
            }
        }
        for &entity in one_by_one {
            *marks[entity.index_u32() as usize].get_mut() = 0;
        }
    }
    debug_assert!(
        marks.iter_mut().all(|mark| *mark.get_mut() == 0),
        "no mark is carried into the next pass"
    );
}
