//! World boxes from a local box and an affine transform (SEMANTICS S1): the
//! result must contain the exact image of every corner of the local box, far
//! from the origin too, where one `f32` rounding of the centre is larger than
//! the whole box.

mod common;

use bevy_rtree::{Aabb, SpatialError};
use glam::{Affine3A, EulerRot, Quat, Vec3};
use proptest::prelude::*;

/// The exact image of `p` under `transform`, to within `f64` rounding (the
/// products of two `f32` are exact in `f64`; three sums round, far below an
/// `f32` ulp), computed without the crate's code.
fn exact_image(transform: &Affine3A, p: Vec3) -> [f64; 3] {
    let m = transform.matrix3;
    let columns = [m.x_axis, m.y_axis, m.z_axis];
    let t = transform.translation;
    let mut out = [f64::from(t.x), f64::from(t.y), f64::from(t.z)];
    for (row, coordinate) in out.iter_mut().enumerate() {
        for (column, axis) in columns.iter().enumerate() {
            *coordinate += f64::from(axis[row]) * f64::from(p[column]);
        }
    }
    out
}

/// A coordinate of magnitude up to `10^exponent`, either sign.
fn far(exponent: i32, unit: f64) -> f32 {
    ((unit * 2.0 - 1.0) * 10f64.powi(exponent)) as f32
}

/// A rotation, a non-uniform scale (mirrored on some axes), a translation
/// up to 1e7 m and a local box whose centre lies up to 1e5 m from its own
/// origin: the cases where `f32` rounding of the centre exceeds one ulp.
fn transform_and_box() -> impl Strategy<Value = (Affine3A, Aabb)> {
    let angles = prop::array::uniform3(-3.2f32..3.2);
    let scale = prop::array::uniform3((0.25f32..4.0, prop::bool::ANY));
    let translation = (0i32..=7, prop::array::uniform3(0.0f64..1.0));
    let centre = (0i32..=5, prop::array::uniform3(0.0f64..1.0));
    let half = prop::array::uniform3(0.0f32..3.0);
    (angles, scale, translation, centre, half).prop_map(
        |(angles, scale, (t_exp, t), (c_exp, c), half)| {
            let rotation = Quat::from_euler(EulerRot::XYZ, angles[0], angles[1], angles[2]);
            let scale = Vec3::from_array(scale.map(|(s, mirror)| if mirror { -s } else { s }));
            let translation = Vec3::from_array(t.map(|u| far(t_exp, u)));
            let transform = Affine3A::from_scale_rotation_translation(scale, rotation, translation);
            let centre = Vec3::from_array(c.map(|u| far(c_exp, u)));
            let half = Vec3::from_array(half);
            let local = Aabb::new(centre - half, centre + half).expect("finite local box");
            (transform, local)
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    /// Every exact corner image lies in the world box, compared in `f64`.
    /// (Evaluating S1's formula in `f32` and widening by one ulp fails this
    /// within a few hundred cases.)
    #[test]
    fn world_boxes_contain_the_exact_image_of_every_corner(
        (transform, local) in transform_and_box(),
    ) {
        let world = local.transformed(&transform).unwrap();
        for corner in common::corners(&local) {
            let image = exact_image(&transform, corner);
            for axis in 0..3 {
                prop_assert!(
                    f64::from(world.min[axis]) <= image[axis]
                        && image[axis] <= f64::from(world.max[axis]),
                    "corner {corner} maps to {image:?}, outside {world:?} on axis {axis}"
                );
            }
        }
    }

    /// The outward rounding costs little: each face lies within two `f32`
    /// ulps of the box the exact corner images span, plus the `f64` error
    /// bound it is widened by.
    #[test]
    fn world_boxes_are_tight(
        (transform, local) in transform_and_box(),
    ) {
        let world = local.transformed(&transform).unwrap();
        for axis in 0..3 {
            let images: Vec<f64> = common::corners(&local)
                .map(|corner| exact_image(&transform, corner)[axis])
                .collect();
            let lo = images.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = images.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            // Ulps of the larger face, so that a face near zero is not held
            // to ulps far finer than its box's own rounding; plus the f64
            // error bound the faces are widened by, which scales with the
            // translation and the centre's image (a face can lie near zero
            // after cancelling a large translation).
            let magnitude = lo.abs().max(hi.abs()) as f32;
            let ulp = f64::from(magnitude.next_up() - magnitude);
            let centre = (local.min + local.max) * 0.5;
            let scale = f64::from(transform.translation.abs().max_element())
                + f64::from((transform.matrix3.abs() * centre.abs()).max_element())
                + (hi - lo);
            let allowed = 2.0 * ulp + 16.0 * f64::EPSILON * scale;
            prop_assert!(lo - f64::from(world.min[axis]) <= allowed, "min {axis}: {lo} vs {world:?}");
            prop_assert!(f64::from(world.max[axis]) - hi <= allowed, "max {axis}: {hi} vs {world:?}");
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]

    /// `Aabb::from_oriented`, the `f32` form for Bevy's centre and half
    /// extents: every exact corner image lies in it, far out too, and each
    /// face lies within 32 units of roundoff of the magnitudes of the box
    /// the exact images span.
    #[test]
    fn oriented_world_boxes_contain_every_exact_corner_and_stay_tight(
        (transform, local) in transform_and_box(),
    ) {
        let centre = (local.min + local.max) * 0.5;
        let half = (local.max - local.min) * 0.5;
        // The exact box of Bevy's convention is centre ± half as given.
        let corners: Vec<Vec3> = (0..8)
            .map(|i| {
                let sign = Vec3::new(
                    if i & 1 == 0 { -1.0 } else { 1.0 },
                    if i & 2 == 0 { -1.0 } else { 1.0 },
                    if i & 4 == 0 { -1.0 } else { 1.0 },
                );
                centre + sign * half
            })
            .collect();
        let world = Aabb::from_oriented(centre, half, &transform).unwrap();
        for axis in 0..3 {
            let images: Vec<f64> = corners
                .iter()
                .map(|&c| {
                    // The corner in f64 from the f32 centre and half extent,
                    // so that its own rounding to f32 does not enter.
                    let sign = (c - centre).signum();
                    let exact = [0, 1, 2].map(|k| f64::from(centre[k]) + f64::from(sign[k]) * f64::from(half[k]));
                    let m = transform.matrix3;
                    let cols = [m.x_axis, m.y_axis, m.z_axis];
                    f64::from(transform.translation[axis])
                        + (0..3).map(|k| f64::from(cols[k][axis]) * exact[k]).sum::<f64>()
                })
                .collect();
            let lo = images.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = images.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            prop_assert!(f64::from(world.min[axis]) <= lo && hi <= f64::from(world.max[axis]),
                "axis {axis}: [{lo}, {hi}] outside {world:?}");
            let scale = f64::from(transform.translation.abs().max_element())
                + f64::from((transform.matrix3.abs() * centre.abs()).max_element())
                + (hi - lo);
            let allowed = 32.0 * f64::from(f32::EPSILON) * scale + 1e-30;
            prop_assert!(lo - f64::from(world.min[axis]) <= allowed, "min {axis}: {lo} vs {world:?}");
            prop_assert!(f64::from(world.max[axis]) - hi <= allowed, "max {axis}: {hi} vs {world:?}");
        }
    }
}

#[test]
fn oriented_boxes_refuse_negative_or_nan_extents_and_unusable_transforms() {
    let ok = Affine3A::from_translation(Vec3::X);
    for half in [
        Vec3::new(-1.0, 1.0, 1.0),
        Vec3::new(f32::NAN, 1.0, 1.0),
        Vec3::INFINITY,
    ] {
        assert_eq!(
            Aabb::from_oriented(Vec3::ZERO, half, &ok),
            Err(SpatialError::InvalidBox)
        );
    }
    let nan = Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0));
    assert_eq!(
        Aabb::from_oriented(Vec3::ZERO, Vec3::ONE, &nan),
        Err(SpatialError::InvalidBox)
    );
    let beyond = Affine3A::from_translation(Vec3::splat(2e15));
    assert_eq!(
        Aabb::from_oriented(Vec3::ZERO, Vec3::ONE, &beyond),
        Err(SpatialError::InvalidBox)
    );
    assert!(
        Aabb::from_oriented(Vec3::ZERO, Vec3::ZERO, &ok).is_ok(),
        "a point is a box"
    );
}

/// A pure translation adds in `f32`, as the entity's other points move.
#[test]
fn a_pure_translation_adds_in_f32() {
    let local = common::aabb([-0.3; 3], [0.7; 3]);
    let offset = Vec3::new(1e6, -2e6, 3e5 + 0.1);
    let world = local
        .transformed(&Affine3A::from_translation(offset))
        .unwrap();
    assert_eq!(world.min, local.min + offset);
    assert_eq!(world.max, local.max + offset);
}

#[test]
fn a_rotated_box_far_out_contains_its_transformed_corners() {
    let local = common::aabb([-0.3; 3], [0.7; 3]);
    let far = Vec3::new(1e6, -2e6, 3e5);
    let transform = Affine3A::from_rotation_translation(Quat::from_rotation_y(0.3), far);
    let world = local.transformed(&transform).unwrap();
    for corner in common::corners(&local) {
        let p = transform.transform_point3(corner);
        assert!(world.contains_point(p), "corner {p} outside {world:?}");
    }
}

#[test]
fn unusable_transforms_and_results_are_refused() {
    let local = common::aabb([-0.3; 3], [0.7; 3]);
    let nan = Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0));
    assert_eq!(local.transformed(&nan), Err(SpatialError::InvalidBox));
    let infinite_scale = Affine3A::from_scale(Vec3::new(f32::INFINITY, 1.0, 1.0));
    assert_eq!(
        local.transformed(&infinite_scale),
        Err(SpatialError::InvalidBox)
    );
    // A finite transform whose image leaves the valid range.
    let huge =
        Affine3A::from_scale(Vec3::splat(1e14)) * Affine3A::from_translation(Vec3::splat(50.0));
    assert_eq!(local.transformed(&huge), Err(SpatialError::InvalidBox));
    assert_eq!(
        common::invalid_boxes()[0].transformed(&Affine3A::IDENTITY),
        Err(SpatialError::InvalidBox)
    );
}
