//! Which axis a median cut of a tiling takes: the bulk loader's, a
//! rebuild's, a repair's repack and the median split all cut entries in
//! two at a median by centre, and this chooses along which axis.
//!
//! Of the three median cuts, the one whose two sides' bounds have the least
//! total surface (the sum of their half areas, as a surface-area
//! heuristic weighs a split): the sides of a cut through a row of boxes
//! along the row's length overlap less and leave fewer empty corners than
//! the sides of a cut across it, whatever the spread of the centres says.
//! Measured on the standard scene against the axis on which the centres
//! spread widest, which the tiling used before: a fresh load's self join
//! visits 38,380 node pairs instead of 40,724 (−5.8 %), and a tree after
//! 300 frames of moves and repairs takes 1.97–2.02 ms for it instead of
//! 2.06–2.12 ms with the repair left on the old axis; the cull and the
//! rays gain 1–3 %. It costs a bulk load of 100,000 entries about 4 ms
//! (12 → 16 ms) and the repair 0.03 ms a frame (see `docs/performance.md`,
//! "Cuts along the axis of least surface").

use glam::Vec3A;

use super::Entry;

/// The most entries a cut's axis is chosen for by surface: the last cuts
/// of a tiling, into leaves and their neighbours, which decide most of the
/// gain. Longer ranges are cut along the widest spread of their centres,
/// which costs one pass: judging them by surface as well, from all their
/// entries or a sample, cost a bulk load another 4 ms for 0.5 % fewer
/// node pairs in a self join, and a sample would depend on the entries'
/// order, where a rebuild in steps must tile as `RTree::rebuild` does.
const SURFACE_CUT_MOST: usize = 64;

/// The axis along which a median cut of `entries` at `cut` (`..cut` on one
/// side, the rest on the other) leaves the least total surface: for each
/// axis, the entries are split at the `cut`-th centre along it and the two
/// sides' bounds weighed by their half areas (in `f64`); the least wins,
/// ties to the lower axis. Ranges longer than [`SURFACE_CUT_MOST`] take
/// [`widest_centre_axis`]; fewer than two entries give axis 0.
pub(super) fn cut_axis(entries: &[Entry], cut: usize) -> usize {
    let n = entries.len();
    if n > SURFACE_CUT_MOST {
        return widest_centre_axis(entries);
    }
    if n < 2 {
        return 0;
    }
    let mut lo = [Vec3A::ZERO; SURFACE_CUT_MOST];
    let mut hi = [Vec3A::ZERO; SURFACE_CUT_MOST];
    for (i, entry) in entries.iter().enumerate() {
        lo[i] = entry.bound.min.into();
        hi[i] = entry.bound.max.into();
    }
    // At least one entry on each side.
    let at = cut.clamp(1, n - 1);
    // Centre keys with the entry's place in the low byte: one integer
    // selection per axis, which measured faster than a selection of pairs
    // by comparator.
    let mut order = [0u64; SURFACE_CUT_MOST];
    let mut best = (f64::INFINITY, 0);
    for axis in 0..3 {
        for (i, slot) in order[..n].iter_mut().enumerate() {
            *slot = u64::from(ordered_bits(lo[i][axis] + hi[i][axis])) << 8 | i as u64;
        }
        let order = &mut order[..n];
        order.select_nth_unstable(at);
        let (low, high) = order.split_at(at);
        let half_area = |side: &[u64]| {
            let (mut min, mut max) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
            for &key in side {
                let i = (key & 0xff) as usize;
                min = min.min(lo[i]);
                max = max.max(hi[i]);
            }
            let e = max.as_dvec3() - min.as_dvec3();
            e.x * e.y + e.y * e.z + e.z * e.x
        };
        let cost = half_area(low) + half_area(high);
        if cost < best.0 {
            best = (cost, axis);
        }
    }
    best.1
}

/// The axis along which the entries' centres spread widest (ties go to the
/// lower axis).
fn widest_centre_axis(entries: &[Entry]) -> usize {
    let (mut lo, mut hi) = (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY);
    for entry in entries {
        let centre = entry.bound.min + entry.bound.max;
        lo = lo.min(centre);
        hi = hi.max(centre);
    }
    let spread = hi - lo;
    if spread.x >= spread.y && spread.x >= spread.z {
        0
    } else if spread.y >= spread.z {
        1
    } else {
        2
    }
}

/// The bits of `key` as an integer that orders as [`f32::total_cmp`]
/// orders the floats: negative values (sign set) reversed below the
/// positive ones.
fn ordered_bits(key: f32) -> u32 {
    let bits = key.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 1 << 31
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;
    use crate::geometry::Aabb;
    use crate::geometry::MAX_COORD;
    use crate::scene::SceneRng;

    fn entry(aabb: Aabb) -> Entry {
        Entry {
            lane_box: aabb,
            bound: aabb,
            child: 0,
        }
    }

    /// The total half area of the two sides of the median cut at `cut`
    /// along `axis`, from a full sort by centre in `f64`.
    fn exact_cost(entries: &[Entry], cut: usize, axis: usize) -> f64 {
        let mut boxes: Vec<Aabb> = entries.iter().map(|e| e.bound).collect();
        let centre = |b: &Aabb| f64::from(b.min[axis]) + f64::from(b.max[axis]);
        boxes.sort_by(|a, b| centre(a).total_cmp(&centre(b)));
        let side = |side: &[Aabb]| {
            let (mut min, mut max) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for b in side {
                for k in 0..3 {
                    min[k] = min[k].min(f64::from(b.min[k]));
                    max[k] = max[k].max(f64::from(b.max[k]));
                }
            }
            let e = [max[0] - min[0], max[1] - min[1], max[2] - min[2]];
            e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
        };
        side(&boxes[..cut]) + side(&boxes[cut..])
    }

    #[test]
    fn ordered_bits_order_as_total_cmp() {
        let keys = [
            f32::NEG_INFINITY,
            -3.5e30,
            -2.0,
            -1e-40,
            -0.0,
            0.0,
            1e-40,
            1.5,
            7.0e20,
            f32::INFINITY,
        ];
        for a in keys {
            for b in keys {
                assert_eq!(
                    ordered_bits(a).cmp(&ordered_bits(b)),
                    a.total_cmp(&b),
                    "{a} {b}"
                );
            }
        }
    }

    #[test]
    fn two_rows_are_cut_between_the_rows_not_across_them() {
        // Centres spread 150 m along x, 100 m along z and 1.5 m in height,
        // so the widest spread is x; but a cut along x leaves both sides
        // 75 m × 100 m, and one along z leaves each row alone, 150 m × 1 m.
        // (Heights differ, so that a cut in height mixes the rows.)
        let entries: Vec<Entry> = (0..32)
            .map(|i| {
                let height = (i * 7 % 16) as f32 * 0.1;
                let at = Vec3::new((i % 16) as f32 * 10.0, height, (i / 16) as f32 * 100.0);
                entry(Aabb::new(at, at + Vec3::ONE).unwrap())
            })
            .collect();
        assert_eq!(cut_axis(&entries, 16), 2);
    }

    #[test]
    fn the_chosen_axis_has_the_least_surface_of_the_three_exact_cuts() {
        let mut rng = SceneRng::new(31);
        for round in 0..400 {
            let n = 2 + rng.below(SURFACE_CUT_MOST - 1);
            let stretch = Vec3::new(
                rng.range(1.0, 50.0),
                rng.range(1.0, 50.0),
                rng.range(1.0, 50.0),
            );
            let entries: Vec<Entry> = (0..n)
                .map(|_| {
                    let at = Vec3::new(rng.unit(), rng.unit(), rng.unit()) * stretch * 10.0;
                    let half = Vec3::new(
                        rng.range(0.1, 20.0),
                        rng.range(0.1, 20.0),
                        rng.range(0.1, 20.0),
                    );
                    entry(Aabb::new(at - half, at + half).unwrap())
                })
                .collect();
            let cut = 1 + rng.below(n - 1);
            let chosen = cut_axis(&entries, cut);
            let costs = [0, 1, 2].map(|axis| exact_cost(&entries, cut, axis));
            let least = costs.iter().copied().fold(f64::INFINITY, f64::min);
            assert!(
                costs[chosen] <= least * (1.0 + 1e-9),
                "round {round}: n {n} cut {cut}: chose {chosen} of {costs:?}"
            );
        }
    }

    #[test]
    fn longer_ranges_are_cut_along_the_widest_spread_of_centres() {
        // Two rows again, 4,000 entries: by surface the cut would go between
        // the rows (z), but the centres spread widest along them (x).
        let mut entries: Vec<Entry> = (0..4000)
            .map(|i| {
                let height = (i * 7 % 16) as f32 * 0.1;
                let at = Vec3::new((i % 2000) as f32, height, (i / 2000) as f32 * 500.0);
                entry(Aabb::new(at, at + Vec3::ONE).unwrap())
            })
            .collect();
        assert_eq!(cut_axis(&entries, 2000), 0);
        entries.reverse();
        assert_eq!(cut_axis(&entries, 2000), 0);
    }

    #[test]
    fn tiny_and_degenerate_ranges_give_an_axis_without_panicking() {
        assert_eq!(cut_axis(&[], 0), 0);
        let one = entry(Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap());
        assert_eq!(cut_axis(&[one], 0), 0);
        // Identical boxes: every axis costs the same, the lowest wins.
        assert_eq!(cut_axis(&[one; 5], 2), 0);
        // Flat boxes as wide as boxes may be.
        let huge = Aabb::new(
            Vec3::splat(-MAX_COORD),
            Vec3::new(MAX_COORD, 0.0, MAX_COORD),
        )
        .unwrap();
        let axis = cut_axis(&[entry(huge), one, entry(huge)], 1);
        assert!(axis < 3);
    }
}
