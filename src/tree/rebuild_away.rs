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
    /// frame). A clone made while the work is away holds the same rebuild,
    /// and either tree takes the work back; a tree whose work never comes
    /// back (dropped, or given to the other) waits until
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

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::geometry::Aabb;
    use crate::query::oracle::BruteForce;
    use crate::scene::{SceneRng, TownScene};
    use crate::tree::ProxyId;

    fn cube(centre: Vec3, half: f32) -> Aabb {
        Aabb::new(centre - half, centre + half).unwrap()
    }

    /// A tree changed frame by frame, with the oracle beside it.
    struct Churned {
        tree: RTree<u32>,
        oracle: BruteForce<u32>,
        live: Vec<(u32, ProxyId)>,
        rng: SceneRng,
        next_key: u32,
    }

    impl Churned {
        fn new(seed: u64) -> Self {
            let scene = TownScene::new(6_000, 21);
            let (tree, ids) = scene.bulk_loaded_tree();
            let mut oracle = BruteForce::default();
            for (key, aabb) in scene.boxes().iter().enumerate() {
                oracle.insert(key as u32, *aabb);
            }
            let live = (0..).zip(ids).collect::<Vec<_>>();
            Churned {
                tree,
                oracle,
                next_key: live.len() as u32,
                live,
                rng: SceneRng::new(seed),
            }
        }

        /// Steps, teleports, removals and inserts; the tree valid after.
        fn frame(&mut self) {
            for _ in 0..150 {
                let (key, id) = self.live[self.rng.below(self.live.len())];
                let (_, now) = self.tree.get(id).unwrap();
                let moved = if self.rng.below(5) == 0 {
                    cube(self.rng.point_in_world(), self.rng.range(0.25, 3.0))
                } else {
                    let step = Vec3::new(self.rng.range(-0.4, 0.4), 0.0, 0.0);
                    Aabb::new(now.min + step, now.max + step).unwrap()
                };
                self.tree.update(id, moved).unwrap();
                self.oracle.update(key, moved);
            }
            for _ in 0..20 {
                let (key, id) = self.live.swap_remove(self.rng.below(self.live.len()));
                assert_eq!(self.tree.remove(id), Ok(key));
                self.oracle.remove(key);
                let aabb = cube(self.rng.point_in_world(), self.rng.range(0.25, 3.0));
                let id = self.tree.insert(self.next_key, aabb).unwrap();
                self.oracle.insert(self.next_key, aabb);
                self.live.push((self.next_key, id));
                self.next_key += 1;
            }
            self.tree.validate().unwrap();
        }

        /// Every handle names its entry, and a box query over part of the
        /// world answers as the oracle.
        fn check(&mut self) {
            let mut live = self.live.clone();
            live.sort_unstable();
            for ((key, want), (live_key, id)) in self.oracle.entries().iter().zip(&live) {
                assert_eq!(key, live_key);
                assert_eq!(self.tree.get(*id), Ok((*key, *want)));
            }
            let query = cube(self.rng.point_in_world(), 300.0);
            assert_eq!(
                self.tree.overlapping(&query),
                self.oracle.overlapping(&query)
            );
        }
    }

    /// Work given back before it is done (some of its steps run away,
    /// with the tree changing before, while and after): the steps here
    /// finish it and swap in a valid tree that answers as the oracle.
    #[test]
    fn work_given_back_half_run_is_finished_by_the_steps() {
        // The steps the whole work takes away from the tree.
        let mut probe = Churned::new(0);
        probe.tree.start_rebuild();
        let mut whole = probe.tree.take_rebuild_work().unwrap();
        let mut total = 0;
        while !whole.is_done() {
            RTree::<u32>::advance(None, &mut whole.job);
            total += 1;
        }
        assert!(total > 20, "{total} steps");
        for share in [1, 30, 70, 99] {
            let steps = (total * share / 100).max(1);
            let mut churned = Churned::new(share as u64);
            churned.tree.start_rebuild();
            churned.frame();
            let mut work = churned.tree.take_rebuild_work().unwrap();
            for _ in 0..steps {
                RTree::<u32>::advance(None, &mut work.job);
            }
            assert!(!work.is_done(), "{steps} of {total} steps");
            churned.frame();
            assert!(churned.tree.finish_rebuild_work(work));
            let mut frames = 0;
            while !churned.tree.step_rebuild_units(10) {
                churned.frame();
                churned.check();
                frames += 1;
                assert!(frames < 10_000, "the rebuild never swaps in");
            }
            assert!(!churned.tree.rebuild_pending());
            churned.tree.validate().unwrap();
            churned.check();
        }
    }

    /// A tree cloned while its rebuild's work is away: both hold the
    /// rebuild the work was made for, so it lands in the one it is given
    /// to, and the other waits for it until cancelled. The two change
    /// apart meanwhile; each stays valid and answers as its oracle.
    #[test]
    fn a_tree_cloned_while_its_work_is_away() {
        let mut original = Churned::new(5);
        original.tree.start_rebuild();
        let mut work = original.tree.take_rebuild_work().unwrap();
        original.frame();
        let mut twin = Churned {
            tree: original.tree.clone(),
            oracle: original.oracle.clone(),
            live: original.live.clone(),
            rng: SceneRng::new(6),
            next_key: original.next_key,
        };
        work.run();
        original.frame();
        twin.frame();
        assert!(twin.tree.finish_rebuild_work(work));
        while !twin.tree.step_rebuild_units(10) {
            twin.frame();
            twin.check();
        }
        twin.check();
        for _ in 0..3 {
            assert!(!original.tree.step_rebuild_units(usize::MAX));
            original.frame();
            original.check();
        }
        assert!(original.tree.rebuild_pending());
        original.tree.cancel_rebuild();
        original.tree.start_rebuild();
        while !original.tree.step_rebuild_units(10) {
            original.frame();
        }
        original.tree.validate().unwrap();
        original.check();
    }
}
