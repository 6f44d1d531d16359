//! What the benches share: the criterion settings, the loop that times
//! one contender of a group, and the conversions of boxes to the peers'
//! types.
#![allow(dead_code, reason = "each bench uses the helpers it needs")]

pub mod indexes;
pub mod paired;
pub mod threads;

use std::hint::black_box;
use std::time::Duration;

use bevy_rtree::Aabb;
use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, Criterion};
use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use rstar::primitives::{GeomWithData, Rectangle};

/// An rstar item: a box with its key.
pub type RstarBox = GeomWithData<Rectangle<[f32; 3]>, u32>;

/// `aabb` as an rstar item keyed `key`.
pub fn to_rstar(aabb: &Aabb, key: u32) -> RstarBox {
    GeomWithData::new(
        Rectangle::from_corners(aabb.min.to_array(), aabb.max.to_array()),
        key,
    )
}

/// `aabb` as a parry3d box.
pub fn to_parry(aabb: &Aabb) -> ParryAabb {
    ParryAabb::new(
        ParryVector::from_array(aabb.min.to_array()),
        ParryVector::from_array(aabb.max.to_array()),
    )
}

/// `v`, sorted (answers are compared as sorted lists).
pub fn sorted<T: Ord>(mut v: Vec<T>) -> Vec<T> {
    v.sort_unstable();
    v
}

/// Criterion with 20 samples after `warm_up`, over `measurement`: modest,
/// so that each bench finishes in a few minutes on two cores.
pub fn config(warm_up: Duration, measurement: Duration) -> Criterion {
    Criterion::default()
        .sample_size(20)
        .warm_up_time(warm_up)
        .measurement_time(measurement)
}

/// Times `answer`, one query per iteration, writing its answer into `out`.
/// `out` and whatever `answer` captures (workspaces, input cycles) live
/// across iterations, as they would across a game's frames, so no timing
/// includes an allocation; the contenders of a group differ only in their
/// `answer`.
pub fn bench_answers<O>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    mut out: O,
    mut answer: impl FnMut(&mut O),
) {
    group.bench_function(name, |b| {
        b.iter(|| {
            answer(&mut out);
            black_box(&out);
        })
    });
}

/// [`bench_answers`] for a query that appends to a list, which is cleared
/// before each iteration.
pub fn bench_list<T>(
    group: &mut BenchmarkGroup<'_, WallTime>,
    name: &str,
    mut append: impl FnMut(&mut Vec<T>),
) {
    bench_answers(group, name, Vec::new(), |out| {
        out.clear();
        append(out);
    });
}
