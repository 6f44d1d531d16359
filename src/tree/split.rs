//! Node splits: when a node overflows, its `W + 1` entries are divided in
//! two. Three strategies, chosen by [`TreeSettings::split`], all from the
//! entries' structural bounds: R* and quadratic compute their surface and
//! overlap heuristics in `f64`; the median split is the bulk loader's cut.
//!
//! [`TreeSettings::split`]: super::TreeSettings::split

use smallvec::SmallVec;

use super::Entry;
use super::bulk::centre_key;
use super::cut_axis::cut_axis;
use crate::geometry::Aabb;

/// How an overflowing node divides its entries between itself and a new
/// sibling. Every strategy leaves both nodes at least the minimum fill, and
/// none changes any answer: they differ in insert and move cost and in how
/// well the tree keeps its shape under churn (see the crate docs, "Accuracy
/// options", for the measurements behind the default).
///
/// ```
/// use bevy_rtree::{RTree, SplitStrategy, TreeSettings};
///
/// let settings = TreeSettings { split: SplitStrategy::Median, ..TreeSettings::default() };
/// let tree: RTree<u32> = RTree::with_settings(settings)?;
/// assert_eq!(tree.settings().split, SplitStrategy::Median);
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SplitStrategy {
    /// The R*-tree split: the axis whose candidate divisions have the least
    /// total margin, then on it the division with the least overlap, then the
    /// least total surface. Sorts the entries six times.
    #[default]
    RStar,
    /// Guttman's quadratic split: the two entries that waste the most surface
    /// together seed the groups; each remaining entry, the one with the
    /// strongest preference first, joins the group it enlarges least.
    Quadratic,
    /// Halves the entries at the median centre along the axis whose halves
    /// have the least surface, the bulk loader's cut. One sort, after three
    /// selections to choose the axis.
    Median,
}

/// Reorders `entries` so that `entries[..cut]` and `entries[cut..]` are the
/// two new nodes, each with at least `min_fill` entries, and returns `cut`.
pub(super) fn choose_split(
    entries: &mut [Entry],
    min_fill: usize,
    strategy: SplitStrategy,
) -> usize {
    debug_assert!(entries.len() >= 2 * min_fill);
    match strategy {
        SplitStrategy::RStar => rstar_split(entries, min_fill),
        SplitStrategy::Quadratic => quadratic_split(entries, min_fill),
        SplitStrategy::Median => median_split(entries),
    }
}

fn rstar_split(entries: &mut [Entry], min_fill: usize) -> usize {
    let n = entries.len();
    let mut bounds = [Aabb::INVERTED; MAX_ENTRIES];
    for (slot, e) in bounds.iter_mut().zip(entries.iter()) {
        *slot = e.bound;
    }
    let bounds = &bounds[..n];
    // R* looks at the entries in order of their lower and of their upper
    // bound on each axis; each of the six orders is computed once.
    let orders: [[Order; 2]; 3] = std::array::from_fn(|axis| {
        [false, true]
            .map(|by_upper| order_by(bounds, |b| if by_upper { b.max[axis] } else { b.min[axis] }))
    });

    let mut best_axis = (f64::INFINITY, 0usize);
    for (axis, axis_orders) in orders.iter().enumerate() {
        let mut margin_sum = 0.0;
        for order in axis_orders {
            let (prefix, suffix) = sweeps(bounds, &order[..n]);
            for cut in min_fill..=n - min_fill {
                margin_sum += prefix[cut - 1].margin() + suffix[cut].margin();
            }
        }
        if margin_sum < best_axis.0 {
            best_axis = (margin_sum, axis);
        }
    }

    let axis = best_axis.1;
    let mut best = ((f64::INFINITY, f64::INFINITY), 0, min_fill);
    for (side, order) in orders[axis].iter().enumerate() {
        let (prefix, suffix) = sweeps(bounds, &order[..n]);
        for cut in min_fill..=n - min_fill {
            let (a, b) = (&prefix[cut - 1], &suffix[cut]);
            let cost = (overlap_volume(a, b), a.half_area() + b.half_area());
            if cost < best.0 {
                best = (cost, side, cut);
            }
        }
    }
    let ordered: SmallVec<[Entry; MAX_ENTRIES]> = orders[axis][best.1][..n]
        .iter()
        .map(|&i| entries[i as usize])
        .collect();
    entries.copy_from_slice(&ordered);
    best.2
}

fn quadratic_split(entries: &mut [Entry], min_fill: usize) -> usize {
    let n = entries.len();
    let surface_growth =
        |group: &Aabb, e: &Entry| group.union(&e.bound).half_area() - group.half_area();
    // Seeds: the pair whose common bound wastes the most surface.
    let mut seeds = (0, 1);
    let mut worst = f64::NEG_INFINITY;
    for i in 0..n {
        for j in i + 1..n {
            let (a, b) = (&entries[i].bound, &entries[j].bound);
            let waste = a.union(b).half_area() - a.half_area() - b.half_area();
            if waste > worst {
                worst = waste;
                seeds = (i, j);
            }
        }
    }
    // `group[i]`: 0 or 1 once entry `i` is assigned.
    let mut group: SmallVec<[Option<u8>; 17]> = SmallVec::from_elem(None, n);
    let mut bounds = [entries[seeds.0].bound, entries[seeds.1].bound];
    let mut counts = [1usize, 1];
    group[seeds.0] = Some(0);
    group[seeds.1] = Some(1);
    let mut left = n - 2;
    while left > 0 {
        // A group that needs every remaining entry to reach the minimum
        // fill takes them all.
        if let Some(short) = (0..2).find(|&g| counts[g] + left == min_fill) {
            for slot in group.iter_mut().filter(|g| g.is_none()) {
                *slot = Some(short as u8);
            }
            counts[short] += left;
            break;
        }
        // Next: the entry that prefers one group the most.
        let (mut next, mut growths, mut strongest) = (0, [0.0; 2], f64::NEG_INFINITY);
        for (i, e) in entries.iter().enumerate() {
            if group[i].is_some() {
                continue;
            }
            let g = [surface_growth(&bounds[0], e), surface_growth(&bounds[1], e)];
            let preference = (g[0] - g[1]).abs();
            if preference > strongest {
                (next, growths, strongest) = (i, g, preference);
            }
        }
        // It joins the group it grows least; ties go to the smaller group
        // by surface, then by count.
        let key = |g: usize| (growths[g], bounds[g].half_area(), counts[g]);
        let chosen = if key(1) < key(0) { 1 } else { 0 };
        group[next] = Some(chosen as u8);
        bounds[chosen] = bounds[chosen].union(&entries[next].bound);
        counts[chosen] += 1;
        left -= 1;
    }
    // Group 0 first, each group in its original order.
    let ordered: SmallVec<[Entry; 17]> = (0..2u8)
        .flat_map(|g| {
            entries
                .iter()
                .zip(&group)
                .filter(move |(_, slot)| **slot == Some(g))
                .map(|(e, _)| *e)
        })
        .collect();
    entries.copy_from_slice(&ordered);
    counts[0]
}

fn median_split(entries: &mut [Entry]) -> usize {
    let half = entries.len() / 2;
    let axis = cut_axis(entries, half);
    entries.sort_by(|a, b| centre_key(&a.bound, axis).total_cmp(&centre_key(&b.bound, axis)));
    half
}

/// The most entries a split divides: a full node of the widest width plus one.
const MAX_ENTRIES: usize = 17;

/// Entry indices in some order; only the first `n` are used.
type Order = [u8; MAX_ENTRIES];

/// The indices of `bounds` in ascending order of `key`, ties in index
/// order. Each key is mapped to an integer in the same order (`-0.0` and
/// `0.0` equal, as `<` has them) with its index below it; the integers
/// are then unique, and each entry's place is the number of them below
/// its own, counted without a branch. A split sorts six keys of at most
/// 17 entries; the count on the `f32` keys with their ties broken by
/// index, which this replaced, was the larger part of a split's time.
fn order_by(bounds: &[Aabb], key: impl Fn(&Aabb) -> f32) -> Order {
    // Padding above every key: never counted below one.
    let mut ranked = [u64::MAX; MAX_ENTRIES];
    for (i, (slot, b)) in ranked.iter_mut().zip(bounds).enumerate() {
        *slot = u64::from(ordered_bits(key(b))) << 8 | i as u64;
    }
    let mut order = [0u8; MAX_ENTRIES];
    for (i, &mine) in ranked.iter().enumerate().take(bounds.len()) {
        let place: u8 = ranked.iter().map(|&other| u8::from(other < mine)).sum();
        order[place as usize] = i as u8;
    }
    order
}

/// `x`'s bits mapped so that integer order is `f32` order for every
/// number (not NaN), with `-0.0` and `0.0` mapped alike.
fn ordered_bits(x: f32) -> u32 {
    let bits = (x + 0.0).to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 1 << 31
    }
}

/// Along `order`: `prefix[i]` bounds its entries `..=i`; `suffix[i]`
/// bounds its entries `i..`.
fn sweeps(bounds: &[Aabb], order: &[u8]) -> ([Aabb; MAX_ENTRIES], [Aabb; MAX_ENTRIES + 1]) {
    let mut prefix = [Aabb::INVERTED; MAX_ENTRIES];
    let mut suffix = [Aabb::INVERTED; MAX_ENTRIES + 1];
    let mut acc = Aabb::INVERTED;
    for (i, &e) in order.iter().enumerate() {
        acc = acc.union(&bounds[e as usize]);
        prefix[i] = acc;
    }
    acc = Aabb::INVERTED;
    for (i, &e) in order.iter().enumerate().rev() {
        acc = acc.union(&bounds[e as usize]);
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use proptest::prelude::*;

    fn entry(child: u32, corner: (i8, i8, i8), size: (u8, u8, u8)) -> Entry {
        let min = Vec3::new(corner.0 as f32, corner.1 as f32, corner.2 as f32) * 0.5;
        let max = min + Vec3::new(size.0 as f32, size.1 as f32, size.2 as f32) * 0.25;
        let aabb = Aabb { min, max };
        Entry {
            lane_box: aabb,
            bound: aabb,
            child,
        }
    }

    fn strategy() -> impl Strategy<Value = SplitStrategy> {
        prop_oneof![
            Just(SplitStrategy::RStar),
            Just(SplitStrategy::Quadratic),
            Just(SplitStrategy::Median),
        ]
    }

    /// The branch-free order is a stable sort by key, on keys that tie
    /// (the grid), on signed zeros, infinities, the extremes and
    /// subnormals.
    #[test]
    fn order_by_is_a_stable_sort_by_key() {
        let mut rng = crate::scene::SceneRng::new(17);
        for round in 0..5_000 {
            let n = 1 + round % MAX_ENTRIES;
            let bounds: Vec<Aabb> = (0..n)
                .map(|_| {
                    let v = match rng.below(10) {
                        7 => -0.0,
                        8 => [0.0, f32::MAX, f32::MIN, f32::INFINITY][rng.below(4)],
                        9 => [f32::NEG_INFINITY, 1e-45, -1e-45, -1.0][rng.below(4)],
                        k if round % 2 == 0 => k as f32 * 0.5,
                        _ => rng.range(-1e3, 1e3),
                    };
                    Aabb {
                        min: Vec3::splat(v),
                        max: Vec3::splat(v),
                    }
                })
                .collect();
            let order = order_by(&bounds, |b| b.min.x);
            let mut expected: Vec<u8> = (0..n as u8).collect();
            expected.sort_by(|&a, &b| {
                let (ka, kb) = (bounds[a as usize].min.x, bounds[b as usize].min.x);
                ka.partial_cmp(&kb).unwrap()
            });
            assert_eq!(&order[..n], &expected[..], "round {round}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

        /// Coarse grid corners and sizes, so that entries coincide, touch
        /// and are flat: every strategy keeps every entry once and leaves
        /// both halves at least the minimum fill.
        #[test]
        fn every_split_keeps_entries_and_minimum_fill(
            (min_fill, shapes) in (2usize..=6).prop_flat_map(|m| {
                (Just(m), prop::collection::vec(
                    ((-3i8..3, -3i8..3, -3i8..3), (0u8..3, 0u8..3, 0u8..3)),
                    2 * m..=17,
                ))
            }),
            split in strategy(),
        ) {
            let mut entries: Vec<Entry> = shapes
                .iter()
                .enumerate()
                .map(|(i, &(corner, size))| entry(i as u32, corner, size))
                .collect();
            let cut = choose_split(&mut entries, min_fill, split);
            prop_assert!(cut >= min_fill && entries.len() - cut >= min_fill);
            let mut children: Vec<u32> = entries.iter().map(|e| e.child).collect();
            children.sort_unstable();
            prop_assert_eq!(children, (0..shapes.len() as u32).collect::<Vec<_>>());
            for e in &entries {
                let (corner, size) = shapes[e.child as usize];
                prop_assert_eq!(e.bound, entry(e.child, corner, size).bound);
            }
        }
    }
}
