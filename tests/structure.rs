//! The structure cases of the contract (`docs/contract.md`): orderings of inserts and removals,
//! identical boxes, sorted and gridded input, huge teleports, and the
//! height the tree keeps on each.

mod common;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{Aabb, MoveKind, ProxyId, RTree, TreeSettings};
use glam::Vec3;

fn unit_at(p: Vec3) -> Aabb {
    Aabb::new(p, p + Vec3::ONE).unwrap()
}

/// The height of a perfectly packed tree of `n` entries and width `w`.
fn optimal_height(n: usize, w: usize) -> usize {
    let mut height = 1;
    let mut capacity = w;
    while capacity < n {
        capacity *= w;
        height += 1;
    }
    height
}

fn fill<const W: usize>(n: usize) -> (RTree<u32, W>, Vec<ProxyId>) {
    let mut tree = RTree::<u32, W>::with_settings(TreeSettings::default()).unwrap();
    let mut ids = Vec::new();
    for i in 0..n as u32 {
        let p = Vec3::new((i * 37 % 101) as f32, (i * 11 % 7) as f32, (i % 13) as f32);
        ids.push(tree.insert(i, unit_at(p)).unwrap());
        tree.validate().unwrap();
    }
    (tree, ids)
}

fn remove_in<const W: usize>(n: usize, order: impl Iterator<Item = usize>) {
    let (mut tree, ids) = fill::<W>(n);
    let probe = Aabb::new(Vec3::splat(-1.0), Vec3::splat(200.0)).unwrap();
    let mut alive: Vec<bool> = vec![true; n];
    for i in order {
        assert_eq!(tree.remove(ids[i]), Ok(i as u32));
        alive[i] = false;
        tree.validate().unwrap();
        let expected: Vec<u32> = (0..n as u32).filter(|&k| alive[k as usize]).collect();
        assert_eq!(tree.overlapping(&probe), expected);
        // Every live node counted at its level, and the freed ones at none.
        let per_level: usize = (0..tree.height()).map(|l| tree.nodes_at_level(l)).sum();
        assert_eq!(per_level, tree.node_count());
        assert_eq!(tree.nodes_at_level(usize::from(u16::MAX)), 0);
    }
    assert!(tree.is_empty());
}

#[test]
fn insert_then_remove_all_in_order_reverse_and_odd_even() {
    for n in 1..=100 {
        remove_in::<4>(n, 0..n);
        remove_in::<8>(n, (0..n).rev());
        remove_in::<8>(n, (0..n).step_by(2).chain((1..n).step_by(2)));
        remove_in::<16>(n, (0..n).step_by(2).chain((1..n).step_by(2)));
    }
}

#[test]
fn ten_thousand_identical_boxes() {
    let mut tree = RTree::new();
    let same = unit_at(Vec3::splat(3.0));
    let ids: Vec<ProxyId> = (0..10_000u32)
        .map(|i| tree.insert(i, same).unwrap())
        .collect();
    tree.validate().unwrap();
    assert_eq!(tree.overlapping(&same), (0..10_000u32).collect::<Vec<_>>());
    assert!(
        tree.height() <= 2 * optimal_height(10_000, RTree::<u32>::WIDTH),
        "height {}",
        tree.height()
    );
    for id in ids.iter().step_by(2) {
        tree.remove(*id).unwrap();
    }
    tree.validate().unwrap();
    let left = tree.overlapping(&same);
    assert_eq!(left, (1..10_000u32).step_by(2).collect::<Vec<_>>());
    assert!(tree.overlapping(&unit_at(Vec3::splat(5.0))).is_empty());
}

#[test]
fn sorted_line_and_grid_keep_a_low_tree() {
    let mut line = RTree::new();
    for i in 0..20_000u32 {
        line.insert(i, unit_at(Vec3::new(i as f32 * 2.0, 0.0, 0.0)))
            .unwrap();
    }
    line.validate().unwrap();
    assert!(
        line.height() <= 2 * optimal_height(20_000, RTree::<u32>::WIDTH),
        "line height {}",
        line.height()
    );

    let mut grid = RTree::new();
    let mut grid_oracle = BruteForce::default();
    let mut key = 0u32;
    for x in 0..30 {
        for y in 0..30 {
            for z in 0..30 {
                let cell = unit_at(Vec3::new(x as f32, y as f32, z as f32) * 1.5);
                grid.insert(key, cell).unwrap();
                grid_oracle.insert(key, cell);
                key += 1;
            }
        }
    }
    grid.validate().unwrap();
    assert!(
        grid.height() <= 2 * optimal_height(27_000, RTree::<u32>::WIDTH),
        "grid height {}",
        grid.height()
    );
    // Cells are 1 m wide, 1.5 m apart: a probe inside one cell, one that
    // touches the faces of eight, and one across a block of them.
    let probes = [
        Aabb::new(Vec3::splat(15.0), Vec3::splat(16.0)).unwrap(),
        Aabb::new(Vec3::splat(16.0), Vec3::splat(16.5)).unwrap(),
        Aabb::new(Vec3::splat(3.2), Vec3::splat(9.1)).unwrap(),
    ];
    for probe in probes {
        let want = grid_oracle.overlapping(&probe);
        assert!(!want.is_empty());
        assert_eq!(grid.overlapping(&probe), want, "{probe:?}");
    }
    let mut line_oracle = BruteForce::default();
    for (_, key, aabb) in line.iter() {
        line_oracle.insert(key, aabb);
    }
    let stretch = Aabb::new(Vec3::new(999.0, 0.5, 0.5), Vec3::new(1_100.0, 0.5, 0.5)).unwrap();
    let want = line_oracle.overlapping(&stretch);
    assert!(want.len() > 40, "the stretch crosses about fifty boxes");
    assert_eq!(line.overlapping(&stretch), want);
}

#[test]
fn teleports_of_a_million_metres_and_back() {
    let mut tree = RTree::new();
    let mut oracle = BruteForce::default();
    let mut ids = Vec::new();
    for i in 0..2_000u32 {
        let b = unit_at(Vec3::new((i % 50) as f32 * 3.0, (i / 50) as f32 * 3.0, 0.0));
        ids.push(tree.insert(i, b).unwrap());
        oracle.insert(i, b);
    }
    for round in 0..3 {
        for (i, id) in ids.iter().enumerate().filter(|(i, _)| i % 3 == round) {
            let far = unit_at(Vec3::new(1e6, -1e6, 1e6) + Vec3::splat(i as f32));
            let kind = tree.update(*id, far).unwrap();
            // The first teleports must restructure; later ones may land in a
            // region the tree already grew towards (any kind is correct then).
            if round == 0 {
                assert_eq!(kind, MoveKind::Reinserted);
            }
            oracle.update(i as u32, far);
        }
        tree.validate().unwrap();
        let far_probe =
            Aabb::new(Vec3::new(1e6, -1e6, 1e6), Vec3::new(1.1e6, -0.9e6, 1.1e6)).unwrap();
        assert_eq!(tree.overlapping(&far_probe), oracle.overlapping(&far_probe));
        let home = Aabb::new(Vec3::splat(-1.0), Vec3::new(200.0, 200.0, 1.0)).unwrap();
        assert_eq!(tree.overlapping(&home), oracle.overlapping(&home));
    }
}

#[test]
fn remove_and_reinsert_in_one_frame() {
    let (mut tree, mut ids) = fill::<8>(500);
    for i in (0..500).step_by(3) {
        let (key, aabb) = tree.get(ids[i]).unwrap();
        tree.remove(ids[i]).unwrap();
        let again = tree.insert(key, aabb).unwrap();
        assert!(tree.get(ids[i]).is_err(), "the old handle is stale");
        ids[i] = again;
    }
    tree.validate().unwrap();
    assert_eq!(tree.len(), 500);
    for (i, id) in ids.iter().enumerate() {
        assert_eq!(tree.get(*id).unwrap().0, i as u32);
    }
}

#[test]
fn small_moves_are_absorbed_without_restructuring() {
    let (mut tree, ids) = fill::<8>(1_000);
    tree.take_maintenance_stats();
    for id in &ids {
        let (_, b) = tree.get(*id).unwrap();
        let nudged = Aabb {
            min: b.min + 0.05,
            max: b.max + 0.05,
        };
        assert_eq!(tree.update(*id, nudged), Ok(MoveKind::InPlace));
    }
    let stats = tree.take_maintenance_stats();
    assert_eq!(stats.moves_in_place, 1_000);
    assert_eq!(stats.moves_reinserted + stats.splits, 0);
    tree.validate().unwrap();
}

#[test]
fn bulk_load_gives_an_optimal_height_and_optimize_keeps_it_valid() {
    let (mut scene, mut tree, ids) = common::town_tree(20_000, 7);
    tree.validate().unwrap();
    assert_eq!(tree.height(), optimal_height(20_000, RTree::<u32>::WIDTH));
    for _ in 0..30 {
        let moved = scene.advance_frame().to_vec();
        for i in moved {
            tree.update(ids[i as usize], scene.boxes()[i as usize])
                .unwrap();
        }
        tree.optimize(usize::MAX);
        tree.validate().unwrap();
    }
    let mut oracle = BruteForce::default();
    for (i, b) in scene.boxes().iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    let probe = Aabb::new(
        Vec3::new(900.0, 0.0, 900.0),
        Vec3::new(1100.0, 100.0, 1100.0),
    )
    .unwrap();
    assert_eq!(tree.overlapping(&probe), oracle.overlapping(&probe));
}

#[test]
fn optimize_packs_churned_leaves_full_and_frees_the_rest() {
    let settings = TreeSettings {
        repack_fraction: f32::MIN_POSITIVE,
        ..TreeSettings::default()
    };
    let mut tree: RTree<u32> = RTree::with_settings(settings).unwrap();
    let mut oracle = BruteForce::default();
    // One-by-one inserts split leaves into half-full ones.
    let ids: Vec<ProxyId> = (0..2_000u32)
        .map(|i| {
            let p = Vec3::new((i % 50) as f32 * 3.0, 0.0, (i / 50) as f32 * 3.0);
            oracle.insert(i, unit_at(p));
            tree.insert(i, unit_at(p)).unwrap()
        })
        .collect();
    // Moves that leave their leaves mark the leaves' parents as churned.
    for (i, id) in ids.iter().enumerate().step_by(3) {
        let p = Vec3::new(
            ((i * 17) % 50) as f32 * 3.0,
            1.5,
            ((i * 31) % 40) as f32 * 3.0,
        );
        tree.update(*id, unit_at(p)).unwrap();
        oracle.update(i as u32, unit_at(p));
    }
    tree.validate().unwrap();
    let before = tree.node_count();
    assert!(tree.pending_repairs() > 0);
    tree.optimize(usize::MAX);
    tree.validate().unwrap();
    assert!(
        tree.node_count() < before,
        "repacking into full leaves frees some: {} -> {}",
        before,
        tree.node_count()
    );
    let everything = Aabb::new(Vec3::splat(-10.0), Vec3::splat(200.0)).unwrap();
    assert_eq!(
        tree.overlapping(&everything),
        oracle.overlapping(&everything)
    );
}

/// Boxes with faces at exactly `±MAX_COORD` are valid: the tree stores,
/// moves and answers them like any other (its enlarged boxes, stretched
/// along a move, are cut at the limit), among ordinary boxes near the
/// origin, and every query family tried agrees with the oracle. One step
/// past the limit is refused.
#[test]
fn boxes_at_the_coordinate_limit_are_indexed_and_answered() {
    use bevy_rtree::{CullMode, Frustum, JoinMode, MAX_COORD, QueryWorkspace, Ray, SpatialError};
    use glam::Quat;

    let m = MAX_COORD;
    let limits = [
        common::aabb([m, 0.0, 0.0], [m, 1.0, 1.0]),
        common::aabb([-m, -m, -m], [-m + 1e9, -m + 1e9, -m + 1e9]),
        common::aabb([-m, -1.0, -1.0], [m, 1.0, 1.0]),
        common::aabb([-m; 3], [m; 3]),
        common::aabb([0.0, m, 0.0], [0.0, m, 0.0]),
        common::aabb([m - 1e9, -m, m - 1e9], [m, -m, m]),
    ];
    let mut tree = RTree::<u32>::new();
    let mut oracle = BruteForce::default();
    let mut ids = Vec::new();
    for (i, b) in limits.iter().enumerate() {
        ids.push(tree.insert(i as u32, *b).unwrap());
        oracle.insert(i as u32, *b);
        tree.validate().unwrap();
    }
    for i in 0..1_000u32 {
        let key = 100 + i;
        let p = Vec3::new((i % 10) as f32, (i / 10 % 10) as f32, (i / 100) as f32) * 3.0;
        tree.insert(key, unit_at(p)).unwrap();
        oracle.insert(key, unit_at(p));
    }
    tree.validate().unwrap();
    for id in &ids {
        let fat = tree.enlarged_box(*id).unwrap();
        assert!(fat.is_valid(), "{fat:?}");
    }
    // Moves to, along and away from the limit.
    let moves = [
        (0, common::aabb([m, 5.0, 5.0], [m, 6.0, 6.0])),
        (4, common::aabb([-m, -m, 0.0], [-m, -m, 0.0])),
        (5, common::aabb([1.0; 3], [2.0; 3])),
    ];
    for (i, b) in moves {
        tree.update(ids[i], b).unwrap();
        oracle.update(i as u32, b);
        tree.validate().unwrap();
        // A move of 2e15 would stretch the box four times that far ahead.
        let fat = tree.enlarged_box(ids[i]).unwrap();
        assert!(fat.is_valid() && fat.contains(&b), "{fat:?}");
    }
    let mut beyond = common::aabb([0.0; 3], [1.0; 3]);
    beyond.max.x = m.next_up();
    assert_eq!(tree.update(ids[5], beyond), Err(SpatialError::InvalidBox));
    assert_eq!(tree.insert(7, beyond), Err(SpatialError::InvalidBox));
    tree.validate().unwrap();

    let queries = [
        common::aabb([m; 3], [m; 3]),
        common::aabb([m - 1.0, 0.0, 0.0], [m, 10.0, 10.0]),
        common::aabb([-m; 3], [-m; 3]),
        common::aabb([0.0; 3], [4.0; 3]),
        common::aabb([-m; 3], [m; 3]),
    ];
    for q in &queries {
        assert_eq!(tree.overlapping(q), oracle.overlapping(q), "{q:?}");
    }
    for p in [
        Vec3::new(m, 5.5, 5.5),
        Vec3::splat(-m),
        Vec3::ZERO,
        Vec3::splat(m),
    ] {
        assert_eq!(tree.containing_point(p), oracle.containing_point(p), "{p}");
    }
    let mut ws = QueryWorkspace::default();
    let rays = [
        Ray::new(Vec3::new(-m, 0.5, 0.5), Vec3::X, f32::INFINITY).unwrap(),
        Ray::new(Vec3::new(0.0, 5.5, 5.5), Vec3::X, 2.0 * m).unwrap(),
        Ray::new(Vec3::new(m, 5.5, 5.5), Vec3::NEG_X, m).unwrap(),
        Ray::new(Vec3::splat(-m), Vec3::ONE, f32::INFINITY).unwrap(),
        Ray::new(Vec3::new(0.5, 0.5, -m), Vec3::Z, f32::INFINITY).unwrap(),
    ];
    for ray in &rays {
        let mut all = Vec::new();
        tree.cast_ray_all(ray, None, &mut ws, &mut all).unwrap();
        assert_eq!(Ok(all), oracle.ray_hits(ray), "{ray:?}");
    }
    for eye in [Vec3::ZERO, Vec3::new(m, 5.5, 5.5), Vec3::splat(-m)] {
        let frustum =
            Frustum::perspective(eye, Quat::IDENTITY, 1.2, 1.5, 0.1, f32::INFINITY).unwrap();
        for mode in [CullMode::Conservative, CullMode::Exact] {
            assert_eq!(
                tree.visible(&frustum, mode),
                oracle.visible(&frustum, mode),
                "{eye} {mode:?}"
            );
        }
    }
    for mode in [JoinMode::Euclidean, JoinMode::Chebyshev] {
        for d in [0.0, 5.0, 1e9] {
            assert_eq!(
                tree.self_join(d, mode),
                oracle.self_join(d, mode),
                "{d} {mode:?}"
            );
        }
    }
    for point in [Vec3::new(m, 0.0, 0.0), Vec3::splat(-m), Vec3::splat(1.5)] {
        let keys = |n: Vec<bevy_rtree::Neighbor<u32>>| -> Vec<(u32, f64)> {
            n.iter().map(|n| (n.key, n.distance_sq)).collect()
        };
        assert_eq!(
            tree.nearest(point, 5, None).map(keys),
            oracle.nearest(point, 5, None).map(keys),
            "{point}"
        );
    }
    for id in ids {
        tree.remove(id).unwrap();
        tree.validate().unwrap();
    }
    assert_eq!(tree.len(), 1_000);
}
