//! `split/*`: the node split strategies (`TreeSettings::split`) side by
//! side on what a split decides: the cost of single inserts and of a
//! frame's moves, and the quality of the tree those leave behind.

use super::box_queries::bench_tree_boxes;
use super::common::sorted;
use super::inputs::{assert_same, bulk_tree, oracle_of, query_boxes};
use super::moves::BevyMoves;
use super::{CHURN_FRAMES, QUERY_COUNT, SEED};
use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, QueryWorkspace, RTree, SplitStrategy, TreeSettings};
use criterion::{BatchSize, Criterion, SamplingMode};

pub(crate) const SPLITS: [(&str, SplitStrategy); 3] = [
    ("rstar", SplitStrategy::RStar),
    ("quadratic", SplitStrategy::Quadratic),
    ("median", SplitStrategy::Median),
];

pub(crate) fn split_settings(split: SplitStrategy) -> TreeSettings {
    TreeSettings {
        split,
        ..TreeSettings::default()
    }
}

pub(crate) fn inserted_tree(boxes: &[Aabb], settings: TreeSettings) -> RTree<u32> {
    let mut tree = RTree::with_settings(settings).expect("valid settings");
    for (i, aabb) in boxes.iter().enumerate() {
        tree.insert(i as u32, *aabb).unwrap();
    }
    tree
}

/// Average nodes visited and entries tested per query of `queries`, after
/// checking every answer against `oracle`.
pub(crate) fn checked_query_work(
    who: &str,
    tree: &RTree<u32>,
    oracle: &BruteForce<u32>,
    queries: &[Aabb],
) -> (f64, f64) {
    let mut ws = QueryWorkspace::default();
    for q in queries {
        let mut got = Vec::new();
        tree.overlapping_into(q, &mut ws, &mut got);
        assert_same(who, q, &sorted(got), &oracle.overlapping(q));
    }
    let s = ws.take_stats();
    let n = queries.len() as f64;
    (s.nodes_visited as f64 / n, s.entries_tested as f64 / n)
}

pub(crate) fn bench_splits(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let boxes = scene.boxes().to_vec();
    let queries = query_boxes(QUERY_COUNT, SEED ^ 0x0E17);

    let oracle = oracle_of(&boxes);
    for (name, split) in SPLITS {
        let tree = inserted_tree(&boxes, split_settings(split));
        tree.validate().unwrap();
        let (nodes, entries) = checked_query_work(name, &tree, &oracle, &queries);
        eprintln!(
            "split check ok: {name} after 100,000 inserts: height {}, {} nodes; per query {nodes:.1} nodes, {entries:.1} entries tested",
            tree.height(),
            tree.node_count()
        );
    }
    let mut group = c.benchmark_group("split/insert_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    for (name, split) in SPLITS {
        group.bench_function(name, |b| {
            b.iter_batched(
                || (),
                |()| inserted_tree(&boxes, split_settings(split)),
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();

    // Each strategy's tree goes through the same frames: first the moves
    // group's (timed, as many as criterion runs), then untimed ones until all
    // trees reach the same frame, at least `CHURN_FRAMES`; the queries are
    // timed on the boxes of that frame.
    let mut churned = Vec::new();
    let mut group = c.benchmark_group("split/moves_10k");
    for (name, split) in SPLITS {
        let mut moves = BevyMoves::with_settings(&scene, true, split_settings(split));
        group.bench_function(name, |b| b.iter_custom(|iters| moves.frame(iters)));
        churned.push(moves);
    }
    group.finish();
    let last_frame = churned
        .iter()
        .map(|m| m.scene.frame())
        .max()
        .unwrap_or(0)
        .max(CHURN_FRAMES as u64);
    for moves in &mut churned {
        let left = last_frame - moves.scene.frame();
        moves.frame(left);
    }
    let oracle = oracle_of(churned[0].scene.boxes());
    let (fresh, _) = bulk_tree(churned[0].scene.boxes());
    let (fresh_nodes, fresh_entries) = checked_query_work("fresh", &fresh, &oracle, &queries);
    eprintln!(
        "split check ok: bulk loaded at frame {last_frame}: height {}, {} nodes; per query {fresh_nodes:.1} nodes, {fresh_entries:.1} entries tested",
        fresh.height(),
        fresh.node_count()
    );
    for ((name, _), moves) in SPLITS.iter().zip(&churned) {
        moves.tree.validate().unwrap();
        let (nodes, entries) = checked_query_work(name, &moves.tree, &oracle, &queries);
        eprintln!(
            "split check ok: {name} churned to frame {last_frame}: height {}, {} nodes; per query {nodes:.1} nodes, {entries:.1} entries tested",
            moves.tree.height(),
            moves.tree.node_count()
        );
    }
    let mut group = c.benchmark_group("split/boxes_churned");
    let trees = std::iter::once(("bulk_loaded", &fresh)).chain(
        SPLITS
            .iter()
            .zip(&churned)
            .map(|((name, _), m)| (*name, &m.tree)),
    );
    for (name, tree) in trees {
        bench_tree_boxes(&mut group, name, tree, &queries);
    }
    group.finish();
}
