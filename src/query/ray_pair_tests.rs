//! The lock-step walk of two rays ([`RTree::walk_pair_with`]) on the
//! four-lane lane test: each ray reports the hits, ends with the limit and
//! visits the nodes of its own walk ([`RTree::walk_with`]). The AVX-512
//! walk runs this same code with its own lane test (which `ray_avx512`'s
//! tests hold to the four-lane one where the processor has AVX-512): here
//! the pairing itself is checked on every processor.

use std::ops::ControlFlow;

use glam::Vec3;

use super::ray::push_far_to_near;
use super::ray_lanes::ray_lanes;
use crate::geometry::predicates::RayTest;
use crate::geometry::{Aabb, Ray};
use crate::scene::SceneRng;
use crate::tree::{QueryStats, RTree};

/// What one ray's walk gave: its hits in the order reported, its final
/// limit, and the nodes it visited.
pub(super) type Walked = (Vec<(u32, f32)>, f32, u64);

/// A visitor that records every hit and either keeps the limit (every hit)
/// or shrinks it to the nearest hit so far (first hit), as the queries do.
pub(super) fn recorder(
    hits: &mut Vec<(u32, f32)>,
    limit: f32,
    first_hit: bool,
) -> impl FnMut(u32, f32) -> ControlFlow<(), f32> + '_ {
    let mut best = limit;
    move |proxy, t| {
        hits.push((proxy, t));
        if first_hit && t < best {
            best = t;
        }
        ControlFlow::Continue(best)
    }
}

pub(super) fn alone<const W: usize>(
    tree: &RTree<u32, W>,
    test: &RayTest,
    limit: f32,
    first: bool,
) -> Walked {
    let (mut hits, mut stack, mut stats) = (Vec::new(), Vec::new(), QueryStats::default());
    let end = tree.walk_with(
        tree.root(),
        test,
        limit,
        &mut stack,
        &mut stats,
        recorder(&mut hits, limit, first),
        ray_lanes::<W>,
        push_far_to_near::<W>,
    );
    (hits, end, stats.nodes_visited)
}

fn paired<const W: usize>(
    tree: &RTree<u32, W>,
    tests: [&RayTest; 2],
    limits: [f32; 2],
    first: bool,
) -> ([Walked; 2], u64) {
    let (mut hits_a, mut hits_b) = (Vec::new(), Vec::new());
    let (mut stack_a, mut stack_b) = (Vec::new(), Vec::new());
    let mut stats = QueryStats::default();
    let ends = tree.walk_pair_with(
        tree.root(),
        tests,
        limits,
        [&mut stack_a, &mut stack_b],
        &mut stats,
        (
            recorder(&mut hits_a, limits[0], first),
            recorder(&mut hits_b, limits[1], first),
        ),
        ray_lanes::<W>,
        push_far_to_near::<W>,
    );
    (
        [(hits_a, ends[0], 0), (hits_b, ends[1], 0)],
        stats.nodes_visited,
    )
}

/// A tree of `entries` boxes (keys `0..entries`) with corners in
/// `[0, world]` and sides in `sides`, inserted one by one.
pub(super) fn random_tree<const W: usize>(
    rng: &mut SceneRng,
    entries: u32,
    world: Vec3,
    sides: (f32, f32),
) -> RTree<u32, W> {
    let mut tree = RTree::<u32, W>::with_settings(Default::default()).unwrap();
    for key in 0..entries {
        let at = Vec3::new(
            rng.range(0.0, world.x),
            rng.range(0.0, world.y),
            rng.range(0.0, world.z),
        );
        let size = Vec3::new(
            rng.range(sides.0, sides.1),
            rng.range(sides.0, sides.1),
            rng.range(sides.0, sides.1),
        );
        tree.insert(key, Aabb::new(at, at + size).unwrap()).unwrap();
    }
    tree
}

fn check_pairs<const W: usize>(seed: u64) {
    let mut rng = SceneRng::new(seed);
    let tree = random_tree::<W>(&mut rng, 3_000, Vec3::new(200.0, 40.0, 200.0), (0.5, 8.0));
    let mut hits = 0;
    for pair in 0..400 {
        let origin = Vec3::new(
            rng.range(-20.0, 220.0),
            rng.range(0.0, 50.0),
            rng.range(-20.0, 220.0),
        );
        let mut directions = [rng.direction(), rng.direction()];
        // Some along a plane (a flat axis), some the same direction twice.
        match pair % 4 {
            0 => directions[1].y = 0.0,
            1 => directions[1] = directions[0],
            _ => {}
        }
        let max_t = [f32::INFINITY, rng.range(5.0, 150.0)][pair % 2];
        let rays = directions.map(|d| {
            Ray::new(origin, d, max_t)
                .and_then(|r| r.canonicalized())
                .unwrap()
        });
        let tests = rays.map(|r| RayTest::new(&r));
        for first in [false, true] {
            let each = [0, 1].map(|i| alone(&tree, &tests[i], max_t, first));
            let (walked, visited) = paired(&tree, [&tests[0], &tests[1]], [max_t; 2], first);
            for i in 0..2 {
                assert_eq!(walked[i].0, each[i].0, "pair {pair}, ray {i}: hits");
                assert_eq!(walked[i].1, each[i].1, "pair {pair}, ray {i}: limit");
            }
            assert_eq!(visited, each[0].2 + each[1].2, "pair {pair}: nodes");
            hits += each[0].0.len() + each[1].0.len();
        }
    }
    assert!(hits > 1_000, "{hits} hits: enough to compare");
}

#[test]
fn two_rays_in_lock_step_walk_as_each_walks_alone() {
    check_pairs::<16>(1);
    check_pairs::<8>(2);
    check_pairs::<4>(3);
}
