//! Distance joins against the oracle: random grid scenes where boxes touch
//! and gaps are exact, the incremental "moved" join, and the join hard cases
//! of the contract (`docs/contract.md`).

mod common;

use std::collections::BTreeSet;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, JoinMode, ProxyId, QueryWorkspace, RTree, SpatialError};
use glam::Vec3;
use proptest::prelude::*;

const MODES: [JoinMode; 2] = [JoinMode::Euclidean, JoinMode::Chebyshev];

fn build<const W: usize>(
    boxes: &[Aabb],
    first_key: u32,
) -> (RTree<u32, W>, BruteForce<u32>, Vec<ProxyId>) {
    let mut tree = RTree::<u32, W>::with_settings(Default::default()).unwrap();
    let mut oracle = BruteForce::default();
    let mut ids = Vec::new();
    for (i, b) in boxes.iter().enumerate() {
        ids.push(tree.insert(first_key + i as u32, *b).unwrap());
        oracle.insert(first_key + i as u32, *b);
    }
    (tree, oracle, ids)
}

fn distance() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(0.0f32),
        (1i32..=8).prop_map(|d| d as f32 * 0.25),
        Just(1.3f32)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn self_joins_match_the_oracle(boxes in prop::collection::vec(common::grid_box(), 0..250), d in distance()) {
        let (tree, oracle, _) = build::<4>(&boxes, 0);
        for mode in MODES {
            let pairs = tree.self_join(d, mode).unwrap();
            prop_assert_eq!(&pairs, &oracle.self_join(d, mode).unwrap());
            // Each unordered pair once, never an entry with itself.
            prop_assert!(pairs.windows(2).all(|w| w[0] != w[1]));
            prop_assert!(pairs.iter().all(|(a, b)| a < b));
        }
        // Chebyshev is a superset of Euclidean.
        let exact: BTreeSet<_> = tree.self_join(d, JoinMode::Euclidean).unwrap().into_iter().collect();
        let fast: BTreeSet<_> = tree.self_join(d, JoinMode::Chebyshev).unwrap().into_iter().collect();
        prop_assert!(exact.is_subset(&fast));
    }

    #[test]
    fn cross_joins_match_the_oracle(
        a in prop::collection::vec(common::grid_box(), 0..200),
        b in prop::collection::vec(common::grid_box(), 0..60),
        d in distance(),
        shared in any::<bool>(),
    ) {
        // Half the cases give the two sets common keys (one entity in two
        // layers), which a cross join never pairs with itself.
        let (ta, oa, _) = build::<8>(&a, 0);
        let (tb, ob, _) = build::<8>(&b, if shared { 0 } else { 10_000 });
        for mode in MODES {
            prop_assert_eq!(ta.cross_join(&tb, d, mode).unwrap(), oa.cross_join(&ob, d, mode).unwrap());
            let mut swapped: Vec<(u32, u32)> = tb.cross_join(&ta, d, mode).unwrap().into_iter().map(|(x, y)| (y, x)).collect();
            swapped.sort_unstable();
            prop_assert_eq!(swapped, oa.cross_join(&ob, d, mode).unwrap());
        }
    }

    /// A tree joined with itself (the same object on both sides, as a
    /// system holding one layer may call it) gives the oracle's pairs once
    /// each: every ordered pair of distinct keys within reach.
    #[test]
    fn a_cross_join_of_a_tree_with_itself_matches_the_oracle(
        boxes in prop::collection::vec(common::grid_box(), 0..250),
        d in distance(),
    ) {
        let (tree, oracle, _) = build::<4>(&boxes, 0);
        for mode in MODES {
            let want = oracle.cross_join(&oracle, d, mode).unwrap();
            prop_assert_eq!(tree.cross_join(&tree, d, mode).unwrap(), want);
        }
    }

    #[test]
    fn moved_joins_report_exactly_the_pairs_of_moved_entries(
        boxes in prop::collection::vec(common::grid_box(), 1..200),
        picks in prop::collection::vec(any::<usize>(), 0..20),
        d in distance(),
    ) {
        let (tree, oracle, ids) = build::<4>(&boxes, 0);
        let moved: Vec<ProxyId> = picks.iter().map(|p| ids[p % ids.len()]).collect();
        let moved_keys: BTreeSet<u32> = moved.iter().map(|id| tree.get(*id).unwrap().0).collect();
        for mode in MODES {
            let mut got = Vec::new();
            tree.visit_self_join_moved(&moved, d, mode, &mut QueryWorkspace::default(), |a, b| {
                got.push((a, b));
                std::ops::ControlFlow::Continue(())
            }).unwrap();
            got.sort_unstable();
            let expected: Vec<(u32, u32)> = oracle
                .self_join(d, mode)
                .unwrap()
                .into_iter()
                .filter(|(a, b)| moved_keys.contains(a) || moved_keys.contains(b))
                .collect();
            prop_assert_eq!(got, expected);
        }
    }
}

/// Two boxes (keys 0 and 1) among 1,000 distractors far from them.
fn pair_world<const W: usize>(a: Aabb, b: Aabb) -> (RTree<u32, W>, BruteForce<u32>) {
    let mut rng = bevy_rtree::scene::SceneRng::new(13);
    let mut boxes = vec![a, b];
    while boxes.len() < 1_002 {
        let c = Vec3::new(
            rng.range(100.0, 400.0),
            rng.range(-50.0, 50.0),
            rng.range(-50.0, 50.0),
        );
        boxes.push(Aabb::new(c, c + Vec3::splat(rng.range(0.0, 2.0))).unwrap());
    }
    let (tree, oracle, _) = build::<W>(&boxes, 0);
    (tree, oracle)
}

/// Whether 0 and 1 pair at distance `d` in `mode`; also checks the whole
/// answer against the oracle.
/// At width 8 and at the default width 16, which must agree.
fn pairs(a: Aabb, b: Aabb, d: f32, mode: JoinMode) -> bool {
    let (narrow, oracle) = pair_world::<8>(a, b);
    let got = narrow.self_join(d, mode).unwrap();
    assert_eq!(got, oracle.self_join(d, mode).unwrap());
    let (wide, _) = pair_world::<16>(a, b);
    assert_eq!(wide.self_join(d, mode).unwrap(), got);
    // Alone, in a tree whose root is its leaf.
    let (alone, alone_oracle, _) = build::<16>(&[a, b], 0);
    let two = alone.self_join(d, mode).unwrap();
    assert_eq!(two, alone_oracle.self_join(d, mode).unwrap());
    assert_eq!(two.contains(&(0, 1)), got.contains(&(0, 1)));
    got.contains(&(0, 1))
}

#[test]
fn a_gap_of_exactly_d_pairs() {
    let a = common::aabb([0.0; 3], [1.0; 3]);
    let b = common::aabb([3.0, 0.0, 0.0], [4.0, 1.0, 1.0]);
    for mode in MODES {
        assert!(pairs(a, b, 2.0, mode));
        assert!(!pairs(a, b, 2f32.next_down(), mode));
    }
}

#[test]
fn a_diagonal_gap_separates_the_modes() {
    let a = common::aabb([0.0; 3], [1.0; 3]);
    let b = common::aabb([2.0, 2.0, 0.0], [3.0, 3.0, 1.0]); // gap (1, 1, 0): sqrt(2) apart
    assert!(!pairs(a, b, 1.0, JoinMode::Euclidean));
    assert!(pairs(a, b, 1.0, JoinMode::Chebyshev));
    assert!(!pairs(a, b, 1.4, JoinMode::Euclidean));
    assert!(pairs(a, b, 1.4, JoinMode::Chebyshev));
    assert!(pairs(a, b, 1.5, JoinMode::Euclidean));
    let c = common::aabb([4.0, 5.0, 0.0], [5.0, 6.0, 1.0]); // gap (3, 4, 0): 5 apart
    assert!(pairs(a, c, 5.0, JoinMode::Euclidean));
    assert!(!pairs(a, c, 4.99, JoinMode::Euclidean));
}

#[test]
fn touching_and_identical_boxes_pair_at_zero() {
    let a = common::aabb([0.0; 3], [1.0; 3]);
    let touching = common::aabb([1.0, 0.0, 0.0], [2.0, 1.0, 1.0]);
    let corner = common::aabb([1.0, 1.0, 1.0], [2.0, 2.0, 2.0]);
    for mode in MODES {
        assert!(pairs(a, touching, 0.0, mode));
        assert!(pairs(a, corner, 0.0, mode));
        let (tree, _) = pair_world::<16>(a, a);
        let got = tree.self_join(0.0, mode).unwrap();
        assert_eq!(
            got.iter().filter(|p| **p == (0, 1)).count(),
            1,
            "identical boxes: one pair"
        );
        assert!(
            got.iter().all(|(x, y)| x != y),
            "never an entry with itself"
        );
    }
}

#[test]
fn boxes_one_ulp_apart_far_out() {
    let x = 1e5f32;
    let a = common::aabb([x - 1.0, 0.0, 0.0], [x, 1.0, 1.0]);
    let b = common::aabb([x.next_up(), 0.0, 0.0], [x + 1.0, 1.0, 1.0]);
    let ulp = x.next_up() - x;
    for mode in MODES {
        assert!(!pairs(a, b, 0.0, mode));
        assert!(pairs(a, b, ulp, mode));
    }
}

/// S8 computes the gap in `f64` from the `f32` boxes, and that rounding can
/// accept a pair whose real gap exceeds `d` by a hair: here the real gap is
/// `5 + 1e-20`, which rounds to `5.0`. A traversal that grows boxes by
/// exactly `d` in `f32` (`-5 + 5 = 0 < 1e-20`), even rounded outward by one
/// ulp, dismisses the pair before the exact test sees it.
#[test]
fn a_pair_the_f64_gap_rounds_into_reach_is_found() {
    let a = common::aabb([-6.0, 0.0, 0.0], [-5.0, 1.0, 1.0]);
    let b = common::aabb([1e-20, 0.0, 0.0], [1.0, 1.0, 1.0]);
    for mode in MODES {
        assert!(pairs(a, b, 5.0, mode), "self join, {mode:?}");
        let (ta, oa, _) = build::<8>(&[a], 0);
        let (tb, ob, _) = build::<8>(&[b], 1);
        assert_eq!(oa.cross_join(&ob, 5.0, mode).unwrap(), vec![(0, 1)]);
        assert_eq!(
            ta.cross_join(&tb, 5.0, mode).unwrap(),
            vec![(0, 1)],
            "cross join, {mode:?}"
        );
        let (both, _, ids) = build::<8>(&[a, b], 0);
        let mut moved = Vec::new();
        both.visit_self_join_moved(
            &ids[..1],
            5.0,
            mode,
            &mut QueryWorkspace::default(),
            |x, y| {
                moved.push((x, y));
                std::ops::ControlFlow::Continue(())
            },
        )
        .unwrap();
        assert_eq!(moved, vec![(0, 1)], "moved join, {mode:?}");
    }
}

#[test]
fn a_key_in_both_sets_is_never_paired_with_itself() {
    // Key 7 stands for one entity in both sets, with the same box; key 8
    // overlaps it in the second set.
    let unit = common::aabb([0.0; 3], [1.0; 3]);
    let (mut ta, mut oa, _) = build::<8>(&[], 0);
    let (mut tb, mut ob, _) = build::<8>(&[], 0);
    ta.insert(7, unit).unwrap();
    oa.insert(7, unit);
    for key in [7, 8] {
        tb.insert(key, unit).unwrap();
        ob.insert(key, unit);
    }
    for mode in MODES {
        assert_eq!(ta.cross_join(&tb, 0.0, mode).unwrap(), vec![(7, 8)]);
        assert_eq!(oa.cross_join(&ob, 0.0, mode).unwrap(), vec![(7, 8)]);
        assert_eq!(tb.cross_join(&ta, 0.0, mode).unwrap(), vec![(8, 7)]);
    }
}

#[test]
fn invalid_distances_are_refused() {
    let (tree, oracle) = pair_world::<16>(
        common::aabb([0.0; 3], [1.0; 3]),
        common::aabb([2.0; 3], [3.0; 3]),
    );
    for d in [f32::NAN, -1.0, f32::INFINITY, f32::NEG_INFINITY] {
        for mode in MODES {
            assert_eq!(tree.self_join(d, mode), Err(SpatialError::InvalidDistance));
            assert_eq!(
                tree.cross_join(&tree, d, mode),
                Err(SpatialError::InvalidDistance)
            );
            assert_eq!(
                oracle.self_join(d, mode),
                Err(SpatialError::InvalidDistance)
            );
        }
    }
}

#[test]
fn the_standard_scene_joins_match_the_sweep() {
    let scene = bevy_rtree::scene::TownScene::new(20_000, 21);
    let (all, all_oracle, _) = build::<8>(scene.boxes(), 0);
    let got = all.self_join(0.0, JoinMode::Euclidean).unwrap();
    assert!(!got.is_empty());
    assert_eq!(got, all_oracle.self_join(0.0, JoinMode::Euclidean).unwrap());
    let enemies = &scene.boxes()[0..2_000];
    let barrels = &scene.boxes()[2_000..3_000];
    let (te, oe, _) = build::<8>(enemies, 0);
    let (tb, ob, _) = build::<8>(barrels, 2_000);
    assert_eq!(
        te.cross_join(&tb, 5.0, JoinMode::Euclidean).unwrap(),
        oe.cross_join(&ob, 5.0, JoinMode::Euclidean).unwrap()
    );
}

/// The incremental join refuses a bad distance or an unknown handle before
/// it reports any pair, even when good handles come first.
#[test]
fn the_moved_join_checks_everything_before_reporting() {
    let boxes: Vec<Aabb> = (0..50)
        .map(|i| common::aabb([i as f32 * 0.5, 0.0, 0.0], [i as f32 * 0.5 + 1.0, 1.0, 1.0]))
        .collect();
    let (mut tree, mut oracle, ids) = build::<16>(&boxes, 0);
    let stale = ids[49];
    tree.remove(stale).unwrap();
    oracle.remove(49);
    let mut ws = QueryWorkspace::default();
    let mut reported = Vec::new();
    let mut count = |a, b| {
        reported.push((a, b));
        std::ops::ControlFlow::Continue(())
    };
    let cases: [(&[ProxyId], f32, SpatialError); 4] = [
        (&[ids[0], ids[1], stale], 0.0, SpatialError::UnknownProxy),
        (&[ids[0], ids[1]], f32::NAN, SpatialError::InvalidDistance),
        (&[ids[0], ids[1]], -1.0, SpatialError::InvalidDistance),
        (
            &[ids[0], ids[1]],
            f32::INFINITY,
            SpatialError::InvalidDistance,
        ),
    ];
    for (moved, d, error) in cases {
        for mode in MODES {
            assert_eq!(
                tree.visit_self_join_moved(moved, d, mode, &mut ws, &mut count),
                Err(error),
                "{d} {mode:?}"
            );
        }
    }
    // The good handles alone do have pairs to report: those of the
    // oracle's self join that involve entry 0 or 1 ((0, 1) and (1, 2)
    // overlap, (0, 2) and (1, 3) touch).
    tree.visit_self_join_moved(&ids[..2], 0.0, JoinMode::Euclidean, &mut ws, &mut count)
        .unwrap();
    reported.sort_unstable();
    let want: Vec<(u32, u32)> = oracle
        .self_join(0.0, JoinMode::Euclidean)
        .unwrap()
        .into_iter()
        .filter(|&(a, b)| a < 2 || b < 2)
        .collect();
    assert_eq!(want.len(), 4);
    assert_eq!(reported, want, "nothing before, these now");
}

/// A cross join of trees of different heights: while the taller one
/// descends alone, its children are tested against the shorter tree's
/// bound, so a one-entry tree far from the town visits a handful of nodes
/// instead of every internal node of the town, and finds what the oracle
/// finds either way round.
#[test]
fn a_small_tree_joined_with_a_large_one_visits_only_what_it_can_reach() {
    let scene = bevy_rtree::scene::TownScene::new(20_000, 22);
    let (town, town_oracle, _) = build::<16>(scene.boxes(), 0);
    assert!(town.height() >= 3);
    for (at, d) in [(Vec3::splat(1e5), 1.0), (Vec3::new(500.0, 0.0, 500.0), 5.0)] {
        let lone = [Aabb::new(at, at + Vec3::ONE).unwrap()];
        let (small, small_oracle, _) = build::<16>(&lone, 1_000_000);
        let mut ws = QueryWorkspace::default();
        let mut pairs = Vec::new();
        small
            .cross_join_into(&town, d, JoinMode::Euclidean, &mut ws, &mut pairs)
            .unwrap();
        let want = small_oracle.cross_join(&town_oracle, d, JoinMode::Euclidean);
        assert_eq!(pairs, want.unwrap());
        let visited = ws.take_stats().nodes_visited;
        assert!(visited < 40, "{visited} node pairs visited");
        let mut swapped = Vec::new();
        town.cross_join_into(&small, d, JoinMode::Euclidean, &mut ws, &mut swapped)
            .unwrap();
        let want_swapped = town_oracle.cross_join(&small_oracle, d, JoinMode::Euclidean);
        swapped.sort_unstable();
        assert_eq!(swapped, want_swapped.unwrap());
        assert_eq!(swapped.len(), pairs.len());
        assert!(ws.take_stats().nodes_visited < 40);
    }
}

/// A visitor that breaks is not called again, and what it saw before are
/// pairs of the join, each once: self and cross joins of the town, broken
/// after 1, 7 and 200 pairs.
#[test]
fn joins_stop_where_their_visitor_breaks() {
    use std::ops::ControlFlow;
    let (_, tree, _) = common::town_tree(4_000, 21);
    let (_, other, _) = common::town_tree(3_000, 22);
    let oracle_of = |tree: &RTree<u32>| {
        let mut oracle = BruteForce::default();
        for (_, key, aabb) in tree.iter() {
            oracle.insert(key, aabb);
        }
        oracle
    };
    let self_pairs: BTreeSet<(u32, u32)> = oracle_of(&tree)
        .self_join(5.0, JoinMode::Euclidean)
        .unwrap()
        .into_iter()
        .collect();
    let cross_pairs: BTreeSet<(u32, u32)> = oracle_of(&tree)
        .cross_join(&oracle_of(&other), 5.0, JoinMode::Euclidean)
        .unwrap()
        .into_iter()
        .collect();
    assert!(
        self_pairs.len() > 200 && cross_pairs.len() > 200,
        "{} and {} pairs",
        self_pairs.len(),
        cross_pairs.len()
    );
    let mut ws = QueryWorkspace::default();
    // Records each pair, and breaks at the `stop`-th.
    let until = |stop: usize, seen: &mut Vec<(u32, u32)>, pair: (u32, u32)| {
        seen.push(pair);
        if seen.len() == stop {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    // Exactly `stop` pairs, distinct, all of the join.
    let check = |seen: Vec<(u32, u32)>, stop: usize, join: &BTreeSet<(u32, u32)>, what: &str| {
        assert_eq!(seen.len(), stop, "{what}");
        let distinct: BTreeSet<_> = seen.into_iter().collect();
        assert_eq!(distinct.len(), stop, "{what}");
        assert!(distinct.is_subset(join), "{what}");
    };
    for stop in [1usize, 7, 200] {
        let mut seen = Vec::new();
        tree.visit_self_join(5.0, JoinMode::Euclidean, &mut ws, |a, b| {
            until(stop, &mut seen, (a.min(b), a.max(b)))
        })
        .unwrap();
        check(seen, stop, &self_pairs, "self join");
        let mut seen = Vec::new();
        tree.visit_cross_join(&other, 5.0, JoinMode::Euclidean, &mut ws, |a, b| {
            until(stop, &mut seen, (a, b))
        })
        .unwrap();
        check(seen, stop, &cross_pairs, "cross join");
    }
}

/// Contract (the S2/S8 refinement): the tree names entries by handle, so
/// two entries that share a key are two entries; a self join pairs them as
/// `(k, k)`, and never pairs an entry with itself.
#[test]
fn a_self_join_pairs_two_entries_that_share_a_key() {
    let entries = [
        (7u32, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
        (7, [0.5, 0.5, 0.5], [2.0, 2.0, 2.0]),
        (3, [10.0, 0.0, 0.0], [11.0, 1.0, 1.0]),
        (7, [20.0, 0.0, 0.0], [21.0, 1.0, 1.0]),
    ];
    let mut tree = RTree::<u32>::new();
    let mut oracle = BruteForce::default();
    for (key, min, max) in entries {
        tree.insert(key, common::aabb(min, max)).unwrap();
        oracle.insert(key, common::aabb(min, max));
    }
    tree.validate().unwrap();
    for distance in [0.0, 0.5, 9.0, 30.0] {
        for mode in MODES {
            let want = oracle.self_join(distance, mode).unwrap();
            assert_eq!(
                tree.self_join(distance, mode).unwrap(),
                want,
                "{distance} {mode:?}"
            );
        }
    }
    // The two overlapping entries of key 7, once; nothing with itself.
    assert_eq!(tree.self_join(0.0, JoinMode::Euclidean).unwrap(), [(7, 7)]);
}
