//! `build/*`: a whole tree from the scene's boxes, by bulk load and by
//! single inserts.

use super::inputs::{
    answer_parry, answer_rstar, assert_same, bulk_tree, keyed, oracle_of, parry_leaves,
    query_boxes, rstar_items,
};
use super::{MOVE_CHECK_QUERIES, SEED};
use bevy_rtree::RTree;
use bevy_rtree::scene::TownScene;
use criterion::{BatchSize, Criterion, SamplingMode};
use parry3d::partitioning::{Bvh, BvhBuildStrategy};
use std::hint::black_box;

pub(crate) fn bench_build(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let boxes = scene.boxes().to_vec();
    let parry = parry_leaves(&boxes);
    let rstar = rstar_items(&boxes);

    // Check every builder's output before timing.
    let oracle = oracle_of(&boxes);
    let checks = query_boxes(MOVE_CHECK_QUERIES, SEED ^ 0xB11D);
    {
        let (bulk, _) = bulk_tree(&boxes);
        bulk.validate().unwrap();
        let mut inserted = RTree::<u32>::new();
        for (i, b) in boxes.iter().enumerate() {
            inserted.insert(i as u32, *b).unwrap();
        }
        inserted.validate().unwrap();
        let rstar_bulk = rstar::RTree::bulk_load(rstar.clone());
        let mut rstar_ins = rstar::RTree::new();
        for item in &rstar {
            rstar_ins.insert(*item);
        }
        let parry_bulk = Bvh::from_leaves(BvhBuildStrategy::Binned, &parry);
        let mut parry_ins = Bvh::new();
        for (i, b) in parry.iter().enumerate() {
            parry_ins.insert(*b, i as u32);
        }
        for q in &checks {
            let want = oracle.overlapping(q);
            assert_same("bevy_rtree bulk", q, &bulk.overlapping(q), &want);
            assert_same("bevy_rtree insert", q, &inserted.overlapping(q), &want);
            assert_same("rstar bulk", q, &answer_rstar(&rstar_bulk, q), &want);
            assert_same("rstar insert", q, &answer_rstar(&rstar_ins, q), &want);
            assert_same("parry3d bulk", q, &answer_parry(&parry_bulk, q), &want);
            assert_same("parry3d insert", q, &answer_parry(&parry_ins, q), &want);
        }
        eprintln!(
            "build check ok: bevy_rtree height bulk {} / inserted {}, nodes {} / {}",
            bulk.height(),
            inserted.height(),
            bulk.node_count(),
            inserted.node_count()
        );
    }

    let mut group = c.benchmark_group("build/bulk_load_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    group.bench_function("bevy_rtree", |b| {
        b.iter_batched(
            || keyed(&boxes),
            |input| {
                let mut tree = RTree::<u32>::new();
                let ids = tree.insert_bulk(input).unwrap();
                (tree, ids)
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("rstar", |b| {
        b.iter_batched(
            || rstar.clone(),
            rstar::RTree::bulk_load,
            BatchSize::LargeInput,
        )
    });
    group.bench_function("parry3d", |b| {
        b.iter_batched(
            || (),
            |()| Bvh::from_leaves(BvhBuildStrategy::Binned, black_box(&parry)),
            BatchSize::LargeInput,
        )
    });
    group.finish();

    let mut group = c.benchmark_group("build/insert_100k");
    group.sampling_mode(SamplingMode::Flat).sample_size(10);
    group.bench_function("bevy_rtree", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut tree = RTree::<u32>::new();
                for (i, aabb) in boxes.iter().enumerate() {
                    tree.insert(i as u32, *aabb).unwrap();
                }
                tree
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("rstar", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut tree = rstar::RTree::new();
                for item in &rstar {
                    tree.insert(*item);
                }
                tree
            },
            BatchSize::LargeInput,
        )
    });
    group.bench_function("parry3d", |b| {
        b.iter_batched(
            || (),
            |()| {
                let mut bvh = Bvh::new();
                for (i, aabb) in parry.iter().enumerate() {
                    bvh.insert(*aabb, i as u32);
                }
                bvh
            },
            BatchSize::LargeInput,
        )
    });
    group.finish();
}
