//! Ties, the visitor's limit, points on boxes, `k` past the length, an
//! empty tree, an inclusive limit, far coordinates, a town, bad input.

use super::*;

#[test]
fn equal_distances_resolve_to_the_smallest_key() {
    let stacked = common::aabb([2.0, 0.0, 0.0], [3.0, 1.0, 1.0]);
    let mirrored = common::aabb([-3.0, 0.0, 0.0], [-2.0, 1.0, 1.0]);
    let far = common::aabb([0.0, 9.0, 0.0], [1.0, 10.0, 1.0]);
    // Keys 9, 4, 7, 5 are stacked and 6 mirrored, all at distance 2; the
    // other keys below 10 are 8.5 away.
    let mut boxes = vec![far; 10];
    for key in [9, 4, 7, 5] {
        boxes[key] = stacked;
    }
    boxes[6] = mirrored;
    let (tree, oracle) = world(&boxes);
    let p = Vec3::new(0.0, 0.5, 0.5);
    assert_eq!(keys(&tree.nearest(p, 1, None).unwrap()), [4]);
    assert_eq!(keys(&tree.nearest(p, 3, None).unwrap()), [4, 5, 6]);
    assert_eq!(keys(&tree.nearest(p, 5, None).unwrap()), [4, 5, 6, 7, 9]);
    assert!(
        tree.nearest(p, 5, None)
            .unwrap()
            .iter()
            .all(|n| n.distance_sq == 4.0)
    );
    assert_eq!(keys(&tree.within_radius(p, 2.0).unwrap()), [4, 5, 6, 7, 9]);
    check(
        &tree,
        &oracle,
        &[query(p, 2.0, 3, 2.0), query(p, 9.0, 7, 8.5)],
    );
}

/// The visitor's limit: a NaN one is ignored (every entry is still
/// reported), a negative one stops every later report, `Break` stops at
/// once, and a limit that shrinks to the best so far finds the nearest.
#[test]
fn the_visitor_s_limit_is_kept_as_documented() {
    let boxes: Vec<Aabb> = (0..40)
        .map(|i| {
            let x = 3.0 + i as f32;
            common::aabb([x, 0.0, 0.0], [x + 0.5, 1.0, 1.0])
        })
        .collect();
    let (tree, oracle) = world(&boxes);
    let mut ws = QueryWorkspace::default();
    let p = Vec3::new(0.0, 0.5, 0.5);
    let visit = |next: fn(usize) -> ControlFlow<(), f64>| {
        let mut seen = Vec::new();
        tree.visit_nearest(p, None, &mut QueryWorkspace::default(), |key, _, _| {
            seen.push(key);
            next(seen.len())
        })
        .unwrap();
        seen.sort_unstable();
        seen
    };
    let mut all: Vec<u32> = tree.iter().map(|(_, key, _)| key).collect();
    all.sort_unstable();
    assert_eq!(visit(|_| ControlFlow::Continue(f64::NAN)), all);
    assert_eq!(visit(|_| ControlFlow::Continue(f64::INFINITY)), all);
    assert_eq!(visit(|_| ControlFlow::Continue(-1.0)).len(), 1);
    assert_eq!(visit(|_| ControlFlow::Break(())).len(), 1);
    assert_eq!(
        visit(|n| if n < 5 {
            ControlFlow::Continue(f64::NAN)
        } else {
            ControlFlow::Break(())
        })
        .len(),
        5
    );
    // The limit shrunk to the best so far: the last report is the nearest.
    let mut best = (u32::MAX, f64::INFINITY);
    tree.visit_nearest(p, None, &mut ws, |key, _, d2| {
        if (d2, key) < (best.1, best.0) {
            best = (key, d2);
        }
        ControlFlow::Continue(best.1)
    })
    .unwrap();
    let want = oracle.nearest(p, 1, None).unwrap();
    assert_eq!((best.0, best.1), (want[0].key, want[0].distance_sq));
    assert_eq!(best.0, 0);
}

/// Squared distances of 1 and 1 + 2^-52 (exact in `f64`) have the same
/// square root, 1.0, after rounding: the order is by the squared distance,
/// so the nearer entry comes first although its key is the larger.
#[test]
fn a_nearer_squared_distance_comes_first_where_the_distances_round_equal() {
    let mut boxes = vec![common::aabb([0.0, 9.0, 0.0], [1.0, 10.0, 1.0]); 6];
    // Key 5 is one metre away along x; key 3 as far along x and 2^-26 above
    // the point's y, so its squared distance is 1 + 2^-52.
    boxes[5] = common::aabb([1.0, 0.0, 0.0], [2.0, 1.0, 1.0]);
    boxes[3] = common::aabb([1.0, 2f32.powi(-26), 0.0], [2.0, 1.0, 1.0]);
    let (tree, oracle) = world(&boxes);
    let nearest = tree.nearest(Vec3::ZERO, 2, None).unwrap();
    assert_eq!(keys(&nearest), [5, 3]);
    // The ground truth, without the crate's arithmetic.
    let (near, farther) = (1.0f64, 1.0 + 2f64.powi(-52));
    assert!(near < farther && near.sqrt() == farther.sqrt());
    assert_eq!(nearest[0].distance_sq, near);
    assert_eq!(nearest[1].distance_sq, farther);
    assert_eq!(nearest[0].distance(), nearest[1].distance());
    assert_eq!(keys(&tree.within_radius(Vec3::ZERO, 1.0).unwrap()), [5]);
    assert_eq!(
        keys(&tree.within_radius(Vec3::ZERO, 1.0 + f32::EPSILON).unwrap()),
        [5, 3]
    );
    check(
        &tree,
        &oracle,
        &[
            query(Vec3::ZERO, 1.0, 1, 1.0),
            query(Vec3::ZERO, 1.5, 2, 1.5),
        ],
    );
}

#[test]
fn ties_spread_over_many_leaves_still_go_to_the_smallest_keys() {
    // 300 identical boxes inserted in descending key order fill many leaves
    // of a width-4 tree; every one is at the same distance.
    let same = common::aabb([5.0, 5.0, 5.0], [6.0, 6.0, 6.0]);
    let mut tree = RTree::<u32, 4>::with_settings(TreeSettings::default()).unwrap();
    let mut oracle = BruteForce::default();
    for key in (0..300u32).rev() {
        tree.insert(key * 7 % 300, same).unwrap();
        oracle.insert(key * 7 % 300, same);
    }
    tree.validate().unwrap();
    let found = tree.nearest(Vec3::ZERO, 5, None).unwrap();
    assert_eq!(keys(&found), [0, 1, 2, 3, 4]);
    assert!(found.iter().all(|n| n.distance_sq == 75.0));
    check(
        &tree,
        &oracle,
        &[
            query(Vec3::ZERO, 75f32.sqrt(), 5, 75f32.sqrt()),
            query(Vec3::splat(5.5), 0.0, 17, 0.0),
        ],
    );
}

#[test]
fn a_point_inside_or_on_a_box_is_at_distance_zero() {
    let unit = common::aabb([0.0; 3], [1.0; 3]);
    let (tree, oracle) = world(&[unit]);
    let mut ws = QueryWorkspace::default();
    for p in [
        [0.5, 0.5, 0.5], // inside
        [1.0, 0.5, 0.5], // on a face
        [1.0, 1.0, 0.5], // on an edge
        [0.0, 0.0, 0.0], // on a corner
    ] {
        let p = Vec3::from(p);
        assert_eq!(
            tree.nearest(p, 1, None).unwrap(),
            [Neighbor {
                key: 0,
                distance_sq: 0.0
            }]
        );
        assert_eq!(keys(&tree.within_radius(p, 0.0).unwrap()), [0]);
        assert_eq!(tree.overlapping_sphere(p, 0.0).unwrap(), [0]);
        assert!(tree.any_overlapping_sphere(p, -0.0, &mut ws).unwrap());
        let mut seen = Vec::new();
        tree.visit_sphere(p, 0.0, &mut ws, |key, aabb, d2| {
            seen.push((key, *aabb, d2));
            ControlFlow::Continue(())
        })
        .unwrap();
        assert_eq!(seen, [(0, unit, 0.0)]);
        check(
            &tree,
            &oracle,
            &[query(p, 0.0, 2, 0.0), query(p, 3.0, 4, 1.0)],
        );
    }
    // One ulp outside a face is no longer at distance zero.
    let outside = Vec3::new(1f32.next_up(), 0.5, 0.5);
    assert!(tree.within_radius(outside, 0.0).unwrap().is_empty());
    assert!(tree.nearest(outside, 1, None).unwrap()[0].distance_sq > 0.0);
}

#[test]
fn k_larger_than_len_returns_every_entry_sorted() {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    for key in 0..10u32 {
        let x = (key * 37 % 10) as f32 * 3.0;
        let b = common::aabb([x, 0.0, 0.0], [x + 1.0, 1.0, 1.0]);
        tree.insert(key, b).unwrap();
        oracle.insert(key, b);
    }
    let p = Vec3::new(-1.0, 0.5, 0.5);
    for k in [10, 11, 100, usize::MAX] {
        let all = tree.nearest(p, k, None).unwrap();
        assert_eq!(all.len(), 10);
        assert!(all.windows(2).all(|w| w[0].distance_sq < w[1].distance_sq));
        assert_eq!(all, oracle.nearest(p, k, None).unwrap());
        // A maximum distance still cuts: x = 0, 3, 6 are within 7 of x = -1.
        let cut = tree.nearest(p, k, Some(7.0)).unwrap();
        assert_eq!(cut.len(), 3);
        assert_eq!(cut, oracle.nearest(p, k, Some(7.0)).unwrap());
    }
}

#[test]
fn an_empty_tree_answers_nothing() {
    let mut emptied = RTree::new();
    let id = emptied
        .insert(1u32, common::aabb([0.0; 3], [1.0; 3]))
        .unwrap();
    emptied.remove(id).unwrap();
    for tree in [RTree::<u32>::new(), emptied] {
        tree.validate().unwrap();
        let mut ws = QueryWorkspace::default();
        let p = Vec3::splat(0.5);
        assert!(tree.nearest(p, 3, None).unwrap().is_empty());
        assert!(tree.nearest(p, 3, Some(100.0)).unwrap().is_empty());
        assert!(tree.within_radius(p, 100.0).unwrap().is_empty());
        assert!(tree.overlapping_sphere(p, 100.0).unwrap().is_empty());
        assert!(!tree.any_overlapping_sphere(p, 100.0, &mut ws).unwrap());
        // Bad input is still refused.
        assert_eq!(tree.nearest(p, 0, None), Err(SpatialError::InvalidCount));
        assert_eq!(
            tree.within_radius(Vec3::NAN, 1.0),
            Err(SpatialError::InvalidBox)
        );
    }
}

#[test]
fn max_distance_exactly_equal_to_an_entry_distance_is_inclusive() {
    // Gap (3, 4, 0) from the origin: distance exactly 5.
    let five = common::aabb([3.0, 4.0, -1.0], [4.0, 5.0, 1.0]);
    // Gap (1, 1, 0): distance √2, between 1.4 and 1.5.
    let diagonal = common::aabb([-2.0, -2.0, -1.0], [-1.0, -1.0, 1.0]);
    let (tree, oracle) = world(&[five, diagonal]);
    let o = Vec3::ZERO;
    let found = tree.nearest(o, 10, Some(5.0)).unwrap();
    assert_eq!(
        found.last().map(|n| (n.key, n.distance_sq)),
        Some((0, 25.0))
    );
    assert_eq!(
        keys(&tree.nearest(o, 10, Some(5f32.next_down())).unwrap()),
        [1]
    );
    assert_eq!(keys(&tree.within_radius(o, 5.0).unwrap()), [1, 0]);
    assert_eq!(tree.overlapping_sphere(o, 5.0).unwrap(), [0, 1]);
    assert_eq!(tree.overlapping_sphere(o, 5f32.next_down()).unwrap(), [1]);
    assert!(tree.nearest(o, 10, Some(1.4)).unwrap().is_empty());
    assert_eq!(keys(&tree.nearest(o, 10, Some(1.5)).unwrap()), [1]);
    // Zero (either sign) is a valid limit: only boxes containing the point.
    assert!(tree.nearest(o, 10, Some(-0.0)).unwrap().is_empty());
    check(
        &tree,
        &oracle,
        &[
            query(o, 5.0, 3, 5.0),
            query(o, 5f32.next_down(), 3, 5f32.next_down()),
            query(o, 1.4, 1, 1.5),
        ],
    );
}

#[test]
fn distances_far_from_the_origin_stay_exact() {
    // Two boxes one ulp (1/128) apart at x = 1e5, and one 100 m from a point
    // at x = 1e7.
    let a = common::aabb([1e5 - 1.0, 0.0, 0.0], [1e5, 1.0, 1.0]);
    let b = common::aabb([1e5f32.next_up(), 0.0, 0.0], [1e5 + 1.0, 1.0, 1.0]);
    let c = common::aabb([1e7, 0.0, 0.0], [1e7 + 1.0, 1.0, 1.0]);
    let (tree, oracle) = world(&[a, b, c]);
    let ulp = (1e5f32.next_up() - 1e5) as f64;
    assert_eq!(ulp, 1.0 / 128.0);
    let p = Vec3::new(1e5, 0.5, 0.5);
    assert_eq!(
        tree.nearest(p, 2, None).unwrap(),
        [
            Neighbor {
                key: 0,
                distance_sq: 0.0
            },
            Neighbor {
                key: 1,
                distance_sq: ulp * ulp
            }
        ]
    );
    assert_eq!(keys(&tree.within_radius(p, 0.0).unwrap()), [0]);
    assert_eq!(keys(&tree.within_radius(p, ulp as f32).unwrap()), [0, 1]);
    let q = Vec3::new(1e7 - 100.0, 0.5, 0.5);
    assert_eq!(
        tree.nearest(q, 1, None).unwrap(),
        [Neighbor {
            key: 2,
            distance_sq: 10_000.0
        }]
    );
    check(
        &tree,
        &oracle,
        &[query(p, ulp as f32, 3, 0.0), query(q, 100.0, 2, 100.0)],
    );
}

#[test]
fn nearest_first_search_in_a_town_matches_the_oracle_and_prunes() {
    let (scene, tree, _) = common::town_tree(20_000, 7);
    let mut oracle = BruteForce::default();
    for (i, b) in scene.boxes().iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    for i in [0usize, 4_321, 19_999] {
        let b = scene.boxes()[i];
        let p = Vec3::new(b.max.x + 3.0, b.min.y - 2.0, b.max.z);
        for k in [1, 10, 100] {
            ws.take_stats();
            tree.nearest_into(p, k, None, &mut ws, &mut out).unwrap();
            assert_eq!(out, oracle.nearest(p, k, None).unwrap());
            let stats = ws.take_stats();
            assert!(stats.nodes_visited > 0 && stats.entries_tested > 0);
            if k == 1 {
                assert!(
                    stats.nodes_visited * 20 < tree.node_count() as u64,
                    "the search visits few nodes: {stats:?} of {}",
                    tree.node_count()
                );
            }
        }
        check(&tree, &oracle, &[query(p, 8.0, 10, 12.0)]);
    }
}

/// Everything observable about a tree, for before/after comparisons.
fn snapshot(tree: &RTree<u32>) -> (usize, Vec<(u32, [f32; 6])>) {
    let mut entries: Vec<(u32, [f32; 6])> = tree
        .iter()
        .map(|(_, k, b)| (k, [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z]))
        .collect();
    entries.sort_by_key(|e| e.0);
    (tree.len(), entries)
}

#[test]
fn bad_input_returns_the_typed_error_and_leaves_the_tree_unchanged() {
    let boxes: Vec<Aabb> = (0..50)
        .map(|i| {
            let p = Vec3::new((i % 7) as f32, (i / 7) as f32, 0.0) * 2.0;
            Aabb::new(p, p + Vec3::ONE).unwrap()
        })
        .collect();
    let (tree, oracle) = world(&boxes);
    let before = snapshot(&tree);
    let good = Vec3::splat(1.0);
    let bad_points = [
        Vec3::new(f32::NAN, 0.0, 0.0),
        Vec3::new(0.0, f32::INFINITY, 0.0),
        Vec3::new(0.0, 0.0, f32::NEG_INFINITY),
        Vec3::new(2e15, 0.0, 0.0),
        Vec3::new(0.0, -1.5e15, 0.0),
    ];
    let bad_distances = [
        -1.0,
        -f32::MIN_POSITIVE,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    let mut ws = QueryWorkspace::default();
    let sentinel = Neighbor {
        key: 12_345u32,
        distance_sq: 1.0,
    };
    let mut near = vec![sentinel];
    let mut keys_out = vec![12_345u32];

    // Every entry point, with the error it must return.
    let mut expect = |point: Vec3, distance: f32, k: usize, error: SpatialError| {
        let mut called = false;
        let result = tree.visit_sphere(point, distance, &mut ws, |_, _, _| {
            called = true;
            ControlFlow::Continue(())
        });
        assert_eq!(result, Err(error), "{point} {distance} {k}");
        let result = tree.visit_nearest(point, Some(distance), &mut ws, |_, _, _| {
            called = true;
            ControlFlow::Continue(0.0)
        });
        assert_eq!(result, Err(error));
        assert!(!called, "no entry is reported for bad input");
        assert_eq!(tree.overlapping_sphere(point, distance), Err(error));
        assert_eq!(
            tree.overlapping_sphere_into(point, distance, &mut ws, &mut keys_out),
            Err(error)
        );
        assert_eq!(
            tree.any_overlapping_sphere(point, distance, &mut ws),
            Err(error)
        );
        assert_eq!(tree.within_radius(point, distance), Err(error));
        assert_eq!(
            tree.within_radius_into(point, distance, &mut ws, &mut near),
            Err(error)
        );
        assert_eq!(tree.nearest(point, k, Some(distance)), Err(error));
        assert_eq!(
            tree.nearest_into(point, k, Some(distance), &mut ws, &mut near),
            Err(error)
        );
        assert_eq!(oracle.overlapping_sphere(point, distance), Err(error));
        assert_eq!(oracle.within_radius(point, distance), Err(error));
        assert_eq!(oracle.nearest(point, k, Some(distance)), Err(error));
        // The output vectors were not touched.
        assert_eq!(near, [sentinel]);
        assert_eq!(keys_out, [12_345]);
    };
    for point in bad_points {
        expect(point, 1.0, 3, SpatialError::InvalidBox);
        assert_eq!(tree.nearest(point, 3, None), Err(SpatialError::InvalidBox));
    }
    for distance in bad_distances {
        expect(good, distance, 3, SpatialError::InvalidDistance);
    }
    assert_eq!(
        tree.nearest_into(good, 0, None, &mut ws, &mut near),
        Err(SpatialError::InvalidCount)
    );
    assert_eq!(near, [sentinel]);
    assert_eq!(tree.nearest(good, 0, None), Err(SpatialError::InvalidCount));
    assert_eq!(
        oracle.nearest(good, 0, None),
        Err(SpatialError::InvalidCount)
    );
    // Zero count is checked first, even with other bad input.
    assert_eq!(
        tree.nearest(Vec3::NAN, 0, Some(f32::NAN)),
        Err(SpatialError::InvalidCount)
    );

    tree.validate().unwrap();
    assert_eq!(snapshot(&tree), before);
    // Nothing broke for later: the same tree answers normally.
    check(
        &tree,
        &oracle,
        &[
            query(good, 3.0, 5, 4.0),
            query(Vec3::new(20.0, 5.0, 1.0), 1.0, 50, 1e6),
        ],
    );
}
