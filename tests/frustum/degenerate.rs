//! Frustums without corners or volume: wedges, prisms open along a line,
//! zero thickness, planes facing apart or nearly coplanar, no far plane.

use super::*;

/// Two side planes through the eye whose normals span only a plane: a wedge
/// with no corner, open along `line`, inside iff `u > |v|` for the other
/// two coordinates `(u, v)` relative to the eye.
fn wedge(eye: Vec3, line: usize) -> Frustum {
    let (u, v) = ((line + 1) % 3, (line + 2) % 3);
    let plane = |sign: f32| {
        let mut normal = Vec3::ZERO;
        normal[u] = 1.0;
        normal[v] = sign;
        HalfSpace {
            normal,
            offset: 0.0,
        }
    };
    let i = HalfSpace::INACTIVE;
    Frustum::new(eye, [plane(1.0), plane(-1.0), i, i, i, i]).unwrap()
}

#[test]
fn a_wedge_without_corners_culls_exactly_beside_its_edge() {
    // The box the planes alone let through: each plane has a corner of it
    // inside, yet all of it lies at u <= -1, behind the wedge's edge.
    let behind = common::aabb([-2.0, -3.0, -1.0], [-1.0, 3.0, 1.0]);
    // Planes (1, 1, 0) and (1, -1, 0) through the origin.
    let along_z = wedge(Vec3::ZERO, 2);
    let (tree, oracle) = with_distractors(&[behind]);
    assert!(tree.visible(&along_z, CullMode::Conservative).contains(&0));
    let exact = tree.visible(&along_z, CullMode::Exact);
    assert!(!exact.contains(&0));
    assert_eq!(exact, oracle.visible(&along_z, CullMode::Exact));
    // Every box of a grid, for wedges open along each axis and away from the
    // origin: visible in exact mode iff some point has u > |v|, that is iff
    // max u > the least |v| over the box. Boxes within a rounding of the
    // boundary are left to the oracle comparison.
    let mut rng = bevy_rtree::scene::SceneRng::new(31);
    let mut boxes = Vec::new();
    for _ in 0..2_000 {
        let min = Vec3::new(
            rng.range(-9.0, 9.0),
            rng.range(-9.0, 9.0),
            rng.range(-9.0, 9.0),
        );
        let size = Vec3::new(
            rng.range(0.0, 4.0),
            rng.range(0.0, 4.0),
            rng.range(0.0, 4.0),
        );
        boxes.push(Aabb::new(min, min + size).unwrap());
    }
    let (tree, oracle) = build(&boxes);
    for line in 0..3 {
        for eye in [Vec3::ZERO, Vec3::new(3.5, -2.25, 1.0)] {
            let view = wedge(eye, line);
            let exact = tree.visible(&view, CullMode::Exact);
            assert_eq!(exact, oracle.visible(&view, CullMode::Exact));
            let (u, v) = ((line + 1) % 3, (line + 2) % 3);
            let mut decided = 0;
            for (key, b) in boxes.iter().enumerate() {
                let (min, max) = (b.min - eye, b.max - eye);
                let least_v = if min[v] > 0.0 {
                    min[v]
                } else if max[v] < 0.0 {
                    -max[v]
                } else {
                    0.0
                };
                let margin = max[u] - least_v;
                if margin.abs() > 1e-3 {
                    decided += 1;
                    assert_eq!(
                        exact.contains(&(key as u32)),
                        margin > 0.0,
                        "{b:?} against the wedge along axis {line} from {eye:?}"
                    );
                }
            }
            assert!(decided > 1_900);
        }
    }
}

#[test]
fn a_prism_open_along_a_diagonal_line_is_not_empty() {
    // Three planes whose normals are all across (1, 0, 1): a prism along that
    // line, which no box face follows. Its interior was once taken for empty
    // (its widest inscribed ball lies out at the solver's bounds, where
    // rounding is large), and exact mode culled everything.
    let plane = |x: f32, y: f32, z: f32, offset: f32| HalfSpace {
        normal: Vec3::new(x, y, z),
        offset,
    };
    let i = HalfSpace::INACTIVE;
    let prism = Frustum::new(
        Vec3::new(6.5, -6.0, -0.75),
        [
            plane(0.0, -2.0, 0.0, 5.0),
            plane(1.0, 2.0, -1.0, -4.5),
            plane(-2.0, -2.0, 2.0, 7.0),
            i,
            i,
            i,
        ],
    )
    .unwrap();
    // The box holds (1.75, -4.3125, -7.25), inside every plane by at least
    // 0.125.
    let holds_inside = common::aabb([1.75, -4.75, -7.25], [3.75, -3.0, -7.0]);
    let (tree, oracle) = with_distractors(&[holds_inside]);
    let exact = tree.visible(&prism, CullMode::Exact);
    assert!(exact.contains(&0));
    assert_eq!(exact, oracle.visible(&prism, CullMode::Exact));
}

#[test]
fn a_zero_thickness_frustum_has_only_conservative_false_positives() {
    let near = HalfSpace {
        normal: Vec3::NEG_Z,
        offset: -5.0,
    };
    let far = HalfSpace {
        normal: Vec3::Z,
        offset: 5.0,
    };
    let i = HalfSpace::INACTIVE;
    let flat = Frustum::new(Vec3::ZERO, [near, far, i, i, i, i]).unwrap();
    let straddling = common::aabb([-1.0, -1.0, -6.0], [1.0, 1.0, -4.0]);
    let (tree, oracle) = with_distractors(&[straddling]);
    // Each plane alone has a corner of the straddling box inside, so the
    // conservative test passes it; the open volume is empty, so exact mode
    // sees nothing at all.
    let conservative = tree.visible(&flat, CullMode::Conservative);
    assert!(conservative.contains(&0));
    assert_eq!(conservative, oracle.visible(&flat, CullMode::Conservative));
    assert!(tree.visible(&flat, CullMode::Exact).is_empty());
    assert!(oracle.visible(&flat, CullMode::Exact).is_empty());
}

/// Two planes through the eye that face exactly away from each other
/// (one is -3 times the other) bound an empty volume: exact mode sees
/// nothing, even at a point where both planes' values round above zero in
/// `f32` (so the conservative test, and the check that a box is inside
/// every plane, both pass it).
#[test]
fn exact_mode_sees_nothing_between_planes_that_face_apart() {
    let i = HalfSpace::INACTIVE;
    let p = HalfSpace {
        normal: Vec3::new(1.0, 0.5, 0.25),
        offset: 0.0,
    };
    let q = HalfSpace {
        normal: Vec3::new(-3.0, -1.5, -0.75),
        offset: 0.0,
    };
    let apart = Frustum::new(Vec3::ZERO, [p, q, i, i, i, i]).unwrap();
    let at = glam::DVec3::new(3.449885129928589, -6.252113342285156, -1.2953135967254639).as_vec3();
    let rounds_inside = common::aabb(at.to_array(), at.to_array());
    // The volume is empty in exact arithmetic: the two normals are
    // opposite (a negative multiple), and both offsets are 0.
    let (n, m) = (apart.planes()[0].normal, apart.planes()[1].normal);
    assert_eq!(n.as_dvec3().cross(m.as_dvec3()), glam::DVec3::ZERO);
    assert!(n.as_dvec3().dot(m.as_dvec3()) < 0.0);
    let (tree, oracle) = with_distractors(&[rounds_inside]);
    let conservative = tree.visible(&apart, CullMode::Conservative);
    assert!(
        conservative.contains(&0),
        "the planes' rounding lets it through"
    );
    assert!(tree.visible(&apart, CullMode::Exact).is_empty());
    assert!(oracle.visible(&apart, CullMode::Exact).is_empty());
    let mut visited = 0;
    tree.visit_visible(
        &[apart],
        CullMode::Exact,
        &mut QueryWorkspace::default(),
        |_, _, _| {
            visited += 1;
            std::ops::ControlFlow::Continue(())
        },
    );
    assert_eq!(visited, 0);
}

/// Four planes whose normals are nearly coplanar (the determinants of
/// their triples about 4e-9): a wedge cut at both ends, with a real
/// interior. Its corners, solved by Cramer's rule, move by thousands of
/// metres at 1e12 m, more than a fixed relative tolerance covers; a box
/// through a point inside every plane by more than a kilometre must stay
/// visible in exact mode.
#[test]
fn exact_mode_keeps_a_box_in_a_wedge_of_nearly_coplanar_planes() {
    let plane = |n: [f64; 3], offset: f64| HalfSpace {
        normal: glam::DVec3::from_array(n).as_vec3(),
        offset: offset as f32,
    };
    let i = HalfSpace::INACTIVE;
    let planes = [
        plane(
            [-0.7908066511154175, 0.6835565567016602, 0.1821395605802536],
            33029203968.0,
        ),
        plane(
            [0.44397300481796265, 0.9656855463981628, -0.7032955884933472],
            944905322496.0,
        ),
        plane(
            [-0.7268339395523071, 0.8227028846740723, 0.08080098778009415],
            169181478912.0,
        ),
        plane(
            [
                -0.6476064920425415,
                0.9950302839279175,
                -0.04470274597406387,
            ],
            337800691712.0,
        ),
        i,
        i,
    ];
    let wedge = Frustum::new(Vec3::ZERO, planes).unwrap();
    // A point inside every plane by more than a kilometre (in `f64`, whose
    // rounding here is below a millimetre).
    let witness = glam::DVec3::new(-580841772169.04, -717923418112.0, -8902393856.0);
    for stored in &wedge.planes()[..4] {
        let value = stored.normal.as_dvec3().dot(witness) + f64::from(stored.offset);
        let distance = value / stored.normal.as_dvec3().length();
        assert!(distance > 1_000.0, "{distance}");
    }
    let through = common::aabb(
        [-1680353525760.0, -717923418112.0, -8902393856.0],
        [518669860864.0, -717923418112.0, -8902393856.0],
    );
    assert!(through.min.as_dvec3().x <= witness.x && witness.x <= through.max.as_dvec3().x);
    let (tree, oracle) = with_distractors(&[through]);
    let exact = tree.visible(&wedge, CullMode::Exact);
    assert!(
        exact.contains(&0),
        "a box through an inside point is culled"
    );
    assert_eq!(exact, oracle.visible(&wedge, CullMode::Exact));
}

#[test]
fn an_inactive_far_plane_sees_boxes_at_1e14_metres() {
    let frustum = Frustum::perspective(
        Vec3::ZERO,
        Quat::IDENTITY,
        60f32.to_radians(),
        1.0,
        0.1,
        f32::INFINITY,
    )
    .unwrap();
    assert!(frustum.planes()[5].is_inactive());
    let far_ahead = common::aabb([-1e12, -1e12, -1.01e14], [1e12, 1e12, -1e14]);
    let far_behind = common::aabb([-1e12, -1e12, 1e14], [1e12, 1e12, 1.01e14]);
    let (tree, oracle) = with_distractors(&[far_ahead, far_behind]);
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let visible = tree.visible(&frustum, mode);
        assert!(visible.contains(&0) && !visible.contains(&1), "{mode:?}");
        assert_eq!(visible, oracle.visible(&frustum, mode));
    }
}
