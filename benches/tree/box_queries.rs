//! `query/boxes`: 1,000 box queries on the scene, each contender on the
//! same boxes.

use super::brute_force::SoaBoxes;
use super::common::{sorted, to_parry};
use super::inputs::{
    answer_parry, answer_rstar, assert_same, bulk_tree, oracle_of, parry_leaves, query_boxes,
    rstar_envelope, rstar_items,
};
use super::moves::BevyMoves;
use super::{CHURN_FRAMES, QUERY_COUNT, SEED};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, QueryWorkspace, RTree};
use criterion::Criterion;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};
use std::hint::black_box;
use std::time::Instant;

/// Times one `query/boxes`-style iteration under `name`: every query of
/// `queries` answered by `answer` into a cleared, reused list.
pub(crate) fn bench_box_queries<Q>(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    queries: &[Q],
    mut answer: impl FnMut(&Q, &mut Vec<u32>),
) {
    group.bench_function(name, |b| {
        let mut out = Vec::new();
        b.iter(|| {
            let mut total = 0;
            for q in queries {
                out.clear();
                answer(q, &mut out);
                total += out.len();
            }
            black_box(total)
        })
    });
}

/// [`bench_box_queries`] on one of our trees.
pub(crate) fn bench_tree_boxes(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    tree: &RTree<u32>,
    queries: &[Aabb],
) {
    let mut ws = QueryWorkspace::default();
    bench_box_queries(group, name, queries, |q, out| {
        tree.overlapping_into(q, &mut ws, out)
    });
}

pub(crate) fn bench_queries(c: &mut Criterion) {
    // The churned tree: 600 frames of moves + optimize on the standard scene.
    let mut churn = BevyMoves::new(&TownScene::new(TownScene::STANDARD_COUNT, SEED), true);
    churn.tree.take_maintenance_stats();
    let start = Instant::now();
    churn.frame(CHURN_FRAMES as u64);
    let BevyMoves {
        scene,
        tree: mut churned,
        ..
    } = churn;
    churned.validate().unwrap();
    let s = churned.take_maintenance_stats();
    eprintln!(
        "churn {CHURN_FRAMES} frames ({:.1} s): moves in place {}, in leaf {}, reinserted {}; splits {}, condensed {}, repacks {}; height {}, nodes {}",
        start.elapsed().as_secs_f64(),
        s.moves_in_place,
        s.moves_in_leaf,
        s.moves_reinserted,
        s.splits,
        s.condensed_nodes,
        s.repacks,
        churned.height(),
        churned.node_count()
    );

    // Every other contender indexes the churned scene's current boxes.
    let boxes = scene.boxes().to_vec();
    let (fresh, _) = bulk_tree(&boxes);
    let rstar = rstar::RTree::bulk_load(rstar_items(&boxes));
    let parry = Bvh::from_leaves(BvhBuildStrategy::Binned, &parry_leaves(&boxes));
    let soa = SoaBoxes::new(&boxes);
    let queries = query_boxes(QUERY_COUNT, SEED ^ 0x0E17);
    let rstar_queries: Vec<_> = queries.iter().map(rstar_envelope).collect();
    let parry_queries: Vec<_> = queries.iter().map(to_parry).collect();

    // Check every contender on every query box. rstar and parry use closed
    // boxes like the oracle, with the same f32 comparisons, so the answers
    // must be identical (no tolerance for touching boxes is needed).
    let oracle = oracle_of(&boxes);
    let mut hits = 0usize;
    let mut ws_fresh = QueryWorkspace::default();
    let mut ws_churned = QueryWorkspace::default();
    for q in &queries {
        let want = oracle.overlapping(q);
        hits += want.len();
        let mut got = Vec::new();
        fresh.overlapping_into(q, &mut ws_fresh, &mut got);
        assert_same("bevy_rtree_fresh", q, &sorted(got), &want);
        let mut got = Vec::new();
        churned.overlapping_into(q, &mut ws_churned, &mut got);
        assert_same("bevy_rtree_churned", q, &sorted(got), &want);
        assert_same("rstar", q, &answer_rstar(&rstar, q), &want);
        assert_same("parry3d", q, &answer_parry(&parry, q), &want);
        let mut got = Vec::new();
        soa.overlapping_into(q, &mut got);
        assert_same("brute_force", q, &got, &want);
    }
    let per_query = |ws: &mut QueryWorkspace| {
        let s = ws.take_stats();
        (
            s.nodes_visited as f64 / QUERY_COUNT as f64,
            s.entries_tested as f64 / QUERY_COUNT as f64,
        )
    };
    let (fresh_nodes, fresh_entries) = per_query(&mut ws_fresh);
    let (churned_nodes, churned_entries) = per_query(&mut ws_churned);
    eprintln!(
        "query check ok: {QUERY_COUNT} boxes, {:.1} hits/query; per query fresh: {fresh_nodes:.1} nodes, {fresh_entries:.1} entries tested (height {}); churned: {churned_nodes:.1} nodes, {churned_entries:.1} entries (height {})",
        hits as f64 / QUERY_COUNT as f64,
        fresh.height(),
        churned.height()
    );

    let mut group = c.benchmark_group("query/boxes");
    for (name, tree) in [
        ("bevy_rtree_fresh", &fresh),
        ("bevy_rtree_churned", &churned),
    ] {
        bench_tree_boxes(&mut group, name, tree, &queries);
    }
    bench_box_queries(&mut group, "rstar", &rstar_queries, |q, out| {
        out.extend(rstar.locate_in_envelope_intersecting(*q).map(|g| g.data))
    });
    bench_box_queries(&mut group, "parry3d", &parry_queries, |q, out| {
        out.extend(parry.intersect_aabb(q))
    });
    bench_box_queries(&mut group, "brute_force", &queries, |q, out| {
        soa.overlapping_into(q, out)
    });
    group.finish();
}
