//! Raycasts: first hit, all hits and any hit, for one ray or a batch.
//!
//! A single ray walks the tree depth first, near children first (by the `t`
//! where it enters them), pruning every node whose entry `t` is beyond the
//! best hit so far. A batch follows the "batched incoherent rays" scheme:
//! every live ray of the batch is tested against a node's lanes at once,
//! the rays that hit a child are gathered into that child's run, and the
//! recursion continues with that run only, children in the node's
//! precomputed order along the rays' dominant axis. The batch is first
//! sorted by dominant direction (axis and sign), and each direction goes
//! as a batch of its own, so that order is near to far for all its rays.
//! A direction's group or a run smaller than [`MIN_RAYS_TO_BATCH`] goes on
//! one ray at a time, in order, as single rays do (see there for why and
//! the measurements). Before the walk, rays that share an origin inside an
//! entry are answered from one point query (`ray_origin`).

use std::ops::{ControlFlow, Range};

use glam::{BVec4A, Vec4};

use super::QueryWorkspace;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Ray, SpatialError};
use crate::tree::RTree;
use crate::tree::node::{LANES_PER_TEST, NIL, Node, four_lanes};

/// One hit: the entry's key and the ray parameter where the ray enters its
/// box (`0` when the origin is inside or on the box).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayHit<K> {
    /// The entry hit.
    pub key: K,
    /// Entry parameter, in units of `|dir|`.
    pub t: f32,
}

/// What a raycast asks for (SEMANTICS S5).
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

/// The answers of a batch: slot `i` belongs to ray `i` (SEMANTICS S6).
#[derive(Clone, Debug)]
pub struct RayResults<K> {
    slots: Vec<Result<(Range<u32>, bool), SpatialError>>,
    hits: Vec<RayHit<K>>,
}

// Not derived: an empty result needs no default key.
impl<K> Default for RayResults<K> {
    fn default() -> Self {
        RayResults {
            slots: Vec::new(),
            hits: Vec::new(),
        }
    }
}

impl<K: Copy> RayResults<K> {
    /// Number of slots (rays of the last batch).
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether the last batch was empty.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The hits of ray `i`, sorted by `(t, key)`: at most one in
    /// [`RayMode::First`], none in [`RayMode::Any`]. The ray's own error if it
    /// was invalid. Panics if `i` is out of range.
    pub fn hits(&self, i: usize) -> Result<&[RayHit<K>], SpatialError> {
        let (range, _) = self.slots[i].as_ref().map_err(|e| *e)?;
        Ok(&self.hits[range.start as usize..range.end as usize])
    }

    /// The first hit of ray `i` (in any mode but [`RayMode::Any`]).
    pub fn first(&self, i: usize) -> Result<Option<RayHit<K>>, SpatialError> {
        Ok(self.hits(i)?.first().copied())
    }

    /// Appends the slots of `other` after this batch's slots.
    #[cfg(feature = "parallel")]
    pub(crate) fn append(&mut self, other: &RayResults<K>) {
        let offset = self.hits.len() as u32;
        self.hits.extend_from_slice(&other.hits);
        self.slots.extend(other.slots.iter().map(|slot| {
            slot.clone()
                .map(|(range, any)| (range.start + offset..range.end + offset, any))
        }));
    }

    /// Empties the results, keeping their memory.
    #[cfg(feature = "parallel")]
    pub(crate) fn clear(&mut self) {
        self.slots.clear();
        self.hits.clear();
    }

    /// Whether ray `i` hit anything (in every mode).
    pub fn any(&self, i: usize) -> Result<bool, SpatialError> {
        self.slots[i].as_ref().map(|(_, any)| *any).map_err(|e| *e)
    }
}

/// Per-ray state of a batch, kept in the workspace between frames.
#[derive(Clone, Debug, Default)]
pub(crate) struct RayBatchScratch {
    pub(super) tests: Vec<RayTest>,
    /// Current limit per ray: shrinks to the best `t` (first hit) or drops
    /// below zero once the ray is done (any hit).
    pub(super) limits: Vec<f32>,
    /// Best `(t, proxy)` per ray in first-hit mode.
    pub(super) best: Vec<(f32, u32)>,
    /// Every `(ray, t, proxy)` hit in all-hits mode.
    all: Vec<(u32, f32, u32)>,
    pub(super) found: Vec<bool>,
    /// Indices of the valid rays: the batch the root is visited with.
    pub(super) active: Vec<u32>,
    /// Per depth: the lane mask of each ray the node at that depth was
    /// visited with (`masks[depth * rays + i]` for its `i`-th ray).
    masks: Vec<u32>,
    /// Per depth: the rays of each child of the node at that depth, one run
    /// per lane, the batches the children are visited with.
    buckets: Vec<Vec<u32>>,
    /// The entries that contain a shared origin, with their boxes.
    pub(super) origin_entries: Vec<(u32, crate::geometry::Aabb)>,
    /// Scratch for sorting the active rays by direction.
    grouped: Vec<u32>,
}

/// Sorts the rays `active` (indices into `tests`) by dominant direction,
/// stably, and returns the range each of the six directions (axis, sign)
/// now holds.
///
/// A batch visits a node's children in one order for all its rays: the
/// order along the first ray's dominant axis. For a ray running another way
/// that order is far to near, so it meets its nearest hit late and walks
/// subtrees it would have pruned. Within one direction's group the order is
/// near to far for every ray. Measured in a probe on 1,000 coherent rays
/// from the clear eye (rays in every direction), width 16, when every group
/// was batched from the root: 0.77 -> 0.55 ms and 17.2 -> 12.4 nodes per
/// ray; incoherent rays unchanged (0.75-0.79 ms).
fn group_by_direction(
    tests: &[RayTest],
    active: &mut Vec<u32>,
    grouped: &mut Vec<u32>,
) -> [Range<usize>; 6] {
    let direction = |r: u32| {
        let (axis, forward) = dominant_axis(tests[r as usize].dir);
        axis * 2 + forward as usize
    };
    let mut counts = [0usize; 6];
    for &r in active.iter() {
        counts[direction(r)] += 1;
    }
    let mut starts = [0usize; 6];
    for d in 1..6 {
        starts[d] = starts[d - 1] + counts[d - 1];
    }
    grouped.clear();
    grouped.resize(active.len(), 0);
    let mut next = starts;
    for &r in active.iter() {
        let d = direction(r);
        grouped[next[d]] = r;
        next[d] += 1;
    }
    std::mem::swap(active, grouped);
    std::array::from_fn(|d| starts[d]..next[d])
}

/// Below this many rays, a run of a batch goes on one ray at a time.
///
/// A batch tests a node once for all its rays, but each ray then visits
/// children in the first ray's order and learns its first hit late, so it
/// tests more entries than alone (on the standard scene 32 against 24 per
/// ray). Alone, each ray goes near to far by its own entry `t` and prunes
/// as soon as it has a hit; run after run, rays through the same subtree
/// still follow each other while that subtree is in cache. Measured on the
/// standard scene (1,000 rays per batch, after 90 frames of churn): runs
/// batched down to a single ray 1.08 ms for incoherent rays and 0.51 ms for
/// coherent ones; with 64 as the limit, 0.83 and 0.53 ms; with 1,024, so
/// that only the root was tested for the whole batch (the root was always
/// batched then), 0.73 and 0.55 ms. The root now follows the same rule: at
/// width 16, 1,000 coherent rays from the clear eye took 0.45–0.61 ms with
/// the root tested for each direction's group and 0.40–0.41 ms ray by ray
/// from the root (a loop of `cast_ray` calls: 0.36–0.39 ms), in alternating
/// probe runs.
const MIN_RAYS_TO_BATCH: usize = 1024;

/// Lane mask and entry `t` per lane of one ray against one node: the S4
/// predicate of `predicates::ray_box_entry`, written over the lane arrays
/// with the same operations in the same order, so that it agrees bit for bit.
///
/// Four lanes at a time in `glam::Vec4`, the bits taken with one movemask:
/// the per-lane loop the compiler vectorised turned its bools into bits
/// slowly (see `Node::overlap_mask`). A ray with no zero direction component
/// (nearly every ray) takes a path with no branch inside the node: which row
/// is near is chosen once per axis, not once per four lanes.
// Always inlined: the inner step of every ray traversal; as a call (with its
// lane array returned through memory) it was about half of a ray's time.
#[inline(always)]
pub(crate) fn ray_lanes<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    if ray.has_flat_axis {
        ray_lanes_with_flat_axis(ray, limit, node)
    } else {
        lanes_of::<W, false>(ray, limit, node)
    }
}

/// [`ray_lanes`] for a ray that runs flat along some axis (a zero direction
/// component), out of line: such rays are rare, and the common path stays
/// small in every traversal it is inlined into.
#[inline(never)]
fn ray_lanes_with_flat_axis<const W: usize>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    lanes_of::<W, true>(ray, limit, node)
}

/// Per axis, the rows of `node`'s bounds through which `ray` enters and
/// leaves the lanes' slabs: `(min, max)` where the ray runs towards `+`,
/// `(max, min)` otherwise. Shared by the four-, eight- and sixteen-lane
/// tests; a plain function, not `array::from_fn`, so that it inlines into
/// the walks compiled for AVX and AVX-512.
#[inline(always)]
pub(super) fn near_far_rows<'a, const W: usize>(
    ray: &RayTest,
    node: &'a Node<W>,
) -> [(&'a [f32; W], &'a [f32; W]); 3] {
    let rows = |axis: usize| {
        if ray.inv[axis] > 0.0 {
            (&node.min[axis], &node.max[axis])
        } else {
            (&node.max[axis], &node.min[axis])
        }
    };
    [rows(0), rows(1), rows(2)]
}

/// The lane test of [`ray_lanes`]. With `FLAT`, an axis the ray runs flat
/// along is a slab test on the origin, as in the scalar predicate; without,
/// the ray must have no zero direction component, and the check is
/// compiled out.
#[inline(always)]
fn lanes_of<const W: usize, const FLAT: bool>(
    ray: &RayTest,
    limit: f32,
    node: &Node<W>,
) -> (u32, [f32; W]) {
    let rows = near_far_rows(ray, node);
    let origin = ray.origin.map(Vec4::splat);
    let inv = ray.inv.map(Vec4::splat);
    let mut entry = [0.0f32; W];
    let mut mask = 0u32;
    for first in (0..W).step_by(LANES_PER_TEST) {
        let mut lo = Vec4::ZERO;
        let mut hi = Vec4::splat(limit);
        let mut slab_ok = BVec4A::splat(true);
        for axis in 0..3 {
            if FLAT && ray.dir[axis] == 0.0 {
                let o = origin[axis];
                let min = four_lanes(&node.min[axis], first);
                let max = four_lanes(&node.max[axis], first);
                slab_ok &= !(o.cmplt(min) | o.cmpgt(max));
                continue;
            }
            let (near, far) = rows[axis];
            let t0 = (four_lanes(near, first) - origin[axis]) * inv[axis];
            let t1 = (four_lanes(far, first) - origin[axis]) * inv[axis];
            lo = greater_or_keep(t0, lo);
            hi = less_or_keep(t1, hi);
        }
        let hit = if FLAT {
            slab_ok & lo.cmple(hi)
        } else {
            lo.cmple(hi)
        };
        mask |= hit.bitmask() << first;
        lo.write_to_slice(&mut entry[first..first + LANES_PER_TEST]);
    }
    (mask, entry)
}

/// Per lane, `t` where `t > bound`, else `bound`: a NaN `t` (0 · inf)
/// leaves the bound as it is, as the scalar `if` does. `f32::max` would
/// not (it returns the other operand), so this is not a max.
#[inline(always)]
fn greater_or_keep(t: Vec4, bound: Vec4) -> Vec4 {
    // glam's SSE2 `max` is `maxps t, bound`, defined as `t > bound ? t :
    // bound`: exactly this, in one instruction instead of the three of a
    // compare-and-select. The lane tests' bit-for-bit unit tests hold it to
    // the scalar predicate.
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        t.max(bound)
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::select(t.cmpgt(bound), t, bound)
    }
}

/// Per lane, `t` where `t < bound`, else `bound` (see [`greater_or_keep`]).
#[inline(always)]
fn less_or_keep(t: Vec4, bound: Vec4) -> Vec4 {
    // `minps t, bound` is `t < bound ? t : bound`.
    #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
    {
        t.min(bound)
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse2")))]
    {
        Vec4::select(t.cmplt(bound), t, bound)
    }
}

/// The axis along which `dir` runs fastest, and whether it runs up it.
#[inline]
fn dominant_axis(dir: [f32; 3]) -> (usize, bool) {
    let abs = dir.map(f32::abs);
    let axis = if abs[0] >= abs[1] && abs[0] >= abs[2] {
        0
    } else if abs[1] >= abs[2] {
        1
    } else {
        2
    };
    (axis, dir[axis] >= 0.0)
}

/// The lane visiting order for a ray direction: the node's order along the
/// ray's dominant axis, forwards when the ray runs up that axis.
#[inline]
fn near_to_far<const W: usize>(node: &Node<W>, dir: [f32; 3]) -> impl Iterator<Item = usize> + '_ {
    let (axis, forward) = dominant_axis(dir);
    let order = &node.order[axis][..node.len()];
    (0..order.len()).map(move |i| order[if forward { i } else { order.len() - 1 - i }] as usize)
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
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// The visitor core for one ray: calls `visit(key, t, )` for hits with
    /// `t <= limit`, where the limit starts at `ray.max_t` and becomes
    /// whatever `visit` returns in `Continue(limit)`; `Break` stops.
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
        while let Some((index, entry_t)) = stack.pop() {
            if entry_t > limit {
                continue;
            }
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
                    match visit(node.child[lane], lane_t[lane]) {
                        ControlFlow::Continue(next) => limit = limit.min(next),
                        ControlFlow::Break(()) => return -1.0,
                    }
                }
            } else {
                push(stack, node, mask, &lane_t);
            }
        }
        limit
    }

    /// The single-ray walk: on the AVX-512 lane test where
    /// `ray_avx512::walk_is_avx512` allows it (its children placed without
    /// a sort unless the ray follows the last one, see [`RayWalkScratch`]),
    /// else on the AVX lane test where `ray_avx::walk_is_avx` does, on the
    /// four-lane test otherwise.
    #[inline(always)]
    fn walk_one<F>(
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
    /// use glam::Vec3;
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
        let mut best: Option<RayHit<K>> = None;
        self.visit_ray(ray, ws, |key, t| {
            let better = match best {
                None => true,
                Some(b) => t < b.t || (t == b.t && key < b.key),
            };
            if better {
                best = Some(RayHit { key, t });
            }
            ControlFlow::Continue(best.map_or(t, |b| b.t))
        })?;
        Ok(best)
    }

    /// Every hit of one ray, sorted by `(t, key)` and cut to `limit`,
    /// written to `out` (cleared first).
    pub fn cast_ray_all(
        &self,
        ray: &Ray,
        limit: Option<usize>,
        ws: &mut QueryWorkspace,
        out: &mut Vec<RayHit<K>>,
    ) -> Result<(), SpatialError> {
        out.clear();
        self.visit_ray(ray, ws, |key, t| {
            out.push(RayHit { key, t });
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
        let mut found = false;
        self.visit_ray(ray, ws, |_, _| {
            found = true;
            ControlFlow::Break(())
        })?;
        Ok(found)
    }

    /// Casts a batch of rays together (the module documentation says how)
    /// and writes slot `i` of `out` for ray `i`. An invalid ray gets its own error; the other
    /// slots are unaffected. Answers equal those of the single-ray calls.
    /// Fewer than 1,024 rays running one way walk one by one, which
    /// measured faster than testing them together.
    ///
    /// Keep rays that start at one point next to each other (a camera's
    /// rays from its eye): in first-hit and any-hit modes, eight or more
    /// consecutive rays with the same origin share one point query there,
    /// and if the origin lies inside an entry, that answers them without a
    /// walk (a hit at `t = 0` comes first; ties go to the smallest key).
    /// Rays with a direction component beyond unit length still walk,
    /// limited to `t = 0`, to meet ties outside the origin's boxes.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree, Ray, RayMode, RayResults, SpatialError};
    /// use glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// tree.insert(7u32, Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0))?)?;
    /// let rays = [
    ///     Ray { origin: Vec3::new(-5.0, 0.0, 0.0), dir: Vec3::X, max_t: 10.0 },
    ///     Ray { origin: Vec3::ZERO, dir: Vec3::ZERO, max_t: 1.0 }, // invalid
    ///     Ray { origin: Vec3::new(-5.0, 3.0, 0.0), dir: Vec3::X, max_t: 10.0 },
    /// ];
    /// let mut out = RayResults::default();
    /// tree.cast_rays(&rays, RayMode::First, &mut QueryWorkspace::default(), &mut out);
    /// assert_eq!(out.first(0)?.map(|h| (h.key, h.t)), Some((7, 4.0)));
    /// assert_eq!(out.first(1), Err(SpatialError::InvalidRay));
    /// assert_eq!(out.first(2)?, None);
    /// # Ok::<(), SpatialError>(())
    /// ```
    pub fn cast_rays(
        &self,
        rays: &[Ray],
        mode: RayMode,
        ws: &mut QueryWorkspace,
        out: &mut RayResults<K>,
    ) {
        let n = rays.len();
        let s = &mut ws.rays;
        s.tests.clear();
        s.limits.clear();
        s.active.clear();
        s.all.clear();
        s.best.clear();
        s.best.resize(n, (f32::INFINITY, NIL));
        s.found.clear();
        s.found.resize(n, false);
        out.slots.clear();
        out.hits.clear();
        let mut errors: Vec<(usize, SpatialError)> = Vec::new();
        for (i, ray) in rays.iter().enumerate() {
            match ray.canonicalized() {
                Ok(ray) => {
                    s.tests.push(RayTest::new(&ray));
                    s.limits.push(ray.max_t);
                    s.active.push(i as u32);
                }
                Err(e) => {
                    // A placeholder that never hits keeps indices aligned.
                    s.tests.push(RayTest::new(&Ray {
                        origin: glam::Vec3::ZERO,
                        dir: glam::Vec3::X,
                        max_t: 0.0,
                    }));
                    s.limits.push(-1.0);
                    errors.push((i, e));
                }
            }
        }
        let height = self.height();
        s.masks.clear();
        s.masks.resize(height * n, 0);
        if s.buckets.len() < height {
            s.buckets.resize_with(height, Vec::new);
        }
        self.answer_shared_origins(mode, ws);
        let mut active = std::mem::take(&mut ws.rays.active);
        let groups = group_by_direction(&ws.rays.tests, &mut active, &mut ws.rays.grouped);
        // The root is a run like any other.
        for group in groups {
            self.walk_run(self.root(), &active[group], 0, mode, ws);
        }
        ws.rays.active = active;

        // Gather answers slot by slot.
        let s = &mut ws.rays;
        if let RayMode::All { .. } = mode {
            let keys = |p: u32| self.key_of(p);
            s.all.sort_unstable_by(|a, b| {
                a.0.cmp(&b.0)
                    .then(a.1.total_cmp(&b.1))
                    .then(keys(a.2).cmp(&keys(b.2)))
            });
        }
        let mut all_cursor = 0usize;
        let mut error_cursor = 0usize;
        for i in 0..n {
            if error_cursor < errors.len() && errors[error_cursor].0 == i {
                out.slots.push(Err(errors[error_cursor].1));
                error_cursor += 1;
                continue;
            }
            let start = out.hits.len() as u32;
            match mode {
                RayMode::First => {
                    let (t, proxy) = s.best[i];
                    if proxy != NIL {
                        out.hits.push(RayHit {
                            key: self.key_of(proxy),
                            t,
                        });
                    }
                }
                RayMode::All { limit } => {
                    let mut kept = 0usize;
                    while all_cursor < s.all.len() && s.all[all_cursor].0 == i as u32 {
                        let (_, t, proxy) = s.all[all_cursor];
                        if limit.is_none_or(|l| kept < l) {
                            out.hits.push(RayHit {
                                key: self.key_of(proxy),
                                t,
                            });
                            kept += 1;
                        }
                        all_cursor += 1;
                    }
                }
                RayMode::Any => {}
            }
            let end = out.hits.len() as u32;
            out.slots.push(Ok((start..end, s.found[i])));
        }
    }

    /// One node of the batched traversal: test every ray of the batch
    /// against the lanes, sort the rays into one run per child they hit
    /// (a counting sort: the work is the number of hits, not rays x lanes),
    /// then visit the children near to far (for the first ray) with their
    /// runs. A ray that is done (any hit found) hits no lane.
    fn batch_node(
        &self,
        index: u32,
        active: &[u32],
        depth: usize,
        mode: RayMode,
        ws: &mut QueryWorkspace,
    ) {
        let node = self.node(index);
        ws.stats.nodes_visited += 1;
        let s = &mut ws.rays;
        let n = s.limits.len();
        if node.is_leaf() {
            ws.stats.entries_tested += (active.len() * node.len()) as u64;
            for &r in active.iter() {
                self.leaf_hits(node, r as usize, mode, s);
            }
            return;
        }
        let masks = &mut s.masks[depth * n..][..active.len()];
        let mut counts = [0u32; W];
        for (mask, &r) in masks.iter_mut().zip(active) {
            let r = r as usize;
            *mask = ray_lanes(&s.tests[r], s.limits[r], node).0;
            let mut bits = *mask;
            while bits != 0 {
                counts[bits.trailing_zeros() as usize] += 1;
                bits &= bits - 1;
            }
        }
        let mut starts = [0u32; W];
        let mut total = 0u32;
        for lane in 0..W {
            starts[lane] = total;
            total += counts[lane];
        }
        if total == 0 {
            return;
        }
        let mut bucket = std::mem::take(&mut s.buckets[depth]);
        bucket.clear();
        bucket.resize(total as usize, 0);
        let mut next = starts;
        for (&mask, &r) in masks.iter().zip(active) {
            let mut bits = mask;
            while bits != 0 {
                let lane = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                bucket[next[lane] as usize] = r;
                next[lane] += 1;
            }
        }
        let dir = s.tests[active[0] as usize].dir;
        for lane in near_to_far(node, dir) {
            let run = &bucket[starts[lane] as usize..next[lane] as usize];
            self.walk_run(node.child[lane], run, depth + 1, mode, ws);
        }
        ws.rays.buckets[depth] = bucket;
    }

    /// The rays `run` through the subtree of `start` (at `depth` below the
    /// root): together if there are at least [`MIN_RAYS_TO_BATCH`] of
    /// them, otherwise one by one.
    fn walk_run(
        &self,
        start: u32,
        run: &[u32],
        depth: usize,
        mode: RayMode,
        ws: &mut QueryWorkspace,
    ) {
        if run.len() >= MIN_RAYS_TO_BATCH {
            self.batch_node(start, run, depth, mode, ws);
        } else {
            for &r in run {
                self.single_from(start, r as usize, mode, ws);
            }
        }
    }

    /// Ray `r` of a batch through the subtree of `start` on its own, as
    /// [`RTree::visit_ray`] does, recording its hits by `mode` as
    /// `leaf_hits` does for a batch.
    fn single_from(&self, start: u32, r: usize, mode: RayMode, ws: &mut QueryWorkspace) {
        let s = &mut ws.rays;
        let limit = s.limits[r];
        if limit < 0.0 {
            return;
        }
        let test = s.tests[r];
        let mut walk = std::mem::take(&mut ws.ray_walk);
        let stats = &mut ws.stats;
        let (best, all, found) = (&mut s.best[r], &mut s.all, &mut s.found[r]);
        // One walk per mode, so that no hit matches on the mode.
        s.limits[r] = match mode {
            RayMode::First => self.walk_one(start, &test, limit, &mut walk, stats, |proxy, t| {
                *found = true;
                if self.is_better_hit((t, proxy), *best) {
                    *best = (t, proxy);
                }
                ControlFlow::Continue(best.0)
            }),
            RayMode::All { .. } => {
                self.walk_one(start, &test, limit, &mut walk, stats, |proxy, t| {
                    *found = true;
                    all.push((r as u32, t, proxy));
                    ControlFlow::Continue(f32::INFINITY)
                })
            }
            RayMode::Any => self.walk_one(start, &test, limit, &mut walk, stats, |_, _| {
                *found = true;
                ControlFlow::Break(())
            }),
        };
        ws.ray_walk = walk;
    }

    /// Whether hit `(t, proxy)` comes before `best` (S5: smaller `t`, then
    /// smaller key; a `best` of `NIL` is no hit yet).
    #[inline]
    pub(super) fn is_better_hit(&self, (t, proxy): (f32, u32), best: (f32, u32)) -> bool {
        let (best_t, best_proxy) = best;
        best_proxy == NIL
            || t < best_t
            || (t == best_t && self.key_of(proxy) < self.key_of(best_proxy))
    }

    /// Ray `r` against the entries of a leaf: records its hits by `mode`
    /// and shrinks its limit (first hit) or ends it (any hit).
    #[inline]
    fn leaf_hits(&self, node: &Node<W>, r: usize, mode: RayMode, s: &mut RayBatchScratch) {
        let limit = s.limits[r];
        if limit < 0.0 {
            return;
        }
        let (mut hits, lane_t) = ray_lanes(&s.tests[r], limit, node);
        while hits != 0 {
            let lane = hits.trailing_zeros() as usize;
            hits &= hits - 1;
            let (t, proxy) = (lane_t[lane], node.child[lane]);
            s.found[r] = true;
            match mode {
                RayMode::First => {
                    if self.is_better_hit((t, proxy), s.best[r]) {
                        s.best[r] = (t, proxy);
                        s.limits[r] = t;
                    }
                }
                RayMode::All { .. } => s.all.push((r as u32, t, proxy)),
                RayMode::Any => {
                    s.limits[r] = -1.0;
                    break;
                }
            }
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geometry::predicates::ray_box_entry;
    use crate::tree::node::LaneSamples;

    /// Holds the lane test `lanes` to the scalar S4 predicate bit for bit,
    /// on grid values that make slabs touch (signed zeros included) and on
    /// arbitrary floats from `seed`. `lanes` may decline a ray (`None`: a
    /// ray its path does not take); returns how many rays it took.
    pub(in crate::query) fn lanes_agree_with_the_scalar_predicate<const W: usize>(
        seed: u64,
        lanes: impl Fn(&RayTest, f32, &Node<W>) -> Option<(u32, [f32; W])>,
    ) -> usize {
        let mut samples = LaneSamples::new(seed, 5.0);
        let mut taken = 0;
        for round in 0..20_000 {
            let grid = round % 2 == 0;
            let node = samples.node::<W>(grid, 1 + round % W);
            let dir = samples.point(grid);
            let Ok(ray) = Ray::new(samples.point(grid), dir, samples.value(grid).abs() * 3.0)
            else {
                continue;
            };
            let test = RayTest::new(&ray);
            let limit = if round % 3 == 0 {
                f32::INFINITY
            } else {
                ray.max_t
            };
            let Some((mask, lane_t)) = lanes(&test, limit, &node) else {
                continue;
            };
            taken += 1;
            for (lane, lane_t) in lane_t.iter().enumerate() {
                let b = node.lane_box(lane);
                let scalar = ray_box_entry(&test, limit, b.min.to_array(), b.max.to_array());
                assert_eq!(
                    mask & (1 << lane) != 0,
                    scalar.is_some(),
                    "lane {lane} round {round}"
                );
                if let Some(t) = scalar {
                    assert_eq!(t.to_bits(), lane_t.to_bits(), "lane {lane} round {round}");
                }
            }
        }
        taken
    }

    /// The four-lane test, on every ray.
    fn four_lane_test_agrees<const W: usize>() {
        let taken = lanes_agree_with_the_scalar_predicate::<W>(5, |ray, limit, node| {
            Some(ray_lanes(ray, limit, node))
        });
        assert!(taken > 10_000, "only {taken} valid rays");
    }

    #[test]
    fn lane_test_agrees_bit_for_bit_with_the_scalar_predicate() {
        four_lane_test_agrees::<4>();
        four_lane_test_agrees::<8>();
        four_lane_test_agrees::<16>();
    }
}
