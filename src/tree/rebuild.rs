//! A rebuild spread over frames: a new structure is bulk loaded beside the
//! current one, a little each step, while the tree keeps answering and
//! changing; when it is complete it is swapped in, and the changes made in
//! the meantime that the new structure has not absorbed are applied to it.
//!
//! The new structure is partitioned from a snapshot of the entries' boxes
//! (the costly part: the median cuts of the k-d tiling); its leaves take
//! the snapshot's boxes, or for an entry that moved since, its box as it
//! is when the leaf is filled. Once an entry sits in a new leaf, a move inside that
//! enlarged box is mirrored there at once (one lane write); any other
//! change (a move beyond it, an insert, a removal) marks the entry. Once
//! built, the new structure catches up with the marked entries over a few
//! steps (`rebuild_catch_up.rs`) and is swapped in when none are left.
//! Handles are slot indices and generations, which the swap does not
//! touch: they stay valid, and answers never change (the swapped
//! structure holds exactly the live entries with their current boxes;
//! `validate` checks it).

use std::time::{Duration, Instant};

use super::bulk::{centre_key, group_range};
use super::cut_axis::cut_axis;
use super::handle::Stamp;
use super::node::{NIL, Node};
use super::rebuild_away::next_ticket;
use super::rebuild_catch_up::CatchUp;
use super::{Entry, RTree};
use crate::geometry::Aabb;

/// A rebuild in progress, owned by its tree.
#[derive(Clone, Debug)]
pub(super) struct RebuildJob<const W: usize> {
    /// The new structure's nodes.
    pub(super) nodes: Vec<Node<W>>,
    /// Per slot: the stamp of the entry the snapshot holds, so that a slot
    /// reused since is told apart.
    pub(super) snapshot_stamps: Vec<Stamp>,
    /// Per slot: where the new structure holds the entry (leaf, lane) and
    /// its enlarged box there, once its leaf is filled.
    pub(super) placed: Vec<(u32, u32, Aabb)>,
    /// Per node of the new structure: for a leaf, the bound its parent
    /// holds for it (fixed once filled).
    pub(super) leaf_bounds: Vec<Aabb>,
    /// Slots changed in a way the new structure has not absorbed, each once.
    pub(super) marked: Vec<u32>,
    pub(super) is_marked: Vec<bool>,
    /// Per slot: moved before its new leaf was filled (the leaf then reads
    /// its box from the tree; the others take the snapshot's, in order).
    pub(super) moved_early: Vec<bool>,
    /// What remains to do.
    pub(super) phase: Phase<W>,
    /// Tells this rebuild's tiling apart from any other's when it comes
    /// back from another thread.
    pub(super) ticket: u64,
    /// Once the tiling was taken to run on another thread: the steps asked
    /// for while it was away, about the frames it took, over which the
    /// changes waiting for the catch-up piled up (`None`: built here).
    pub(super) steps_away: Option<usize>,
}

impl<const W: usize> RebuildJob<W> {
    /// The bytes this rebuild holds (allocated capacity): the new
    /// structure, its per-slot tables and the current phase's buffers.
    pub(super) fn memory(&self) -> usize {
        let phase = match &self.phase {
            Phase::Partition { entries, cuts, .. } => bytes(entries) + bytes(cuts),
            Phase::Fill { entries, above, .. } => bytes(entries) + bytes(above),
            Phase::Away | Phase::Done { .. } => 0,
            Phase::CatchUp(catch_up) => catch_up.memory(),
        };
        bytes(&self.nodes)
            + bytes(&self.snapshot_stamps)
            + bytes(&self.placed)
            + bytes(&self.leaf_bounds)
            + bytes(&self.marked)
            + bytes(&self.is_marked)
            + bytes(&self.moved_early)
            + phase
    }

    /// Marks a slot for the swap, once.
    pub(super) fn mark(&mut self, slot: u32) {
        let s = slot as usize;
        if s >= self.is_marked.len() {
            self.is_marked.resize(s + 1, false);
        }
        if !self.is_marked[s] {
            self.is_marked[s] = true;
            self.marked.push(slot);
        }
    }
}

#[derive(Clone, Debug)]
pub(super) enum Phase<const W: usize> {
    /// Tiling the entries of `level` into `groups` groups: median cuts
    /// still to make, as (start, end, first group, group count).
    Partition {
        level: u16,
        entries: Vec<Entry>,
        groups: usize,
        cuts: Vec<(usize, usize, usize, usize)>,
    },
    /// Filling a node per group of `level`, from `next_group` on, and
    /// gathering their entries for the level above.
    Fill {
        level: u16,
        entries: Vec<Entry>,
        groups: usize,
        next_group: usize,
        above: Vec<Entry>,
    },
    /// The work was taken out to run elsewhere
    /// ([`RTree::take_rebuild_work`]); nothing to do until it comes back.
    Away,
    /// Built: the new root.
    Done { root: u32 },
    /// Built, and bringing the new structure up to date with the changes
    /// made meanwhile before the swap (`rebuild_catch_up.rs`).
    CatchUp(CatchUp<W>),
}

/// One median cut of a level's tiling, if any remain: splits the range on
/// top of `cuts` between its groups. Returns whether cuts remain.
pub(super) fn cut_once(
    entries: &mut [Entry],
    groups: usize,
    cuts: &mut Vec<(usize, usize, usize, usize)>,
) -> bool {
    if let Some((start, end, first, count)) = cuts.pop()
        && count > 1
    {
        let n = entries.len();
        let slice = &mut entries[start..end];
        let left = count / 2;
        let cut = group_range(n, groups, first + left).start - start;
        let axis = cut_axis(slice, cut);
        slice.select_nth_unstable_by(cut, |a, b| {
            centre_key(&a.bound, axis).total_cmp(&centre_key(&b.bound, axis))
        });
        cuts.push((start, start + cut, first, left));
        cuts.push((start + cut, end, first + left, count - left));
    }
    !cuts.is_empty()
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Starts rebuilding the tree's structure beside the current one, to
    /// be advanced by [`RTree::step_rebuild`] a little at a time (a rebuild
    /// already under way goes on). While it runs the tree answers and
    /// changes as usual; when it completes it is swapped in, as fresh as
    /// [`RTree::rebuild`] makes it (except that an entry that moved while
    /// it ran keeps the enlarged box the tree gave it, with the stretch of
    /// its motion). Handles stay valid and answers never change, before,
    /// during and after the swap. [`RTree::rebuild`], a non-empty
    /// [`RTree::insert_bulk`] and [`RTree::clear`] retile or empty the tree
    /// themselves and drop a rebuild under way.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    /// use std::time::Duration;
    ///
    /// let mut tree = RTree::new();
    /// let ids: Vec<_> = (0..1_000u32)
    ///     .map(|i| tree.insert(i, Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))?))
    ///     .collect::<Result<_, _>>()?;
    /// tree.start_rebuild();
    /// let mut frames = 0;
    /// loop {
    ///     // A frame: moves as usual, then a slice of the rebuild.
    ///     tree.update(ids[7], Aabb::new(Vec3::splat(-5.0), Vec3::splat(-4.0))?)?;
    ///     frames += 1;
    ///     if tree.step_rebuild(Duration::from_micros(200)) {
    ///         break;
    ///     }
    /// }
    /// assert!(!tree.rebuild_pending());
    /// assert_eq!(tree.containing_point(Vec3::splat(-4.5)), vec![7]);
    /// tree.validate().unwrap();
    /// # let _ = frames;
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn start_rebuild(&mut self) {
        if self.rebuild_job.is_some() {
            return;
        }
        let entries = self.live_entries_in_leaf_order();
        let slots = self.proxies.len();
        self.rebuild_job = Some(Box::new(RebuildJob {
            nodes: Vec::new(),
            snapshot_stamps: self.stamps.clone(),
            placed: vec![(NIL, 0, Aabb::INVERTED); slots],
            leaf_bounds: Vec::new(),
            marked: Vec::new(),
            is_marked: vec![false; slots],
            moved_early: vec![false; slots],
            phase: Self::partition_phase(0, entries),
            ticket: next_ticket(),
            steps_away: None,
        }));
    }

    /// Whether a rebuild started by [`RTree::start_rebuild`] is under way.
    pub fn rebuild_pending(&self) -> bool {
        self.rebuild_job.is_some()
    }

    /// Drops a rebuild under way; the tree is as it would be without it.
    pub fn cancel_rebuild(&mut self) {
        self.rebuild_job = None;
    }

    /// Advances the rebuild under way for about `budget` (one median cut or
    /// one node at least, so that every call makes progress; the first
    /// cuts of a large tree take longest, about 1 ms per 100,000 entries).
    /// Once the new structure is built, each step applies to it the
    /// changes the tree made meanwhile: at least those made since the
    /// previous step and an eighth of those waiting when it was built,
    /// whatever the budget, so that it is swapped in within about eight
    /// steps; after work that ran on another thread
    /// ([`RTree::take_rebuild_work`]), within as many steps as were asked
    /// for while it was away (at most eight): at the first step after work
    /// that took a frame. Returns `true` when it is swapped in;
    /// `false` while work remains or when no rebuild is under way.
    /// A budget too long for the clock (`Duration::MAX`) has no deadline:
    /// the call finishes the rebuild and swaps it in, unless its tiling is
    /// away on another thread ([`RTree::take_rebuild_work`]).
    pub fn step_rebuild(&mut self, budget: Duration) -> bool {
        let deadline = Instant::now().checked_add(budget);
        self.step_rebuild_until(usize::MAX, deadline)
    }

    /// Keeps the tiling as good as fresh within `budget` a call: starts a
    /// rebuild when the changes that wear the tiling (see
    /// [`RTree::is_worn`]) since the last one reach a quarter of the
    /// entries, and advances it by `budget`; returns
    /// whether one was swapped in. Call it once a frame.
    ///
    /// What it buys, measured on the standard scene's 100,000 entities
    /// (`cargo bench --bench decay`, 2,000 frames): the maintained tree
    /// visits 6 to 74 % more nodes than a fresh bulk load of the same
    /// entries, depending on how things move, and the same entries retiled
    /// 0 to 7 % more. With this at 0.25 ms a frame, steps come back to
    /// 6 % more (maintenance 0.29 → 0.60 ms a frame); where 1 % of the
    /// entries teleport or respawn every frame, a rebuild that takes tens
    /// of frames meets many of them changed by the swap, and the tree
    /// stays 45–60 % above fresh. The plugin keeps its trees fresh through
    /// its own path instead (`RebuildMode`, feature `plugin`).
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    /// use std::time::Duration;
    ///
    /// let mut tree = RTree::new();
    /// let ids: Vec<_> = (0..2_000u32)
    ///     .map(|i| tree.insert(i, Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))?))
    ///     .collect::<Result<_, _>>()?;
    /// let mut swaps = 0;
    /// for frame in 0..200u32 {
    ///     // Teleports wear the tiling.
    ///     let i = (frame * 37 % 2_000) as usize;
    ///     let far = Vec3::splat(5_000.0 - i as f32);
    ///     tree.update(ids[i], Aabb::new(far, far + 1.0)?)?;
    ///     swaps += usize::from(tree.rebuild_when_worn(Duration::from_micros(50)));
    /// }
    /// assert!(swaps > 0);
    /// tree.validate().unwrap();
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn rebuild_when_worn(&mut self, budget: Duration) -> bool {
        if self.rebuild_job.is_none() {
            if !self.is_worn() {
                return false;
            }
            self.start_rebuild();
        }
        self.step_rebuild(budget)
    }

    /// Whether the changes that wear the tiling (inserts, removals, moves
    /// that grew a leaf or were reinserted, a jump that left its leaf
    /// counting twice, as the removal and insert of a respawn do; see
    /// [`TreeSettings::jump_limit`](crate::TreeSettings::jump_limit))
    /// since the last rebuild reach a quarter of the entries: the point
    /// where [`RTree::rebuild_when_worn`] starts one.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// for i in 0..100u32 {
    ///     tree.insert(i, Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))?)?;
    /// }
    /// // Built one insert at a time: worn.
    /// assert!(tree.is_worn());
    /// tree.rebuild();
    /// assert!(!tree.is_worn());
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn is_worn(&self) -> bool {
        self.wear * 4 >= self.len as u64 && self.len > W
    }

    /// [`RTree::step_rebuild`] by a count of work units (median cuts and
    /// nodes), for tests that must not depend on the clock.
    #[doc(hidden)]
    pub fn step_rebuild_units(&mut self, units: usize) -> bool {
        self.step_rebuild_until(units.max(1), None)
    }

    fn step_rebuild_until(&mut self, units: usize, deadline: Option<Instant>) -> bool {
        let Some(mut job) = self.rebuild_job.take() else {
            return false;
        };
        // At least one unit per call, then until the units or the time run
        // out; a finished build catches up and is swapped in.
        if matches!(job.phase, Phase::Away) {
            // The tiling runs elsewhere; nothing to do here until it is back.
            *job.steps_away.get_or_insert(0) += 1;
            self.rebuild_job = Some(job);
            return false;
        }
        let mut done = 0usize;
        loop {
            if let Phase::Done { root } = job.phase {
                job.phase = self.begin_catch_up(&mut job, root);
            }
            if matches!(job.phase, Phase::CatchUp(_)) {
                let swapped = self.catch_up(&mut job, units.saturating_sub(done), deadline);
                if !swapped {
                    self.rebuild_job = Some(job);
                }
                return swapped;
            }
            let out_of_time = deadline.is_some_and(|d| Instant::now() >= d);
            if done > 0 && (done >= units || out_of_time) {
                self.rebuild_job = Some(job);
                return false;
            }
            Self::advance(Some(self), &mut job);
            done += 1;
        }
    }

    /// The first phase of a level: tiling, or the root if the entries fit
    /// in one node.
    pub(super) fn partition_phase(level: u16, entries: Vec<Entry>) -> Phase<W> {
        let groups = if entries.len() <= W {
            1
        } else {
            Self::groups_at(level, entries.len(), Self::LEAF_FILL_WITH_ROOM)
        };
        let cuts = vec![(0, entries.len(), 0, groups)];
        Phase::Partition {
            level,
            entries,
            groups,
            cuts,
        }
    }

    /// One unit of work: a median cut, or a node filled.
    /// `tree` is the tree the rebuild belongs to, or `None` where the work
    /// runs away from it ([`RTree::take_rebuild_work`]): every entry then
    /// takes the snapshot's box, and the changes made meanwhile are
    /// applied at the swap.
    pub(super) fn advance(tree: Option<&Self>, job: &mut RebuildJob<W>) {
        match &mut job.phase {
            Phase::Partition {
                level,
                entries,
                groups,
                cuts,
            } => {
                if !cut_once(entries, *groups, cuts) {
                    job.phase = Phase::Fill {
                        level: *level,
                        entries: std::mem::take(entries),
                        groups: *groups,
                        next_group: 0,
                        above: Vec::new(),
                    };
                }
            }
            Phase::Fill {
                level,
                entries,
                groups,
                next_group,
                above,
            } => {
                let range = group_range(entries.len(), *groups, *next_group);
                *next_group += 1;
                let node = if *level == 0 {
                    let lone = *groups == 1;
                    let marks = (&mut job.marked, &mut job.is_marked);
                    let group = &entries[range];
                    let filled = Self::fill_new_leaf(
                        tree,
                        &mut job.nodes,
                        &mut job.placed,
                        marks,
                        group,
                        lone,
                        (&job.snapshot_stamps, &job.moved_early),
                    );
                    if let Some((index, bound)) = filled {
                        job.leaf_bounds.resize(index as usize + 1, Aabb::INVERTED);
                        job.leaf_bounds[index as usize] = bound;
                    }
                    filled
                } else {
                    Some(fill_new_internal(&mut job.nodes, *level, &entries[range]))
                };
                if let Some((index, bound)) = node {
                    above.push(Entry {
                        lane_box: bound,
                        bound,
                        child: index,
                    });
                }
                if *next_group == *groups {
                    let level_done = *level;
                    let above = std::mem::take(above);
                    job.phase = if above.is_empty() {
                        // Every entry left meanwhile: an empty leaf.
                        job.nodes.push(Node::empty(0, NIL));
                        Phase::Done {
                            root: (job.nodes.len() - 1) as u32,
                        }
                    } else if *groups == 1 {
                        // This level's one node is the root.
                        Phase::Done {
                            root: above[0].child,
                        }
                    } else {
                        Self::partition_phase(level_done + 1, above)
                    };
                }
            }
            Phase::Away | Phase::Done { .. } | Phase::CatchUp(_) => {}
        }
    }

    /// Fills a new leaf with the entries of a group that still hold the
    /// entry the snapshot saw: an entry that has not moved since with the
    /// snapshot's box and a fresh enlarged box, one that has with its box
    /// as it is now and the enlarged box the tree gives it now (with the
    /// stretch of its motion); returns the leaf and its bound. An entry that jumped since
    /// the snapshot (farther than [`TreeSettings::jump_limit`] box sizes)
    /// would stretch a leaf tiled for where it was: it is marked for
    /// reinsertion at the swap instead, and so are the entries of a group
    /// that kept too few to fill a node (`None`; unless the group is the
    /// whole tree).
    ///
    /// [`TreeSettings::jump_limit`]: crate::TreeSettings::jump_limit
    fn fill_new_leaf(
        tree: Option<&Self>,
        nodes: &mut Vec<Node<W>>,
        placed: &mut [(u32, u32, Aabb)],
        (marked, is_marked): (&mut Vec<u32>, &mut Vec<bool>),
        group: &[Entry],
        lone: bool,
        (snapshot_stamps, moved_early): (&[Stamp], &[bool]),
    ) -> Option<(u32, Aabb)> {
        let mut leaf = Node::empty(0, NIL);
        let mut kept: smallvec::SmallVec<[(u32, Aabb, Aabb); 16]> = smallvec::SmallVec::new();
        let mut mark = |slot: u32| {
            if !is_marked[slot as usize] {
                is_marked[slot as usize] = true;
                marked.push(slot);
            }
        };
        for entry in group {
            let slot = entry.child as usize;
            let Some(this) = tree else {
                // Away from the tree: the snapshot's box; the swap applies
                // whatever changed.
                kept.push((entry.child, entry.lane_box, entry.bound));
                continue;
            };
            if this.stamps[slot] != snapshot_stamps[slot] {
                // Removed meanwhile (and marked then).
                continue;
            }
            if !moved_early[slot] {
                kept.push((entry.child, entry.lane_box, entry.bound));
                continue;
            }
            let proxy = &this.proxies[slot];
            let exact = this.nodes[proxy.leaf as usize].lane_box(proxy.lane as usize);
            let then = entry.lane_box;
            let size = then.extent().max_element().max(this.settings.margin);
            let moved = ((exact.min + exact.max) - (then.min + then.max)).abs() * 0.5;
            if moved.max_element() > this.settings.jump_limit * size {
                mark(entry.child);
                continue;
            }
            kept.push((entry.child, exact, proxy.fat));
        }
        if kept.is_empty() || (kept.len() < Self::MIN_FILL && !lone) {
            kept.iter().for_each(|&(slot, ..)| mark(slot));
            return None;
        }
        let index = nodes.len() as u32;
        let mut bound = Aabb::INVERTED;
        for (lane, &(slot, exact, fat)) in kept.iter().enumerate() {
            leaf.set_lane_box(lane, &exact);
            leaf.child[lane] = slot;
            placed[slot as usize] = (index, lane as u32, fat);
            bound = bound.union(&fat);
        }
        leaf.len = kept.len() as u16;
        leaf.refresh_order();
        nodes.push(leaf);
        Some((index, bound))
    }

    /// Called on every change of a slot while a rebuild is under way, after
    /// this structure made it: a move whose new enlarged box (`moved_to`:
    /// the exact box and the enlarged one this structure gave it) stays
    /// inside the bound of the entry's new leaf is mirrored there (a lane
    /// write); any other change marks the slot, to be applied to the new
    /// structure before the swap.
    pub(super) fn note_change(&mut self, slot: u32, moved_to: Option<(&Aabb, &Aabb)>) {
        let Some(job) = self.rebuild_job.as_deref_mut() else {
            return;
        };
        let s = slot as usize;
        if let (Some((exact, fat)), Phase::CatchUp(state)) = (moved_to, &mut job.phase) {
            // Built and catching up: a move that stays inside the new
            // leaf of the same entry is mirrored there.
            let unmarked = !job.is_marked.get(s).copied().unwrap_or(false);
            let same_entry = job.snapshot_stamps.get(s) == Some(&self.stamps[s]);
            if unmarked && same_entry && state.mirror_move(s, exact, fat) {
                return;
            }
        }
        if let (Some((exact, fat)), Some(placed)) = (moved_to, job.placed.get_mut(s))
            && !job.is_marked[s]
        {
            if placed.0 == NIL {
                // Not in a new leaf yet: its leaf will take the box it has
                // then.
                job.moved_early[s] = true;
                return;
            }
            if job.leaf_bounds[placed.0 as usize].contains(fat) {
                job.nodes[placed.0 as usize].set_lane_box(placed.1 as usize, exact);
                placed.2 = *fat;
                return;
            }
        }
        job.mark(slot);
    }
}

/// Fills a new internal node of `level` with the nodes of a group (the
/// entries of the level below); returns it and its bound.
fn fill_new_internal<const W: usize>(
    nodes: &mut Vec<Node<W>>,
    level: u16,
    group: &[Entry],
) -> (u32, Aabb) {
    let index = nodes.len() as u32;
    let mut node = Node::empty(level, NIL);
    let mut bound = Aabb::INVERTED;
    for (lane, entry) in group.iter().enumerate() {
        node.set_lane_box(lane, &entry.lane_box);
        node.child[lane] = entry.child;
        bound = bound.union(&entry.bound);
    }
    node.len = group.len() as u16;
    node.refresh_order();
    nodes.push(node);
    for entry in group {
        nodes[entry.child as usize].parent = index;
    }
    (index, bound)
}

/// The allocated capacity of `v`, in bytes.
pub(super) fn bytes<T>(v: &Vec<T>) -> usize {
    v.capacity() * std::mem::size_of::<T>()
}
