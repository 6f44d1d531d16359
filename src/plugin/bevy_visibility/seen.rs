//! The entities a view saw, per visibility class, and their sort into the
//! order Bevy's lists are kept in.
//!
//! The pass in storage order split over the pool (`storage_order.rs`)
//! writes a view's entities into one list per thread, batch after batch,
//! and the threads' lists are appended afterwards. Each batch's part is a
//! run in storage order, which is `Entity` order backwards where the
//! entities were spawned together; but a thread takes every n-th batch, so
//! its list is one long run through all the entities, interleaved with
//! the other threads' runs, and a sort of the whole list merges as many
//! runs as there are threads. On the 2-core machine with a pool of 16
//! threads, one camera's lists took 0.17–0.19 ms to sort against 0.05 ms
//! with 2 threads (`BEVY_RTREE_THREADS` in `benches/bevy_visibility.rs`).
//! So each batch notes the part of the lists it wrote, and the parts are
//! put in order of their least entity, each the right way round, before
//! the sort: batches are disjoint ranges of rows, and where rows follow
//! `Entity` order the sort then finds the list sorted. Where they do not,
//! the sort does the rest: the lists are sorted whatever the parts. With
//! the parts, the town's lists (docs/performance.md, "Sixteen cores")
//! took 0.05 ms instead of 0.41 for one camera with 16 threads, and
//! 0.16–0.17 instead of 0.61–0.73 ms for four.

use std::any::TypeId;

use bevy_ecs::entity::Entity;

/// A part of one class's list that one batch of a parallel pass wrote.
#[derive(Clone, Copy, Debug)]
struct Part {
    /// The index of the class's list.
    class: usize,
    start: u32,
    end: u32,
}

/// The entities a view saw, per visibility class.
#[derive(Default)]
pub(super) struct Seen {
    lists: Vec<(TypeId, Vec<Entity>)>,
    /// The parts of the lists each batch of a parallel pass wrote.
    parts: Vec<Part>,
}

impl Seen {
    pub(super) fn push(&mut self, entity: Entity, class: TypeId) {
        match self.lists.iter_mut().find(|(c, _)| *c == class) {
            Some((_, list)) => list.push(entity),
            None => self.lists.push((class, vec![entity])),
        }
    }

    pub(super) fn clear(&mut self) {
        self.lists.iter_mut().for_each(|(_, list)| list.clear());
        self.parts.clear();
    }

    /// Each class's list and its entities.
    pub(super) fn lists(&self) -> &[(TypeId, Vec<Entity>)] {
        &self.lists
    }

    /// [`Self::lists`], to take the lists away (their parts are forgotten).
    pub(super) fn lists_mut(&mut self) -> &mut [(TypeId, Vec<Entity>)] {
        self.parts.clear();
        &mut self.lists
    }

    /// The length of each class's list, where a batch starts writing.
    pub(super) fn lengths(&self) -> Vec<u32> {
        self.lists
            .iter()
            .map(|(_, list)| list.len() as u32)
            .collect()
    }

    /// Notes what a batch that started at `lengths` wrote.
    pub(super) fn end_batch(&mut self, lengths: &[u32]) {
        for (class, (_, list)) in self.lists.iter().enumerate() {
            let start = lengths.get(class).copied().unwrap_or(0);
            let end = list.len() as u32;
            if end > start {
                self.parts.push(Part { class, start, end });
            }
        }
    }

    /// Moves what `other` saw into this list, with its batches' parts
    /// (emptying `other`'s lists but keeping their allocations).
    pub(super) fn take_from(&mut self, other: &mut Seen) {
        for (theirs, (class, list)) in other.lists.iter_mut().enumerate() {
            let mine = match self.lists.iter().position(|(c, _)| c == class) {
                Some(mine) => mine,
                None => {
                    self.lists.push((*class, Vec::new()));
                    self.lists.len() - 1
                }
            };
            let offset = self.lists[mine].1.len() as u32;
            let parts = other.parts.iter().filter(|p| p.class == theirs);
            self.parts.extend(parts.map(|p| Part {
                class: mine,
                start: p.start + offset,
                end: p.end + offset,
            }));
            self.lists[mine].1.append(list);
        }
        other.parts.clear();
    }

    /// Sorts every class's list into `Entity` order, as Bevy's diffing of
    /// visible lists needs (see the module docs). `spare` is working space.
    pub(super) fn sort(&mut self, spare: &mut Vec<Entity>) {
        let Seen { lists, parts } = self;
        parts.sort_unstable_by_key(|p| (p.class, least(&lists[p.class].1, p)));
        for (class, (_, list)) in lists.iter_mut().enumerate() {
            let mine = parts.iter().filter(|p| p.class == class);
            let covered: u32 = mine.clone().map(|p| p.end - p.start).sum();
            if covered as usize == list.len() && mine.clone().count() > 1 {
                spare.clear();
                for part in mine {
                    let piece = &list[part.start as usize..part.end as usize];
                    if piece.first() > piece.last() {
                        spare.extend(piece.iter().rev());
                    } else {
                        spare.extend_from_slice(piece);
                    }
                }
                std::mem::swap(list, spare);
            }
            if !list.is_sorted() {
                list.sort();
            }
        }
        parts.clear();
    }
}

/// The lesser of a part's ends: its least entity where it runs one way.
fn least(list: &[Entity], part: &Part) -> Entity {
    list[part.start as usize].min(list[part.end as usize - 1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneRng;

    fn entity(index: u32, generation: u32) -> Entity {
        let first = Entity::from_raw_u32(index).unwrap().to_bits();
        Entity::from_bits(first | u64::from(generation) << 32)
    }

    struct Mesh;
    struct Light;

    /// Lists written as a parallel pass writes them (batches in storage
    /// order, every n-th batch to one of n threads' lists, the threads'
    /// lists appended), with entities in or out of storage order, in two
    /// classes, come out sorted as the standard sort sorts them.
    #[test]
    fn sorts_every_list_as_the_standard_sort_does() {
        let mut rng = SceneRng::new(0x5EE4);
        let mut spare = Vec::new();
        for round in 0..200 {
            let threads = 1 + rng.below(16);
            let count = [0, 1, 40, 3_000, 20_000][round % 5];
            // Storage order: indices upwards, as one spawn gives them (which
            // is `Entity` order backwards);
            // every third round some rows out of that order, and some
            // entities listed twice (once per class they name in Bevy).
            let generation = rng.below(3) as u32;
            let mut rows: Vec<Entity> = (0..count).map(|i| entity(i, generation)).collect();
            if round % 3 == 1 {
                for _ in 0..rows.len() / 20 {
                    let (a, b) = (rng.below(rows.len()), rng.below(rows.len()));
                    rows.swap(a, b);
                }
                for _ in 0..rows.len() / 50 {
                    let again = rows[rng.below(rows.len())];
                    rows.insert(rng.below(rows.len()), again);
                }
            }
            let batch = 1 + rng.below(600);
            let mut locals: Vec<Seen> = (0..threads).map(|_| Seen::default()).collect();
            for (b, rows) in rows.chunks(batch).enumerate() {
                let local = &mut locals[b % threads];
                let lengths = local.lengths();
                for &row in rows {
                    match rng.below(4) {
                        0 => {}
                        1 => local.push(row, TypeId::of::<Light>()),
                        _ => local.push(row, TypeId::of::<Mesh>()),
                    }
                }
                local.end_batch(&lengths);
            }
            let mut seen = Seen::default();
            for local in &mut locals {
                seen.take_from(local);
            }
            let mut expected: Vec<(TypeId, Vec<Entity>)> = seen.lists().to_vec();
            expected.iter_mut().for_each(|(_, list)| list.sort());
            seen.sort(&mut spare);
            assert_eq!(seen.lists(), expected, "round {round}: {threads} threads");
        }
    }

    /// The parts are what the sort works from: on lists of disjoint parts
    /// in storage order, putting the parts in order leaves the standard
    /// sort nothing to do. Fails if the parts lose their place in the
    /// appended lists.
    #[test]
    fn parts_of_disjoint_batches_come_out_sorted_before_the_sort() {
        let mut locals = [Seen::default(), Seen::default(), Seen::default()];
        for (b, rows) in (0..3_000).collect::<Vec<u32>>().chunks(100).enumerate() {
            let local = &mut locals[b % 3];
            let lengths = local.lengths();
            rows.iter()
                .for_each(|&i| local.push(entity(i, 1), TypeId::of::<Mesh>()));
            local.end_batch(&lengths);
        }
        let mut seen = Seen::default();
        for local in &mut locals {
            seen.take_from(local);
        }
        let Seen { lists, parts } = &mut seen;
        parts.sort_unstable_by_key(|p| (p.class, least(&lists[p.class].1, p)));
        let list = &lists[0].1;
        let mut joined: Vec<Entity> = Vec::new();
        for part in parts.iter() {
            let piece = &list[part.start as usize..part.end as usize];
            assert!(piece.first() > piece.last(), "storage order is backwards");
            joined.extend(piece.iter().rev());
        }
        assert_eq!(parts.len(), 30);
        assert!(joined.is_sorted() && joined.len() == 3_000);
    }
}
