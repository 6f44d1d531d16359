//! The R*-tree split: pick the axis whose distributions have the least total
//! margin, then the distribution on it with the least overlap, then the
//! least total area. Heuristics are computed in `f64` (SEMANTICS S0).

use super::Entry;
use crate::geometry::Aabb;

/// Reorders `entries` so that `entries[..cut]` and `entries[cut..]` are the
/// two new nodes, each with at least `min_fill` entries, and returns `cut`.
pub(super) fn choose_split(entries: &mut [Entry], min_fill: usize) -> usize {
    let n = entries.len();
    debug_assert!(n >= 2 * min_fill);

    // Sort keys: per axis, by lower then by upper bound (R*: both orders).
    let mut best_axis = (f64::INFINITY, 0usize);
    for axis in 0..3 {
        let mut margin_sum = 0.0;
        for by_upper in [false, true] {
            sort(entries, axis, by_upper);
            let (prefix, suffix) = sweeps(entries);
            for cut in min_fill..=n - min_fill {
                margin_sum += prefix[cut - 1].margin() + suffix[cut].margin();
            }
        }
        if margin_sum < best_axis.0 {
            best_axis = (margin_sum, axis);
        }
    }

    let axis = best_axis.1;
    let mut best = ((f64::INFINITY, f64::INFINITY), false, min_fill);
    for by_upper in [false, true] {
        sort(entries, axis, by_upper);
        let (prefix, suffix) = sweeps(entries);
        for cut in min_fill..=n - min_fill {
            let (a, b) = (&prefix[cut - 1], &suffix[cut]);
            let cost = (overlap_volume(a, b), a.half_area() + b.half_area());
            if cost < best.0 {
                best = (cost, by_upper, cut);
            }
        }
    }
    sort(entries, axis, best.1);
    best.2
}

fn sort(entries: &mut [Entry], axis: usize, by_upper: bool) {
    if by_upper {
        entries.sort_by(|a, b| a.bound.max[axis].total_cmp(&b.bound.max[axis]));
    } else {
        entries.sort_by(|a, b| a.bound.min[axis].total_cmp(&b.bound.min[axis]));
    }
}

/// `prefix[i]` bounds entries `..=i`; `suffix[i]` bounds entries `i..`.
fn sweeps(entries: &[Entry]) -> ([Aabb; 17], [Aabb; 18]) {
    let mut prefix = [Aabb::INVERTED; 17];
    let mut suffix = [Aabb::INVERTED; 18];
    let mut acc = Aabb::INVERTED;
    for (i, e) in entries.iter().enumerate() {
        acc = acc.union(&e.bound);
        prefix[i] = acc;
    }
    acc = Aabb::INVERTED;
    for (i, e) in entries.iter().enumerate().rev() {
        acc = acc.union(&e.bound);
        suffix[i] = acc;
    }
    (prefix, suffix)
}

fn overlap_volume(a: &Aabb, b: &Aabb) -> f64 {
    let lo = a.min.max(b.min).as_dvec3();
    let hi = a.max.min(b.max).as_dvec3();
    let e = (hi - lo).max(glam::DVec3::ZERO);
    e.x * e.y * e.z
}
