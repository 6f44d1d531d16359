//! Every query family against a ground truth computed here, in `f64`, without
//! the crate's predicates. The oracle (`BruteForce`) calls the very predicate
//! the tree calls, so a wrong predicate makes both agree on a wrong answer;
//! these tests decide each case independently, on random and extreme inputs,
//! count only the cases decided beyond a rounding band, and require many.

mod common;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, CullMode, Frustum, HalfSpace, JoinMode, MAX_COORD};
use bevy_rtree::{Neighbor, QueryWorkspace, RTree, Ray};
use glam::{DQuat, DVec3, Quat, Vec3};

type Tree = RTree<u32, 4>;
type Oracle = BruteForce<u32>;

/// The `f32` unit roundoff, 2^-24.
const U: f64 = 1.0 / 16_777_216.0;
/// The largest coordinate, in `f64`.
const M: f64 = MAX_COORD as f64;
/// Magnitudes of positions: the origin, a town, a country, far space and the
/// largest allowed coordinate.
const PROFILES: [f64; 5] = [0.0, 1e3, 1e6, 1e12, 1e15];

/// A xorshift generator; every test has its own fixed seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn pick<T: Copy>(&mut self, from: &[T]) -> T {
        from[self.below(from.len())]
    }
    /// `±pick(magnitudes) * [0.5, 1.5)`.
    fn magnitude(&mut self, magnitudes: &[f64]) -> f64 {
        self.pick(&[-1.0, 1.0]) * self.pick(magnitudes) * (0.5 + self.unit())
    }
    /// Each component in `(-scale, scale)`.
    fn vec(&mut self, scale: f64) -> DVec3 {
        DVec3::from_array([0; 3].map(|_| (2.0 * self.unit() - 1.0) * scale))
    }
    /// Each component `pick(magnitudes) * [0, 1)`.
    fn extent(&mut self, magnitudes: &[f64]) -> DVec3 {
        DVec3::from_array([0; 3].map(|_| self.pick(magnitudes) * self.unit()))
    }
}

fn dv(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

/// `v` clamped within `MAX_COORD`.
fn world(v: DVec3) -> DVec3 {
    v.clamp(DVec3::splat(-M), DVec3::splat(M))
}

/// The smallest valid `f32` box holding `[min, max]` (clamped to `MAX_COORD`).
fn outward(min: DVec3, max: DVec3) -> Option<Aabb> {
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x { f.next_up() } else { f }
    };
    let min = Vec3::from(world(min).to_array().map(|x| -up(-x)));
    Aabb::new(min, Vec3::from(world(max).to_array().map(up))).ok()
}

fn profile_point(rng: &mut Rng) -> Vec3 {
    let scale = rng.pick(&PROFILES);
    world(rng.vec(scale)).as_vec3()
}

fn distractors(rng: &mut Rng, n: usize) -> Vec<Aabb> {
    let boxes = (0..n).map(|_| {
        let c = dv(profile_point(rng));
        let h = rng.extent(&[0.0, 1.0, 1e3, 1e6, 1e12]);
        outward(c - h, c + h)
    });
    boxes.flatten().collect()
}

/// A tree and an oracle holding `boxes` under keys `first..`.
fn build(boxes: &[Aabb], first: u32) -> (Tree, Oracle) {
    let mut tree = Tree::with_settings(Default::default()).unwrap();
    let mut oracle = BruteForce::default();
    for (key, b) in (first..).zip(boxes) {
        tree.insert(key, *b).unwrap();
        oracle.insert(key, *b);
    }
    (tree, oracle)
}

/// Runs `f` on the tree and the oracle with `aabb` added as key 0.
fn with_entry<R>(tree: &mut Tree, o: &Oracle, b: Aabb, f: impl FnOnce(&Tree, &Oracle) -> R) -> R {
    let id = tree.insert(0, b).unwrap();
    tree.validate().unwrap();
    let mut oracle = o.clone();
    oracle.insert(0, b);
    let result = f(tree, &oracle);
    tree.remove(id).unwrap();
    tree.validate().unwrap();
    result
}

/// Every test must decide (not skip as too close to call) over 40 % of its cases.
fn enough(decided: usize, cases: usize) {
    assert!(decided * 10 > cases * 4, "{decided} of {cases} decided");
}

/// Both answers must be common: `part` within 10 % .. 90 % of `all`.
fn mixed(part: usize, all: usize, what: &str) {
    assert!(
        part * 10 > all && part * 10 < all * 9,
        "{part} of {all} {what}"
    );
}

/// `|v|` without overflow or underflow of the squares.
fn norm(v: DVec3) -> f64 {
    let m = v.abs().max_element();
    if m == 0.0 { 0.0 } else { m * (v / m).length() }
}

/// Within this band of 0 an `f32` plane value may have either sign: with `s`
/// = `Σ|n_i||x_i - eye_i|`, about six roundings of at most 2^-24 of `s + |d|`
/// (1e-6 covers them 16 times), plus 2^-149 · 4e15 < 1e-28 of the largest
/// normal component where the crate's scaling of the normal (to a largest
/// component in (0.5, 1]) rounds the others into `f32` subnormals.
fn plane_band(n: DVec3, s: f64, d: f32) -> f64 {
    1e-6 * (s + d.abs() as f64) + 1e-28 * n.abs().max_element()
}

/// A normal with components of random sign and magnitude, 0 and `f32`
/// subnormals included, not all zero.
fn random_normal(rng: &mut Rng) -> DVec3 {
    loop {
        let mags = [0.0, 1e-40, 1e-20, 1e-3, 1.0, 1e3, 1e30];
        let n = DVec3::from_array([0; 3].map(|_| rng.magnitude(&mags) as f32 as f64));
        if n != DVec3::ZERO {
            return n;
        }
    }
}

/// An eye, a box around a point `q`, and six planes (some inactive) that each
/// hold `q` strictly inside by a margin beyond [`plane_band`] in `f64`; `None`
/// where some plane's margin is within the band.
fn frustum_case(rng: &mut Rng) -> Option<(Vec3, Aabb, [HalfSpace; 6])> {
    let eye = profile_point(rng);
    let scale = rng.pick(&[0.0, 1e-3, 1.0, 1e3, 1e6, 1e12]);
    let q = world(dv(eye) + rng.vec(scale)).as_vec3();
    let h = DVec3::from_array([0; 3].map(|_| rng.pick(&[0.0, 1e-3, 1.0, 1e3])));
    let aabb = outward(dv(q) - h, dv(q) + h)?;
    let rel = dv(q) - dv(eye);
    let mut planes = [HalfSpace::INACTIVE; 6];
    for plane in &mut planes {
        if rng.below(6) == 0 {
            continue;
        }
        let n = random_normal(rng);
        let (v, s) = (n.dot(rel), n.abs().dot(rel.abs() + h));
        let d = (-v + rng.pick(&[1e-5, 1e-2, 1.0, 1e6]) * s).min(f32::MAX as f64) as f32;
        let d = if rng.below(8) == 0 { f32::MAX } else { d };
        if !d.is_finite() || v + d as f64 <= plane_band(n, s, d) {
            return None;
        }
        (plane.normal, plane.offset) = (n.as_vec3(), d);
    }
    Some((eye, aabb, planes))
}

/// Asserts that `aabb` (as key 0, among the distractors) is visible or culled
/// in both modes, in the tree and in the oracle.
fn expect_visible(tree: &mut Tree, base: &Oracle, f: &Frustum, aabb: Aabb, want: bool) {
    with_entry(tree, base, aabb, |tree, oracle| {
        for mode in [CullMode::Conservative, CullMode::Exact] {
            let got = tree.visible(f, mode);
            assert_eq!(got.contains(&0), want, "{mode:?} {aabb:?} {f:?}");
            assert_eq!(got, oracle.visible(f, mode), "{mode:?} {f:?}");
        }
    });
}

/// Frustum cases from [`frustum_case`], with one plane replaced by one that
/// leaves the whole box outside by a margin if `outside`.
fn frustum_cases(seed: u64, cases: usize, outside: bool) {
    let mut rng = Rng(seed);
    let (mut tree, base) = build(&distractors(&mut rng, 50), 1);
    let mut decided = 0;
    for _ in 0..cases {
        let Some((eye, aabb, mut planes)) = frustum_case(&mut rng) else {
            continue;
        };
        if outside {
            // The others hold a point of the box: the volume need not be
            // empty, and exact mode has to find the separation itself.
            let n = random_normal(&mut rng);
            let (lo, hi) = (dv(aabb.min) - dv(eye), dv(aabb.max) - dv(eye));
            let furthest = (n * lo).max(n * hi).element_sum(); // over the corners
            let s = n.abs().dot(lo.abs().max(hi.abs()));
            let d = (-furthest - rng.pick(&[1e-5, 1e-2, 1.0, 1e6]) * s) as f32;
            let d = if rng.below(8) == 0 { -f32::MAX } else { d };
            if !d.is_finite() || furthest + d as f64 >= -plane_band(n, s, d) {
                continue;
            }
            let normal = n.as_vec3();
            planes[rng.below(6)] = HalfSpace { normal, offset: d };
        }
        let frustum = Frustum::new(eye, planes).expect("a valid eye and valid planes");
        expect_visible(&mut tree, &base, &frustum, aabb, !outside);
        decided += 1;
    }
    enough(decided, cases);
}

#[test]
fn a_box_holding_a_point_strictly_inside_every_plane_is_visible_in_both_modes() {
    frustum_cases(0x0123_4567_89AB_CDEF, 3000, false);
}

#[test]
fn a_box_outside_one_plane_by_a_margin_is_culled_in_both_modes() {
    // Fewer cases: exact mode is slow to prepare for a volume that may be empty.
    frustum_cases(0xFEDC_BA98_7654_3210, 600, true);
}

/// A perspective frustum rebuilt in `f64` from its parameters: eye-relative
/// corners (index bits: x right, y up, z far), inward unit face planes,
/// separating axes and the size of the volume.
struct View {
    corners: [DVec3; 8],
    planes: [(DVec3, f64); 6],
    axes: Vec<DVec3>,
    size: f64,
}

impl View {
    fn new(rotation: Quat, fov_y: f32, aspect: f32, near: f32, far: f32) -> View {
        let [x, y, z, w] = rotation.to_array().map(|c| c as f64);
        let r = DQuat::from_xyzw(x, y, z, w).normalize();
        let (forward, up, right) = (r * DVec3::NEG_Z, r * DVec3::Y, r * DVec3::X);
        let tan_y = (fov_y as f64 * 0.5).tan();
        let tan_x = tan_y * aspect as f64;
        let corners: [DVec3; 8] = std::array::from_fn(|i| {
            let dist = if i & 4 == 0 { near } else { far } as f64;
            let sx = if i & 1 == 0 { -tan_x } else { tan_x };
            let sy = if i & 2 == 0 { -tan_y } else { tan_y };
            (forward + right * sx + up * sy) * dist
        });
        let centroid = corners.iter().sum::<DVec3>() / 8.0;
        let planes = std::array::from_fn(|f| {
            let bit = 1 << (f / 2);
            let face = (0..8).filter(|i| (i & bit != 0) == (f % 2 == 1));
            let face: Vec<DVec3> = face.map(|i| corners[i]).collect();
            let n = (face[1] - face[0]).cross(face[2] - face[0]).normalize();
            let n = n * n.dot(centroid - face[0]).signum();
            (n, -n.dot(face[0]))
        });
        let mut edges = vec![right, up];
        edges.extend((0..4).map(|i| corners[i + 4] - corners[i]));
        let mut axes = vec![DVec3::X, DVec3::Y, DVec3::Z];
        axes.extend(planes.iter().map(|p: &(DVec3, f64)| p.0));
        let unit = edges.iter().map(|e| e.normalize());
        let crossed = unit.flat_map(|e| [DVec3::X, DVec3::Y, DVec3::Z].map(|b| b.cross(e)));
        axes.extend(crossed.filter(|a| a.length() > 1e-9).map(DVec3::normalize));
        let size = corners.iter().map(|c| c.length()).fold(0.0, f64::max);
        View {
            corners,
            planes,
            axes,
            size,
        }
    }

    /// The margin: the crate builds its planes in `f32` (a quaternion
    /// normalised and applied, a tangent, a normalisation: a dozen roundings
    /// of unit quantities, each at most 2^-24), which can move them by about
    /// 1e-6 of the distance from the eye; 1e-5 leaves room for that.
    fn margin(&self, lo: DVec3, hi: DVec3) -> f64 {
        1e-5 * (self.size + lo.abs().max(hi.abs()).length())
    }

    /// Whether some axis separates the eye-relative box `[lo, hi]` from the
    /// volume by more than the margin.
    fn separated(&self, lo: DVec3, hi: DVec3) -> bool {
        let (c, h) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
        self.axes.iter().any(|a| {
            let along = self.corners.map(|k| a.dot(k));
            let fmin = along.into_iter().fold(f64::INFINITY, f64::min);
            let fmax = along.into_iter().fold(f64::NEG_INFINITY, f64::max);
            let (bc, br) = (a.dot(c), a.abs().dot(h));
            (fmin - (bc + br)).max(bc - br - fmax) > self.margin(lo, hi)
        })
    }

    /// Whether a point of a 5 x 5 x 5 lattice over the box is inside every
    /// face plane by more than that plane's rounding there: the crate's
    /// plane is off by about 1e-6 of the point's distance from the eye
    /// (its normal) plus 1e-6 of the plane's own offset (near or far), so
    /// a point near the eye is held to a band near the eye's size, not to
    /// the whole volume's.
    fn witness(&self, lo: DVec3, hi: DVec3) -> bool {
        let ts = [0.001, 0.25, 0.5, 0.75, 0.999];
        (0..125).any(|i| {
            let x = lo + (hi - lo) * DVec3::new(ts[i % 5], ts[i / 5 % 5], ts[i / 25]);
            self.planes
                .iter()
                .all(|(n, d)| n.dot(x) + d > 1e-5 * (x.length() + d.abs()))
        })
    }
}

#[test]
fn exact_culling_agrees_with_a_separating_axis_test_of_its_own() {
    let mut rng = Rng(0x0BAD_CAFE_F00D_D00D);
    let (mut cases, mut decided, mut false_positives, mut small_seen) = (0, 0, 0, 0);
    for _ in 0..60 {
        let eye_scale = rng.pick(&[0.0, 1e3, 1e6, 1e12]);
        let eye = world(rng.vec(eye_scale)).as_vec3();
        let length = rng.pick(&[1.0, 1e-3, 7.0]); // normalised by `perspective`
        let rotation = [0; 4].map(|_| ((2.0 * rng.unit() - 1.0) * length) as f32);
        let rotation = Quat::from_array(rotation);
        let fov = (0.1 + 2.9 * rng.unit()) as f32;
        let aspect = (0.3 + 2.7 * rng.unit()) as f32;
        let near = (rng.pick(&[0.05, 1.0, 10.0]) * (0.5 + rng.unit())) as f32;
        let far = near * rng.pick(&[1.5, 10.0, 1e3, 1e6, 2e9]);
        let frustum = Frustum::perspective(eye, rotation, fov, aspect, near, far).unwrap();
        let view = View::new(rotation, fov, aspect, near, far);
        // Boxes of all sizes about the corners, along the edges and inside.
        let mut sized_to_anchor = Vec::new();
        let boxes: Vec<Aabb> = (0..200)
            .filter_map(|_| {
                // The other end: any corner, or a neighbour (an edge).
                let i = rng.below(8);
                let (j, k) = (rng.below(8), i ^ (1 << rng.below(3)));
                let j = rng.pick(&[j, k]);
                let t = rng.unit();
                let anchor = view.corners[i].lerp(view.corners[j], rng.pick(&[0.0, t]));
                // Sized to the volume, or to the anchor's own distance (small
                // boxes at the near corners of a deep volume).
                let small = rng.below(2) == 0;
                let size = if small {
                    anchor.length().max(near as f64)
                } else {
                    view.size.max(anchor.length())
                };
                let off = size * rng.pick(&[0.0, 1e-3, 0.03, 0.2]);
                let c = dv(eye) + anchor + rng.vec(off);
                let h = rng.extent(&[1e-3, 0.03, 0.2, 0.6]) * size;
                let b = outward(c - h, c + h)?;
                sized_to_anchor.push(small);
                Some(b)
            })
            .collect();
        let (tree, oracle) = build(&boxes, 0);
        let cons = tree.visible(&frustum, CullMode::Conservative);
        let exact = tree.visible(&frustum, CullMode::Exact);
        assert_eq!(cons, oracle.visible(&frustum, CullMode::Conservative));
        assert_eq!(exact, oracle.visible(&frustum, CullMode::Exact));
        assert!(exact.iter().all(|k| cons.contains(k)));
        for ((key, b), &small) in (0u32..).zip(&boxes).zip(&sized_to_anchor) {
            let (lo, hi) = (dv(b.min) - dv(eye), dv(b.max) - dv(eye));
            if view.separated(lo, hi) {
                assert!(!exact.contains(&key), "{b:?} {frustum:?}");
                false_positives += cons.contains(&key) as usize;
                decided += 1;
            } else if view.witness(lo, hi) {
                assert!(exact.contains(&key), "{b:?} {frustum:?}");
                assert!(cons.contains(&key), "{b:?} {frustum:?}");
                decided += 1;
                small_seen += small as usize;
            }
        }
        cases += boxes.len();
    }
    enough(decided, cases);
    assert!(
        small_seen >= 100,
        "{small_seen} small boxes seen through a witness"
    );
    assert!(false_positives >= 20, "{false_positives} false positives");
}

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
