//! Raycasts of one ray: first hit, all hits and any hit.
//!
//! A single ray walks the tree depth first, near children first (by the `t`
//! where it enters them), pruning every node whose entry `t` is beyond the
//! best hit so far. The lane test of this walk (`ray_lanes.rs`) is shared
//! with batches (`ray_batch.rs`), whose small runs go on this walk ray by
//! ray.

use std::ops::ControlFlow;

use super::QueryWorkspace;
use super::ray_lanes::ray_lanes;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Ray, SpatialError};
use crate::tree::RTree;
use crate::tree::node::Node;
use crate::tree::prefetch::prefetch_lines;

/// One hit: the entry's key and the ray parameter where the ray enters its
/// box (`0` when the origin is inside or on the box).
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit<K> {
    /// The entry hit.
    pub key: K,
    /// Entry parameter, in units of `|dir|`.
    pub t: f32,
}

/// What a raycast asks for ([contract S5](crate::contract)).
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum RayMode {
    /// The hit with the smallest `(t, key)`.
    #[default]
    First,
    /// Every hit once, sorted by `(t, key)`, cut to `limit` if given.
    All {
        /// Keep at most this many of the sorted hits.
        limit: Option<usize>,
    },
    /// Whether anything is hit (occlusion, line of sight); no hits listed.
    Any,
}

/// Pushes the children of `node` that the ray hits (`mask`) in order of
/// where it enters them (`lane_t`), far to near, so the nearest is popped
/// first: the earliest hit shrinks the limit soonest.
///
/// The hits are few per node, so an insertion sort orders them in place on
/// the stack: with a general sort over a growable list, 1,000 rays took
/// 3–8 % longer. Visiting in the node's precomputed order along the ray's
/// dominant axis instead, with no sort at all, cost incoherent rays 35 %
/// more: the entry `t` is the better guide to what is near. Where AVX-512
/// runs the walk, rays that do not follow the previous one take a twin
/// that places the children without the sort's branches (see
/// [`RayWalkScratch`]).
#[inline]
pub(super) fn push_far_to_near<const W: usize>(
    stack: &mut Vec<(u32, f32)>,
    node: &Node<W>,
    mask: u32,
    lane_t: &[f32; W],
) {
    let base = stack.len();
    let mut hits = mask;
    while hits != 0 {
        let lane = hits.trailing_zeros() as usize;
        hits &= hits - 1;
        stack.push((node.child[lane], lane_t[lane]));
    }
    super::sort_far_to_near(&mut stack[base..]);
}

/// The next node on a walk's stack whose entry `t` is within `limit`;
/// nodes beyond it are dropped (the limit only shrinks).
#[inline(always)]
fn pop_within(stack: &mut Vec<(u32, f32)>, limit: f32) -> Option<u32> {
    while let Some((index, entry_t)) = stack.pop() {
        // Only an entry `t` known to lie beyond the limit drops a node.
        if entry_t > limit {
            continue;
        }
        return Some(index);
    }
    None
}

/// The single-ray walk's scratch: its stack, and where the last walked ray
/// started.
///
/// A node's hit children go on the stack ordered by entry `t`, and the
/// order of rays that start where the ray before them started (a camera's
/// rays) repeats from ray to ray, so the processor predicts the insertion
/// sort's branches. For rays from scattered origins it does not: there the
/// AVX-512 walk places each child straight into its slot, counting the
/// children that go below it (`ray_avx512::push_far_to_near_ranked`), the
/// same order without a branch per comparison. Measured in a probe on
/// 1,000 rays, eight batches in turn, alternating builds: incoherent rays
/// 0.331–0.343 → 0.304–0.325 ms with the twin for every ray, but rays from
/// the clear eye 0.166–0.174 → 0.178–0.186 ms, hence the choice by origin.
#[derive(Clone, Debug, Default)]
// Only x86-64 has a walk that reads the origin.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) struct RayWalkScratch {
    pub stack: Vec<(u32, f32)>,
    /// The second ray's stack when two rays walk in lock step.
    pub partner_stack: Vec<(u32, f32)>,
    previous_origin: [f32; 3],
}

impl RayWalkScratch {
    /// Whether a ray from `origin` starts where the last walked ray did;
    /// notes `origin` as the last.
    #[inline]
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    fn follows_previous(&mut self, origin: [f32; 3]) -> bool {
        let follows = self.previous_origin == origin;
        self.previous_origin = origin;
        follows
    }

    /// Notes `origin` as where the last walked ray started, for rays walked
    /// without [`RTree::walk_one`] (pairs in lock step).
    #[inline]
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    pub(super) fn note_origin(&mut self, origin: [f32; 3]) {
        self.previous_origin = origin;
    }
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The visitor core for one ray: calls `visit(key, t)` for hits with
    /// `t <= limit`, where the limit starts at `ray.max_t` and becomes the
    /// smaller of itself and what `visit` returns in `Continue(limit)` (it
    /// only shrinks: pruned nodes are not visited again); `Break` stops.
    /// Nodes are visited near to far and pruned when their entry `t` is
    /// beyond the limit, so equal-`t` ties are still seen.
    pub fn visit_ray<F>(
        &self,
        ray: &Ray,
        ws: &mut QueryWorkspace,
        mut visit: F,
    ) -> Result<(), SpatialError>
    where
        F: FnMut(K, f32) -> ControlFlow<(), f32>,
    {
        let ray = ray.canonicalized()?;
        let test = RayTest::new(&ray);
        let mut walk = std::mem::take(&mut ws.ray_walk);
        self.walk_one(
            self.root(),
            &test,
            ray.max_t,
            &mut walk,
            &mut ws.stats,
            |proxy, t| visit(self.key_of(proxy), t),
        );
        ws.ray_walk = walk;
        Ok(())
    }

    /// One ray through the subtree of `start`, depth first, near to far:
    /// children are pushed far to near by where the ray enters them, and a
    /// node is skipped once that entry `t` is beyond the limit. Calls
    /// `visit(proxy, t)` for each hit within the limit, which becomes the
    /// smaller of itself and what `visit` returns; `Break` stops the walk.
    /// Returns the final limit (`-1` after a `Break`).
    ///
    /// The one walk of a single ray, whether alone or in a batch's small
    /// run; always inlined, so that each caller's `visit` is compiled into
    /// the loop. (The batch's own earlier copy of this walk, which re-read
    /// the ray's state at every node and matched on the mode at every hit,
    /// made batched rays about 10 % slower than single ones.) `lanes` is
    /// the lane test: [`ray_lanes`], or its AVX or AVX-512 twin where
    /// `walk_one` finds the processor has them; `push` puts a node's hit
    /// children on the stack far to near: [`push_far_to_near`] or its
    /// AVX-512 twin.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn walk_with<F, L, P>(
        &self,
        start: u32,
        test: &RayTest,
        mut limit: f32,
        stack: &mut Vec<(u32, f32)>,
        stats: &mut crate::tree::QueryStats,
        mut visit: F,
        lanes: L,
        push: P,
    ) -> f32
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
        L: Fn(&RayTest, f32, &Node<W>) -> (u32, [f32; W]),
        P: Fn(&mut Vec<(u32, f32)>, &Node<W>, u32, &[f32; W]),
    {
        stack.clear();
        stack.push((start, 0.0));
        while let Some(index) = pop_within(stack, limit) {
            match self.walk_node::<true, _, _, _>(
                index, test, limit, stack, stats, &mut visit, &lanes, &push,
            ) {
                ControlFlow::Continue(shrunk) => limit = shrunk,
                ControlFlow::Break(()) => return -1.0,
            }
        }
        limit
    }

    /// Two rays' walks in lock step, one node of each per turn, from the
    /// same `start`: each ray visits the nodes, reports the hits and ends
    /// with the limit of its own [`RTree::walk_with`] (the turns only
    /// interleave the two walks), returned in the order of `tests`.
    ///
    /// A walk is a chain of dependent steps (the node to load next comes
    /// off the stack the last node filled), so one ray leaves the processor
    /// idle while a node arrives; two independent chains overlap. Where the
    /// two walks branch alike, as rays from one point do, that pays:
    /// 1,000 rays from the clear eye, batched, 0.177–0.188 → 0.150–0.158
    /// ms in a probe (eight batches in turn, alternating builds), 0.200–0.233
    /// → 0.185–0.191 ms in alternating runs of the queries bench; from the
    /// standard eye of the accuracy report's scene (seed 2024) after 600
    /// frames, 0.278–0.283 → 0.250–0.255 ms in the probe. Rays from
    /// scattered origins branch at random, each misprediction discards the
    /// other ray's work too, and they lost (0.33–0.35 → 0.37–0.39 ms in
    /// the probe), so only rays from one point are paired (`ray_batch.rs`).
    /// Three or four rays in lock step were no faster than two (a loop over
    /// arrays of `N` rays: 0.154–0.166 ms for each `N`, the pair's own loop
    /// 0.149–0.157 ms in the same runs).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn walk_pair_with<FA, FB, L, P>(
        &self,
        start: u32,
        tests: [&RayTest; 2],
        limits: [f32; 2],
        stacks: [&mut Vec<(u32, f32)>; 2],
        stats: &mut crate::tree::QueryStats,
        mut visits: (FA, FB),
        lanes: L,
        push: P,
    ) -> [f32; 2]
    where
        FA: FnMut(u32, f32) -> ControlFlow<(), f32>,
        FB: FnMut(u32, f32) -> ControlFlow<(), f32>,
        L: Fn(&RayTest, f32, &Node<W>) -> (u32, [f32; W]),
        P: Fn(&mut Vec<(u32, f32)>, &Node<W>, u32, &[f32; W]),
    {
        let [test_a, test_b] = tests;
        let [mut limit_a, mut limit_b] = limits;
        let [stack_a, stack_b] = stacks;
        for stack in [&mut *stack_a, &mut *stack_b] {
            stack.clear();
            stack.push((start, 0.0));
        }
        loop {
            let a = pop_within(stack_a, limit_a);
            let b = pop_within(stack_b, limit_b);
            if a.is_none() && b.is_none() {
                return [limit_a, limit_b];
            }
            if let Some(index) = a {
                let visit = &mut visits.0;
                limit_a = self.turn(index, test_a, limit_a, stack_a, stats, visit, &lanes, &push);
            }
            if let Some(index) = b {
                let visit = &mut visits.1;
                limit_b = self.turn(index, test_b, limit_b, stack_b, stats, visit, &lanes, &push);
            }
        }
    }

    /// One ray's turn in lock step: [`RTree::walk_node`] on its next node,
    /// returning its limit after it, or `-1` with its stack emptied once
    /// `visit` breaks (the ray is done, as [`RTree::walk_with`] returns).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn turn<F, L, P>(
        &self,
        index: u32,
        test: &RayTest,
        limit: f32,
        stack: &mut Vec<(u32, f32)>,
        stats: &mut crate::tree::QueryStats,
        visit: &mut F,
        lanes: &L,
        push: &P,
    ) -> f32
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
        L: Fn(&RayTest, f32, &Node<W>) -> (u32, [f32; W]),
        P: Fn(&mut Vec<(u32, f32)>, &Node<W>, u32, &[f32; W]),
    {
        match self.walk_node::<false, _, _, _>(index, test, limit, stack, stats, visit, lanes, push)
        {
            ControlFlow::Continue(shrunk) => shrunk,
            ControlFlow::Break(()) => {
                stack.clear();
                -1.0
            }
        }
    }

    /// One node of a ray's walk, returning the ray's limit after it: a leaf
    /// reports its hits within `limit` to `visit`, the limit shrinking to
    /// what `visit` returns (`Break` when `visit` breaks); an internal node
    /// pushes its hit children far to near (and with `PREFETCH` asks for
    /// their cache lines).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn walk_node<const PREFETCH: bool, F, L, P>(
        &self,
        index: u32,
        test: &RayTest,
        mut limit: f32,
        stack: &mut Vec<(u32, f32)>,
        stats: &mut crate::tree::QueryStats,
        visit: &mut F,
        lanes: &L,
        push: &P,
    ) -> ControlFlow<(), f32>
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
        L: Fn(&RayTest, f32, &Node<W>) -> (u32, [f32; W]),
        P: Fn(&mut Vec<(u32, f32)>, &Node<W>, u32, &[f32; W]),
    {
        let node = self.node(index);
        stats.nodes_visited += 1;
        let (mask, lane_t) = lanes(test, limit, node);
        if node.is_leaf() {
            stats.entries_tested += node.len() as u64;
            let mut hits = mask;
            while hits != 0 {
                let lane = hits.trailing_zeros() as usize;
                hits &= hits - 1;
                if lane_t[lane] > limit {
                    continue;
                }
                limit = limit.min(visit(node.child[lane], lane_t[lane])?);
            }
        } else {
            if PREFETCH {
                // Every hit child is requested now, so that the loads of a
                // ray's next nodes overlap instead of waiting one after
                // another when the tree is cold (1,000 incoherent rays,
                // cold: 0.50 -> 0.42 x parry3d's time; warm 0.41 -> 0.39).
                // Rays from one point walk in pairs without it: their
                // nodes are in cache, and the requests cost them 10 %.
                let mut hits = mask;
                while hits != 0 {
                    let lane = hits.trailing_zeros() as usize;
                    hits &= hits - 1;
                    prefetch_lines(self.node(node.child[lane]));
                }
            }
            push(stack, node, mask, &lane_t);
        }
        ControlFlow::Continue(limit)
    }

    /// The single-ray walk: on the AVX-512 lane test where
    /// `ray_avx512::walk_is_avx512` allows it (its children placed without
    /// a sort unless the ray follows the last one, see [`RayWalkScratch`]),
    /// else on the AVX lane test where `ray_avx::walk_is_avx` does, on the
    /// four-lane test otherwise.
    #[inline(always)]
    pub(super) fn walk_one<F>(
        &self,
        start: u32,
        test: &RayTest,
        limit: f32,
        walk: &mut RayWalkScratch,
        stats: &mut crate::tree::QueryStats,
        visit: F,
    ) -> f32
    where
        F: FnMut(u32, f32) -> ControlFlow<(), f32>,
    {
        #[cfg(target_arch = "x86_64")]
        {
            // Only the AVX-512 walk has the ranked twin to choose.
            let follows = walk.follows_previous(test.origin);
            let stack = &mut walk.stack;
            if super::ray_avx512::walk_is_avx512::<W>(test) {
                // SAFETY: `walk_is_avx512` is true only once the standard
                // library's run-time check has found AVX-512 (and
                // `popcnt`) on this processor, the one requirement of a
                // function compiled with them enabled.
                #[allow(unsafe_code)]
                return unsafe {
                    self.walk_one_avx512(start, test, limit, stack, stats, visit, !follows)
                };
            }
            if super::ray_avx::walk_is_avx::<W>(test) {
                // SAFETY: as above, for AVX and `walk_is_avx`.
                #[allow(unsafe_code)]
                return unsafe { self.walk_one_avx(start, test, limit, stack, stats, visit) };
            }
        }
        self.walk_with(
            start,
            test,
            limit,
            &mut walk.stack,
            stats,
            visit,
            ray_lanes::<W>,
            push_far_to_near::<W>,
        )
    }

    /// The first hit of one ray: the smallest `(t, key)`.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree, Ray};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::new(5.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0))?)?;
    /// tree.insert(2u32, Aabb::new(Vec3::new(2.0, -1.0, -1.0), Vec3::new(3.0, 1.0, 1.0))?)?;
    /// let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0)?;
    /// let hit = tree.cast_ray(&ray, &mut QueryWorkspace::default())?.unwrap();
    /// assert_eq!((hit.key, hit.t), (2, 2.0));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn cast_ray(
        &self,
        ray: &Ray,
        ws: &mut QueryWorkspace,
    ) -> Result<Option<RayHit<K>>, SpatialError> {
        self.cast_ray_where(ray, ws, |_| true)
    }

    /// [`RTree::cast_ray`] among the entries whose key `allow` accepts: the
    /// first hit as if the others were not in the tree.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree, Ray};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(1u32, Aabb::new(Vec3::new(-1.0, -1.0, -1.0), Vec3::ONE)?)?; // around the origin
    /// tree.insert(2u32, Aabb::new(Vec3::new(4.0, -1.0, -1.0), Vec3::new(5.0, 1.0, 1.0))?)?;
    /// let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0)?;
    /// let ws = &mut QueryWorkspace::default();
    /// assert_eq!(tree.cast_ray(&ray, ws)?.map(|h| h.key), Some(1));
    /// assert_eq!(tree.cast_ray_where(&ray, ws, |k| k != 1)?.map(|h| (h.key, h.t)), Some((2, 4.0)));
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn cast_ray_where(
        &self,
        ray: &Ray,
        ws: &mut QueryWorkspace,
        allow: impl Fn(K) -> bool,
    ) -> Result<Option<RayHit<K>>, SpatialError> {
        let max_t = ray.max_t;
        let mut best: Option<RayHit<K>> = None;
        self.visit_ray(ray, ws, |key, t| {
            let better = match best {
                None => true,
                Some(b) => t < b.t || (t == b.t && key < b.key),
            };
            if better && allow(key) {
                best = Some(RayHit { key, t });
            }
            ControlFlow::Continue(best.map_or(max_t, |b| b.t))
        })?;
        Ok(best)
    }

    /// Every hit of one ray, sorted by `(t, key)` and cut to `limit`,
    /// written to `out` (cleared first). An invalid ray is an
    /// [`SpatialError::InvalidRay`], checked before `out` is touched.
    pub fn cast_ray_all(
        &self,
        ray: &Ray,
        limit: Option<usize>,
        ws: &mut QueryWorkspace,
        out: &mut Vec<RayHit<K>>,
    ) -> Result<(), SpatialError> {
        self.cast_ray_all_where(ray, limit, ws, out, |_| true)
    }

    /// [`RTree::cast_ray_all`] among the entries whose key `allow` accepts
    /// (the limit counts those only).
    pub fn cast_ray_all_where(
        &self,
        ray: &Ray,
        limit: Option<usize>,
        ws: &mut QueryWorkspace,
        out: &mut Vec<RayHit<K>>,
        allow: impl Fn(K) -> bool,
    ) -> Result<(), SpatialError> {
        let ray = ray.canonicalized()?;
        out.clear();
        self.visit_ray(&ray, ws, |key, t| {
            if allow(key) {
                out.push(RayHit { key, t });
            }
            ControlFlow::Continue(f32::INFINITY)
        })?;
        out.sort_unstable_by(|a, b| a.t.total_cmp(&b.t).then(a.key.cmp(&b.key)));
        if let Some(limit) = limit {
            out.truncate(limit);
        }
        Ok(())
    }

    /// Whether one ray hits anything (stops at the first hit found).
    pub fn ray_hits_any(&self, ray: &Ray, ws: &mut QueryWorkspace) -> Result<bool, SpatialError> {
        self.ray_hits_any_where(ray, ws, |_| true)
    }

    /// Whether one ray hits an entry whose key `allow` accepts.
    pub fn ray_hits_any_where(
        &self,
        ray: &Ray,
        ws: &mut QueryWorkspace,
        allow: impl Fn(K) -> bool,
    ) -> Result<bool, SpatialError> {
        let max_t = ray.max_t;
        let mut found = false;
        self.visit_ray(ray, ws, |key, _| {
            if allow(key) {
                found = true;
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(max_t)
        })?;
        Ok(found)
    }
}
