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
//! spread widest, which the tiling used before: a self join visits 38,380
//! node pairs instead of 40,724 on a fresh load (−5.8 %), and 47,219
//! instead of 49,950 after 300 frames of moves and repairs (−5.5 %); the
//! cull and the rays stay within the noise (a coherent batch from one
//! viewpoint moved by up to a fifth either way between variants of the
//! rule, while the mean over 39 other viewpoints did not move). It costs
//! a bulk load of 100,000 entries about 4.4 ms (12.0 → 16.4 ms) and the
//! repair about 0.035 ms a frame (see `docs/performance.md`, "The self
//! join: one region test for two leaves, and cuts along the axis of least
//! surface").

use glam::Vec3A;

use super::Entry;

/// The most entries a cut's axis is judged from: all of a range of up to
/// this many (the last cuts, into leaves and their neighbours), a sample of
/// a longer one (the first cuts, which a sample judges well enough at a
/// fraction of the cost of all their entries).
const SAMPLE_MOST: usize = 64;

/// The axis along which a median cut of `entries` at `cut` (`..cut` on one
/// side, the rest on the other) leaves the least total surface: for each
/// axis, the entries are split at the `cut`-th centre along it and the two
/// sides' bounds weighed by their half areas (in `f64`); the least wins,
/// ties to the lower axis. Ranges longer than [`SAMPLE_MOST`] are judged
/// from the sample [`Sample::of`] draws; fewer than two entries give axis 0.
pub(super) fn cut_axis(entries: &[Entry], cut: usize) -> usize {
    let n = entries.len();
    if n < 2 {
        return 0;
    }
    let sample = Sample::of(entries);
    let (lo, hi, m) = (&sample.lo, &sample.hi, sample.len);
    if m < 2 {
        return 0;
    }
    // The cut's place in the sample, with at least one entry on each side.
    let at = ((cut * m + n / 2) / n).clamp(1, m - 1);
    // Centre keys with the entry's place in the sample in the low byte: one
    // integer selection per axis, which measured faster than a selection
    // of tuples by comparator. Equal centres fall by their place, as in the
    // cut itself (`select_nth_unstable_by` on the entries).
    let mut order = [0u64; SAMPLE_MOST];
    let mut best = (f64::INFINITY, 0);
    for axis in 0..3 {
        for (i, slot) in order[..m].iter_mut().enumerate() {
            let centre = u64::from(ordered_bits(lo[i][axis] + hi[i][axis]));
            *slot = centre << 8 | i as u64;
        }
        let order = &mut order[..m];
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

/// The entries a cut is judged from, their bounds' corners: all of a range
/// of up to
/// [`SAMPLE_MOST`], every `k`-th entry of a longer range (`k` the range's
/// length ÷ [`SAMPLE_MOST`], rounded up). A strided sample depends on the
/// entries' order, so a rebuild at once and one in steps start from the
/// same order ([`RTree::live_entries_in_leaf_order`]) and tile alike.
///
/// [`RTree::live_entries_in_leaf_order`]: super::RTree::live_entries_in_leaf_order
struct Sample {
    lo: [Vec3A; SAMPLE_MOST],
    hi: [Vec3A; SAMPLE_MOST],
    len: usize,
}

impl Sample {
    fn of(entries: &[Entry]) -> Sample {
        let mut sample = Sample {
            lo: [Vec3A::ZERO; SAMPLE_MOST],
            hi: [Vec3A::ZERO; SAMPLE_MOST],
            len: 0,
        };
        let step = entries.len().div_ceil(SAMPLE_MOST).max(1);
        for entry in entries.iter().step_by(step) {
            let i = sample.len;
            sample.lo[i] = entry.bound.min.into();
            sample.hi[i] = entry.bound.max.into();
            sample.len += 1;
        }
        sample
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
            let n = 2 + rng.below(SAMPLE_MOST - 1);
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
    fn a_sample_of_a_long_range_finds_the_rows() {
        // Two rows of 4,000 entries: the centres spread widest along the
        // rows (x), but the cut between them (z) leaves the least surface.
        // (Shuffled, a sample of 64 can hold the rows unevenly, so that its
        // cut mixes them and loses to the cut along x: it judges, it does
        // not prove.)
        let entries: Vec<Entry> = (0..8000u32)
            .map(|i| {
                let height = (i * 7 % 16) as f32 * 0.1;
                let at = Vec3::new((i % 4000) as f32, height, (i / 4000) as f32 * 500.0);
                Entry {
                    child: i,
                    ..entry(Aabb::new(at, at + Vec3::ONE).unwrap())
                }
            })
            .collect();
        assert_eq!(Sample::of(&entries).len, SAMPLE_MOST);
        assert_eq!(cut_axis(&entries, 4000), 2);
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
