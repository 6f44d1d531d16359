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
//! the sort. Where a batch's rows are one run in `Entity` order (a batch
//! within one table whose entities were spawned together, the common
//! case) the sort then finds the list sorted; where they are not (a batch
//! over several small tables, entities respawned in between) the sort does
//! the rest. The lists are sorted whatever the parts. The measurements:
//! docs/performance.md, "Sixteen cores".

use std::any::TypeId;

use bevy_camera::visibility::VisibilityClass;
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
    /// The lists' lengths where the batch under way started.
    batch_start: Vec<u32>,
    /// The list [`Self::push`] wrote to last (its class is the likeliest
    /// next).
    last: usize,
}

impl Seen {
    /// Lists `entity` once under each visibility class it names, as Bevy
    /// lists a visible entity (twice under a class it names twice; under
    /// none without a `VisibilityClass`).
    #[inline]
    pub(super) fn push_classes(&mut self, entity: Entity, classes: Option<&VisibilityClass>) {
        let Some(classes) = classes else {
            return;
        };
        for &class in classes.iter() {
            self.push(entity, class);
        }
    }

    /// Lists `entity` under `class`. Called once per visible entity and
    /// view, so the list pushed to last is tried first: a scene's
    /// renderables are mostly of one class.
    #[inline]
    fn push(&mut self, entity: Entity, class: TypeId) {
        match self.lists.get_mut(self.last) {
            Some((last, list)) if *last == class => list.push(entity),
            _ => self.push_to_another(entity, class),
        }
    }

    /// [`Self::push`] under a class other than the last one's.
    #[inline(never)]
    fn push_to_another(&mut self, entity: Entity, class: TypeId) {
        match self.lists.iter().position(|(c, _)| *c == class) {
            Some(at) => {
                self.lists[at].1.push(entity);
                self.last = at;
            }
            None => {
                self.last = self.lists.len();
                self.lists.push((class, vec![entity]));
            }
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

    /// [`Self::lists`], to hand the lists over (swapped out): their parts
    /// are forgotten.
    pub(super) fn lists_to_hand_over(&mut self) -> &mut [(TypeId, Vec<Entity>)] {
        self.parts.clear();
        &mut self.lists
    }

    /// Notes where a batch of a parallel pass starts writing.
    pub(super) fn start_batch(&mut self) {
        self.batch_start.clear();
        let lengths = self.lists.iter().map(|(_, list)| list.len() as u32);
        self.batch_start.extend(lengths);
    }

    /// Notes the part each list got since [`Self::start_batch`] (a class
    /// first seen in the batch from its start).
    pub(super) fn end_batch(&mut self) {
        for (class, (_, list)) in self.lists.iter().enumerate() {
            let start = self.batch_start.get(class).copied().unwrap_or(0);
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
            let mine = self.lists.iter().position(|(c, _)| c == class);
            let at = mine.unwrap_or(self.lists.len());
            let offset = mine.map_or(0, |mine| self.lists[mine].1.len() as u32);
            let parts = other.parts.iter().filter(|p| p.class == theirs);
            self.parts.extend(parts.map(|p| Part {
                class: at,
                start: p.start + offset,
                end: p.end + offset,
            }));
            match mine {
                Some(mine) => self.lists[mine].1.append(list),
                None => self.lists.push((*class, std::mem::take(list))),
            }
        }
        other.parts.clear();
    }

    /// Sorts every class's list into `Entity` order, as Bevy's diffing of
    /// visible lists needs (see the module docs). `spare` is working space.
    pub(super) fn sort(&mut self, spare: &mut Vec<Entity>) {
        self.in_part_order(spare);
        for (_, list) in &mut self.lists {
            if !list.is_sorted() {
                list.sort();
            }
        }
    }

    /// Puts each list whose parts cover it in the order of its parts'
    /// least entities, each part the right way round, and forgets the
    /// parts.
    fn in_part_order(&mut self, spare: &mut Vec<Entity>) {
        let Seen { lists, parts, .. } = self;
        parts.sort_unstable_by_key(|p| (p.class, least(&lists[p.class].1, p)));
        for (class, (_, list)) in lists.iter_mut().enumerate() {
            let mine = parts.iter().filter(|p| p.class == class);
            let covered: u32 = mine.clone().map(|p| p.end - p.start).sum();
            if covered as usize != list.len() || mine.clone().count() < 2 {
                continue;
            }
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
                local.start_batch();
                for &row in rows {
                    match rng.below(4) {
                        0 => {}
                        1 => local.push(row, TypeId::of::<Light>()),
                        _ => local.push(row, TypeId::of::<Mesh>()),
                    }
                }
                local.end_batch();
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

    /// Each entity is listed under each class it names, as often as it
    /// names it, whatever the class of the entity before it (the list
    /// written last is tried first). Fails if an entity lands in another
    /// class's list.
    #[test]
    fn lists_each_entity_under_the_classes_it_names() {
        struct Sprite;
        let kinds = [
            TypeId::of::<Mesh>(),
            TypeId::of::<Light>(),
            TypeId::of::<Sprite>(),
        ];
        let mut rng = SceneRng::new(0xC1A5);
        let mut seen = Seen::default();
        for round in 0..20 {
            seen.clear();
            let mut expected: Vec<(TypeId, Vec<Entity>)> = Vec::new();
            for i in 0..500 {
                let mut classes = VisibilityClass::default();
                // Mostly one class for many entities in a row, as a scene's
                // renderables come; sometimes none, two, or one twice.
                for _ in 0..[1, 1, 1, 0, 2][rng.below(5)] {
                    classes.push(kinds[(i / 50 + rng.below(2) * rng.below(3)) % 3]);
                }
                let e = entity(i as u32, round);
                let named = (rng.below(8) != 0).then_some(&classes);
                seen.push_classes(e, named);
                for &class in named.into_iter().flat_map(|c| c.iter()) {
                    match expected.iter_mut().find(|(c, _)| *c == class) {
                        Some((_, list)) => list.push(e),
                        None => expected.push((class, vec![e])),
                    }
                }
            }
            for (class, list) in seen.lists() {
                let mine = expected.iter().find(|(c, _)| c == class);
                assert_eq!(
                    list,
                    &mine.map_or(Vec::new(), |m| m.1.clone()),
                    "round {round}"
                );
            }
            for (class, list) in &expected {
                assert!(seen.lists().iter().any(|(c, l)| c == class && l == list));
            }
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
            local.start_batch();
            rows.iter()
                .for_each(|&i| local.push(entity(i, 1), TypeId::of::<Mesh>()));
            local.end_batch();
        }
        let mut seen = Seen::default();
        for local in &mut locals {
            seen.take_from(local);
        }
        assert_eq!(seen.parts.len(), 30);
        let list = &seen.lists()[0].1;
        assert!(!list.is_sorted() && list.len() == 3_000);
        seen.in_part_order(&mut Vec::new());
        let list = &seen.lists()[0].1;
        assert!(list.is_sorted() && list.len() == 3_000);
    }
}
