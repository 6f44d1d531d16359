//! Batches through the standard scene and the grid against single rays
//! and the oracle, and a visitor that breaks or shortens.

use super::*;

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
