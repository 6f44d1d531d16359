//! What a frustum accepts and refuses when it is made, and views far
//! from the origin or many at once.

use super::*;

#[test]
fn nan_and_zero_normal_planes_are_refused() {
    let i = HalfSpace::INACTIVE;
    let nan = HalfSpace {
        normal: Vec3::new(f32::NAN, 0.0, 1.0),
        offset: 0.0,
    };
    let nan_offset = HalfSpace {
        normal: Vec3::Z,
        offset: f32::NAN,
    };
    let zero_normal = HalfSpace {
        normal: Vec3::ZERO,
        offset: 1.0,
    };
    let inf_offset = HalfSpace {
        normal: Vec3::Z,
        offset: f32::INFINITY,
    };
    for bad in [nan, nan_offset, zero_normal, inf_offset] {
        assert_eq!(
            Frustum::new(Vec3::ZERO, [bad, i, i, i, i, i]),
            Err(SpatialError::InvalidFrustum)
        );
    }
    assert_eq!(
        Frustum::new(Vec3::NAN, [i; 6]),
        Err(SpatialError::InvalidFrustum)
    );
    assert_eq!(
        Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, f32::NAN, 1.0, 0.1, 10.0),
        Err(SpatialError::InvalidFrustum)
    );
}

/// `Frustum::perspective` refuses every parameter outside its documented
/// range (field of view in (0, pi), finite aspect > 0, near > 0, far > near)
/// and a rotation that is zero or not a number.
#[test]
fn perspective_frustums_refuse_bad_parameters() {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let pi = std::f32::consts::PI;
    // (fov_y, aspect, near, far), each with one parameter out of its range
    // (an infinite near plane leaves no far plane beyond it).
    let bad = [
        (0.0, 1.5, 0.1, 10.0),
        (-1.0, 1.5, 0.1, 10.0),
        (pi, 1.5, 0.1, 10.0),
        (inf, 1.5, 0.1, 10.0),
        (1.0, 0.0, 0.1, 10.0),
        (1.0, -1.5, 0.1, 10.0),
        (1.0, nan, 0.1, 10.0),
        (1.0, inf, 0.1, 10.0),
        (1.0, 1.5, 0.0, 10.0),
        (1.0, 1.5, -0.1, 10.0),
        (1.0, 1.5, nan, 10.0),
        (1.0, 1.5, inf, inf),
        (1.0, 1.5, 0.1, 0.1),
        (1.0, 1.5, 0.1, 0.05),
        (1.0, 1.5, 0.1, nan),
        (1.0, 1.5, 0.1, -inf),
    ];
    for (fov, aspect, near, far) in bad {
        assert_eq!(
            Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, fov, aspect, near, far),
            Err(SpatialError::InvalidFrustum),
            "fov {fov} aspect {aspect} near {near} far {far}"
        );
    }
    for rotation in [
        Quat::from_xyzw(0.0, 0.0, 0.0, 0.0),
        Quat::from_xyzw(nan, 0.0, 0.0, 1.0),
    ] {
        assert_eq!(
            Frustum::perspective(Vec3::ZERO, rotation, 1.0, 1.5, 0.1, 10.0),
            Err(SpatialError::InvalidFrustum),
            "{rotation:?}"
        );
    }
    for eye in [Vec3::new(nan, 0.0, 0.0), Vec3::new(0.0, inf, 0.0)] {
        assert_eq!(
            Frustum::perspective(eye, Quat::IDENTITY, 1.0, 1.5, 0.1, 10.0),
            Err(SpatialError::InvalidFrustum),
            "{eye}"
        );
    }
    // The limits of the ranges themselves are fine: an infinite far plane,
    // a tiny near plane, a very wide view.
    for (fov, aspect, near, far) in [
        (1.0, 1.5, 0.1, inf),
        (1.0, 1.5, 1e-6, 1e6),
        (3.1, 10.0, 0.1, 10.0),
    ] {
        assert!(Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, fov, aspect, near, far).is_ok());
    }
}

#[test]
fn a_one_centimetre_box_two_centimetres_inside_stays_visible_a_million_metres_out() {
    // The camera sits a million metres from the origin and looks along +x.
    let eye = Vec3::new(1e6, 0.0, 0.0);
    let look_x = Quat::from_rotation_y(-std::f32::consts::FRAC_PI_2);
    let frustum = Frustum::perspective(eye, look_x, 60f32.to_radians(), 1.0, 0.1, 500.0).unwrap();
    // Ten metres ahead the top plane is at y = 10 * tan(30 deg).
    let edge = 10.0 * 30f32.to_radians().tan();
    let inside = common::aabb(
        [1e6 + 10.0, edge - 0.03, -0.005],
        [1e6 + 10.0, edge - 0.02, 0.005],
    );
    let outside = common::aabb(
        [1e6 + 10.0, edge + 0.02, -0.005],
        [1e6 + 10.0, edge + 0.03, 0.005],
    );
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    for (i, b) in [inside, outside].into_iter().enumerate() {
        tree.insert(i as u32, b).unwrap();
        oracle.insert(i as u32, b);
    }
    for mode in [CullMode::Conservative, CullMode::Exact] {
        assert_eq!(tree.visible(&frustum, mode), vec![0], "{mode:?}");
        assert_eq!(oracle.visible(&frustum, mode), vec![0]);
    }

    // Among 2,000 centimetre boxes scattered around the camera, so that the
    // tree prunes real nodes around the two, both modes still agree with
    // the oracle and keep the inside box while culling the outside one.
    let mut rng = bevy_rtree::scene::SceneRng::new(6);
    for key in 2..2_002u32 {
        let centre = eye
            + Vec3::new(
                rng.range(-20.0, 40.0),
                rng.range(-15.0, 15.0),
                rng.range(-15.0, 15.0),
            );
        let b = Aabb::from_center_half_extents(centre, Vec3::splat(0.005)).unwrap();
        tree.insert(key, b).unwrap();
        oracle.insert(key, b);
    }
    assert!(tree.height() > 1);
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let visible = tree.visible(&frustum, mode);
        assert_eq!(visible, oracle.visible(&frustum, mode), "{mode:?}");
        assert!(visible.contains(&0) && !visible.contains(&1), "{mode:?}");
        assert!(
            visible.len() > 100 && visible.len() < 1_900,
            "{}",
            visible.len()
        );
    }
}

#[test]
fn many_views_in_one_traversal_match_single_views() {
    let (_, tree, _) = common::town_tree(20_000, 3);
    let views: Vec<Frustum> = (0..11)
        .map(|i| {
            let rotation = Quat::from_euler(EulerRot::YXZ, i as f32 * 0.6, -0.2, 0.0);
            Frustum::perspective(
                Vec3::new(1000.0, 50.0, 1000.0),
                rotation,
                1.0,
                1.7,
                0.1,
                300.0,
            )
            .unwrap()
        })
        .collect();
    let mut oracle = BruteForce::default();
    for (_, key, aabb) in tree.iter() {
        oracle.insert(key, aabb);
    }
    for mode in [CullMode::Conservative, CullMode::Exact] {
        let mut out = vec![Vec::new(); views.len()];
        tree.visible_into(&views, mode, &mut QueryWorkspace::default(), &mut out);
        for (view, mut keys) in views.iter().zip(out) {
            keys.sort_unstable();
            assert!(!keys.is_empty());
            assert_eq!(keys, tree.visible(view, mode));
            assert_eq!(keys, oracle.visible(view, mode));
        }
    }
}
