//! A rebuild's work taken out of the tree to run on another thread: the
//! tiling of the snapshot and the filling of the new nodes, all of it
//! from the snapshot's boxes. The tree keeps answering and changing
//! meanwhile and marks every entry that changes; when the work comes back
//! the steps apply those changes to the new structure (a move inside the
//! entry's new leaf is a lane write, anything else a reinsertion), a share
//! a step, and swap it in.

use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};

use super::RTree;
use super::rebuild::{Phase, RebuildJob};

/// Tickets tell one rebuild's work from another's (of this tree or any
/// other), so that work never lands in a rebuild it was not made for.
static TICKETS: AtomicU64 = AtomicU64::new(1);

pub(super) fn next_ticket() -> u64 {
    TICKETS.fetch_add(1, Ordering::Relaxed)
}

/// The work of a rebuild, out of its tree ([`RTree::take_rebuild_work`]):
/// [`RebuildWork::run`] it anywhere (it owns its data and is `Send`), then
/// give it back with [`RTree::finish_rebuild_work`].
///
/// ```
/// use bevy_rtree::{Aabb, RTree};
/// use bevy_rtree::glam::Vec3;
/// use std::time::Duration;
///
/// let mut tree = RTree::new();
/// let ids: Vec<_> = (0..5_000u32)
///     .map(|i| tree.insert(i, Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 1.0))?))
///     .collect::<Result<_, _>>()?;
/// tree.start_rebuild();
/// let mut work = tree.take_rebuild_work().unwrap();
/// // On another thread (a game would use its task pool).
/// let worker = std::thread::spawn(move || {
///     work.run();
///     work
/// });
/// // Meanwhile the tree answers and changes as usual.
/// tree.update(ids[3], Aabb::new(Vec3::splat(-9.0), Vec3::splat(-8.0))?)?;
/// assert!(tree.finish_rebuild_work(worker.join().unwrap()));
/// // The changes made meanwhile applied, and the swap, in the next steps.
/// while !tree.step_rebuild(Duration::from_micros(100)) {}
/// assert_eq!(tree.containing_point(Vec3::splat(-8.5)), vec![3]);
/// tree.validate().unwrap();
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
pub struct RebuildWork<K, const W: usize = 16> {
    job: Box<RebuildJob<W>>,
    keys: PhantomData<fn() -> K>,
}

impl<K, const W: usize> std::fmt::Debug for RebuildWork<K, W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RebuildWork")
            .field("done", &self.is_done())
            .field("nodes", &self.job.nodes.len())
            .finish()
    }
}

impl<K, const W: usize> RebuildWork<K, W> {
    /// Whether [`RebuildWork::run`] has finished it.
    pub fn is_done(&self) -> bool {
        matches!(self.job.phase, Phase::Done { .. })
    }
}

impl<K: Copy + Ord, const W: usize> RebuildWork<K, W> {
    /// Does all of the work (for 100,000 entries, about the time of a bulk
    /// load: ten milliseconds).
    pub fn run(&mut self) {
        while !self.is_done() {
            RTree::<K, W>::advance(None, &mut self.job);
        }
    }
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Takes the work of the rebuild just started out of the tree, so that
    /// it runs on another thread ([`RebuildWork::run`]); `None` if no
    /// rebuild is under way or its steps have left more than one part of
    /// its first level still to cut (the work then goes on in
    /// [`RTree::step_rebuild`]; take it straight after
    /// [`RTree::start_rebuild`] to be sure of it). Until the work comes back
    /// ([`RTree::finish_rebuild_work`]) the tree answers and changes as
    /// usual, marking each entry that changes, and `step_rebuild` only
    /// counts the calls: keep calling it once a frame, and the changes
    /// that piled up are applied over about as many steps after the work
    /// is back (at most eight; at the first step after work that took a
    /// frame). Work that never comes back (dropped, or taken from a tree
    /// that was cloned since) leaves the rebuild waiting until
    /// [`RTree::cancel_rebuild`].
    pub fn take_rebuild_work(&mut self) -> Option<RebuildWork<K, W>> {
        let job = self.rebuild_job.as_mut()?;
        let fresh = matches!(
            &job.phase,
            Phase::Partition { level: 0, cuts, .. } if cuts.len() == 1
        );
        if !fresh {
            return None;
        }
        // Entries that moved since the start are marked: away from the
        // tree, their leaves take the snapshot's boxes.
        let early: Vec<u32> = (0..job.moved_early.len() as u32)
            .filter(|&s| job.moved_early[s as usize])
            .collect();
        for slot in early {
            job.mark(slot);
        }
        // The tree keeps the marks, and goes on marking; the work takes
        // the rest.
        let away = RebuildJob {
            nodes: Vec::new(),
            snapshot_stamps: std::mem::take(&mut job.snapshot_stamps),
            placed: std::mem::take(&mut job.placed),
            leaf_bounds: Vec::new(),
            marked: Vec::new(),
            is_marked: Vec::new(),
            moved_early: Vec::new(),
            phase: std::mem::replace(&mut job.phase, Phase::Away),
            ticket: job.ticket,
            steps_away: None,
        };
        job.steps_away = Some(0);
        Some(RebuildWork {
            job: Box::new(away),
            keys: PhantomData,
        })
    }

    /// Gives back work taken by [`RTree::take_rebuild_work`]; the next
    /// steps ([`RTree::step_rebuild`]) finish what it did not finish,
    /// apply the changes made meanwhile and swap it in. Returns `false`, and drops the work, if it is not this
    /// tree's rebuild under way (dropped meanwhile by `cancel_rebuild`,
    /// `rebuild`, a non-empty `insert_bulk` or `clear`, or another tree's):
    /// the tree is then unchanged.
    pub fn finish_rebuild_work(&mut self, work: RebuildWork<K, W>) -> bool {
        let Some(job) = self.rebuild_job.as_mut() else {
            return false;
        };
        if job.ticket != work.job.ticket || !matches!(job.phase, Phase::Away) {
            return false;
        }
        let back = *work.job;
        let marked_away = std::mem::take(&mut job.marked);
        let marked_there = back.marked;
        job.nodes = back.nodes;
        job.snapshot_stamps = back.snapshot_stamps;
        job.placed = back.placed;
        job.leaf_bounds = back.leaf_bounds;
        job.phase = back.phase;
        job.is_marked.iter_mut().for_each(|m| *m = false);
        for slot in marked_away.into_iter().chain(marked_there) {
            job.mark(slot);
        }
        if job.moved_early.len() < job.placed.len() {
            job.moved_early.resize(job.placed.len(), false);
        }
        true
    }
}
