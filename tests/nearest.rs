//! Sphere overlap, within-radius and nearest neighbours against the oracle:
//! random scenes, grid scenes where faces coincide and distances tie, trees
//! after inserts, moves and removals, and the named edge cases (ties, points
//! inside boxes, inclusive limits, empty trees, bad input).

mod common;

use std::ops::ControlFlow;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, Neighbor, ProxyId, QueryWorkspace, RTree, SpatialError, TreeSettings};
use glam::Vec3;
use proptest::prelude::*;

/// One query of every family: sphere / within-radius with `radius`, nearest
/// with `k`, without and with `max_distance`.
#[derive(Clone, Copy, Debug)]
struct Query {
    point: Vec3,
    radius: f32,
    k: usize,
    max_distance: f32,
}

/// A change to a live entry, picked by index modulo the live count:
/// `Some(box)` moves it there, `None` removes it.
type Churn = (usize, Option<Aabb>);

/// A tree (and the oracle) after inserting `boxes` as keys `0..`, then
/// applying `churn`, with `validate()` after every mutation.
fn churned<const W: usize>(boxes: &[Aabb], churn: &[Churn]) -> (RTree<u32, W>, BruteForce<u32>) {
    let mut tree = RTree::<u32, W>::with_settings(TreeSettings::default()).unwrap();
    let mut oracle = BruteForce::default();
    let mut live: Vec<(u32, ProxyId)> = Vec::new();
    for (i, b) in boxes.iter().enumerate() {
        live.push((i as u32, tree.insert(i as u32, *b).unwrap()));
        oracle.insert(i as u32, *b);
    }
    tree.validate().unwrap();
    for (pick, change) in churn {
        if live.is_empty() {
            break;
        }
        let slot = pick % live.len();
        let (key, id) = live[slot];
        match change {
            Some(b) => {
                tree.update(id, *b).unwrap();
                oracle.update(key, *b);
            }
            None => {
                assert_eq!(tree.remove(id), Ok(key));
                oracle.remove(key);
                live.swap_remove(slot);
            }
        }
        tree.validate().unwrap();
    }
    assert_eq!(tree.len(), oracle.len());
    (tree, oracle)
}

/// Every answer of every family equals the oracle's, through every
/// convenience, with one workspace reused throughout.
fn check<const W: usize>(tree: &RTree<u32, W>, oracle: &BruteForce<u32>, queries: &[Query]) {
    let mut ws = QueryWorkspace::default();
    let mut keys = Vec::new();
    let mut near = Vec::new();
    for q in queries {
        let (p, r, k) = (q.point, q.radius, q.k);
        let sphere = oracle.overlapping_sphere(p, r).unwrap();
        assert_eq!(tree.overlapping_sphere(p, r).unwrap(), sphere, "{q:?}");
        keys.clear();
        tree.overlapping_sphere_into(p, r, &mut ws, &mut keys)
            .unwrap();
        keys.sort_unstable();
        assert_eq!(keys, sphere);
        assert_eq!(
            tree.any_overlapping_sphere(p, r, &mut ws).unwrap(),
            !sphere.is_empty()
        );

        let within = oracle.within_radius(p, r).unwrap();
        assert_eq!(tree.within_radius(p, r).unwrap(), within, "{q:?}");
        tree.within_radius_into(p, r, &mut ws, &mut near).unwrap();
        assert_eq!(near, within);
        assert_eq!(
            within
                .iter()
                .map(|n| n.key)
                .collect::<std::collections::BTreeSet<_>>(),
            sphere.iter().copied().collect(),
            "within-radius is the sphere predicate"
        );

        for max in [None, Some(q.max_distance)] {
            let expected = oracle.nearest(p, k, max).unwrap();
            assert_eq!(tree.nearest(p, k, max).unwrap(), expected, "{q:?} {max:?}");
            tree.nearest_into(p, k, max, &mut ws, &mut near).unwrap();
            assert_eq!(near, expected);
        }
        // The same predicate again: nearest within r is within-radius, cut.
        assert_eq!(
            tree.nearest(p, k, Some(r)).unwrap(),
            within[..k.min(within.len())]
        );
    }
}

fn random_box() -> impl Strategy<Value = Aabb> {
    (
        prop::array::uniform3(-50.0f32..50.0),
        prop::array::uniform3(0.0f32..8.0),
    )
        .prop_map(|(min, extent)| {
            let min = Vec3::from(min);
            Aabb::new(min, min + Vec3::from(extent)).unwrap()
        })
}

fn random_query() -> impl Strategy<Value = Query> {
    (
        prop::array::uniform3(-70.0f32..70.0),
        0.0f32..30.0,
        1usize..40,
        0.0f32..30.0,
    )
        .prop_map(|(point, radius, k, max_distance)| Query {
            point: Vec3::from(point),
            radius,
            k,
            max_distance,
        })
}

/// Grid points and radii that are multiples of 0.25: distances tie often and
/// land exactly on the limit.
fn grid_query() -> impl Strategy<Value = Query> {
    (common::grid_point(), 0i32..=24, 1usize..=24, 0i32..=24).prop_map(
        |(point, radius, k, max_distance)| Query {
            point,
            radius: radius as f32 * 0.25,
            k,
            max_distance: max_distance as f32 * 0.25,
        },
    )
}

fn churn(boxes: impl Strategy<Value = Aabb>) -> impl Strategy<Value = Vec<Churn>> {
    prop::collection::vec((any::<usize>(), prop::option::weighted(0.6, boxes)), 0..60)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn random_scenes_match_the_oracle(
        boxes in prop::collection::vec(random_box(), 0..250),
        changes in churn(random_box()),
        queries in prop::collection::vec(random_query(), 1..16),
    ) {
        let (tree, oracle) = churned::<4>(&boxes, &changes);
        check(&tree, &oracle, &queries);
        let (tree, oracle) = churned::<8>(&boxes, &changes);
        check(&tree, &oracle, &queries);
    }

    #[test]
    fn grid_scenes_with_ties_match_the_oracle(
        boxes in prop::collection::vec(common::grid_box(), 0..250),
        changes in churn(common::grid_box()),
        queries in prop::collection::vec(grid_query(), 1..16),
    ) {
        let (tree, oracle) = churned::<4>(&boxes, &changes);
        check(&tree, &oracle, &queries);
        let (tree, oracle) = churned::<16>(&boxes, &changes);
        check(&tree, &oracle, &queries);
    }
}

/// `boxes` as keys `0..` among 1,000 distractors (keys from 1,000) at least
/// 20 m from the origin, so that pruning is exercised.
fn world(boxes: &[Aabb]) -> (RTree<u32>, BruteForce<u32>) {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        tree.insert(i as u32, *b).unwrap();
        oracle.insert(i as u32, *b);
    }
    let mut rng = bevy_rtree::scene::SceneRng::new(23);
    let mut key = 1_000u32;
    while key < 2_000 {
        let c = Vec3::new(
            rng.range(-80.0, 80.0),
            rng.range(-80.0, 80.0),
            rng.range(-80.0, 80.0),
        );
        if c.abs().max_element() > 20.0 {
            let b = Aabb::new(c, c + Vec3::splat(rng.range(0.0, 2.0))).unwrap();
            tree.insert(key, b).unwrap();
            oracle.insert(key, b);
            key += 1;
        }
    }
    tree.validate().unwrap();
    (tree, oracle)
}

fn keys(neighbors: &[Neighbor<u32>]) -> Vec<u32> {
    neighbors.iter().map(|n| n.key).collect()
}

fn query(point: Vec3, radius: f32, k: usize, max_distance: f32) -> Query {
    Query {
        point,
        radius,
        k,
        max_distance,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// The k nearest allowed entries are the oracle's nearest with the
    /// left-out keys removed (a filter worked out here), cut to k: on a
    /// grid, where equal distances are common.
    #[test]
    fn the_nearest_allowed_are_the_nearest_with_the_others_left_out(
        boxes in prop::collection::vec(common::grid_box(), 1..200),
        point in common::grid_point(),
        k in 1usize..9,
        skip in 2u32..5,
        max in prop::option::of(0.0f32..6.0),
    ) {
        let mut tree = RTree::<u32, 8>::with_settings(TreeSettings::default()).unwrap();
        let mut oracle = BruteForce::default();
        for (i, b) in boxes.iter().enumerate() {
            tree.insert(i as u32, *b).unwrap();
            oracle.insert(i as u32, *b);
        }
        let allowed = |key: u32| !key.is_multiple_of(skip);
        let mut expected = oracle.nearest(point, boxes.len(), max).unwrap();
        expected.retain(|n| allowed(n.key));
        expected.truncate(k);
        let mut got = Vec::new();
        tree.nearest_where_into(point, k, max, &mut QueryWorkspace::default(), &mut got, allowed)
            .unwrap();
        prop_assert_eq!(got, expected);
    }
}

#[path = "nearest/hard_cases.rs"]
mod hard_cases;
