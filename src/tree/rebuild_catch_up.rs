//! The end of a rebuild: the new structure, built from a snapshot, is
//! brought up to date with the changes the tree made meanwhile, a slice
//! per step, while the tree keeps answering from its current structure;
//! once nothing is left to apply it is swapped in.
//!
//! A step applies at least what was marked since the previous step plus
//! a share of what was waiting when the build finished, so the waiting
//! list shrinks every step and the swap comes within a bounded number of
//! steps: eight after a tiling built in slices on the calling thread (see
//! `CATCH_UP_STEPS`), and after one that ran on another thread as many as
//! the frames it took, at most eight (one at 60 Hz).
//!
//! Applying a change to the new structure uses the tree's own moves,
//! inserts and removals: the new structure is exchanged with the current
//! one for the slice (a handful of `Vec` swaps), and exchanged back.

use std::time::Instant;

use super::handle::{Proxy, Stamp};
use super::node::{NIL, Node};
use super::rebuild::{Phase, RebuildJob};
use super::repair_queue::RepairQueue;
use super::{Entry, RTree};
use crate::geometry::Aabb;

/// Steps within which the changes waiting when a build in slices
/// finished are applied (at least an eighth of them a step, besides the
/// new ones).
///
/// A build in slices on the calling thread spans dozens of frames, and
/// thousands of changes wait when it is done: applied at once, where 1 %
/// of 100,000 entries teleport or respawn each frame, they made a frame of
/// 44–56 ms (the decay bench at 60 Hz, 1,000 frames, slices of 0.25 ms),
/// against 10–15 ms spread over eight steps, for no better tree.
const CATCH_UP_STEPS: usize = 8;

/// After a tiling that ran on another thread: as many steps as steps
/// were asked for while it was away (about the frames it took, over which
/// the waiting changes piled up), at least one and at most
/// [`CATCH_UP_STEPS`], so that a step applies about one frame's worth of
/// them besides its own frame's.
///
/// At 60 Hz the work on 100,000 entries spans a frame, so the swap comes
/// at the first step after it is back; the inserts among the waiting
/// changes land in the room rebuilt leaves keep
/// (`RTree::LEAF_FILL_WITH_ROOM`) instead of splitting them. Spread over
/// eight steps instead, each applied that frame's changes to both
/// structures and the tree swapped in was eight frames behind. The decay
/// bench at 60 Hz, 1,000 frames, the work on another thread, eight steps
/// → one: nodes visited ÷ fresh over the last 200 frames, crowd 1.40 → 1.21, teleports 1.22 → 1.15, respawn 1.18 →
/// 1.11, bullets 1.18 → 1.14, steps 1.07 → 1.09; maintenance a frame,
/// crowd 10.9 → 5.9 ms, bullets 8.2 → 5.3, respawn 2.3 → 1.7, teleports
/// 3.7 → 3.1, steps 1.27 → 1.17; the worst frame 30 → 23, 15 → 13, 5.9 →
/// 7.2, 7.9 → 9.0, 4.6 → 4.8 ms. Two steps gave the crowd the same tree
/// as one. Work that spans many frames (a larger tree, a faster frame
/// rate, frames back to back) piles up as many frames of changes, and
/// those are spread again.
fn catch_up_steps_after_work_away(steps_away: usize) -> usize {
    steps_away.clamp(1, CATCH_UP_STEPS)
}

/// Changes applied between two looks at the clock.
const CHUNK: usize = 32;

/// The structural half of a tree: what a rebuild builds beside it and
/// swaps in. Keys, stamps, free slots, the count and the settings belong
/// to the slots and stay with the tree.
#[derive(Clone, Debug)]
pub(super) struct Structure<const W: usize> {
    nodes: Vec<Node<W>>,
    free_nodes: Vec<u32>,
    root: u32,
    proxies: Vec<Proxy>,
    churn: Vec<u32>,
    held_bounds: Vec<Aabb>,
    dirty: RepairQueue,
    wear: u64,
}

/// Catching up: the new structure and how much each step applies.
#[derive(Clone, Debug)]
pub(super) struct CatchUp<const W: usize> {
    structure: Box<Structure<W>>,
    /// Changes waiting when the build finished, ÷ `CATCH_UP_STEPS`.
    floor: usize,
    /// Changes left waiting after the previous step: what was marked
    /// since is the excess over it.
    left: usize,
}

impl<const W: usize> CatchUp<W> {
    /// The bytes the new structure holds (allocated capacity).
    pub(super) fn memory(&self) -> usize {
        use super::rebuild::bytes;
        let s = &*self.structure;
        bytes(&s.nodes)
            + bytes(&s.free_nodes)
            + bytes(&s.proxies)
            + bytes(&s.churn)
            + bytes(&s.held_bounds)
            + s.dirty.memory()
    }

    /// Mirrors a move of the entry in `slot` (which the new structure
    /// holds, checked by the caller) into its new leaf, if its enlarged
    /// box `fat` stays inside that leaf's bound: one lane write, nothing
    /// structural. Returns whether it did.
    pub(super) fn mirror_move(&mut self, slot: usize, exact: &Aabb, fat: &Aabb) -> bool {
        let structure = &mut *self.structure;
        let Some(proxy) = structure.proxies.get_mut(slot) else {
            return false;
        };
        if !proxy.is_live() || !structure.held_bounds[proxy.leaf as usize].contains(fat) {
            return false;
        }
        structure.nodes[proxy.leaf as usize].set_lane_box(proxy.lane as usize, exact);
        proxy.fat = *fat;
        true
    }
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The finished build as a structure of its own (its records, the
    /// bounds its parents hold, no repairs due), to catch up.
    pub(super) fn begin_catch_up(&self, job: &mut RebuildJob<W>, root: u32) -> Phase<W> {
        let nodes = std::mem::take(&mut job.nodes);
        let count = nodes.len();
        let mut held_bounds = vec![Aabb::EVERYWHERE; count];
        for node in nodes.iter().filter(|node| !node.is_leaf()) {
            for lane in 0..node.len() {
                held_bounds[node.child[lane] as usize] = node.lane_box(lane);
            }
        }
        // Every slot's record points into the new structure, or nowhere for
        // an entry it does not hold.
        let slots = self.proxies.len().max(job.placed.len());
        let proxies = (0..slots)
            .map(|slot| match job.placed.get(slot) {
                Some(&(leaf, lane, fat)) if leaf != NIL => Proxy { fat, leaf, lane },
                _ => Proxy {
                    fat: Aabb::INVERTED,
                    leaf: NIL,
                    lane: 0,
                },
            })
            .collect();
        job.placed = Vec::new();
        job.leaf_bounds = Vec::new();
        let waiting = job.marked.len();
        let steps = match job.steps_away {
            Some(steps_away) => catch_up_steps_after_work_away(steps_away),
            None => CATCH_UP_STEPS,
        };
        Phase::CatchUp(CatchUp {
            structure: Box::new(Structure {
                nodes,
                free_nodes: Vec::new(),
                root,
                proxies,
                churn: vec![0; count],
                held_bounds,
                dirty: RepairQueue::default(),
                wear: 0,
            }),
            floor: waiting.div_ceil(steps),
            left: waiting,
        })
    }

    /// One step of catching up: applies marked changes to the new
    /// structure (at least the step's floor, then until `units` changes
    /// or the deadline), and swaps it in once none are left. Returns
    /// whether it was swapped in.
    pub(super) fn catch_up(
        &mut self,
        job: &mut RebuildJob<W>,
        units: usize,
        deadline: Option<Instant>,
    ) -> bool {
        let Phase::CatchUp(state) = &mut job.phase else {
            return false;
        };
        let at_least = state.floor + job.marked.len().saturating_sub(state.left);
        let mut done = 0;
        let mut first = true;
        while !job.marked.is_empty() {
            let out_of_time = deadline.is_some_and(|d| Instant::now() >= d);
            if done >= at_least && (done >= units || out_of_time) {
                break;
            }
            let take = CHUNK.min(job.marked.len());
            let chunk = job.marked.split_off(job.marked.len() - take);
            // The changed entries as they are now (exact and enlarged
            // boxes), read from the current structure before the new one
            // is exchanged in.
            let now: Vec<(u32, Option<(Aabb, Aabb)>)> = chunk
                .iter()
                .map(|&slot| {
                    job.is_marked[slot as usize] = false;
                    let p = &self.proxies[slot as usize];
                    let boxes = p
                        .is_live()
                        .then(|| (self.nodes[p.leaf as usize].lane_box(p.lane as usize), p.fat));
                    (slot, boxes)
                })
                .collect();
            // The replays go through the tree's own moves, inserts and
            // removals, which count themselves; they are the rebuild's work,
            // not the caller's, whose changes were counted as they came.
            let counted = self.maintenance;
            self.exchange(&mut state.structure);
            if first {
                // A level whose other nodes lost all their entries while
                // the build ran leaves a root with a single child: collapsed
                // first, so that removals never empty a root.
                self.shrink_root();
                first = false;
            }
            for (slot, boxes) in now {
                self.apply_change(slot, boxes, &mut job.snapshot_stamps);
            }
            self.exchange(&mut state.structure);
            self.maintenance = counted;
            done += take;
        }
        state.left = job.marked.len();
        if !job.marked.is_empty() {
            return false;
        }
        // Nothing waits: the new structure holds exactly the live entries
        // with their current boxes.
        self.exchange(&mut state.structure);
        self.shrink_root();
        self.maintenance.rebuilds += 1;
        true
    }

    /// Exchanges the tree's structure with `other`; records for slots
    /// that one side never saw are added to the other, empty.
    fn exchange(&mut self, other: &mut Structure<W>) {
        let slots = self.proxies.len().max(other.proxies.len());
        let empty = Proxy {
            fat: Aabb::INVERTED,
            leaf: NIL,
            lane: 0,
        };
        self.proxies.resize(slots, empty.clone());
        other.proxies.resize(slots, empty);
        std::mem::swap(&mut self.nodes, &mut other.nodes);
        std::mem::swap(&mut self.free_nodes, &mut other.free_nodes);
        std::mem::swap(&mut self.root, &mut other.root);
        std::mem::swap(&mut self.proxies, &mut other.proxies);
        std::mem::swap(&mut self.churn, &mut other.churn);
        std::mem::swap(&mut self.held_bounds, &mut other.held_bounds);
        std::mem::swap(&mut self.dirty, &mut other.dirty);
        std::mem::swap(&mut self.wear, &mut other.wear);
    }

    /// Applies one slot's change to the structure in place (the new one,
    /// exchanged in): `boxes` are its exact and enlarged boxes now, `None`
    /// if the slot is free.
    /// `held` is, per slot, the stamp of the entry this structure holds.
    /// What wears the new tiling is what this changes in its structure (a
    /// move that grows a leaf or is reinserted counts itself), not the
    /// entries it only rewrites in place.
    fn apply_change(&mut self, slot: u32, boxes: Option<(Aabb, Aabb)>, held: &mut Vec<Stamp>) {
        let s = slot as usize;
        let holds_it = self.proxies[s].is_live() && held.get(s) == Some(&self.stamps[s]);
        if let (true, Some((exact, fat))) = (holds_it, boxes) {
            // The entry moved: moved here with the enlarged box the tree
            // gave it (most moves only write its lane or grow its leaf's
            // bound). A box stretched here afresh would stretch over every
            // frame since the snapshot at once, as a jump of that many
            // steps: where a whole crowd walks, twice as far ahead as the
            // tree's own boxes after two frames away, and leaves grown to
            // hold it. The decay bench's crowd (60 Hz, 2,000 frames, nodes
            // over the last 200 frames ÷ fresh): 1.28–1.30 → 1.18–1.19.
            // A teleport replayed here wears the tiling once, where made to
            // the tree it wears it twice: the displacement since the
            // snapshot cannot tell a jump from several frames of walking.
            self.move_proxy_with_fat(slot, exact, fat);
            return;
        }
        let exact = boxes.map(|(exact, _)| exact);
        if self.proxies[s].is_live() {
            // This structure holds what the slot was (removed since, or a
            // respawn in the freed slot): removed here, wearing the tiling
            // as an insert does, so a respawn counts twice as it does
            // made to the tree.
            self.detach(slot);
            self.proxies[s].leaf = NIL;
            self.wear += 1;
        }
        if let Some(exact) = exact {
            let fat = self.settings.fatten(&exact, glam::Vec3::ZERO);
            self.proxies[s].fat = fat;
            self.wear += 1;
            self.insert_entry(
                Entry {
                    lane_box: exact,
                    bound: fat,
                    child: slot,
                },
                0,
            );
            if held.len() <= s {
                held.resize(s + 1, Stamp::FRESH);
            }
            held[s] = self.stamps[s];
        }
    }
}
