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

#[path = "ground_truth/exact_culling.rs"]
mod exact_culling;
#[path = "ground_truth/rays_and_distances.rs"]
mod rays_and_distances;
