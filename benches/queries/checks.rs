//! Every contender held to the oracle on every timed input, before any
//! timing counts.

use super::brute_force::Sweep;
use super::common::sorted;
use super::peers::{
    Planes, RayPrep, parry_build_and_cross_join, parry_cross_join, parry_first_hit, parry_leaves,
    parry_self_join, parry_visible_into, rstar_cross_join, rstar_first_hit, rstar_self_join,
    rstar_visible_into,
};
use super::{Contenders, SELF_JOIN_DISTANCE, n};
use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, CullMode, JoinMode, QueryWorkspace, RayHit, RayMode, RayResults};
use parry3d::partitioning::BvhWorkspace;
use std::ops::Range;
use std::time::Instant;

// Checks.

/// Panics with the first differences when `got` (sorted) is not `want`.
pub(crate) fn assert_same<T: Ord + std::fmt::Debug>(who: &str, what: &str, got: &[T], want: &[T]) {
    if got != want {
        let missing: Vec<_> = want
            .iter()
            .filter(|k| got.binary_search(k).is_err())
            .take(10)
            .collect();
        let extra: Vec<_> = got
            .iter()
            .filter(|k| want.binary_search(k).is_err())
            .take(10)
            .collect();
        panic!(
            "{who} disagrees with the oracle on {what}: {} answers vs {}; first missing {missing:?}, first extra {extra:?}",
            got.len(),
            want.len()
        );
    }
}

/// Compares one ray's first hit with the oracle's sorted hits. With
/// `tie_ok`, another key hit at exactly the first `t` is accepted; returns
/// whether that happened.
pub(crate) fn check_ray(
    who: &str,
    ray_index: usize,
    got: Option<(u32, f32)>,
    hits: &[RayHit<u32>],
    tie_ok: bool,
) -> bool {
    let want = hits.first().map(|h| (h.key, h.t));
    let same = |a: Option<(u32, f32)>, b: Option<(u32, f32)>| match (a, b) {
        (None, None) => true,
        (Some((ka, ta)), Some((kb, tb))) => ka == kb && ta.to_bits() == tb.to_bits(),
        _ => false,
    };
    if same(got, want) {
        return false;
    }
    if tie_ok
        && let (Some((key, t)), Some((_, first_t))) = (got, want)
        && t.to_bits() == first_t.to_bits()
        && hits
            .iter()
            .take_while(|h| h.t == first_t)
            .any(|h| h.key == key)
    {
        return true;
    }
    panic!("{who} disagrees with the oracle on ray {ray_index}: got {got:?}, want {want:?}");
}

pub(crate) fn hit_pair(hit: Option<RayHit<u32>>) -> Option<(u32, f32)> {
    hit.map(|h| (h.key, h.t))
}

pub(crate) fn oracle_of(boxes: &[Aabb], range: Range<usize>) -> BruteForce<u32> {
    let mut oracle = BruteForce::default();
    for i in range {
        oracle.insert(i as u32, boxes[i]);
    }
    oracle
}

/// Compares every contender with the oracle on every timed input, and prints
/// the answer sizes and bevy_rtree's work per query.
pub(crate) fn check(c: &Contenders) {
    let start = Instant::now();
    let boxes = &c.boxes;
    let oracle = oracle_of(boxes, 0..n());
    let mut ws = QueryWorkspace::default();
    let per = |total: u64, count: usize| total as f64 / count as f64;

    // Frustums.
    let mut visible = 0usize;
    for (f, frustum) in c.frustums.iter().enumerate() {
        let what = format!("frustum of frame {}", f + 1);
        let want = oracle.visible(frustum, CullMode::Conservative);
        visible += want.len();
        let mut out = vec![Vec::new()];
        c.bevy.tree.visible_into(
            std::slice::from_ref(frustum),
            CullMode::Conservative,
            &mut ws,
            &mut out,
        );
        let got = out.pop().unwrap_or_default();
        assert_same("bevy_rtree", &what, &sorted(got), &want);
        let planes = Planes::new(frustum);
        let mut got = Vec::new();
        parry_visible_into(&c.parry.bvh, &planes, &mut got);
        assert_same("parry3d", &what, &sorted(got), &want);
        let mut got = Vec::new();
        rstar_visible_into(&c.rstar.tree, &planes, &mut got);
        assert_same("rstar", &what, &sorted(got), &want);
        let mut got = Vec::new();
        c.soa.visible_into(&planes, &mut got);
        assert_same("brute_force", &what, &got, &want);
    }
    let s = ws.take_stats();
    let views = c.frustums.len();
    eprintln!(
        "check frustum ok: {views} views, {:.0} visible per view; bevy_rtree per view: {:.0} nodes visited, {:.0} entries tested",
        per(visible as u64, views),
        per(s.nodes_visited, views),
        per(s.entries_tested, views)
    );

    // Rays.
    let kinds = [
        ("incoherent", &c.incoherent),
        ("coherent", &c.coherent),
        ("coherent, clear eye", &c.coherent_clear_eye),
    ];
    for (kind, batches) in kinds {
        let (mut hits, mut at_zero, mut parry_ties) = (0usize, 0usize, 0usize);
        let mut single_ws = QueryWorkspace::default();
        let mut results = RayResults::default();
        let rays_total: usize = batches.iter().map(Vec::len).sum();
        for rays in batches.iter() {
            c.bevy
                .tree
                .cast_rays(rays, RayMode::First, &mut ws, &mut results);
            for (i, ray) in rays.iter().enumerate() {
                let all = oracle.ray_hits(ray).expect("the scene's rays are valid");
                hits += !all.is_empty() as usize;
                at_zero += all.first().is_some_and(|h| h.t == 0.0) as usize;
                let batched = hit_pair(results.first(i).expect("valid ray"));
                check_ray("bevy_rtree (cast_rays)", i, batched, &all, false);
                let single = c
                    .bevy
                    .tree
                    .cast_ray(ray, &mut single_ws)
                    .expect("valid ray");
                check_ray("bevy_rtree (cast_ray)", i, hit_pair(single), &all, false);
                let parry = parry_first_hit(&c.parry.bvh, boxes, ray);
                parry_ties += check_ray("parry3d", i, parry, &all, true) as usize;
                check_ray("rstar", i, rstar_first_hit(&c.rstar.tree, ray), &all, false);
                let brute = c.soa.first_hit(&RayPrep::new(ray));
                check_ray("brute_force", i, brute, &all, false);
            }
        }
        let (s, s1) = (ws.take_stats(), single_ws.take_stats());
        let batches_n = batches.len();
        eprintln!(
            "check rays {kind} ok: {batches_n} batches of {} rays, {:.0} % hit, {:.0} % first hit at t = 0 (origin in a box); parry3d named another key at a tied t on {parry_ties} rays; bevy_rtree cast_rays per batch: {:.0} nodes visited, {:.0} ray-entry tests; cast_ray per ray: {:.1} nodes, {:.1} entries",
            rays_total / batches_n.max(1),
            100.0 * hits as f64 / rays_total as f64,
            100.0 * at_zero as f64 / rays_total as f64,
            per(s.nodes_visited, batches_n),
            per(s.entries_tested, batches_n),
            per(s1.nodes_visited, rays_total),
            per(s1.entries_tested, rays_total),
        );
    }

    eprintln!(
        "the eye is inside {} boxes: every coherent ray starts inside them, so its first hit is at t = 0 and S5 ties are broken by key among them",
        oracle.containing_point(TownScene::eye()).len()
    );
    eprintln!(
        "the clear eye of queries/rays_coherent_clear_eye is {:?}, inside no box",
        c.coherent_clear_eye[0][0].origin
    );

    // Cross join.
    let d = TownScene::JOIN_DISTANCE;
    let want = oracle_of(boxes, TownScene::ENEMIES)
        .cross_join(
            &oracle_of(boxes, TownScene::BARRELS),
            d,
            JoinMode::Euclidean,
        )
        .expect("valid distance");
    let what = "the cross join";
    let mut got = Vec::new();
    c.bevy_enemies
        .tree
        .cross_join_into(
            &c.bevy_barrels.tree,
            d,
            JoinMode::Euclidean,
            &mut ws,
            &mut got,
        )
        .expect("valid distance");
    assert_same("bevy_rtree", what, &sorted(got), &want);
    let s = ws.take_stats();
    let mut got = Vec::new();
    let (enemy_leaves, barrel_leaves) = (
        parry_leaves(boxes, TownScene::ENEMIES),
        parry_leaves(boxes, TownScene::BARRELS),
    );
    parry_build_and_cross_join(&enemy_leaves, &barrel_leaves, boxes, d, &mut got);
    assert_same("parry3d_with_build", what, &sorted(got), &want);
    let mut got = Vec::new();
    parry_cross_join(
        &c.parry_enemies.bvh,
        &c.parry_barrels.bvh,
        boxes,
        d,
        &mut got,
    );
    assert_same("parry3d_maintained", what, &sorted(got), &want);
    let mut got = Vec::new();
    rstar_cross_join(
        &c.rstar_enemies_grown.tree,
        &c.rstar_barrels.tree,
        boxes,
        d,
        &mut got,
    );
    assert_same("rstar", what, &sorted(got), &want);
    let mut got = Vec::new();
    Sweep::default().cross_join(boxes, TownScene::ENEMIES, TownScene::BARRELS, d, &mut got);
    assert_same("brute_force", what, &sorted(got), &want);
    eprintln!(
        "check cross join ok: {} pairs; bevy_rtree: {} node pairs visited, {} entry pairs tested",
        want.len(),
        s.nodes_visited,
        s.entries_tested
    );

    // Self join.
    let want = oracle
        .self_join(SELF_JOIN_DISTANCE, JoinMode::Euclidean)
        .expect("valid distance");
    let what = "the self join";
    let mut got = Vec::new();
    c.bevy
        .tree
        .self_join_into(SELF_JOIN_DISTANCE, JoinMode::Euclidean, &mut ws, &mut got)
        .expect("valid distance");
    assert_same("bevy_rtree", what, &sorted(got), &want);
    let s = ws.take_stats();
    let mut got = Vec::new();
    parry_self_join(
        &c.parry.bvh,
        &mut BvhWorkspace::default(),
        SELF_JOIN_DISTANCE,
        &mut got,
    );
    assert_same("parry3d", what, &sorted(got), &want);
    let mut got = Vec::new();
    rstar_self_join(&c.rstar.tree, SELF_JOIN_DISTANCE, &mut got);
    assert_same("rstar", what, &sorted(got), &want);
    let mut got = Vec::new();
    Sweep::default().self_join(boxes, SELF_JOIN_DISTANCE, &mut got);
    assert_same("brute_force", what, &sorted(got), &want);
    eprintln!(
        "check self join ok: {} pairs; bevy_rtree: {} node pairs visited, {} entry pairs tested",
        want.len(),
        s.nodes_visited,
        s.entries_tested
    );
    eprintln!(
        "all answers equal the oracle's ({:.1} s)\n",
        start.elapsed().as_secs_f64()
    );
}
