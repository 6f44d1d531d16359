//! Rays of a batch that share an origin: one question for all of them.
//!
//! A hit at `t = 0` comes before every other hit (S5), and as long as no
//! direction component exceeds unit length, which entries a ray hits at
//! `t = 0` does not depend on its direction: they are the entries whose
//! closed box contains the origin. So when consecutive rays of a batch
//! start at the same point (camera rays from an eye, a shotgun's pellets),
//! one point query at that origin can answer all of them in first-hit and
//! any-hit modes, if the origin lies inside an entry, before any of them
//! walks the tree.
//!
//! Exactness, by the S4 steps. For an entry whose box contains the origin,
//! every `near - o` is `<= 0` and every `far - o` is zero or has the sign of
//! `inv`, so `lo` stays `0` and `hi >= 0`: a hit at `t = 0`. For an entry
//! that does not contain it, on some axis the origin lies beyond the box:
//! with `d == 0` on that axis the ray misses; otherwise either `near - o`
//! has the sign of `inv` (then `t0 > 0`, a later entry) or `far - o` has the
//! opposite sign (then `t1 < 0`, a miss). The difference of two distinct
//! floats is never zero, so both products keep their sign unless they
//! underflow to zero, which needs `|inv| < 1`. So the point query finds
//! every `t = 0` hit of a ray whose direction components all lie within
//! `[-1, 1]`; any other ray keeps its `t = 0` hit as its best so far and
//! still walks the tree, limited to `t = 0`, to meet the rest. Each
//! candidate is still decided by the S4 predicate itself.

use glam::Vec3;
use std::ops::ControlFlow;

use super::QueryWorkspace;
use super::ray::RayMode;
use crate::geometry::Aabb;
use crate::geometry::predicates::{RayTest, ray_box_entry};
use crate::tree::RTree;
use crate::tree::node::NIL;

/// The fewest consecutive rays with one origin that get a point query.
///
/// When the origin lies in no entry the query is wasted, but it visits
/// fewer nodes than one ray's walk (a point is smaller than a ray's path),
/// so a group of eight pays less than an eighth of a walk per ray; when the
/// origin lies in an entry, each ray that needs no walk saves a whole one.
const MIN_RAYS_SHARING_AN_ORIGIN: usize = 8;

/// Whether every `t = 0` hit of `ray` has a box that contains its origin
/// (all direction components within `[-1, 1]`, see the module docs).
#[inline]
fn zero_hits_contain_origin(ray: &RayTest) -> bool {
    !zero_hits_may_lie_outside(Vec3::from_array(ray.dir))
}

/// Whether a ray along `dir` may hit an entry at `t = 0` that does not
/// contain its origin (a component beyond unit length, see the module docs).
#[inline]
fn zero_hits_may_lie_outside(dir: Vec3) -> bool {
    dir.abs().max_element() > 1.0
}

/// Bitwise equal origins (so `-0.0` and `0.0` start different groups,
/// which costs at most a query and never an answer).
#[inline]
fn same_origin(a: [f32; 3], b: [f32; 3]) -> bool {
    a.map(f32::to_bits) == b.map(f32::to_bits)
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Answers the rays of the batch's active list that start, with at
    /// least [`MIN_RAYS_SHARING_AN_ORIGIN`] - 1 neighbours in the list, at
    /// an origin inside an entry, and takes those that need no walk out of
    /// the list. First-hit and any-hit modes only; all-hits needs every hit.
    pub(super) fn answer_shared_origins(&self, mode: RayMode, ws: &mut QueryWorkspace) {
        if let RayMode::All { .. } = mode {
            return;
        }
        let mut active = std::mem::take(&mut ws.rays.active);
        let mut inside = std::mem::take(&mut ws.rays.origin_entries);
        let mut kept = 0;
        let mut start = 0;
        while start < active.len() {
            let tests = &ws.rays.tests;
            let first = &tests[active[start] as usize];
            let end = start
                + active[start..]
                    .iter()
                    .take_while(|&&r| same_origin(tests[r as usize].origin, first.origin))
                    .count();
            if end - start < MIN_RAYS_SHARING_AN_ORIGIN {
                // Too few to share a query: every ray of the group walks.
                active.copy_within(start..end, kept);
                kept += end - start;
                start = end;
                continue;
            }
            let origin = Vec3::from_array(first.origin);
            let point = Aabb {
                min: origin,
                max: origin,
            };
            inside.clear();
            self.visit_overlapping_proxies(&point, ws, |proxy, aabb| {
                inside.push((proxy, *aabb));
                ControlFlow::Continue(())
            });
            for i in start..end {
                let r = active[i];
                if !self.answer_at_origin(r as usize, mode, &inside, ws) {
                    active[kept] = r;
                    kept += 1;
                }
            }
            start = end;
        }
        active.truncate(kept);
        ws.rays.active = active;
        ws.rays.origin_entries = inside;
    }

    /// How many rays of `rays` [`RTree::answer_shared_origins`] would answer
    /// without a walk, at the cost of one point query per group of
    /// consecutive rays with one origin: those of a group of at least
    /// [`MIN_RAYS_SHARING_AN_ORIGIN`] whose origin lies inside an entry,
    /// that have no direction component beyond unit length (or are invalid,
    /// which needs no walk either).
    ///
    /// An estimate for deciding whether a batch is worth splitting across
    /// threads, never used for an answer (it groups invalid rays with their
    /// neighbours, which the batch itself skips).
    #[cfg(feature = "parallel")]
    pub(super) fn rays_answered_at_shared_origins(
        &self,
        rays: &[crate::geometry::Ray],
        mode: RayMode,
        ws: &mut QueryWorkspace,
    ) -> usize {
        if let RayMode::All { .. } = mode {
            return 0;
        }
        let mut answered = 0;
        for group in rays.chunk_by(|a, b| same_origin(a.origin.to_array(), b.origin.to_array())) {
            if group.len() < MIN_RAYS_SHARING_AN_ORIGIN {
                continue;
            }
            let origin = group[0].origin;
            let point = Aabb {
                min: origin,
                max: origin,
            };
            if self.any_overlapping(&point, ws) {
                // Invalid rays are answered by their error: no walk either.
                answered += group
                    .iter()
                    .filter(|ray| !zero_hits_may_lie_outside(ray.dir))
                    .count();
            }
        }
        answered
    }

    /// Records ray `r`'s `t = 0` hits among `inside` (the entries that
    /// contain its origin); true if the ray needs no walk after that.
    fn answer_at_origin(
        &self,
        r: usize,
        mode: RayMode,
        inside: &[(u32, Aabb)],
        ws: &mut QueryWorkspace,
    ) -> bool {
        let s = &mut ws.rays;
        let (test, limit) = (s.tests[r], s.limits[r]);
        let mut best = (f32::INFINITY, NIL);
        for (proxy, aabb) in inside {
            let (min, max) = (aabb.min.to_array(), aabb.max.to_array());
            if let Some(t) = ray_box_entry(&test, limit, min, max)
                && self.is_better_hit((t, *proxy), best)
            {
                best = (t, *proxy);
            }
        }
        let (t, proxy) = best;
        if proxy == NIL {
            return false;
        }
        s.found[r] = true;
        match mode {
            RayMode::Any => {
                s.limits[r] = -1.0;
                true
            }
            _ => {
                // `t` is 0 by the module docs; a walk, if any, only meets
                // ties, which it resolves by key against this best.
                s.best[r] = (t, proxy);
                s.limits[r] = t;
                t == 0.0 && zero_hits_contain_origin(&test)
            }
        }
    }
}
