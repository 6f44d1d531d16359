//! Boxes on, across and a rounding away from a plane, and planes whose
//! numbers test the arithmetic: huge boxes, tiny offsets, re-based eyes.

use super::*;

fn x_slab(eye: Vec3, offset: f32) -> Frustum {
    // Inside iff x - eye.x + offset > 0, i.e. x > eye.x - offset.
    let plane = HalfSpace {
        normal: Vec3::X,
        offset,
    };
    Frustum::new(
        eye,
        [
            plane,
            HalfSpace::INACTIVE,
            HalfSpace::INACTIVE,
            HalfSpace::INACTIVE,
            HalfSpace::INACTIVE,
            HalfSpace::INACTIVE,
        ],
    )
    .unwrap()
}

#[test]
fn a_face_on_the_plane_from_outside_is_culled_and_one_ulp_inside_is_visible() {
    let on_plane = common::aabb([-3.0, 0.0, 0.0], [5.0, 1.0, 1.0]);
    let ulp_inside = common::aabb([-3.0, 0.0, 0.0], [5f32.next_up(), 1.0, 1.0]);
    let (tree, oracle) = with_distractors(&[on_plane, ulp_inside]);
    // Inside iff x > 5.
    let view = x_slab(Vec3::ZERO, -5.0);
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let visible = tree.visible(&view, mode);
        assert!(!visible.contains(&0), "touching from outside is culled");
        assert!(visible.contains(&1), "one ulp inside is visible");
        assert_eq!(visible, oracle.visible(&view, mode));
    }
}

/// A plane whose offset is tiny beside its normal (1e-30 beside 1e30) is
/// stored scaled so that the offset falls into `f32`'s subnormals or below:
/// a point on the plane's zero set through the eye keeps the offset's
/// sign, as the plane in `f64` says (there, `1e30 * 0 + 1e-30 > 0`).
#[test]
fn an_offset_tiny_beside_its_normal_keeps_what_the_plane_keeps() {
    let at_eye = common::aabb([0.0; 3], [0.0; 3]);
    let i = HalfSpace::INACTIVE;
    for (offset, kept) in [(1e-30f32, true), (1e-38, true), (-1e-30, false)] {
        let plane = HalfSpace {
            normal: Vec3::new(1e30, 0.0, 0.0),
            offset,
        };
        // Ground truth in f64, without the crate: the box's p-vertex is
        // the eye itself.
        let truth = 1e30f64 * 0.0 + offset as f64 > 0.0;
        assert_eq!(truth, kept);
        let view = Frustum::new(Vec3::ZERO, [plane, i, i, i, i, i]).unwrap();
        assert_eq!(view.intersects_conservative(&at_eye), kept, "{offset:e}");
        let (tree, oracle) = with_distractors(&[at_eye]);
        for mode in [CullMode::Conservative, CullMode::Exact] {
            let visible = tree.visible(&view, mode);
            assert_eq!(visible.contains(&0), kept, "{offset:e} {mode:?}");
            assert_eq!(visible, oracle.visible(&view, mode));
        }
    }
}

/// A box of 1e15 m reaching 1/64 m into a small cube of a frustum: the
/// exact test's projections of its corners round by more than the overlap,
/// which must keep the box, not cull it. A point known to be in both, in
/// exact arithmetic, is the ground truth.
#[test]
fn a_huge_box_reaching_a_little_into_the_view_is_kept_in_exact_mode() {
    let far = -1e15f32;
    let huge = common::aabb([far, far, far], [0.03125, -far, -far]);
    let plane = |normal: Vec3, offset: f32| HalfSpace { normal, offset };
    // Inside iff 1/64 < x < 1, -1 < y < 1, -1 < z < 1.
    let cube = Frustum::new(
        Vec3::ZERO,
        [
            plane(Vec3::X, -0.015625),
            plane(Vec3::NEG_X, 1.0),
            plane(Vec3::Y, 1.0),
            plane(Vec3::NEG_Y, 1.0),
            plane(Vec3::Z, 1.0),
            plane(Vec3::NEG_Z, 1.0),
        ],
    )
    .unwrap();
    // (0.02, 0, 0) is in the box and strictly inside every plane.
    let witness = [0.02f64, 0.0, 0.0];
    assert!(witness[0] > 0.015625 && witness[0] < 1.0 && witness[0] <= 0.03125);
    let (tree, oracle) = with_distractors(&[huge]);
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let visible = tree.visible(&cube, mode);
        assert!(visible.contains(&0), "{mode:?}");
        assert_eq!(visible, oracle.visible(&cube, mode));
    }
}

/// World planes re-based on an eye whose offset `f64` cannot hold exactly
/// (1 + 2^-60 rounds to 1, an `f32` value): the stored offset must still
/// not fall below it, or a point the world plane keeps is culled. The
/// world plane is x + y > 0; the point (0, 2^-61, 0) is inside by 2^-61.
#[test]
fn a_plane_re_based_on_an_eye_keeps_what_the_world_plane_keeps() {
    let tiny = 2f32.powi(-60);
    let eye = Vec3::new(1.0, tiny, 0.0);
    let inactive = (Vec3::ZERO, f32::INFINITY);
    let planes = [
        (Vec3::new(1.0, 1.0, 0.0), 0.0),
        inactive,
        inactive,
        inactive,
        inactive,
        inactive,
    ];
    let view = Frustum::from_world_planes(eye, planes).unwrap();
    let point = common::aabb([0.0, tiny / 2.0, 0.0], [0.0, tiny / 2.0, 0.0]);
    // Ground truth in f64, without the crate: 0 + 2^-61 + 0 > 0 exactly.
    assert!(0.0 + (tiny / 2.0) as f64 > 0.0);
    assert!(view.intersects_conservative(&point));
    // The stored offset, over the largest normal component, is not below
    // the exact 1 + 2^-60 (which f32 cannot hold: so above it).
    let plane = view.planes()[0];
    assert!(plane.offset as f64 / plane.normal.x as f64 > 1.0);
    let (tree, oracle) = with_distractors(&[point]);
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let visible = tree.visible(&view, mode);
        assert!(visible.contains(&0), "{mode:?}");
        assert_eq!(visible, oracle.visible(&view, mode));
    }
}

#[test]
fn the_conservative_false_positive_and_its_removal_in_exact_mode() {
    // Looking down -z, 90 degree fov, square: inside iff |x|, |y| < -z and
    // 1 < -z < 10. The box lies beyond the far corner: every plane alone has
    // a corner of it inside, yet no point of it is inside all planes.
    let frustum = Frustum::perspective(
        Vec3::ZERO,
        Quat::IDENTITY,
        90f32.to_radians(),
        1.0,
        1.0,
        10.0,
    )
    .unwrap();
    let outside = common::aabb([12.0, 12.0, -30.0], [30.0, 30.0, -8.0]);
    let inside = common::aabb([-1.0, -1.0, -5.0], [1.0, 1.0, -4.0]);
    let (tree, oracle) = with_distractors(&[outside, inside]);
    let conservative = tree.visible(&frustum, CullMode::Conservative);
    let exact = tree.visible(&frustum, CullMode::Exact);
    assert!(conservative.contains(&0), "the documented false positive");
    assert!(!exact.contains(&0), "exact mode removes it");
    assert!(exact.contains(&1) && conservative.contains(&1));
    assert_eq!(
        conservative,
        oracle.visible(&frustum, CullMode::Conservative)
    );
    assert_eq!(exact, oracle.visible(&frustum, CullMode::Exact));
    // Geometric truth: no sample of the box is inside the frustum.
    let inside_frustum =
        |p: Vec3| p.x.abs() < -p.z && p.y.abs() < -p.z && -p.z > 1.0 && -p.z < 10.0;
    for i in 0..=20 {
        for j in 0..=20 {
            for k in 0..=20 {
                let t = Vec3::new(i as f32, j as f32, k as f32) / 20.0;
                assert!(!inside_frustum(
                    outside.min + (outside.max - outside.min) * t
                ));
            }
        }
    }
}
