//! The ray hard cases of the contract on the unit box among distractors:
//! grazing faces, edges and corners, `max_t` at a face, flat boxes,
//! subnormal directions, bad rays, ties, origins far out.

use super::*;

/// A ray whose direction is far beyond unit length can hit a box that does
/// not contain its origin at `t = 0`: leaving it, `(max - o) * inv`
/// underflows to `-0.0`. Such a tie with smaller key must still win over the
/// box around the origin when many rays share that origin.
#[test]
fn a_zero_t_hit_outside_a_shared_origin_still_wins_its_tie() {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    for (key, b) in [
        (0u32, common::aabb([0.0; 3], [1.0; 3])),
        (5, common::aabb([1.0, 0.0, 0.0], [2.0, 1.0, 1.0])),
    ] {
        tree.insert(key, b).unwrap();
        oracle.insert(key, b);
    }
    let away = ray([1f32.next_up(), 0.5, 0.5], [3e38, 0.0, 0.0], 10.0);
    let hits = oracle.ray_hits(&away).unwrap();
    assert_eq!(hits.first(), Some(&RayHit { key: 0, t: 0.0 }));
    assert_eq!(hits.len(), 2);
    check_rays(&tree, &oracle, &[away; 8]);
}

/// Camera rays from an eye inside several stacked boxes all hit the one
/// with the smallest key first, at `t = 0`, whatever order the tree holds
/// them in.
#[test]
fn rays_from_inside_stacked_boxes_hit_the_smallest_key_at_zero() {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    let stacked = common::aabb([0.0; 3], [4.0; 3]);
    for key in [9u32, 4, 7, 5] {
        tree.insert(key, stacked).unwrap();
        oracle.insert(key, stacked);
    }
    // Distractors around them make the tree a few levels deep.
    for key in 100..400u32 {
        let at = Vec3::new(
            (key % 10) as f32,
            (key / 10 % 10) as f32,
            (key / 100) as f32,
        ) * 9.0;
        let b = Aabb::new(at + 20.0, at + 21.0).unwrap();
        tree.insert(key, b).unwrap();
        oracle.insert(key, b);
    }
    let rays: Vec<Ray> = (0..16)
        .map(|i| {
            let angle = i as f32 * 0.4;
            ray([2.0; 3], [angle.cos(), angle.sin(), 0.25], 10.0)
        })
        .collect();
    let mut out = RayResults::default();
    let mut ws = QueryWorkspace::default();
    tree.cast_rays(&rays, RayMode::First, &mut ws, &mut out);
    for i in 0..rays.len() {
        assert_eq!(out.first(i), Ok(Some(RayHit { key: 4, t: 0.0 })));
    }
    // One point query answered them all: a walk per ray would visit the
    // tree's one node once per ray.
    assert!(ws.take_stats().nodes_visited < rays.len() as u64);
    check_rays(&tree, &oracle, &rays);
}

#[test]
fn grazing_every_face_along_every_axis_hits() {
    for axis in 0..3 {
        for other in (0..3).filter(|&a| a != axis) {
            for face in [0.0, 1.0] {
                let mut o = [0.5; 3];
                o[axis] = -1.0;
                o[other] = face;
                let mut d = [0.0; 3];
                d[axis] = 1.0;
                expect(ray(o, d, f32::INFINITY), Some(1.0));
                // A negative zero in the direction changes nothing.
                let third = 3 - axis - other;
                d[third] = -0.0;
                expect(ray(o, d, f32::INFINITY), Some(1.0));
            }
        }
    }
    expect(ray([-1.0, 1.0, 0.5], [1.0, -0.0, 0.0], 10.0), Some(1.0));
}

#[test]
fn edges_and_corners_count_as_hits() {
    expect(ray([-1.0, 1.0, 1.0], [1.0, 0.0, 0.0], 10.0), Some(1.0)); // along an edge
    expect(ray([0.0, 2.0, 0.0], [1.0, -1.0, 1.0], 10.0), Some(1.0)); // touches corner (1,1,1) only
    expect(ray([2.0, 2.0, 0.5], [-1.0, 1.0, 0.0], 10.0), None); // passes beside the edge
    expect(ray([2.0, 0.0, 0.5], [-1.0, 1.0, 0.0], 10.0), Some(1.0)); // touches edge x=1,y=1 only
}

#[test]
fn origins_inside_or_on_the_box_hit_at_zero() {
    expect(ray([0.5, 0.5, 0.5], [1.0, 0.0, 0.0], 10.0), Some(0.0));
    expect(ray([1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 10.0), Some(0.0)); // on a face, pointing out
    expect(ray([1.0, 0.5, 0.5], [1.0, 2.0, 3.0], 0.0), Some(0.0)); // max_t = 0 on the face
    expect(ray([1.5, 0.5, 0.5], [-1.0, 0.0, 0.0], 0.0), None); // max_t = 0 outside
}

#[test]
fn max_t_exactly_reaching_a_face_hits_and_one_ulp_short_misses() {
    expect(ray([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 1.0), Some(1.0));
    expect(
        ray([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 1f32.next_down()),
        None,
    );
}

#[test]
fn point_and_flat_boxes_in_and_across_their_plane() {
    let point = common::aabb([5.0, 5.0, 5.0], [5.0, 5.0, 5.0]);
    let flat = common::aabb([8.0, 8.0, 8.0], [9.0, 9.0, 8.0]);
    let (tree, oracle) = unit_world::<16>(&[point, flat]);
    let cases = [
        ray([0.0, 5.0, 5.0], [1.0, 0.0, 0.0], 10.0), // through the point
        ray([5.0, 5.0, 0.0], [0.0, 0.0, 1.0], 10.0), // through the point along z
        ray([8.5, 8.5, 0.0], [0.0, 0.0, 1.0], 10.0), // across the flat box
        ray([7.0, 8.5, 8.0], [1.0, 0.0, 0.0], 10.0), // in its plane
        ray([7.0, 8.5, 8.0], [1.0, 1.0, 0.0], 0.5),  // in its plane, stops short
    ];
    for (i, r) in cases.iter().enumerate() {
        let hits = oracle.ray_hits(r).unwrap();
        let target = if i < 2 { 1 } else { 2 };
        assert_eq!(hits.iter().any(|h| h.key == target), i < 4, "case {i}");
    }
    check_rays(&tree, &oracle, &cases);
}

#[test]
fn boxes_behind_the_origin_are_missed_and_found_when_reversed() {
    expect(ray([3.0, 0.5, 0.5], [1.0, 0.0, 0.0], f32::INFINITY), None);
    expect(
        ray([3.0, 0.5, 0.5], [-1.0, 0.0, 0.0], f32::INFINITY),
        Some(2.0),
    );
}

#[test]
fn subnormal_direction_components_become_zero() {
    // Canonically (1, 0, 0): the ray runs along the face y = 1.
    expect(ray([-1.0, 1.0, 0.5], [1.0, 1e-40, 0.0], 10.0), Some(1.0));
    expect(ray([-1.0, 1.0 + 1e-6, 0.5], [1.0, -1e-40, 0.0], 10.0), None);
}

#[test]
fn bad_rays_fail_in_their_own_slot_only() {
    let (tree, oracle) = unit_world::<16>(&[]);
    let good = ray([-1.0, 0.5, 0.5], [1.0, 0.0, 0.0], 10.0);
    let batch = [
        good,
        ray([0.0; 3], [0.0; 3], 1.0),
        ray([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 1.0),
        ray([0.0; 3], [1.0, 0.0, 0.0], -1.0),
        ray([0.0; 3], [1.0, 0.0, 0.0], f32::NAN),
        good,
    ];
    let mut out = RayResults::default();
    tree.cast_rays(
        &batch,
        RayMode::First,
        &mut QueryWorkspace::default(),
        &mut out,
    );
    for i in 1..5 {
        assert_eq!(out.first(i), Err(SpatialError::InvalidRay));
        assert_eq!(out.any(i), Err(SpatialError::InvalidRay));
    }
    for i in [0, 5] {
        assert_eq!(out.first(i).unwrap(), Some(RayHit { key: 0, t: 1.0 }));
    }
    check_rays(&tree, &oracle, &batch);
}

#[test]
fn a_batch_of_only_bad_rays_on_a_deep_tree_reports_each_error() {
    let (_, tree, _) = common::town_tree(2_000, 5);
    assert!(tree.height() > 1, "the root must be an inner node");
    let batch = [
        ray([0.0; 3], [0.0; 3], 1.0),
        ray([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 1.0),
    ];
    for mode in [RayMode::First, RayMode::All { limit: None }, RayMode::Any] {
        let mut out = RayResults::default();
        tree.cast_rays(&batch, mode, &mut QueryWorkspace::default(), &mut out);
        assert_eq!(out.len(), 2);
        for i in 0..2 {
            assert_eq!(out.any(i), Err(SpatialError::InvalidRay));
        }
    }
}

#[test]
fn far_from_the_origin_hits_stay_exact() {
    let far = common::aabb([1e7, 0.0, 0.0], [1e7 + 1.0, 1.0, 1.0]);
    let tiny = common::aabb([1e5, 0.5, 0.5], [1e5 + 1e-6, 0.5 + 1e-6, 0.5 + 1e-6]);
    assert_eq!(
        tiny.min.x, tiny.max.x,
        "the tiny box collapses to a point in x"
    );
    let (tree, oracle) = unit_world::<16>(&[far, tiny]);
    let at_far = ray([1e7 - 100.0, 0.5, 0.5], [1.0, 0.0, 0.0], f32::INFINITY);
    let at_tiny = ray([0.0, 0.5, 0.5], [1.0, 0.0, 0.0], f32::INFINITY);
    let mut ws = QueryWorkspace::default();
    assert_eq!(
        tree.cast_ray(&at_far, &mut ws).unwrap(),
        Some(RayHit { key: 1, t: 100.0 })
    );
    let mut all = Vec::new();
    tree.cast_ray_all(&at_tiny, None, &mut ws, &mut all)
        .unwrap();
    assert!(all.iter().any(|h| h.key == 2 && h.t == 1e5), "{all:?}");
    check_rays(&tree, &oracle, &[at_far, at_tiny]);
}

#[test]
fn equal_t_ties_resolve_to_the_smallest_key() {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    let stacked = common::aabb([2.0, 0.0, 0.0], [3.0, 1.0, 1.0]);
    for key in [9u32, 4, 7, 5] {
        tree.insert(key, stacked).unwrap();
        oracle.insert(key, stacked);
    }
    let r = ray([0.0, 0.5, 0.5], [1.0, 0.0, 0.0], 10.0);
    assert_eq!(
        tree.cast_ray(&r, &mut QueryWorkspace::default()).unwrap(),
        Some(RayHit { key: 4, t: 2.0 })
    );
    check_rays(&tree, &oracle, &[r]);
}
