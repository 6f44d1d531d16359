//! The frame's mode comparisons on the default tree: conservative against
//! exact culling, batched against single rays, Chebyshev against Euclidean
//! joins, each answer held to the oracle's, each figure kept per frame.

use std::time::Instant;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{CullMode, JoinMode, QueryWorkspace, RayHit, RayResults};

use crate::contenders::{Joined, Kept};
use crate::measure::ms_since;
use crate::{CULL_REPS, RAY_COUNT, RAY_ORACLE_EVERY, RAY_REPS};

/// The per-frame figures of the mode comparisons on the default tree.
#[derive(Default)]
pub struct FrameFigures {
    /// `[conservative, exact]`.
    pub cull_ms: [Vec<f64>; 2],
    pub visible_exact: Vec<f64>,
    pub visible_conservative: Vec<f64>,
    pub cull_false_positives: Vec<f64>,
    pub cull_false_share: Vec<f64>,
    /// `[Chebyshev, Euclidean]`.
    pub join_ms: [Vec<f64>; 2],
    pub pairs_euclidean: Vec<f64>,
    pub pairs_chebyshev: Vec<f64>,
    pub join_extra: Vec<f64>,
    pub join_extra_share: Vec<f64>,
    /// `[incoherent, coherent]` x `[batched, single]`.
    pub ray_ms: [[Vec<f64>; 2]; 2],
    pub ray_hits: [Vec<f64>; 2],
    pub ray_frames_compared: usize,
    pub ray_frames_oracle: usize,
}

const CULL_MODES: [CullMode; 2] = [CullMode::Conservative, CullMode::Exact];
const JOIN_MODES: [JoinMode; 2] = [JoinMode::Chebyshev, JoinMode::Euclidean];

/// Culls, rays and joins of one frame on the default tree and the kept
/// enemy and barrel trees, each checked against the oracle.
pub fn frame_modes(
    frame: usize,
    last: bool,
    default: &dyn Kept,
    joined: &dyn Joined,
    scene: &mut TownScene,
    oracles: [&BruteForce<u32>; 3],
    figures: &mut FrameFigures,
) {
    let [oracle, enemy_oracle, barrel_oracle] = oracles;
    let mut ws = QueryWorkspace::default();

    // Culling: both modes, interleaved, the first mode alternating.
    let frustum = scene.frustum();
    let mut visible: [Vec<u32>; 2] = Default::default();
    for rep in 0..CULL_REPS {
        for k in 0..2 {
            let m = (k + rep + frame) % 2;
            visible[m].clear();
            let start = Instant::now();
            default.cull_into(&frustum, CULL_MODES[m], &mut ws, &mut visible[m]);
            figures.cull_ms[m].push(ms_since(start));
        }
    }
    for (m, list) in visible.iter_mut().enumerate() {
        list.sort_unstable();
        let expected = oracle.visible(&frustum, CULL_MODES[m]);
        assert_eq!(
            *list, expected,
            "{:?} cull differs from the oracle",
            CULL_MODES[m]
        );
    }
    // Exact is conservative plus a separating-axis test: a subset.
    assert!(
        visible[1]
            .iter()
            .all(|k| visible[0].binary_search(k).is_ok()),
        "the exact cull is not within the conservative one"
    );
    let exact = visible[1].len() as f64;
    let false_positives = (visible[0].len() - visible[1].len()) as f64;
    figures.visible_exact.push(exact);
    figures.visible_conservative.push(visible[0].len() as f64);
    figures.cull_false_positives.push(false_positives);
    figures
        .cull_false_share
        .push(false_positives / exact.max(1.0));

    // Rays: batched and single, incoherent then coherent, order alternating.
    let ray_sets = [scene.incoherent_rays(RAY_COUNT), scene.coherent_rays()];
    let check_oracle = frame.is_multiple_of(RAY_ORACLE_EVERY) || last;
    for (r, rays) in ray_sets.iter().enumerate() {
        let mut batched = RayResults::default();
        let mut single: Vec<Option<RayHit<u32>>> = Vec::with_capacity(rays.len());
        for k in 0..2 * RAY_REPS {
            let start = Instant::now();
            if (k + frame).is_multiple_of(2) {
                default.cast_rays_first(rays, &mut ws, &mut batched);
                figures.ray_ms[r][0].push(ms_since(start));
            } else {
                single.clear();
                single.extend(rays.iter().map(|ray| default.cast_ray_first(ray, &mut ws)));
                figures.ray_ms[r][1].push(ms_since(start));
            }
        }
        for (i, hit) in single.iter().enumerate() {
            assert_eq!(
                batched.first(i).expect("valid ray"),
                *hit,
                "batched and single rays differ"
            );
        }
        if check_oracle {
            for (ray, hit) in rays.iter().zip(&single) {
                assert_eq!(
                    oracle.ray_first(ray).expect("valid ray"),
                    *hit,
                    "ray differs from the oracle"
                );
            }
        }
        figures.ray_hits[r].push(single.iter().flatten().count() as f64);
    }
    figures.ray_frames_compared += 1;
    figures.ray_frames_oracle += usize::from(check_oracle);

    // Joins on the kept enemy and barrel trees, the first mode alternating.
    let mut pairs: [Vec<(u32, u32)>; 2] = Default::default();
    for k in 0..2 {
        let m = (k + frame) % 2;
        pairs[m].clear();
        let start = Instant::now();
        joined.cross_join_into(JOIN_MODES[m], &mut ws, &mut pairs[m]);
        figures.join_ms[m].push(ms_since(start));
    }
    for (m, list) in pairs.iter_mut().enumerate() {
        list.sort_unstable();
        let expected = enemy_oracle
            .cross_join(barrel_oracle, TownScene::JOIN_DISTANCE, JOIN_MODES[m])
            .expect("a valid distance");
        assert_eq!(
            *list, expected,
            "{:?} join differs from the oracle",
            JOIN_MODES[m]
        );
    }
    // Chebyshev accepts every Euclidean pair, so the difference is extra.
    assert!(
        pairs[1].iter().all(|p| pairs[0].binary_search(p).is_ok()),
        "the Euclidean pairs are not within the Chebyshev ones"
    );
    let euclidean = pairs[1].len() as f64;
    let extra = (pairs[0].len() - pairs[1].len()) as f64;
    figures.pairs_euclidean.push(euclidean);
    figures.pairs_chebyshev.push(pairs[0].len() as f64);
    figures.join_extra.push(extra);
    figures.join_extra_share.push(extra / euclidean.max(1.0));
}
