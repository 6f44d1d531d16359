//! The brute-force contender: structure-of-arrays boxes, padded to whole
//! blocks with inverted boxes (which every predicate rejects), so the lane
//! loops have no tail and vectorise; its joins are a sort-and-sweep on x.

use super::peers::{Planes, RayPrep, within_euclidean};
use bevy_rtree::Aabb;
use glam::Vec3;
use std::ops::Range;

pub(crate) const LANES: usize = 16;

/// One coordinate of `LANES` boxes: a fixed-size block, so the lane loops
/// have a known length and no bounds checks.
pub(crate) type Block = [f32; LANES];

pub(crate) struct SoaBoxes {
    /// `min[axis][block][lane]`, likewise `max`.
    pub(crate) min: [Vec<Block>; 3],
    pub(crate) max: [Vec<Block>; 3],
}

impl SoaBoxes {
    pub(crate) fn new(boxes: &[Aabb]) -> Self {
        let blocks = boxes.len().div_ceil(LANES);
        let inverted = Aabb {
            min: Vec3::splat(f32::INFINITY),
            max: Vec3::splat(f32::NEG_INFINITY),
        };
        let mut soa = SoaBoxes {
            min: std::array::from_fn(|_| vec![[0.0; LANES]; blocks]),
            max: std::array::from_fn(|_| vec![[0.0; LANES]; blocks]),
        };
        for i in 0..blocks * LANES {
            let b = boxes.get(i).unwrap_or(&inverted);
            for axis in 0..3 {
                soa.min[axis][i / LANES][i % LANES] = b.min[axis];
                soa.max[axis][i / LANES][i % LANES] = b.max[axis];
            }
        }
        soa
    }

    pub(crate) fn blocks(&self) -> usize {
        self.min[0].len()
    }

    /// Appends the indices of the boxes visible in `planes` (S7 conservative).
    pub(crate) fn visible_into(&self, planes: &Planes, out: &mut Vec<u32>) {
        let e = planes.eye;
        for block in 0..self.blocks() {
            // Per-lane flags first, the bit mask once per block: a shape the
            // compiler turns into packed compares.
            let mut keep = [true; LANES];
            for i in 0..planes.count {
                let n = planes.normal[i];
                // The p-vertex: per axis the max where the normal is >= 0.
                let pick = |axis: usize, positive: bool| -> &Block {
                    if positive {
                        &self.max[axis][block]
                    } else {
                        &self.min[axis][block]
                    }
                };
                let (px, py, pz) = (
                    pick(0, n.x >= 0.0),
                    pick(1, n.y >= 0.0),
                    pick(2, n.z >= 0.0),
                );
                for j in 0..LANES {
                    let v = n.x * (px[j] - e.x)
                        + n.y * (py[j] - e.y)
                        + n.z * (pz[j] - e.z)
                        + planes.offset[i];
                    keep[j] &= v > 0.0;
                }
            }
            let mut mask = 0u32;
            for (j, &k) in keep.iter().enumerate() {
                mask |= (k as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                out.push((block * LANES + j) as u32);
            }
        }
    }

    /// The first hit `(key, t)` of one ray: the smallest `(t, key)`. Blocks
    /// are visited in key order, so a strictly smaller `t` is needed to
    /// replace the best, and the limit is the best `t` (closed, S5).
    pub(crate) fn first_hit(&self, ray: &RayPrep) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        let mut limit = ray.max_t;
        for block in 0..self.blocks() {
            let mut lo: Block = [0.0; LANES];
            let mut hi: Block = [limit; LANES];
            let mut slab_ok = [true; LANES];
            for axis in 0..3 {
                let o = ray.origin[axis];
                let (min, max) = (&self.min[axis][block], &self.max[axis][block]);
                if ray.dir[axis] == 0.0 {
                    for j in 0..LANES {
                        slab_ok[j] &= !(o < min[j] || o > max[j]);
                    }
                    continue;
                }
                let inv = ray.inv[axis];
                let (near, far) = if inv > 0.0 { (min, max) } else { (max, min) };
                for j in 0..LANES {
                    let t0 = (near[j] - o) * inv;
                    let t1 = (far[j] - o) * inv;
                    // Explicit selects, as S4 writes them.
                    lo[j] = if t0 > lo[j] { t0 } else { lo[j] };
                    hi[j] = if t1 < hi[j] { t1 } else { hi[j] };
                }
            }
            let mut mask = 0u32;
            for j in 0..LANES {
                mask |= ((slab_ok[j] & (lo[j] <= hi[j])) as u32) << j;
            }
            while mask != 0 {
                let j = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if best.is_none_or(|(_, t)| lo[j] < t) {
                    best = Some(((block * LANES + j) as u32, lo[j]));
                    limit = lo[j];
                }
            }
        }
        best
    }
}

/// The brute-force joins: sort-and-sweep on x, buffers kept between frames.
#[derive(Default)]
pub(crate) struct Sweep {
    pub(crate) order_a: Vec<u32>,
    pub(crate) order_b: Vec<u32>,
}

impl Sweep {
    /// Self join: sort by `min.x`; each box meets the boxes after it until
    /// their `min.x` alone is more than `d` past its `max.x`.
    pub(crate) fn self_join(&mut self, boxes: &[Aabb], d: f32, out: &mut Vec<(u32, u32)>) {
        let order = &mut self.order_a;
        order.clear();
        order.extend(0..boxes.len() as u32);
        order
            .sort_unstable_by(|&a, &b| boxes[a as usize].min.x.total_cmp(&boxes[b as usize].min.x));
        let exact = d as f64;
        for (i, &a) in order.iter().enumerate() {
            let ba = &boxes[a as usize];
            for &b in &order[i + 1..] {
                let bb = &boxes[b as usize];
                if bb.min.x as f64 - ba.max.x as f64 > exact {
                    break;
                }
                if within_euclidean(ba, bb, exact) {
                    out.push((a.min(b), a.max(b)));
                }
            }
        }
    }

    /// Cross join: sort `b` by `min.x`; for each box of `a` scan the `b`s
    /// whose `min.x` can be within `d` (from `a.min.x - d - widest b` to
    /// `a.max.x + d`).
    pub(crate) fn cross_join(
        &mut self,
        boxes: &[Aabb],
        a: Range<usize>,
        b: Range<usize>,
        d: f32,
        out: &mut Vec<(u32, u32)>,
    ) {
        let order = &mut self.order_b;
        order.clear();
        order.extend(b.start as u32..b.end as u32);
        order
            .sort_unstable_by(|&x, &y| boxes[x as usize].min.x.total_cmp(&boxes[y as usize].min.x));
        let widest = order
            .iter()
            .map(|&i| boxes[i as usize].max.x as f64 - boxes[i as usize].min.x as f64)
            .fold(0.0f64, f64::max);
        let exact = d as f64;
        for ia in a {
            let ba = &boxes[ia];
            let from = ba.min.x as f64 - exact - widest;
            let start = order.partition_point(|&i| (boxes[i as usize].min.x as f64) < from);
            for &ib in &order[start..] {
                let bb = &boxes[ib as usize];
                if bb.min.x as f64 - ba.max.x as f64 > exact {
                    break;
                }
                if ia as u32 != ib && within_euclidean(ba, bb, exact) {
                    out.push((ia as u32, ib));
                }
            }
        }
    }
}
