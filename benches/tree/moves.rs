//! `frame/moves_10k`: a frame's 10,000 moved boxes applied to each
//! contender's persistent index. Each contender owns its index and its own
//! clone of the scene; one iteration advances its scene by a frame
//! (untimed) and times only applying that frame's moved boxes.

use super::common::{RstarBox, to_parry, to_rstar};
use super::inputs::{
    answer_parry, answer_rstar, assert_same, bulk_tree_with, oracle_of, parry_leaves, query_boxes,
    rstar_items,
};
use super::{CHECK_FRAMES, MOVE_CHECK_QUERIES, SEED};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, ProxyId, RTree, TreeSettings};
use criterion::Criterion;
use parry3d::partitioning::{Bvh, BvhBuildStrategy, BvhWorkspace};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Times `apply` on `iters` consecutive frames of `scene`, advancing the
/// scene untimed before each.
pub(crate) fn time_frames(
    scene: &mut TownScene,
    iters: u64,
    mut apply: impl FnMut(&[u32], &[Aabb]),
) -> Duration {
    time_frames_excluding(scene, iters, |moved, boxes| {
        apply(moved, boxes);
        Duration::ZERO
    })
}

/// [`time_frames`] for an `apply` that returns how long a part of its work
/// took that is not to be counted.
pub(crate) fn time_frames_excluding(
    scene: &mut TownScene,
    iters: u64,
    mut apply: impl FnMut(&[u32], &[Aabb]) -> Duration,
) -> Duration {
    let mut total = Duration::ZERO;
    for _ in 0..iters {
        scene.advance_frame();
        let (moved, boxes) = (scene.moved(), scene.boxes());
        let start = Instant::now();
        let excluded = apply(moved, boxes);
        total += start.elapsed().saturating_sub(excluded);
    }
    total
}

pub(crate) struct BevyMoves {
    pub(crate) scene: TownScene,
    pub(crate) tree: RTree<u32>,
    pub(crate) ids: Vec<ProxyId>,
    /// One `update_batch` per frame, or one `update` per move.
    pub(crate) batched: bool,
    /// Whether the frame's churn repair (`optimize`) counts in the time; it
    /// runs every frame either way, so the tree is the same.
    pub(crate) repair_timed: bool,
    /// The frame's moves, for `update_batch` (kept to avoid reallocating).
    pub(crate) moves: Vec<(ProxyId, Aabb)>,
}

impl BevyMoves {
    pub(crate) fn new(scene: &TownScene, batched: bool) -> Self {
        Self::with_settings(scene, batched, TreeSettings::default())
    }

    pub(crate) fn with_settings(scene: &TownScene, batched: bool, settings: TreeSettings) -> Self {
        let (tree, ids) = bulk_tree_with(scene.boxes(), settings);
        BevyMoves {
            scene: scene.clone(),
            tree,
            ids,
            batched,
            repair_timed: true,
            moves: Vec::new(),
        }
    }

    /// A contender that times the moves alone, with the churn repair run
    /// every frame but not counted: the counterpart of parry3d's update
    /// path, which repairs nothing.
    pub(crate) fn repair_untimed(mut self) -> Self {
        self.repair_timed = false;
        self
    }

    pub(crate) fn frame(&mut self, iters: u64) -> Duration {
        let (tree, ids, moves, batched, repair_timed) = (
            &mut self.tree,
            &self.ids,
            &mut self.moves,
            self.batched,
            self.repair_timed,
        );
        time_frames_excluding(&mut self.scene, iters, |moved, boxes| {
            if batched {
                moves.clear();
                moves.extend(moved.iter().map(|&i| (ids[i as usize], boxes[i as usize])));
                tree.update_batch(moves).unwrap();
            } else {
                for &i in moved {
                    tree.update(ids[i as usize], boxes[i as usize]).unwrap();
                }
            }
            let repair = Instant::now();
            black_box(tree.optimize(usize::MAX));
            if repair_timed {
                Duration::ZERO
            } else {
                repair.elapsed()
            }
        })
    }
    pub(crate) fn check(&self, queries: &[Aabb]) {
        self.tree.validate().unwrap();
        let oracle = oracle_of(self.scene.boxes());
        for q in queries {
            assert_same(
                "bevy_rtree (moves)",
                q,
                &self.tree.overlapping(q),
                &oracle.overlapping(q),
            );
        }
    }
}

pub(crate) struct RstarMoves {
    scene: TownScene,
    tree: rstar::RTree<RstarBox>,
    /// The item each entity currently has in the tree (to remove it).
    current: Vec<RstarBox>,
}

impl RstarMoves {
    fn new(scene: &TownScene) -> Self {
        let current = rstar_items(scene.boxes());
        RstarMoves {
            scene: scene.clone(),
            tree: rstar::RTree::bulk_load(current.clone()),
            current,
        }
    }

    fn apply(
        tree: &mut rstar::RTree<RstarBox>,
        current: &mut [RstarBox],
        moved: &[u32],
        boxes: &[Aabb],
    ) {
        for &i in moved {
            let new = to_rstar(&boxes[i as usize], i);
            let old = std::mem::replace(&mut current[i as usize], new);
            let removed = tree.remove(&old);
            assert!(removed.is_some(), "rstar lost entity {i}");
            tree.insert(new);
        }
    }

    fn frame(&mut self, iters: u64) -> Duration {
        let (tree, current) = (&mut self.tree, &mut self.current);
        time_frames(&mut self.scene, iters, |moved, boxes| {
            Self::apply(tree, current, moved, boxes)
        })
    }

    fn check(&self, queries: &[Aabb]) {
        assert_eq!(self.tree.size(), self.scene.len());
        let oracle = oracle_of(self.scene.boxes());
        for q in queries {
            assert_same(
                "rstar (moves)",
                q,
                &answer_rstar(&self.tree, q),
                &oracle.overlapping(q),
            );
        }
    }
}

pub(crate) struct ParryMoves {
    scene: TownScene,
    bvh: Bvh,
    workspace: BvhWorkspace,
    margin: f32,
    /// Whether each frame ends with `optimize_incremental`, parry3d's
    /// counterpart of bevy_rtree's churn repair.
    optimize: bool,
}

impl ParryMoves {
    fn new(scene: &TownScene, margin: f32) -> Self {
        ParryMoves {
            scene: scene.clone(),
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &parry_leaves(scene.boxes())),
            workspace: BvhWorkspace::default(),
            margin,
            optimize: false,
        }
    }

    /// The same update path followed by `optimize_incremental` each frame.
    fn optimized(mut self) -> Self {
        self.optimize = true;
        self
    }

    fn apply(bvh: &mut Bvh, ws: &mut BvhWorkspace, margin: f32, moved: &[u32], boxes: &[Aabb]) {
        for &i in moved {
            bvh.insert_or_update_partially(to_parry(&boxes[i as usize]), i, margin);
        }
        bvh.refit(ws);
    }

    fn frame(&mut self, iters: u64) -> Duration {
        let (bvh, ws, margin, optimize) = (
            &mut self.bvh,
            &mut self.workspace,
            self.margin,
            self.optimize,
        );
        time_frames(&mut self.scene, iters, |moved, boxes| {
            Self::apply(bvh, ws, margin, moved, boxes);
            if optimize {
                bvh.optimize_incremental(ws);
            }
        })
    }

    /// With a margin the leaves hold enlarged boxes, so the BVH answers a
    /// superset; filtered by the exact boxes it must equal the oracle.
    fn check(&self, queries: &[Aabb]) {
        assert_eq!(self.bvh.leaf_count() as usize, self.scene.len());
        let boxes = self.scene.boxes();
        let oracle = oracle_of(boxes);
        let who = format!("parry3d margin {} (moves)", self.margin);
        for q in queries {
            let want = oracle.overlapping(q);
            let candidates = answer_parry(&self.bvh, q);
            let exact: Vec<u32> = candidates
                .iter()
                .copied()
                .filter(|&i| boxes[i as usize].intersects(q))
                .collect();
            assert_same(&who, q, &exact, &want);
            if self.margin == 0.0 {
                assert_same(&who, q, &candidates, &want);
            }
        }
    }
}

pub(crate) struct FlatMoves {
    scene: TownScene,
    flat: Vec<Aabb>,
}

impl FlatMoves {
    fn frame(&mut self, iters: u64) -> Duration {
        let flat = &mut self.flat;
        time_frames(&mut self.scene, iters, |moved, boxes| {
            for &i in moved {
                flat[i as usize] = boxes[i as usize];
            }
            black_box(&mut *flat);
        })
    }

    fn check(&self) {
        assert_eq!(self.flat, self.scene.boxes(), "flat array out of date");
    }
}

pub(crate) fn bench_moves(c: &mut Criterion) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let checks = query_boxes(MOVE_CHECK_QUERIES, SEED ^ 0x3073);

    let mut bevy = BevyMoves::new(&scene, true);
    let mut bevy_moves_alone = BevyMoves::new(&scene, true).repair_untimed();
    let mut bevy_single = BevyMoves::new(&scene, false);
    let mut rstar = RstarMoves::new(&scene);
    let mut parry0 = ParryMoves::new(&scene, 0.0);
    let mut parry01 = ParryMoves::new(&scene, 0.1);
    let mut parry0_optimized = ParryMoves::new(&scene, 0.0).optimized();
    let mut flat = FlatMoves {
        scene: scene.clone(),
        flat: scene.boxes().to_vec(),
    };

    // A few frames, then check every contender against the oracle.
    bevy.frame(CHECK_FRAMES as u64);
    bevy_moves_alone.frame(CHECK_FRAMES as u64);
    bevy_single.frame(CHECK_FRAMES as u64);
    rstar.frame(CHECK_FRAMES as u64);
    parry0.frame(CHECK_FRAMES as u64);
    parry01.frame(CHECK_FRAMES as u64);
    parry0_optimized.frame(CHECK_FRAMES as u64);
    flat.frame(CHECK_FRAMES as u64);
    bevy.check(&checks);
    bevy_moves_alone.check(&checks);
    bevy_single.check(&checks);
    rstar.check(&checks);
    parry0.check(&checks);
    parry01.check(&checks);
    parry0_optimized.check(&checks);
    flat.check();
    eprintln!("moves check ok after {CHECK_FRAMES} frames");
    bevy.tree.take_maintenance_stats();
    let frames_before = bevy.scene.frame();

    let mut group = c.benchmark_group("frame/moves_10k");
    group.bench_function("bevy_rtree", |b| b.iter_custom(|iters| bevy.frame(iters)));
    group.bench_function("bevy_rtree_repair_untimed", |b| {
        b.iter_custom(|iters| bevy_moves_alone.frame(iters))
    });
    group.bench_function("bevy_rtree_one_by_one", |b| {
        b.iter_custom(|iters| bevy_single.frame(iters))
    });
    group.bench_function("rstar", |b| b.iter_custom(|iters| rstar.frame(iters)));
    group.bench_function("parry3d_margin0", |b| {
        b.iter_custom(|iters| parry0.frame(iters))
    });
    group.bench_function("parry3d_margin0.1", |b| {
        b.iter_custom(|iters| parry01.frame(iters))
    });
    group.bench_function("parry3d_margin0_optimize_incremental", |b| {
        b.iter_custom(|iters| parry0_optimized.frame(iters))
    });
    group.bench_function("flat_array", |b| b.iter_custom(|iters| flat.frame(iters)));
    group.finish();

    // The indexes went through many more frames while timed: check again.
    bevy.check(&checks);
    bevy_moves_alone.check(&checks);
    bevy_single.check(&checks);
    rstar.check(&checks);
    parry0.check(&checks);
    parry01.check(&checks);
    parry0_optimized.check(&checks);
    flat.check();
    let frames = (bevy.scene.frame() - frames_before).max(1);
    let stats = bevy.tree.take_maintenance_stats();
    eprintln!(
        "moves bench: bevy_rtree ran {frames} timed/warm-up frames; per frame: in place {:.0}, in leaf {:.0}, leaf grown {:.0}, reinserted {:.0}, splits {:.1}, condensed {:.1}, repacks {:.1}; height {}; post-check ok",
        stats.moves_in_place as f64 / frames as f64,
        stats.moves_in_leaf as f64 / frames as f64,
        stats.moves_leaf_grown as f64 / frames as f64,
        stats.moves_reinserted as f64 / frames as f64,
        stats.splits as f64 / frames as f64,
        stats.condensed_nodes as f64 / frames as f64,
        stats.repacks as f64 / frames as f64,
        bevy.tree.height()
    );
}
