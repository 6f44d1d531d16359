//! Batched raycasts: many rays through the tree together.
//!
//! A batch follows the "batched incoherent rays" scheme: every live ray of
//! the batch is tested against a node's lanes at once, the rays that hit a
//! child are gathered into that child's run, and the recursion continues
//! with that run only, children in the node's precomputed order along the
//! rays' dominant axis. A batch with at least [`MIN_RAYS_TO_BATCH`] rays
//! left to walk (valid, and not answered at a shared origin) is first
//! sorted by dominant direction (axis and sign), and each direction
//! goes as a batch of its own, so that order is near to far for all its
//! rays; a smaller batch walks ray by ray in the caller's order. A
//! direction's group or a run smaller than [`MIN_RAYS_TO_BATCH`] goes on
//! one ray at a time, in order, on the single-ray walk of `ray.rs` (see
//! the constant for why and the measurements), two consecutive rays from
//! one point in lock step where AVX-512 runs it (`RTree::walk_pair_with`).
//! Before the walk, rays that share an origin inside an entry are answered
//! from one point query (`ray_origin`).

use std::ops::{ControlFlow, Range};

use super::QueryWorkspace;
use super::ray::{RayHit, RayMode};
use super::ray_lanes::ray_lanes;
use super::ray_results::RayResults;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Ray, SpatialError};
use crate::tree::RTree;
use crate::tree::node::{NIL, Node};

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

/// The visitor of an any-hit walk: notes that the ray hit and ends it.
#[inline(always)]
fn any_hit_recorder(found: &mut bool) -> impl FnMut(u32, f32) -> ControlFlow<(), f32> + '_ {
    move |_, _| {
        *found = true;
        ControlFlow::Break(())
    }
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

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
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
    /// limited to `t = 0`, to meet ties outside the origin's boxes. Where
    /// AVX-512 runs the walk, rays from one point that do walk go two at a
    /// time in lock step (first and any hit): a camera's 1,000 rays took
    /// 10–17 % less time so in the benches than one after the other.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, QueryWorkspace, RTree, Ray, RayMode, RayResults, SpatialError};
    /// use bevy_rtree::glam::Vec3;
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
        // The root is a run like any other. Below the size that is batched,
        // no direction's group could be batched either, so grouping would
        // only reorder the rays; in the caller's order (a camera's rays in
        // pixel order) neighbouring rays follow each other through the same
        // nodes. 1,000 rays from the clear eye took 0.173–0.181 ms against
        // 0.180–0.184 ms grouped (a probe, four alternating runs of each
        // build: within the noise), incoherent rays the same.
        if active.len() < MIN_RAYS_TO_BATCH {
            self.walk_run(self.root(), &active, 0, mode, ws);
        } else {
            let groups = group_by_direction(&ws.rays.tests, &mut active, &mut ws.rays.grouped);
            for group in groups {
                self.walk_run(self.root(), &active[group], 0, mode, ws);
            }
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
            self.walk_one_by_one(start, run, mode, ws);
        }
    }

    /// The rays `run` through the subtree of `start` one at a time, except
    /// that where the AVX-512 walk runs, two consecutive rays that start at
    /// one point (a camera's, say) walk in lock step, for first or any hit
    /// (see [`RTree::walk_pair_with`]). Each ray gets the answer, visits
    /// the nodes and counts the statistics of its own walk either way.
    fn walk_one_by_one(&self, start: u32, run: &[u32], mode: RayMode, ws: &mut QueryWorkspace) {
        let mut i = 0;
        while i < run.len() {
            let r = run[i] as usize;
            match run.get(i + 1) {
                Some(&partner) if self.may_walk_paired(r, partner as usize, mode, &ws.rays) => {
                    self.pair_from(start, [r, partner as usize], mode, ws);
                    i += 2;
                }
                _ => {
                    self.single_from(start, r, mode, ws);
                    i += 1;
                }
            }
        }
    }

    /// Whether rays `a` and `b` walk in lock step: both still to walk, from
    /// one origin, both on the AVX-512 walk, and the mode keeps one answer
    /// per ray (all-hits rays share one list of hits, and go one by one).
    fn may_walk_paired(&self, a: usize, b: usize, mode: RayMode, s: &RayBatchScratch) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            !matches!(mode, RayMode::All { .. })
                && s.limits[a] >= 0.0
                && s.limits[b] >= 0.0
                && s.tests[a].origin == s.tests[b].origin
                && super::ray_avx512::walk_is_avx512::<W>(&s.tests[a])
                && super::ray_avx512::walk_is_avx512::<W>(&s.tests[b])
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (a, b, mode, s);
            false
        }
    }

    /// Rays `a` and `b` of a batch through the subtree of `start` in lock
    /// step, recording their hits as [`RTree::single_from`] does, where
    /// [`RTree::may_walk_paired`] allows; else one after the other.
    fn pair_from(&self, start: u32, [a, b]: [usize; 2], mode: RayMode, ws: &mut QueryWorkspace) {
        #[cfg(target_arch = "x86_64")]
        {
            let s = &mut ws.rays;
            let (test_a, test_b) = (s.tests[a], s.tests[b]);
            // The run-time check again (cached, cheap): the AVX-512 walk
            // below is reached only where it found those instructions,
            // whoever calls this.
            let avx512 = super::ray_avx512::walk_is_avx512::<W>;
            let limits = [s.limits[a], s.limits[b]];
            if avx512(&test_a)
                && avx512(&test_b)
                && let (Ok([best_a, best_b]), Ok([found_a, found_b])) = (
                    s.best.get_disjoint_mut([a, b]),
                    s.found.get_disjoint_mut([a, b]),
                )
            {
                let mut walk = std::mem::take(&mut ws.ray_walk);
                walk.note_origin(test_a.origin);
                let super::ray::RayWalkScratch {
                    stack,
                    partner_stack,
                    ..
                } = &mut walk;
                let (tests, stacks) = ([&test_a, &test_b], [stack, partner_stack]);
                let stats = &mut ws.stats;
                // SAFETY: `walk_is_avx512` (just above) found the AVX-512
                // walk for both rays, which requires the standard library's
                // run-time check to have found AVX-512 and `popcnt`.
                #[allow(unsafe_code)]
                let walked = match mode {
                    RayMode::First => Some(unsafe {
                        self.walk_pair_avx512(
                            start,
                            tests,
                            limits,
                            stacks,
                            stats,
                            (
                                self.first_hit_recorder(best_a, found_a),
                                self.first_hit_recorder(best_b, found_b),
                            ),
                        )
                    }),
                    RayMode::Any => Some(unsafe {
                        self.walk_pair_avx512(
                            start,
                            tests,
                            limits,
                            stacks,
                            stats,
                            (any_hit_recorder(found_a), any_hit_recorder(found_b)),
                        )
                    }),
                    RayMode::All { .. } => None,
                };
                ws.ray_walk = walk;
                if let Some([limit_a, limit_b]) = walked {
                    ws.rays.limits[a] = limit_a;
                    ws.rays.limits[b] = limit_b;
                    return;
                }
            }
        }
        // Not reached where `may_walk_paired` allowed the pair (two
        // distinct rays, first or any hit, on the AVX-512 walk); kept so
        // that the function answers every call.
        for r in [a, b] {
            self.single_from(start, r, mode, ws);
        }
    }

    /// The visitor of a first-hit walk: notes that the ray hit and keeps
    /// the best hit (S5), whose `t` becomes the walk's limit.
    #[inline(always)]
    fn first_hit_recorder<'a>(
        &'a self,
        best: &'a mut (f32, u32),
        found: &'a mut bool,
    ) -> impl FnMut(u32, f32) -> ControlFlow<(), f32> + 'a {
        move |proxy, t| {
            *found = true;
            if self.is_better_hit((t, proxy), *best) {
                *best = (t, proxy);
            }
            ControlFlow::Continue(best.0)
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
            RayMode::First => self.walk_one(
                start,
                &test,
                limit,
                &mut walk,
                stats,
                self.first_hit_recorder(best, found),
            ),
            RayMode::All { .. } => {
                self.walk_one(start, &test, limit, &mut walk, stats, |proxy, t| {
                    *found = true;
                    all.push((r as u32, t, proxy));
                    ControlFlow::Continue(f32::INFINITY)
                })
            }
            RayMode::Any => self.walk_one(
                start,
                &test,
                limit,
                &mut walk,
                stats,
                any_hit_recorder(found),
            ),
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
