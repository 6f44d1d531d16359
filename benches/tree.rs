//! Side-by-side benchmark of `bevy_rtree` against its peers on the standard
//! "town" scene (`bevy_rtree::scene::TownScene`): rstar 0.14, parry3d 0.31's
//! `Bvh`, and the flat / brute-force lower and upper limits.
//!
//! Groups:
//! - `build/bulk_load_100k`, `build/insert_100k`: building an index of the
//!   scene from scratch;
//! - `frame/moves_10k`: applying one frame's 10,000 moves to a persistent
//!   index (the scene is advanced untimed before each timed frame);
//!   `bevy_rtree` gathers them into one `update_batch`, as the plugin does,
//!   then runs the churn repair (`optimize`); `bevy_rtree_repair_untimed`
//!   is the same with the repair run but not counted (the counterpart of
//!   parry3d's update path, which repairs nothing), and
//!   `bevy_rtree_one_by_one` calls `update` per move. parry3d runs
//!   `insert_or_update_partially` per move and `refit`, with a margin of 0
//!   or 0.1, and once more with `optimize_incremental` after each frame
//!   (its own repair);
//! - `query/boxes`: 1,000 box-overlap queries against a fresh and a churned
//!   tree and the peers, all over the same boxes;
//! - `split/insert_100k`, `split/moves_10k`, `split/boxes_churned`: the node
//!   split strategies (`TreeSettings::split`) side by side: 100,000 single
//!   inserts, a frame's moves, and the `query/boxes` queries on each
//!   strategy's tree after `CHURN_FRAMES` frames of moves (with a tree bulk
//!   loaded from the same boxes for reference).
//!
//! Every contender's answers are checked against the oracle
//! (`bevy_rtree::oracle::BruteForce`) before any timing; a disagreement
//! panics.

use std::time::Duration;

use criterion::{criterion_group, criterion_main};

mod common;

/// The scene's seed; every contender sees the same boxes and frames.
const SEED: u64 = 0x5EED_2024;
/// Frames of churn applied to the tree queried as "bevy_rtree_churned".
const CHURN_FRAMES: usize = 600;
/// Query boxes per `query/boxes` iteration.
const QUERY_COUNT: usize = 1_000;
/// Half extent of a query box (a cube, clamped to the world in y).
const QUERY_HALF_EXTENT: f32 = 10.0;
/// Frames applied to each moves contender before its answers are checked.
const CHECK_FRAMES: usize = 5;
/// Query boxes used by the moves group's correctness checks.
const MOVE_CHECK_QUERIES: usize = 200;

#[path = "tree/brute_force.rs"]
mod brute_force;
#[path = "tree/build.rs"]
mod build;
#[path = "tree/inputs.rs"]
mod inputs;
use build::bench_build;
#[path = "tree/moves.rs"]
mod moves;
use moves::bench_moves;
#[path = "tree/box_queries.rs"]
mod box_queries;
use box_queries::bench_queries;
#[path = "tree/splits.rs"]
mod splits;
use splits::bench_splits;

criterion_group! {
    name = benches;
    config = common::config(Duration::from_secs(1), Duration::from_secs(3));
    targets = bench_build, bench_moves, bench_queries, bench_splits
}
criterion_main!(benches);
