//! The exact frustum test's precomputation: the frustum's vertices and
//! unbounded directions in `f64`, projected once onto every separating axis
//! that its planes alone do not cover.

use glam::DVec3;

use super::{Aabb, Frustum};

/// At most 3 box axes plus 15 plane-pair edges times 3 box axes.
const MAX_AXES: usize = 48;

/// A bound on the relative rounding of a box's projection in
/// [`FrustumSat::separates`], with room to spare: about eight roundings of
/// 2^-53 each, taken as 2^-49.
const PROJECTION_ROUNDING: f64 = 1.0 / (1u64 << 49) as f64;

/// How far (relative) a normal may lean along a volume's line and still
/// count as across it, and the lean every axis across the line is widened
/// by: one bound for both, so that the widening covers what the test lets
/// through.
const LINE_TOLERANCE: f64 = 1e-12;

/// A frustum prepared for exact box tests ([contract S7](crate::contract), exact mode).
///
/// Axes: the three box face normals, and each box edge direction crossed
/// with each frustum edge direction (every pair of plane normals, crossed).
/// Extra axes never cause a false separation, so taking all plane pairs is
/// safe. The frustum's own planes are the conservative test's job.
/// Everything is relative to the eye and in `f64`; where a projection is
/// uncertain, the interval is widened, so rounding can only keep a box.
#[derive(Clone, Debug)]
pub struct FrustumSat {
    eye: DVec3,
    axes: [DVec3; MAX_AXES],
    lo: [f64; MAX_AXES],
    hi: [f64; MAX_AXES],
    count: usize,
    /// The open volume is empty (or flat): nothing is visible in exact mode.
    empty: bool,
    /// Where the planes' normals span only a plane, the volume holds a whole
    /// line: its (unit) direction. The axes are then projected from the
    /// slice of the volume through the eye, and `slope` bounds how far each
    /// axis may lean along the line, rounding included.
    line: Option<DVec3>,
    slope: [f64; MAX_AXES],
}

impl FrustumSat {
    /// Prepares `frustum` (a few microseconds; do it once per query).
    pub fn new(frustum: &Frustum) -> FrustumSat {
        let planes: Vec<(DVec3, f64)> = frustum
            .planes()
            .iter()
            .filter(|p| !p.is_inactive())
            .map(|p| (p.normal.as_dvec3(), p.offset as f64))
            .collect();
        let mut sat = FrustumSat {
            eye: frustum.eye().as_dvec3(),
            axes: [DVec3::ZERO; MAX_AXES],
            lo: [f64::NEG_INFINITY; MAX_AXES],
            hi: [f64::INFINITY; MAX_AXES],
            count: 0,
            empty: !has_interior(&planes),
            line: None,
            slope: [0.0; MAX_AXES],
        };
        if sat.empty {
            return sat;
        }
        let (mut vertices, mut rays) = polytope(&planes);
        if vertices.is_empty() {
            // No corner: the normals span at most a plane, so the volume
            // holds every line along their common perpendicular (a wedge of
            // two side planes, say). The planes' own test misses boxes
            // beside the wedge's edge, so project the slice of the volume
            // through the eye, across the line, onto the axes that lie
            // across it. Normals along a single direction (a half-space or
            // a slab) leave nothing to separate beyond the planes' test.
            let Some(line) = common_perpendicular(&planes) else {
                return sat;
            };
            let mut sliced = planes.clone();
            sliced.extend([(line, 0.0), (-line, 0.0)]);
            (vertices, rays) = polytope(&sliced);
            if vertices.is_empty() {
                return sat;
            }
            sat.line = Some(line);
        }
        let mut candidate_axes: Vec<DVec3> = vec![DVec3::X, DVec3::Y, DVec3::Z];
        for i in 0..planes.len() {
            for j in i + 1..planes.len() {
                let edge = planes[i].0.cross(planes[j].0);
                if edge.length_squared()
                    < 1e-20 * planes[i].0.length_squared() * planes[j].0.length_squared()
                {
                    continue;
                }
                for b in [DVec3::X, DVec3::Y, DVec3::Z] {
                    let axis = b.cross(edge);
                    if axis.length_squared() > 1e-24 * edge.length_squared() {
                        candidate_axes.push(axis);
                    }
                }
            }
        }
        for axis in candidate_axes.into_iter().take(MAX_AXES) {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for &(v, error) in &vertices {
                // Each vertex as far as its rounding may have moved it.
                let d = axis.dot(v);
                let reach = error * axis.length();
                lo = lo.min(d - reach);
                hi = hi.max(d + reach);
            }
            // Widen by a relative tolerance, and to infinity along every
            // unbounded direction the axis does not see as exactly flat.
            let scale = vertices
                .iter()
                .map(|(v, _)| v.abs().max_element())
                .fold(0.0, f64::max)
                * axis.length();
            lo -= 1e-9 * scale;
            hi += 1e-9 * scale;
            for r in &rays {
                let d = axis.dot(*r);
                let tol = 1e-9 * axis.length() * r.length();
                if d > -tol {
                    hi = f64::INFINITY;
                }
                if d < tol {
                    lo = f64::NEG_INFINITY;
                }
            }
            if let Some(line) = sat.line {
                // The volume runs along the line, so an axis that leans
                // along it sees the volume without end. The axes built
                // across it lean only by rounding: bound that lean (with
                // the line's own error and the planes' lean, both within
                // `LINE_TOLERANCE`), and `separates` widens the interval by
                // it times the box's reach along the line.
                let lean = axis.dot(line).abs() + 2.0 * LINE_TOLERANCE * axis.length();
                if lean > 1e-6 * axis.length() {
                    continue;
                }
                sat.slope[sat.count] = lean;
            }
            sat.axes[sat.count] = axis;
            sat.lo[sat.count] = lo;
            sat.hi[sat.count] = hi;
            sat.count += 1;
        }
        sat
    }

    /// Whether the frustum's open volume is empty (or flat), so that exact
    /// mode sees nothing in it, whatever its planes let through.
    pub(crate) fn sees_nothing(&self) -> bool {
        self.empty
    }

    /// Whether one of the prepared axes separates the box from the frustum.
    pub(crate) fn separates(&self, aabb: &Aabb) -> bool {
        if self.empty {
            return true;
        }
        let min = aabb.min.as_dvec3() - self.eye;
        let max = aabb.max.as_dvec3() - self.eye;
        let centre = (min + max) * 0.5;
        let half = (max - min) * 0.5;
        // How far along the volume's line (if it has one) the box reaches
        // from the slice through the eye.
        let reach = self
            .line
            .map_or(0.0, |line| line.dot(centre).abs() + line.abs().dot(half));
        // What the box's projection may be off by: the eye-relative corners,
        // their centre and half, and the dot products each round in `f64`,
        // by a few units of 2^-53 of the corners' magnitudes (which can
        // dwarf the box's overlap with the frustum: a box from -1e15 to
        // 0.03 reaches into a frustum that starts at 0.016 from the eye).
        let magnitude = min.abs() + max.abs() + self.eye.abs();
        (0..self.count).any(|i| {
            let axis = self.axes[i];
            let c = axis.dot(centre);
            let rounding = PROJECTION_ROUNDING * axis.abs().dot(magnitude);
            let r = axis.abs().dot(half) + self.slope[i] * reach + rounding;
            c + r < self.lo[i] || c - r > self.hi[i]
        })
    }
}

/// The vertices (intersections of three planes inside all others), each
/// with a bound on how far its rounding may have moved it, and the
/// unbounded directions (intersections of two planes inside all others) of
/// `{x : n·x + d > 0 for every plane}`, relative to the eye.
fn polytope(planes: &[(DVec3, f64)]) -> (Vec<(DVec3, f64)>, Vec<DVec3>) {
    let inside = |x: DVec3, error: f64, skip: &[usize]| {
        planes.iter().enumerate().all(|(k, (n, d))| {
            let tolerance = 1e-9 * (n.length() * x.length() + d.abs() + 1.0);
            skip.contains(&k) || n.dot(x) + d >= -(tolerance + n.length() * error)
        })
    };
    let mut vertices = Vec::new();
    for i in 0..planes.len() {
        for j in i + 1..planes.len() {
            for k in j + 1..planes.len() {
                let (a, b, c) = (planes[i], planes[j], planes[k]);
                let size = a.0.length() * b.0.length() * c.0.length();
                let det = a.0.dot(b.0.cross(c.0));
                if det.abs() < 1e-12 * size {
                    continue;
                }
                // Solve n·x = -d for the three planes (Cramer's rule).
                let (bc, ca, ab) = (b.0.cross(c.0), c.0.cross(a.0), a.0.cross(b.0));
                let x = (bc * -a.1 + ca * -b.1 + ab * -c.1) / det;
                // Where the three normals are nearly coplanar, the
                // determinant and the numerator both cancel, and the vertex
                // moves by about u / |det| of the terms, in any direction:
                // a bound of its error (the normals and offsets are exact
                // `f32`s; each product and sum rounds by at most u, with
                // room to spare).
                let terms = bc.length() * a.1.abs()
                    + ca.length() * b.1.abs()
                    + ab.length() * c.1.abs()
                    + x.length() * size;
                let error = 16.0 * f64::EPSILON * terms / det.abs();
                if x.is_finite() && error.is_finite() && inside(x, error, &[i, j, k]) {
                    vertices.push((x, error));
                }
            }
        }
    }
    let mut rays = Vec::new();
    for i in 0..planes.len() {
        for j in i + 1..planes.len() {
            let r = planes[i].0.cross(planes[j].0);
            if r.length_squared() == 0.0 {
                continue;
            }
            for dir in [r, -r] {
                let ok = planes
                    .iter()
                    .all(|(n, _)| n.dot(dir) >= -1e-9 * n.length() * dir.length());
                if ok {
                    rays.push(dir);
                }
            }
        }
    }
    (vertices, rays)
}

/// The unit direction perpendicular to every normal of `planes`, if their
/// normals span exactly a plane (no direction if they span space, or all
/// lie along one line).
fn common_perpendicular(planes: &[(DVec3, f64)]) -> Option<DVec3> {
    let line = planes
        .iter()
        .enumerate()
        .flat_map(|(i, a)| planes[i + 1..].iter().map(move |b| a.0.cross(b.0)))
        .filter(|edge| edge.length_squared() > 0.0)
        .max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))
        .map(super::unit_or_nan_f64)?;
    let spans_space = planes
        .iter()
        .any(|(n, _)| n.dot(line).abs() > LINE_TOLERANCE * n.length());
    (!spans_space).then_some(line)
}

/// Whether `{x : n·x + d > 0 for every plane}` has an interior, decided by
/// finding a point that is provably strictly inside every plane.
///
/// Candidates are the vertices of a linear programme that looks for the
/// largest ball inside all planes (maximise its radius `t`) within a cube
/// of half-width `R` around the eye, with `t <= R`: its best vertex is the
/// centre of that ball. A candidate counts only when its value against
/// every plane, evaluated in `f64`, exceeds that evaluation's rounding
/// bound, so the answer "has an interior" is never a rounding artefact, at
/// any distance: no threshold relative to the farthest plane (which made
/// every frustum with a plane 1e9 m away "empty"). `R` grows from 1 m in
/// steps of 10^4, so a volume far from the eye is reached, and a point near
/// the eye is tried with coordinates small enough to certify a thin volume
/// there. A volume thinner than about 1e-11 of its distance from the eye
/// may be taken as empty (the conservative test in `f32` cannot resolve it
/// either).
fn has_interior(planes: &[(DVec3, f64)]) -> bool {
    const REACHES: [f64; 5] = [1.0, 1e4, 1e8, 1e12, 1e16];
    // Rows a·(x, t) <= b. Plane: -n̂·x + t <= d̂.
    let mut rows: Vec<([f64; 4], f64)> = Vec::new();
    for (n, d) in planes {
        let len = n.length();
        rows.push(([-n.x / len, -n.y / len, -n.z / len, 1.0], d / len));
    }
    let planes_rows = rows.len();
    for reach in REACHES {
        rows.truncate(planes_rows);
        for axis in 0..3 {
            let mut a = [0.0; 4];
            a[axis] = 1.0;
            rows.push((a, reach));
            a[axis] = -1.0;
            rows.push((a, reach));
        }
        rows.push(([0.0, 0.0, 0.0, 1.0], reach));
        let m = rows.len();
        for i in 0..m {
            for j in i + 1..m {
                for k in j + 1..m {
                    for l in k + 1..m {
                        let Some(x) = solve4([rows[i], rows[j], rows[k], rows[l]]) else {
                            continue;
                        };
                        if x[3] > 0.0 && strictly_inside(planes, DVec3::new(x[0], x[1], x[2])) {
                            return true;
                        }
                    }
                }
            }
        }
    }
    false
}

/// Whether `point` is strictly inside every plane beyond doubt: each value
/// `n·point + d`, evaluated in `f64`, exceeds the bound on its rounding
/// error (four roundings of the terms' magnitudes, doubled for safety).
fn strictly_inside(planes: &[(DVec3, f64)], point: DVec3) -> bool {
    planes.iter().all(|(n, d)| {
        let value = n.dot(point) + d;
        let magnitude = (*n * point).abs().element_sum() + d.abs();
        value > 8.0 * f64::EPSILON * magnitude
    })
}

/// Solves the 4x4 system `a x = b` by Gaussian elimination with pivoting.
fn solve4(rows: [([f64; 4], f64); 4]) -> Option<[f64; 4]> {
    let mut m: [[f64; 5]; 4] = rows.map(|(a, b)| [a[0], a[1], a[2], a[3], b]);
    for col in 0..4 {
        let pivot = (col..4).max_by(|&r, &s| m[r][col].abs().total_cmp(&m[s][col].abs()))?;
        if m[pivot][col].abs() < 1e-12 {
            return None;
        }
        m.swap(col, pivot);
        for r in 0..4 {
            if r != col {
                let f = m[r][col] / m[col][col];
                let pivot_row = m[col];
                for (value, p) in m[r].iter_mut().zip(pivot_row).skip(col) {
                    *value -= f * p;
                }
            }
        }
    }
    let x = [
        m[0][4] / m[0][0],
        m[1][4] / m[1][1],
        m[2][4] / m[2][2],
        m[3][4] / m[3][3],
    ];
    x.iter().all(|v| v.is_finite()).then_some(x)
}
