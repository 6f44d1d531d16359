//! The parallel queries (feature `parallel`) return exactly what the
//! single-threaded ones return, in the same order: on random grid scenes
//! with every split forced, and on the standard scene with the default
//! thresholds.
#![cfg(feature = "parallel")]

mod common;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, ParallelWorkspace, QueryWorkspace, RTree, Ray, RayMode,
    RayResults, SpatialError,
};
use glam::{EulerRot, Quat, Vec3};
use proptest::prelude::*;

const RAY_MODES: [RayMode; 4] = [
    RayMode::First,
    RayMode::All { limit: None },
    RayMode::All { limit: Some(2) },
    RayMode::Any,
];

/// Slot by slot: the same error, or the same hits and the same "any".
fn assert_same_rays(a: &RayResults<u32>, b: &RayResults<u32>) {
    assert_eq!(a.len(), b.len());
    for i in 0..a.len() {
        assert_eq!(a.hits(i), b.hits(i), "slot {i}");
        assert_eq!(a.any(i), b.any(i), "slot {i}");
    }
}

/// A workspace that splits everything it can, however small.
fn split_everything() -> ParallelWorkspace<u32> {
    ParallelWorkspace::default()
        .with_min_rays_per_task(1)
        .with_min_entries_to_split(0)
        .with_min_view_entries_to_split(0)
}

fn build(boxes: &[Aabb], first_key: u32) -> (RTree<u32, 4>, BruteForce<u32>) {
    let mut tree = RTree::<u32, 4>::with_settings(Default::default()).unwrap();
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        tree.insert(first_key + i as u32, *b).unwrap();
        oracle.insert(first_key + i as u32, *b);
    }
    (tree, oracle)
}

fn grid_ray() -> impl Strategy<Value = Ray> {
    let dir = (-2i32..=2, -2i32..=2, -2i32..=2)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32));
    let max_t = prop_oneof![
        (0i32..=64).prop_map(|t| t as f32 * 0.25),
        Just(f32::INFINITY),
        Just(-1.0f32),
    ];
    (common::grid_point(), dir, max_t).prop_map(|(origin, dir, max_t)| Ray { origin, dir, max_t })
}

fn view() -> impl Strategy<Value = Frustum> {
    (
        common::grid_point(),
        0.0f32..std::f32::consts::TAU,
        -1.4f32..1.4,
        20f32..120.0,
    )
        .prop_map(|(eye, yaw, pitch, fov)| {
            let rotation = Quat::from_euler(EulerRot::YXZ, yaw, pitch, 0.0);
            Frustum::perspective(eye, rotation, fov.to_radians(), 1.5, 0.1, 12.0).unwrap()
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn parallel_rays_equal_single_threaded_rays(
        boxes in prop::collection::vec(common::grid_box(), 0..300),
        rays in prop::collection::vec(grid_ray(), 0..60),
    ) {
        let (tree, _) = build(&boxes, 0);
        let mut pws = split_everything();
        for mode in RAY_MODES {
            let mut serial = RayResults::default();
            tree.cast_rays(&rays, mode, &mut QueryWorkspace::default(), &mut serial);
            let mut parallel = RayResults::default();
            tree.par_cast_rays(&rays, mode, &mut pws, &mut parallel);
            assert_same_rays(&serial, &parallel);
        }
    }

    #[test]
    fn parallel_culling_equals_single_threaded_culling(
        boxes in prop::collection::vec(common::grid_box(), 0..400),
        views in prop::collection::vec(view(), 1..11),
    ) {
        let (tree, oracle) = build(&boxes, 0);
        let mut pws = split_everything();
        for mode in [CullMode::Conservative, CullMode::Exact] {
            let mut serial = vec![Vec::new(); views.len()];
            tree.visible_into(&views, mode, &mut QueryWorkspace::default(), &mut serial);
            let mut parallel = vec![Vec::new(); views.len()];
            tree.par_visible_into(&views, mode, &mut pws, &mut parallel);
            // Same keys in the same order, and both right.
            prop_assert_eq!(&serial, &parallel);
            for (view, mut keys) in views.iter().zip(parallel) {
                keys.sort_unstable();
                prop_assert_eq!(keys, oracle.visible(view, mode));
            }
        }
    }

    #[test]
    fn parallel_joins_equal_single_threaded_joins(
        a in prop::collection::vec(common::grid_box(), 0..400),
        b in prop::collection::vec(common::grid_box(), 0..120),
        d in prop_oneof![Just(0.0f32), (1i32..=8).prop_map(|d| d as f32 * 0.25)],
    ) {
        let (tree_a, oracle_a) = build(&a, 0);
        let (tree_b, oracle_b) = build(&b, 10_000);
        let mut pws = split_everything();
        for mode in [JoinMode::Euclidean, JoinMode::Chebyshev] {
            let mut serial = Vec::new();
            tree_a.self_join_into(d, mode, &mut QueryWorkspace::default(), &mut serial).unwrap();
            let mut parallel = Vec::new();
            tree_a.par_self_join_into(d, mode, &mut pws, &mut parallel).unwrap();
            prop_assert_eq!(&serial, &parallel);
            parallel.sort_unstable();
            prop_assert_eq!(parallel, oracle_a.self_join(d, mode).unwrap());

            let mut serial = Vec::new();
            tree_a.cross_join_into(&tree_b, d, mode, &mut QueryWorkspace::default(), &mut serial).unwrap();
            let mut parallel = Vec::new();
            tree_a.par_cross_join_into(&tree_b, d, mode, &mut pws, &mut parallel).unwrap();
            prop_assert_eq!(&serial, &parallel);
            parallel.sort_unstable();
            prop_assert_eq!(parallel, oracle_a.cross_join(&oracle_b, d, mode).unwrap());
        }
    }
}

/// Splits happen when the machine has threads to split over.
fn expect_split(pws: &ParallelWorkspace<u32>) {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if cores > 1 {
        assert!(pws.last_split() > 1, "ran as {} task(s)", pws.last_split());
    } else {
        assert_eq!(pws.last_split(), 1);
    }
}

#[test]
fn the_standard_scene_splits_and_answers_the_same() {
    let (mut scene, tree, _) = common::town_tree(20_000, 7);
    let mut pws = ParallelWorkspace::default();
    let mut ws = QueryWorkspace::default();

    let rays = scene.incoherent_rays(1_000);
    for mode in RAY_MODES {
        let mut serial = RayResults::default();
        tree.cast_rays(&rays, mode, &mut ws, &mut serial);
        let mut parallel = RayResults::default();
        tree.par_cast_rays(&rays, mode, &mut pws, &mut parallel);
        expect_split(&pws);
        assert_same_rays(&serial, &parallel);
    }

    // Ten views of 20,000 entries reach the default 200,000 view-entries
    // and span two passes of eight; one view stays on the calling thread.
    let views: Vec<Frustum> = (0..10)
        .map(|i| {
            let rotation = Quat::from_rotation_y(i as f32 * 2.0);
            Frustum::perspective(TownScene::eye(), rotation, 1.0, 1.8, 0.1, 500.0).unwrap()
        })
        .collect();
    for (views, splits) in [(&views[..], true), (&views[..1], false)] {
        let mut serial = vec![Vec::new(); views.len()];
        tree.visible_into(views, CullMode::Conservative, &mut ws, &mut serial);
        let mut parallel = vec![Vec::new(); views.len()];
        tree.par_visible_into(views, CullMode::Conservative, &mut pws, &mut parallel);
        if splits {
            expect_split(&pws);
        } else {
            assert_eq!(pws.last_split(), 1);
        }
        assert_eq!(serial, parallel);
        assert!(parallel.iter().all(|keys| !keys.is_empty()));
    }

    let mut serial = Vec::new();
    tree.self_join_into(1.0, JoinMode::Euclidean, &mut ws, &mut serial)
        .unwrap();
    let mut parallel = Vec::new();
    tree.par_self_join_into(1.0, JoinMode::Euclidean, &mut pws, &mut parallel)
        .unwrap();
    expect_split(&pws);
    assert!(!parallel.is_empty());
    assert_eq!(serial, parallel);

    // Work done is counted over every task.
    assert!(pws.take_stats().nodes_visited > 0);
    assert_eq!(pws.stats().nodes_visited, 0);
}

#[test]
fn small_batches_run_on_the_calling_thread() {
    let (mut scene, tree, _) = common::town_tree(500, 3);
    let mut pws = ParallelWorkspace::default();
    let mut out = RayResults::default();
    tree.par_cast_rays(
        &scene.incoherent_rays(10),
        RayMode::First,
        &mut pws,
        &mut out,
    );
    assert_eq!((pws.last_split(), out.len()), (1, 10));
    let mut pairs = Vec::new();
    tree.par_self_join_into(0.5, JoinMode::Euclidean, &mut pws, &mut pairs)
        .unwrap();
    assert_eq!(pws.last_split(), 1);
    let mut oracle = BruteForce::default();
    for (_, key, aabb) in tree.iter() {
        oracle.insert(key, aabb);
    }
    pairs.sort_unstable();
    assert_eq!(pairs, oracle.self_join(0.5, JoinMode::Euclidean).unwrap());
}

#[test]
fn rays_answered_at_their_shared_origin_are_not_split() {
    let (scene, mut tree, _) = common::town_tree(5_000, 11);
    let eye = TownScene::eye();
    // An entry around the eye: every camera ray has a hit at t = 0.
    let room = Aabb::new(eye - Vec3::splat(2.0), eye + Vec3::splat(2.0)).unwrap();
    tree.insert(u32::MAX, room).unwrap();
    let inside = scene.coherent_rays_from(eye);
    // Above the world's ceiling (100 m), in no entry; the rays look down.
    let above = eye + Vec3::new(0.0, 150.0, 0.0);
    let clear = scene.coherent_rays_from(above);
    assert!(!tree.containing_point(eye).is_empty());
    assert!(tree.containing_point(above).is_empty());
    // Longer than unit directions may hit entries that do not hold the
    // origin at t = 0, so these rays still walk.
    let stretched: Vec<Ray> = inside
        .iter()
        .map(|ray| Ray::new(ray.origin, ray.dir * 4.0, ray.max_t).unwrap())
        .collect();
    let mixed: Vec<Ray> = inside.iter().chain(&clear).copied().collect();

    let mut pws = ParallelWorkspace::default();
    let mut ws = QueryWorkspace::default();
    for (rays, splits) in [
        (&inside, false),
        (&clear, true),
        (&stretched, true),
        (&mixed, true),
    ] {
        for mode in RAY_MODES {
            let mut serial = RayResults::default();
            ws.take_stats();
            tree.cast_rays(rays, mode, &mut ws, &mut serial);
            let mut parallel = RayResults::default();
            pws.take_stats();
            tree.par_cast_rays(rays, mode, &mut pws, &mut parallel);
            assert_same_rays(&serial, &parallel);
            // Every hit is counted for all-hits, so nothing is answered early.
            if splits || matches!(mode, RayMode::All { .. }) {
                expect_split(&pws);
            } else {
                assert_eq!(pws.last_split(), 1, "{mode:?}");
                // Deciding not to split is no work of the batch's.
                assert_eq!(pws.take_stats(), ws.take_stats(), "{mode:?}");
            }
        }
    }
}

#[test]
fn bad_input_fails_in_its_own_place() {
    let (mut scene, tree, _) = common::town_tree(5_000, 5);
    let mut pws = split_everything();
    let mut pairs = vec![(1, 2)];
    for bad in [f32::NAN, -1.0, f32::INFINITY] {
        assert_eq!(
            tree.par_self_join_into(bad, JoinMode::Euclidean, &mut pws, &mut pairs),
            Err(SpatialError::InvalidDistance)
        );
        assert_eq!(
            tree.par_cross_join_into(&tree, bad, JoinMode::Euclidean, &mut pws, &mut pairs),
            Err(SpatialError::InvalidDistance)
        );
    }
    assert_eq!(pairs, [(1, 2)], "a refused join appends nothing");

    // Bad rays spread over every run keep their slots.
    let mut rays = scene.incoherent_rays(200);
    for ray in rays.iter_mut().step_by(7) {
        ray.dir = Vec3::ZERO;
    }
    let mut out = RayResults::default();
    tree.par_cast_rays(&rays, RayMode::First, &mut pws, &mut out);
    expect_split(&pws);
    for (i, ray) in rays.iter().enumerate() {
        if i % 7 == 0 {
            assert_eq!(out.first(i), Err(SpatialError::InvalidRay));
        } else {
            assert_eq!(
                out.first(i),
                tree.cast_ray(ray, &mut QueryWorkspace::default())
            );
        }
    }
}

/// A view over the whole scene (every node inside every plane, as an
/// overview camera's or a light's) is split at the root's children, which
/// are inside every plane already, and the answer is the single-threaded
/// one in the same order.
#[test]
fn a_view_that_holds_the_whole_scene_splits_and_answers_the_same() {
    let (_, tree, _) = common::town_tree(20_000, 9);
    // High above the town's middle, looking straight down, far enough to
    // hold all of it.
    let above = Vec3::new(1000.0, 5000.0, 1000.0);
    let down = Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2);
    let view = Frustum::perspective(above, down, 1.2, 1.0, 1.0, 1e5).unwrap();
    let mut ws = QueryWorkspace::default();
    let mut serial = vec![Vec::new()];
    tree.visible_into(&[view], CullMode::Conservative, &mut ws, &mut serial);
    assert_eq!(serial[0].len(), 20_000, "the view holds every entry");
    let mut pws = split_everything();
    let mut parallel = vec![Vec::new()];
    tree.par_visible_into(&[view], CullMode::Conservative, &mut pws, &mut parallel);
    expect_split(&pws);
    assert_eq!(serial, parallel);
}
