//! Raycasts against the oracle: random scenes on a coarse grid where rays
//! graze faces and edges, batches with invalid rays, and the ray hard cases
//! of the contract (`docs/contract.md`).

mod common;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, QueryWorkspace, RTree, Ray, RayHit, RayMode, RayResults, SpatialError};
use glam::Vec3;
use proptest::prelude::*;

fn grid_ray() -> impl Strategy<Value = Ray> {
    let dir = (-2i32..=2, -2i32..=2, -2i32..=2)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32));
    let max_t = prop_oneof![
        (0i32..=64).prop_map(|t| t as f32 * 0.25),
        Just(f32::INFINITY)
    ];
    (common::grid_point(), dir, max_t).prop_map(|(origin, dir, max_t)| Ray { origin, dir, max_t })
}

fn build<const W: usize>(boxes: &[Aabb]) -> (RTree<u32, W>, BruteForce<u32>) {
    let mut tree = RTree::<u32, W>::with_settings(Default::default()).unwrap();
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        tree.insert(i as u32, *b).unwrap();
        oracle.insert(i as u32, *b);
    }
    (tree, oracle)
}

/// Every single-ray and batched answer equals the oracle's.
fn check_rays<const W: usize>(tree: &RTree<u32, W>, oracle: &BruteForce<u32>, rays: &[Ray]) {
    let mut ws = QueryWorkspace::default();
    let mut all = Vec::new();
    for ray in rays {
        let expected = oracle.ray_hits(ray);
        assert_eq!(
            tree.cast_ray(ray, &mut ws),
            expected.clone().map(|h| h.first().copied()),
            "{ray:?}"
        );
        assert_eq!(
            tree.cast_ray_all(ray, None, &mut ws, &mut all)
                .map(|_| all.clone()),
            expected.clone()
        );
        assert_eq!(
            tree.ray_hits_any(ray, &mut ws),
            expected.map(|h| !h.is_empty())
        );
    }
    let mut out = RayResults::default();
    for mode in [
        RayMode::First,
        RayMode::All { limit: None },
        RayMode::All { limit: Some(2) },
        RayMode::Any,
    ] {
        tree.cast_rays(rays, mode, &mut ws, &mut out);
        assert_eq!(out.len(), rays.len());
        for (i, ray) in rays.iter().enumerate() {
            let expected = oracle.ray_hits(ray);
            match (&expected, mode) {
                (Err(e), _) => assert_eq!(out.hits(i).map(<[_]>::to_vec), Err(*e)),
                (Ok(hits), RayMode::First) => {
                    assert_eq!(out.hits(i).unwrap(), &hits[..hits.len().min(1)])
                }
                (Ok(hits), RayMode::All { limit }) => {
                    let cut = limit.unwrap_or(usize::MAX).min(hits.len());
                    assert_eq!(out.hits(i).unwrap(), &hits[..cut], "ray {i} {ray:?}");
                }
                (Ok(hits), RayMode::Any) => {
                    assert!(out.hits(i).unwrap().is_empty());
                    assert_eq!(out.any(i).unwrap(), !hits.is_empty());
                }
            }
            if let Ok(hits) = &expected {
                assert_eq!(out.any(i).unwrap(), !hits.is_empty());
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn rays_on_a_grid_match_the_oracle(
        boxes in prop::collection::vec(common::grid_box(), 0..250),
        rays in prop::collection::vec(grid_ray(), 1..40),
    ) {
        let (tree, oracle) = build::<4>(&boxes);
        check_rays(&tree, &oracle, &rays);
        let (tree, oracle) = build::<8>(&boxes);
        check_rays(&tree, &oracle, &rays);
    }
}

/// Batches whose rays start at one origin (a corner, the centre or the
/// far corner of one of `boxes`, or any grid point), as camera rays do, in
/// runs long enough and too short to be answered from one point query,
/// with directions beyond unit length too.
fn shared_origin_rays(boxes: Vec<Aabb>) -> impl Strategy<Value = Vec<Ray>> {
    let count = boxes.len();
    let origin = prop_oneof![
        common::grid_point(),
        (0..count, 0..3usize).prop_map(move |(i, corner)| {
            let b = boxes[i];
            [b.min, (b.min + b.max) * 0.5, b.max][corner]
        }),
    ];
    let dir = (-2i32..=2, -2i32..=2, -2i32..=2, 0usize..4).prop_map(|(x, y, z, scale)| {
        Vec3::new(x as f32, y as f32, z as f32) * [1.0, 0.5, 1e-20, 1e30][scale]
    });
    let max_t = prop_oneof![Just(0.0), Just(3.0), Just(f32::INFINITY)];
    (origin, prop::collection::vec((dir, max_t), 1..20)).prop_map(|(origin, rays)| {
        rays.into_iter()
            .map(|(dir, max_t)| Ray { origin, dir, max_t })
            .collect()
    })
}

fn scene_with_shared_origins() -> impl Strategy<Value = (Vec<Aabb>, Vec<Ray>)> {
    prop::collection::vec(common::grid_box(), 1..250).prop_flat_map(|boxes| {
        let groups = prop::collection::vec(shared_origin_rays(boxes.clone()), 1..4);
        (Just(boxes), groups.prop_map(|groups| groups.concat()))
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn rays_sharing_an_origin_match_the_oracle((boxes, rays) in scene_with_shared_origins()) {
        let (tree, oracle) = build::<8>(&boxes);
        check_rays(&tree, &oracle, &rays);
        // Inserted from the last key down, so that entries are met in
        // about the opposite order of their keys and ties need the keys.
        let mut tree = RTree::<u32>::new();
        for (i, b) in boxes.iter().enumerate().rev() {
            tree.insert(i as u32, *b).unwrap();
        }
        check_rays(&tree, &oracle, &rays);
    }
}

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

/// The unit box as key 0 among 1,000 distractors away from it.
fn unit_world<const W: usize>(extra: &[Aabb]) -> (RTree<u32, W>, BruteForce<u32>) {
    let mut rng = bevy_rtree::scene::SceneRng::new(11);
    let mut boxes = vec![common::aabb([0.0; 3], [1.0; 3])];
    boxes.extend_from_slice(extra);
    while boxes.len() < 1_000 + 1 + extra.len() {
        let c = Vec3::new(
            rng.range(-60.0, 60.0),
            rng.range(-60.0, 60.0),
            rng.range(-60.0, 60.0),
        );
        if c.abs().max_element() > 5.0 {
            boxes.push(Aabb::new(c, c + Vec3::splat(rng.range(0.0, 2.0))).unwrap());
        }
    }
    build::<W>(&boxes)
}

/// Asserts the ray hits key 0 first at `t` (or misses it), and that every
/// answer, single and batched, equals the oracle's.
/// Both at width 8 and at the default width 16.
fn expect(ray: Ray, unit_t: Option<f32>) {
    let (narrow, oracle) = unit_world::<8>(&[]);
    let hits = oracle.ray_hits(&ray).unwrap();
    let unit = hits.iter().find(|h| h.key == 0).map(|h| h.t);
    assert_eq!(unit, unit_t, "{ray:?}");
    check_rays(&narrow, &oracle, &[ray]);
    let (wide, oracle) = unit_world::<16>(&[]);
    check_rays(&wide, &oracle, &[ray]);
    // Alone, in a tree whose root is its leaf.
    let (alone, oracle) = build::<16>(&[common::aabb([0.0; 3], [1.0; 3])]);
    check_rays(&alone, &oracle, &[ray]);
}

fn ray(o: [f32; 3], d: [f32; 3], max_t: f32) -> Ray {
    Ray {
        origin: Vec3::from(o),
        dir: Vec3::from(d),
        max_t,
    }
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

#[test]
fn batches_of_the_standard_scene_match_single_rays() {
    let (mut scene, tree, _) = common::town_tree(20_000, 4);
    let mut rays = scene.incoherent_rays(300);
    rays.extend(scene.coherent_rays());
    let mut ws = QueryWorkspace::default();
    let mut out = RayResults::default();
    tree.cast_rays(&rays, RayMode::First, &mut ws, &mut out);
    let mut hits = 0;
    for (i, r) in rays.iter().enumerate() {
        let single = tree.cast_ray(r, &mut ws).unwrap();
        assert_eq!(out.first(i).unwrap(), single);
        hits += single.is_some() as usize;
    }
    assert!(hits > 100, "the scene's rays hit things ({hits})");
}

/// Batches big enough that runs of over 1,024 rays are tested together
/// (the batched path), in every mode, equal to single rays: among them
/// 2,000 rays looking down from distinct origins, one direction's group.
#[test]
fn large_batches_match_single_rays_in_every_mode() {
    let (mut scene, tree, _) = common::town_tree(20_000, 6);
    let mut rays = Vec::new();
    for _ in 0..4 {
        scene.advance_frame();
        rays.extend(scene.coherent_rays());
    }
    rays.extend(scene.incoherent_rays(500));
    let mut rng = bevy_rtree::scene::SceneRng::new(17);
    let down: Vec<Ray> = (0..2_000)
        .map(|_| {
            let origin = Vec3::new(rng.range(0.0, 2_000.0), 95.0, rng.range(0.0, 2_000.0));
            let dir = Vec3::new(rng.range(-0.3, 0.3), -1.0, rng.range(-0.3, 0.3));
            ray(origin.to_array(), dir.to_array(), 200.0)
        })
        .collect();
    // Tested together, the downward rays visit the root once, not once per
    // ray: proof that the batched path ran.
    let mut ws = QueryWorkspace::default();
    tree.cast_rays(&down, RayMode::First, &mut ws, &mut RayResults::default());
    let together = ws.take_stats().nodes_visited;
    for r in &down {
        tree.cast_ray(r, &mut ws).unwrap();
    }
    let alone = ws.take_stats().nodes_visited;
    assert!(
        together + 1_000 < alone,
        "batched {together} nodes, alone {alone}"
    );
    rays.extend(down);
    let mut ws = QueryWorkspace::default();
    let mut out = RayResults::default();
    let mut all = Vec::new();
    for mode in [RayMode::First, RayMode::All { limit: None }, RayMode::Any] {
        tree.cast_rays(&rays, mode, &mut ws, &mut out);
        for (i, ray) in rays.iter().enumerate() {
            match mode {
                RayMode::First => {
                    assert_eq!(out.first(i).unwrap(), tree.cast_ray(ray, &mut ws).unwrap())
                }
                RayMode::All { .. } => {
                    tree.cast_ray_all(ray, None, &mut ws, &mut all).unwrap();
                    assert_eq!(out.hits(i).unwrap(), &all[..], "ray {i}");
                }
                RayMode::Any => assert_eq!(
                    out.any(i).unwrap(),
                    tree.ray_hits_any(ray, &mut ws).unwrap()
                ),
            }
        }
    }
}

/// The batched path (runs of over 1,024 rays tested together) against the
/// oracle, not only against single rays: a grid scene where rays graze
/// faces and edges and tie at equal `t`, 1,300 grid rays (some of length
/// 0, some sharing an origin), every mode, widths 4, 8 and 16.
#[test]
fn large_batches_of_grid_rays_match_the_oracle() {
    let mut rng = bevy_rtree::scene::SceneRng::new(41);
    let mut grid = |lo: i32, hi: i32| (lo + rng.below((hi - lo + 1) as usize) as i32) as f32 * 0.25;
    let boxes: Vec<Aabb> = (0..600)
        .map(|_| {
            let min = Vec3::new(grid(-32, 32), grid(-32, 32), grid(-32, 32));
            let extent = Vec3::new(grid(0, 8), grid(0, 8), grid(0, 8));
            Aabb::new(min, min + extent).unwrap()
        })
        .collect();
    let shared = Vec3::new(grid(-8, 8), grid(-8, 8), grid(-8, 8));
    let rays: Vec<Ray> = (0..1_300)
        .map(|i| {
            let origin = if i % 5 == 0 {
                shared
            } else {
                Vec3::new(grid(-40, 40), grid(-40, 40), grid(-40, 40))
            };
            // Most look down +x (one direction's group, batched together
            // once it has over 1,024 rays); the rest anywhere.
            let dir = if i % 13 == 0 {
                Vec3::new(grid(-8, 8), grid(-8, 8), grid(-8, 8)) * 4.0
            } else {
                Vec3::new(grid(5, 8), grid(-4, 4), grid(-4, 4)) * 4.0
            };
            let max_t = match i % 7 {
                0 => 0.0,
                1 => f32::INFINITY,
                _ => grid(0, 64),
            };
            Ray { origin, dir, max_t }
        })
        .collect();
    let (tree, oracle) = build::<4>(&boxes);
    let hit = rays
        .iter()
        .filter(|r| oracle.ray_first(r).is_ok_and(|h| h.is_some()))
        .count();
    assert!(hit >= 200, "the rays hit the scene ({hit})");
    // Proof that the batched path ran: one ray at a time, the batch would
    // visit exactly the nodes the single rays do; tested together, rays
    // share node visits.
    let mut ws = QueryWorkspace::default();
    tree.cast_rays(&rays, RayMode::First, &mut ws, &mut RayResults::default());
    let together = ws.take_stats().nodes_visited;
    for r in &rays {
        let _ = tree.cast_ray(r, &mut ws);
    }
    let alone = ws.take_stats().nodes_visited;
    assert!(together < alone, "batched {together}, alone {alone}");
    check_rays(&tree, &oracle, &rays);
    let (tree, oracle) = build::<8>(&boxes);
    check_rays(&tree, &oracle, &rays);
    let (tree, oracle) = build::<16>(&boxes);
    check_rays(&tree, &oracle, &rays);
}

/// The hard cases above mostly run along an axis, where a direction
/// component of zero sends the walk to the four-lane test; these run
/// diagonally, so that the wide lane tests (AVX, AVX-512) take them too,
/// at widths 4, 8 and 16. Each answer is known exactly.
#[test]
fn diagonal_hard_cases_are_exact_on_every_lane_test() {
    let far = common::aabb([1e7, 0.0, 0.0], [1e7 + 1.0, 1.0, 1.0]);
    let point = common::aabb([2.0, 2.0, 2.0], [2.0, 2.0, 2.0]);
    // Key 0 is the unit box, 1 the far box, 2 the point box.
    let cases = [
        // The corner (0, 0, 0) reached exactly at max_t, then one ulp short.
        (ray([-1.0; 3], [1.0; 3], 1.0), Some((0, 1.0))),
        (ray([-1.0; 3], [1.0; 3], 1f32.next_down()), None),
        // Far from the origin: (1e7, 0.5, 0.5) at t = 100 exactly.
        (
            ray([1e7 - 100.0, -99.5, -99.5], [1.0; 3], f32::INFINITY),
            Some((1, 100.0)),
        ),
        // A point box touched at t = 1 from the far side.
        (ray([3.0; 3], [-1.0; 3], f32::INFINITY), Some((2, 1.0))),
        // Along the face z = 1 of the unit box, sinking into it by 1e-30
        // a metre: inside from t = 1; then one ulp of 1 above the face.
        (
            ray([-1.0, -1.0, 1.0], [1.0, 1.0, -1e-30], 10.0),
            Some((0, 1.0)),
        ),
        (
            ray([-1.0, -1.0, 1f32.next_up()], [1.0, 1.0, -1e-30], 10.0),
            None,
        ),
        // Rising out of it by 1e-30 a metre: outside for every t > 0.
        (ray([-1.0, -1.0, 1.0], [1.0, 1.0, 1e-30], 10.0), None),
    ];
    let first = |tree_hit: Option<RayHit<u32>>| tree_hit.map(|h| (h.key, h.t));
    let mut ws = QueryWorkspace::default();
    for (r, expected) in cases {
        let (tree4, oracle) = unit_world::<4>(&[far, point]);
        let (tree8, _) = unit_world::<8>(&[far, point]);
        let (tree16, _) = unit_world::<16>(&[far, point]);
        assert_eq!(
            first(tree4.cast_ray(&r, &mut ws).unwrap()),
            expected,
            "{r:?}, width 4"
        );
        assert_eq!(
            first(tree8.cast_ray(&r, &mut ws).unwrap()),
            expected,
            "{r:?}, width 8"
        );
        assert_eq!(
            first(tree16.cast_ray(&r, &mut ws).unwrap()),
            expected,
            "{r:?}, width 16"
        );
        check_rays(&tree4, &oracle, &[r]);
        check_rays(&tree8, &oracle, &[r]);
        check_rays(&tree16, &oracle, &[r]);
    }
}

/// `visit_ray` stops where its visitor breaks, and a visitor that returns
/// a shorter limit is only shown hits up to it: through the town, every
/// hit of the oracle up to the first break, in `(t, key)` order.
#[test]
fn a_ray_visitor_that_breaks_or_shortens_is_obeyed() {
    use std::ops::ControlFlow;
    let (mut scene, tree, _) = common::town_tree(20_000, 8);
    let mut oracle = BruteForce::default();
    for (_, key, aabb) in tree.iter() {
        oracle.insert(key, aabb);
    }
    let mut ws = QueryWorkspace::default();
    let mut checked = 0;
    for r in scene.incoherent_rays(1_000) {
        let hits = oracle.ray_hits(&r).unwrap();
        if hits.len() < 2 {
            continue;
        }
        checked += 1;
        // Break at the second hit seen: exactly two calls.
        let mut calls = 0;
        tree.visit_ray(&r, &mut ws, |_, _| {
            calls += 1;
            if calls == 2 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(f32::INFINITY)
            }
        })
        .unwrap();
        assert_eq!(calls, 2);
        // Shortened to the second hit's t: nothing beyond it is shown, and
        // every hit up to it is.
        let limit = hits[1].t;
        let mut seen = Vec::new();
        tree.visit_ray(&r, &mut ws, |key, t| {
            seen.push(RayHit { key, t });
            ControlFlow::Continue(limit)
        })
        .unwrap();
        let within: Vec<RayHit<u32>> = hits.iter().copied().filter(|h| h.t <= limit).collect();
        let shown: Vec<RayHit<u32>> = seen.iter().copied().filter(|h| h.t <= limit).collect();
        let mut shown_sorted = shown.clone();
        shown_sorted.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.key.cmp(&b.key)));
        assert_eq!(shown_sorted, within, "{r:?}");
        // The limit shrank at the first call: nothing beyond it after.
        assert!(seen[1..].iter().all(|h| h.t <= limit), "{seen:?}");
    }
    assert!(checked > 20, "rays with two hits or more: {checked}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// The filtered ray queries answer as the oracle does with the
    /// filtered-out keys left out (a filter worked out here, not through
    /// the crate): the first allowed hit, the first `limit` allowed hits,
    /// whether any allowed one is hit; on a grid, where ties are common.
    #[test]
    fn filtered_rays_answer_as_if_the_left_out_keys_were_not_there(
        boxes in prop::collection::vec(common::grid_box(), 1..200),
        rays in prop::collection::vec(grid_ray(), 1..30),
        skip in 2u32..5,
        limit in prop::option::of(0usize..4),
    ) {
        let (tree, oracle) = build::<8>(&boxes);
        let allowed = |key: u32| !key.is_multiple_of(skip);
        let mut ws = QueryWorkspace::default();
        let mut all = Vec::new();
        for ray in &rays {
            let expected: Result<Vec<RayHit<u32>>, SpatialError> = oracle
                .ray_hits(ray)
                .map(|hits| hits.into_iter().filter(|h| allowed(h.key)).collect());
            prop_assert_eq!(
                tree.cast_ray_where(ray, &mut ws, allowed),
                expected.clone().map(|h| h.first().copied())
            );
            let got = tree
                .cast_ray_all_where(ray, limit, &mut ws, &mut all, allowed)
                .map(|_| all.clone());
            let cut = expected.clone().map(|h| {
                let n = limit.unwrap_or(usize::MAX).min(h.len());
                h[..n].to_vec()
            });
            prop_assert_eq!(got, cut);
            prop_assert_eq!(
                tree.ray_hits_any_where(ray, &mut ws, allowed),
                expected.map(|h| !h.is_empty())
            );
        }
    }
}
