//! Timing and the measurements made on every contender at once: each
//! answer checked against the oracle first, then the timed runs round robin
//! across trees so that none is always the first to meet a cold cache.

use std::ops::Range;
use std::time::Instant;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, QueryWorkspace, Ray, RayHit, RayResults, TreeSettings,
};
use glam::Vec3;

use crate::contenders::{BoxCost, Contender, Index, Joined, Kept, WorkCost};
use crate::{
    BOX_QUERY_HALF, BUILD_REPS, CHURNED_CULL_REPS, JOIN_RAY_REPS, QUERY_REPS, WIDTH_REPS, WIDTHS,
};

pub(crate) fn ms_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

pub(crate) fn ms_between(start: Instant, end: Instant) -> f64 {
    (end - start).as_secs_f64() * 1e3
}

pub(crate) fn median(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let mid = v.len() / 2;
    if v.len() % 2 == 1 {
        v[mid]
    } else {
        (v[mid - 1] + v[mid]) / 2.0
    }
}

pub(crate) fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len().max(1) as f64
}

pub(crate) fn min_max(values: &[f64]) -> (f64, f64) {
    values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        })
}

pub(crate) fn oracle_of(boxes: &[Aabb], range: Range<usize>) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for i in range {
        oracle.insert(i as u32, boxes[i]);
    }
    oracle
}

/// Boxes of half extent `BOX_QUERY_HALF` around the current centres of the
/// `around` entities, so queries land where the entities are, as gameplay
/// queries do. The same entities serve before and after the churn, so the
/// two measurements differ by the trees, not by a new sample of queries.
pub(crate) fn box_queries(boxes: &[Aabb], around: &[usize]) -> Vec<Aabb> {
    around
        .iter()
        .map(|&i| {
            let b = boxes[i];
            Aabb::from_center_half_extents((b.min + b.max) * 0.5, Vec3::splat(BOX_QUERY_HALF))
                .expect("a valid query box")
        })
        .collect()
}

/// Checks every contender's answers to `queries` against `truth`, counts
/// its work, then times the set `QUERY_REPS` times per tree, round robin
/// across trees.
pub(crate) fn measure_box_queries(
    contenders: &[Contender],
    queries: &[Aabb],
    truth: &[Vec<u32>],
) -> Vec<BoxCost> {
    let answers: usize = truth.iter().map(Vec::len).sum();
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    let mut costs: Vec<BoxCost> = contenders
        .iter()
        .map(|c| {
            ws.take_stats();
            for (query, expected) in queries.iter().zip(truth) {
                out.clear();
                c.index.overlapping_into(query, &mut ws, &mut out);
                out.sort_unstable();
                assert_eq!(
                    &out, expected,
                    "{}: box query differs from the oracle",
                    c.label
                );
            }
            let stats = ws.take_stats();
            BoxCost {
                ms: 0.0,
                extra_per_query: (stats.entries_tested as usize - answers) as f64
                    / queries.len() as f64,
                nodes_per_query: stats.nodes_visited as f64 / queries.len() as f64,
            }
        })
        .collect();
    let n = contenders.len();
    let mut times = vec![Vec::with_capacity(QUERY_REPS); n];
    for rep in 0..QUERY_REPS {
        for k in 0..n {
            let i = (k + rep) % n;
            let start = Instant::now();
            for query in queries {
                out.clear();
                contenders[i]
                    .index
                    .overlapping_into(query, &mut ws, &mut out);
            }
            times[i].push(ms_since(start));
        }
    }
    for (cost, t) in costs.iter_mut().zip(&times) {
        cost.ms = median(t);
    }
    costs
}

/// Checks every contender's self join (d = 0) against the oracle and its
/// first hits of `rays` against `hits` (the oracle's), counts the nodes they visit, then times both
/// `JOIN_RAY_REPS` times per tree, round robin across trees. These are the
/// queries that descend the most internal nodes, where fat bounds cost.
pub(crate) fn measure_churned_joins_and_rays(
    contenders: &[Contender],
    rays: &[Ray],
    hits: &[Option<RayHit<u32>>],
    oracle: &BruteForce<u32>,
) -> Vec<[WorkCost; 2]> {
    let pairs = oracle
        .self_join(0.0, JoinMode::Euclidean)
        .expect("a valid distance");
    let mut ws = QueryWorkspace::default();
    let mut results = RayResults::default();
    let mut out = Vec::new();
    let mut costs: Vec<[WorkCost; 2]> = contenders
        .iter()
        .map(|c| {
            ws.take_stats();
            out.clear();
            c.index.self_join_into(&mut ws, &mut out);
            let join = ws.take_stats();
            out.sort_unstable();
            assert!(
                out == pairs,
                "{}: self join differs from the oracle",
                c.label
            );
            c.index.cast_rays_first(rays, &mut ws, &mut results);
            let ray = ws.take_stats();
            for (i, hit) in hits.iter().enumerate() {
                assert_eq!(
                    results.first(i).expect("valid ray"),
                    *hit,
                    "{}: ray differs from the oracle",
                    c.label
                );
            }
            [join.nodes_visited, ray.nodes_visited].map(|nodes| WorkCost { ms: 0.0, nodes })
        })
        .collect();
    let n = contenders.len();
    let mut times = vec![[Vec::new(), Vec::new()]; n];
    for rep in 0..JOIN_RAY_REPS {
        for k in 0..n {
            let i = (k + rep) % n;
            out.clear();
            let start = Instant::now();
            contenders[i].index.self_join_into(&mut ws, &mut out);
            times[i][0].push(ms_since(start));
            let start = Instant::now();
            contenders[i]
                .index
                .cast_rays_first(rays, &mut ws, &mut results);
            times[i][1].push(ms_since(start));
        }
    }
    for (cost, t) in costs.iter_mut().zip(&times) {
        cost[0].ms = median(&t[0]);
        cost[1].ms = median(&t[1]);
    }
    costs
}

/// Checks every contender's conservative culls of the recorded frustums
/// against the oracle, then times them, round robin across trees.
pub(crate) fn measure_churned_culls(
    contenders: &[Contender],
    frustums: &[Frustum],
    oracle: &BruteForce<u32>,
) -> Vec<f64> {
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    for frustum in frustums {
        let expected = oracle.visible(frustum, CullMode::Conservative);
        for c in contenders {
            out.clear();
            c.index
                .cull_into(frustum, CullMode::Conservative, &mut ws, &mut out);
            out.sort_unstable();
            assert_eq!(out, expected, "{}: cull differs from the oracle", c.label);
        }
    }
    let n = contenders.len();
    let mut times = vec![Vec::new(); n];
    for rep in 0..CHURNED_CULL_REPS {
        for (f, frustum) in frustums.iter().enumerate() {
            for k in 0..n {
                let i = (k + f + rep) % n;
                out.clear();
                let start = Instant::now();
                contenders[i]
                    .index
                    .cull_into(frustum, CullMode::Conservative, &mut ws, &mut out);
                times[i].push(ms_since(start));
            }
        }
    }
    times.iter().map(|t| median(t)).collect()
}

/// Median bulk-load time of the whole scene per node width, builds
/// interleaved across widths.
pub(crate) fn measure_builds(boxes: &[Aabb]) -> [f64; 3] {
    let mut times: [Vec<f64>; 3] = Default::default();
    let settings = TreeSettings::default();
    let all = || 0..boxes.len();
    for rep in 0..BUILD_REPS {
        for k in 0..3 {
            let w = (k + rep) % 3;
            let start = Instant::now();
            let height = match WIDTHS[w] {
                4 => Index::<4>::load(boxes, all(), settings).tree.height(),
                8 => Index::<8>::load(boxes, all(), settings).tree.height(),
                _ => Index::<16>::load(boxes, all(), settings).tree.height(),
            };
            // Includes dropping the tree, as a rebuild would.
            times[w].push(ms_since(start));
            std::hint::black_box(height);
        }
    }
    times.map(|t| median(&t))
}

/// Batched rays and the Euclidean join per node width on the final state,
/// each checked against the oracle, timed round robin across widths.
pub(crate) fn measure_width_queries(
    trees: [&dyn Kept; 3],
    joins: &[Box<dyn Joined>],
    ray_sets: &[Vec<Ray>; 2],
    ray_truth: &[Vec<Option<RayHit<u32>>>; 2],
    pairs: &[(u32, u32)],
) -> ([[f64; 2]; 3], [f64; 3]) {
    let mut ws = QueryWorkspace::default();
    let mut results = RayResults::default();
    let mut out = Vec::new();
    for (rays, expected) in ray_sets.iter().zip(ray_truth) {
        for tree in trees {
            tree.cast_rays_first(rays, &mut ws, &mut results);
            for (i, hit) in expected.iter().enumerate() {
                assert_eq!(
                    results.first(i).expect("valid ray"),
                    *hit,
                    "ray differs from the oracle"
                );
            }
        }
    }
    for join in joins {
        out.clear();
        join.cross_join_into(JoinMode::Euclidean, &mut ws, &mut out);
        out.sort_unstable();
        assert_eq!(out, pairs, "join differs from the oracle");
    }
    let mut ray_times: [[Vec<f64>; 2]; 3] = Default::default();
    let mut join_times: [Vec<f64>; 3] = Default::default();
    for rep in 0..WIDTH_REPS {
        for k in 0..3 {
            let w = (k + rep) % 3;
            for (r, rays) in ray_sets.iter().enumerate() {
                let start = Instant::now();
                trees[w].cast_rays_first(rays, &mut ws, &mut results);
                ray_times[w][r].push(ms_since(start));
            }
            out.clear();
            let start = Instant::now();
            joins[w].cross_join_into(JoinMode::Euclidean, &mut ws, &mut out);
            join_times[w].push(ms_since(start));
        }
    }
    (
        ray_times.map(|[a, b]| [median(&a), median(&b)]),
        join_times.map(|t| median(&t)),
    )
}
