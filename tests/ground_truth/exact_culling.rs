//! Exact culling against a separating-axis test of its own, on
//! perspective frustums rebuilt in `f64`.

// The ground truth's own arithmetic (on valid views, whose vectors are never
// zero), kept apart from the crate's helpers.
#![allow(clippy::disallowed_methods)]

use super::*;

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
