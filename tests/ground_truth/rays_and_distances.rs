//! Rays, joins, spheres, nearest and points against `f64` slabs,
//! distances and comparisons computed without the crate.

use super::*;

/// The slab entry and exit `(lo, hi)` of the segment in `f64`, or `None`
/// where a flat axis lies outside the box (decided exactly).
fn slabs(o: DVec3, d: DVec3, max_t: f64, b: &Aabb) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (0.0f64, max_t);
    for i in 0..3 {
        let (min, max) = (b.min[i] as f64, b.max[i] as f64);
        if d[i] == 0.0 {
            if o[i] < min || o[i] > max {
                return None;
            }
            continue;
        }
        let (near, far) = if d[i] > 0.0 { (min, max) } else { (max, min) };
        lo = lo.max((near - o[i]) / d[i]);
        hi = hi.min((far - o[i]) / d[i]);
    }
    Some((lo, hi))
}

#[test]
fn ray_hits_and_entry_distances_match_slabs_computed_in_f64() {
    let mut rng = Rng(0x7777_0000_1234_9999);
    let (mut tree, base) = build(&distractors(&mut rng, 50), 1);
    let mut ws = QueryWorkspace::default();
    let (cases, mut hits, mut misses, mut false_hits) = (12_000, 0, 0, Vec::new());
    for _ in 0..cases {
        let o = profile_point(&mut rng);
        let scale = rng.pick(&[1e-3, 1.0, 1e3, 1e6, 1e12]);
        let c = dv(o) + rng.vec(scale);
        let h = rng.extent(&[0.0, 1e-3, 0.1, 1.0]) * scale;
        let (Some(aabb), w) = (outward(c - h, c + h), c + h * rng.vec(1.5) - dv(o)) else {
            continue;
        };
        // Aimed near the box; largest component 1e-37 ..= 1e37, so that
        // `1 / d` stays a normal `f32`; some components zero or subnormal.
        let big = rng.pick(&[1e-37, 1e-20, 1.0, 1e20, 1e37]);
        let mut dir = (w / w.abs().max_element() * big).as_vec3();
        for i in 0..3 {
            if rng.below(6) == 0 {
                dir[i] = rng.pick(&[0.0, -0.0, 1e-40, -1e-40, 1e-45, f32::MIN_POSITIVE]);
            }
        }
        // Canonical as SEMANTICS S3 says: |d| < f32::MIN_POSITIVE becomes 0.
        let d = dv(dir).map(|x| x * (x.abs() >= f32::MIN_POSITIVE as f64) as u8 as f64);
        let entry = slabs(dv(o), d, f64::INFINITY, &aabb).map_or(1.0, |(lo, _)| lo);
        let about = (entry * rng.pick(&[0.5, 0.99999, 1.00001, 2.0])) as f32;
        let max_t = rng.pick(&[f32::INFINITY, f32::MAX, 0.0, about, about]);
        let Ok(ray) = Ray::new(o, dir, max_t) else {
            assert!(d == DVec3::ZERO || d.is_nan(), "{o} {dir} {max_t} refused");
            continue;
        };
        assert_eq!(dv(ray.dir), d, "canonical direction of {dir}");
        let truth = match slabs(dv(o), d, max_t as f64, &aabb) {
            None => Some(false),
            Some((lo, hi)) => {
                let band = 1e-5 * (lo.abs() + hi.abs()) + 1e-37;
                (hi - lo > band || lo - hi > band).then_some(lo < hi)
            }
        };
        let Some(hit) = truth else { continue };
        let found = with_entry(&mut tree, &base, aabb, |tree, oracle| {
            let mut all = Vec::new();
            tree.cast_ray_all(&ray, None, &mut ws, &mut all).unwrap();
            assert_eq!(all, oracle.ray_hits(&ray).unwrap(), "{ray:?}");
            assert_eq!(tree.ray_hits_any(&ray, &mut ws).unwrap(), !all.is_empty());
            assert_eq!(tree.cast_ray(&ray, &mut ws).unwrap(), all.first().copied());
            all.iter().find(|h| h.key == 0).map(|h| h.t)
        });
        if !hit {
            // Collected, so that the other checks still run: see the end.
            if let Some(t) = found {
                false_hits.push(format!("t = {t}: {ray:?} misses {aabb:?}"));
            }
            misses += 1;
            continue;
        }
        let lo = slabs(dv(o), d, max_t as f64, &aabb).unwrap().0;
        // A true entry beyond `f32::MAX` has no `f32` t: a miss.
        if lo > f32::MAX as f64 {
            assert_eq!(found, None, "{ray:?} enters {aabb:?} beyond f32::MAX");
            continue;
        }
        let t = found.unwrap_or_else(|| panic!("{ray:?} hits {aabb:?}"));
        // Each slab t rounds three times in `f32` (a difference, `1 / d`, a
        // product): within 3 · 2^-24 of its value, or 2^-150 where it
        // underflows; 4 · 2^-24 and 1e-44 cover that.
        let t_tol = 4.0 * U * lo + 1e-44;
        let ctx = || format!("t = {t}, truth {lo}: {ray:?} {aabb:?}");
        assert!((t as f64 - lo).abs() <= t_tol, "{}", ctx());
        for i in 0..3 {
            let (o, step) = (o[i] as f64, t as f64 * d[i]);
            let (min, max) = (aabb.min[i] as f64, aabb.max[i] as f64);
            let tol = 1e-6 * (o.abs() + step.abs() + min.abs() + max.abs()) + t_tol * d[i].abs();
            let p = o + step;
            assert!(p >= min - tol && p <= max + tol, "{p}: {}", ctx());
        }
        hits += 1;
    }
    enough(hits + misses, cases);
    mixed(hits, hits + misses, "hits");
    // Where both slabs' t overflow `f32` to inf, lo = hi = inf used to "hit"
    // a box the ray passes far from; e.g. origin 0, dir (1e-37, 1e-37, 0),
    // max_t inf and the box [100, 101] x [200, 201] x [0, 0].
    let (count, first) = (false_hits.len(), false_hits.first());
    assert!(first.is_none(), "{count} false hits, first {first:?}");
}

/// Two boxes a random gap apart per axis (negative: overlapping), at any
/// position, extent and gap magnitude.
fn join_pair(rng: &mut Rng) -> Option<(Aabb, Aabb)> {
    let sizes = [0.0, 1e-3, 1.0, 1e3, 1e10];
    let ca = dv(profile_point(rng));
    let (ha, hb) = (rng.extent(&sizes), rng.extent(&sizes));
    let gaps = [0.0, 1e-30, 1e-3, 1.0, 1e3, 1e10, 1e15];
    let gap = DVec3::from_array([0; 3].map(|_| rng.magnitude(&gaps)));
    let side = DVec3::from_array([0; 3].map(|_| rng.pick(&[-1.0, 1.0])));
    let cb = ca + side * (ha + hb + gap);
    Some((outward(ca - ha, ca + ha)?, outward(cb - hb, cb + hb)?))
}

/// Whether `x <= limit` is beyond rounding doubt. `Σg²` in `f64` rounds a few
/// times by 2^-53 of its value: 1e-9 of the values is far beyond that.
/// Equal zeros (touching boxes, a point in its box) are decided exactly.
fn decided(x: f64, limit: f64) -> Option<bool> {
    ((x - limit).abs() >= 1e-9 * (x + limit)).then_some(x <= limit)
}

#[test]
fn joins_pair_boxes_iff_their_f64_distance_is_within_d() {
    let mut rng = Rng(0x4242_4242_1357_2468);
    let others = distractors(&mut rng, 20);
    let (cases, mut decisions, mut paired) = (2500, 0, 0);
    for _ in 0..cases {
        let Some((a, b)) = join_pair(&mut rng) else {
            continue;
        };
        // Per-axis gaps: 0 clamped into the Minkowski difference a - b.
        let (lo, hi) = (dv(a.min) - dv(b.max), dv(a.max) - dv(b.min));
        let gaps = DVec3::ZERO.clamp(lo, hi).abs();
        let (dist, cheb) = (norm(gaps), gaps.max_element());
        // Near the boundary: 1e-8 is within `f32` rounding of d, 1e-6 beyond.
        let near = rng.pick(&[1.0 - 1e-8, 1.0 + 1e-8, 1.0 - 1e-6, 1.0 + 1e-6, 0.999, 1.001]);
        let d = match rng.below(3) {
            0 => rng.pick(&[0.0, 1e-30, 1e-3, 1.0, 1e3, 1e10, 1e30, f32::MAX as f64]),
            1 => dist * near,
            _ => cheb * near,
        };
        let d = d.min(f32::MAX as f64) as f32;
        let (mut tree, mut oracle) = build(&others, 2);
        for (key, aabb) in [(0, a), (1, b)] {
            tree.insert(key, aabb).unwrap();
            oracle.insert(key, aabb);
        }
        let ((one_a, _), (one_b, _)) = (build(&[a], 0), build(&[b], 1));
        for (mode, x) in [(JoinMode::Euclidean, dist), (JoinMode::Chebyshev, cheb)] {
            let Some(want) = decided(x, d as f64) else {
                continue;
            };
            let ctx = format!("{mode:?} d = {d}, truth {x}: {a:?} {b:?}");
            let both = [tree.self_join(d, mode), oracle.self_join(d, mode)];
            let both = both.map(|pairs| pairs.unwrap().contains(&(0, 1)));
            assert_eq!(both, [want; 2], "{ctx}");
            let cross = one_a.cross_join(&one_b, d, mode).unwrap();
            assert_eq!(cross, if want { vec![(0, 1)] } else { vec![] }, "{ctx}");
            decisions += 1;
            paired += want as usize;
        }
    }
    enough(decisions, cases * 2);
    mixed(paired, decisions, "paired");
}

#[test]
fn sphere_radius_and_nearest_queries_match_clamped_f64_distances() {
    let mut rng = Rng(0x5151_7373_9595_B7B7);
    let (mut cases, mut decisions, mut inside) = (0, 0, 0);
    for _ in 0..300 {
        let p = profile_point(&mut rng);
        let scale = rng.pick(&[1e-3, 1.0, 1e3, 1e6, 1e12]);
        let boxes: Vec<Aabb> = (0..24)
            .filter_map(|_| {
                let c = dv(p) + rng.vec(scale);
                let h = rng.extent(&[0.0, 0.01, 0.3, 1.0]) * scale;
                outward(c - h, c + h)
            })
            .collect();
        // The distance from p to p clamped into the box.
        let clamped = boxes.iter().map(|b| dv(p).clamp(dv(b.min), dv(b.max)));
        let dist: Vec<f64> = clamped.map(|c| norm(dv(p) - c)).collect();
        let (tree, oracle) = build(&boxes, 0);
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * (x + y);
        // A neighbour list: its distances are mine, in my order.
        let check = |list: &[Neighbor<u32>]| {
            for n in list {
                let mine = dist[n.key as usize];
                assert!(close(n.distance(), mine), "{n:?}, truth {mine}: {p}");
            }
            for pair in list.windows(2) {
                let (x, y) = (dist[pair[0].key as usize], dist[pair[1].key as usize]);
                assert!(x <= y || close(x, y), "{pair:?} out of order: {x} > {y}");
            }
        };
        for _ in 0..3 {
            let r = match rng.below(2) {
                0 => rng.pick(&[0.0, 1e-30, 1e-3 * scale, scale, 1e30, f32::MAX as f64]),
                _ => dist[rng.below(dist.len())] * rng.pick(&[1.0 - 1e-8, 1.0 + 1e-6]),
            } as f32;
            let within = tree.within_radius(p, r).unwrap();
            check(&within);
            let keys: Vec<u32> = within.iter().map(|n| n.key).collect();
            assert_eq!(within, oracle.within_radius(p, r).unwrap());
            assert_eq!(within, tree.nearest(p, boxes.len(), Some(r)).unwrap());
            let mut sorted = keys.clone();
            sorted.sort_unstable();
            assert_eq!(tree.overlapping_sphere(p, r).unwrap(), sorted);
            for (key, &x) in (0u32..).zip(&dist) {
                cases += 1;
                if let Some(want) = decided(x, r as f64) {
                    assert_eq!(keys.contains(&key), want, "{p} r = {r}: {key} at {x}");
                    decisions += 1;
                    inside += want as usize;
                }
            }
        }
        let near = tree.nearest(p, 5, None).unwrap();
        assert_eq!(near.len(), 5.min(boxes.len()));
        check(&near);
        let worst = near.iter().fold(0.0, |w, n| dist[n.key as usize].max(w));
        for (key, &x) in (0u32..).zip(&dist) {
            let kept = near.iter().any(|n| n.key == key);
            let ok = kept || x >= worst || close(x, worst);
            assert!(ok, "{key} at {x} is nearer than {worst}");
        }
    }
    enough(decisions, cases);
    mixed(inside, decisions, "inside");
}

#[test]
fn points_inside_and_outside_and_overlapping_boxes_match_f64_comparisons() {
    let mut rng = Rng(0x2468_ACE0_1357_9BDF);
    let (mut tree, base) = build(&distractors(&mut rng, 50), 1);
    let (cases, mut decisions, mut overlaps) = (3000, 0, 0);
    for _ in 0..cases {
        let c = dv(profile_point(&mut rng));
        let h = rng.extent(&[0.0, 1e-3, 1.0, 1e3, 1e12]);
        let Some(aabb) = outward(c - h, c + h) else {
            continue;
        };
        // Inside: a convex combination of the corners, rounded, clamped in.
        let weights = [0; 8].map(|_| rng.unit());
        let sum: f64 = weights.iter().sum();
        let corners = common::corners(&aabb).zip(weights);
        let inner: DVec3 = corners.map(|(k, w)| dv(k) * (w / sum)).sum();
        let p = inner.as_vec3().clamp(aabb.min, aabb.max);
        // Outside: one coordinate beyond a face by a relative step, if it
        // stays beyond once rounded.
        let axis = rng.below(3);
        let step = rng.pick(&[1e-6, 1e-3, 1.0]) * (aabb.max[axis].abs() as f64 + h[axis] + 1e-30);
        let face = rng.pick(&[(aabb.max[axis], 1.0), (aabb.min[axis], -1.0)]);
        let mut q = p;
        q[axis] = (face.0 as f64 + face.1 * step) as f32;
        let q_out = (q[axis] as f64 - face.0 as f64) * face.1 > 0.0;
        // A query box near this one: closed intervals, compared exactly.
        let reach = rng.pick(&[1e-3, 1.0, 1e3, 1e12]);
        let qc = inner + rng.vec(reach);
        let qh = rng.extent(&[0.0, 1e-3, 1.0, 1e3, 1e12]);
        let query = outward(qc - qh, qc + qh);
        let meets = |b: &Aabb| (0..3).all(|i| b.min[i] <= aabb.max[i] && aabb.min[i] <= b.max[i]);
        with_entry(&mut tree, &base, aabb, |tree, oracle| {
            let both = [tree.containing_point(p), oracle.containing_point(p)];
            assert_eq!(both.map(|k| k.contains(&0)), [true; 2], "{p} {aabb:?}");
            if q_out {
                let both = [tree.containing_point(q), oracle.containing_point(q)];
                assert_eq!(both.map(|k| k.contains(&0)), [false; 2], "{q} {aabb:?}");
                decisions += 1;
            }
            if let Some(query) = query {
                let want = meets(&query);
                let both = [tree.overlapping(&query), oracle.overlapping(&query)];
                let both = both.map(|k| k.contains(&0));
                assert_eq!(both, [want; 2], "{query:?} {aabb:?}");
                decisions += 1;
                overlaps += want as usize;
            }
        });
    }
    enough(decisions, cases * 2);
    assert!(overlaps > cases / 20, "only {overlaps} overlaps");
}
