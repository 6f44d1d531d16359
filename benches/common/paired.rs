//! Ratios of two contenders timed in alternating blocks.
//!
//! Criterion times one contender for a few seconds, then the next, and on a
//! shared machine the speed of the whole machine drifts between the two
//! (see docs/performance.md). Here the two run in turn, a short block of
//! iterations each, so that both see the same machine, and each round's
//! ratio compares neighbours in time. The order within a round alternates,
//! so neither always runs on the caches the other left.

use std::hint::black_box;
use std::time::{Duration, Instant};

/// Each block starts with untimed iterations, at least this many and for
/// at least [`MIN_WARM_UP`], so that the contender's data is back in cache
/// after the other contender's block.
const MIN_WARM_UP_ITERATIONS: usize = 2;
/// See [`MIN_WARM_UP_ITERATIONS`].
const MIN_WARM_UP: Duration = Duration::from_millis(3);

/// The ratio `a ÷ b` of two contenders' times over all rounds.
#[derive(Clone, Copy, Debug)]
pub struct PairedRatio {
    /// The median over the rounds of each round's ratio of block medians.
    pub median: f64,
    /// The smallest round ratio.
    pub low: f64,
    /// The largest round ratio.
    pub high: f64,
    /// The median of `a`'s block medians, in µs per iteration.
    pub a_us: f64,
    /// The median of `b`'s block medians, in µs per iteration.
    pub b_us: f64,
}

/// Times `a` and `b` in `rounds` rounds of `per_block` iterations each
/// (after untimed ones, see [`MIN_WARM_UP_ITERATIONS`]), alternating which
/// goes first, and returns the ratios `a ÷ b` of the two blocks' median
/// iteration times. Each iteration's result goes through `black_box`, as
/// criterion's does. Inputs that cycle should cycle within an iteration, or
/// `per_block` should hold whole cycles, so that both blocks of a round
/// time the same inputs.
pub fn paired_ratio<A, B>(
    rounds: usize,
    per_block: usize,
    mut a: impl FnMut() -> A,
    mut b: impl FnMut() -> B,
) -> PairedRatio {
    fn block<T>(per_block: usize, f: &mut dyn FnMut() -> T) -> f64 {
        // Untimed first, as criterion warms up: the other contender's block
        // has just filled the caches with its own data.
        let warm_up = Instant::now();
        let mut warmed = 0;
        while warmed < MIN_WARM_UP_ITERATIONS || warm_up.elapsed() < MIN_WARM_UP {
            black_box(f());
            warmed += 1;
        }
        let mut times: Vec<f64> = (0..per_block)
            .map(|_| {
                let start = Instant::now();
                black_box(f());
                start.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        median(&mut times)
    }
    // One untimed round, so that both have run before the first timed one.
    block(per_block, &mut a);
    block(per_block, &mut b);
    let (mut ratios, mut a_us, mut b_us) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..rounds {
        let (ta, tb) = if round % 2 == 0 {
            let ta = block(per_block, &mut a);
            (ta, block(per_block, &mut b))
        } else {
            let tb = block(per_block, &mut b);
            (block(per_block, &mut a), tb)
        };
        ratios.push(ta / tb);
        a_us.push(ta);
        b_us.push(tb);
    }
    summarize(ratios, a_us, b_us)
}

/// The rounds' ratios and times as a [`PairedRatio`].
fn summarize(mut ratios: Vec<f64>, mut a_us: Vec<f64>, mut b_us: Vec<f64>) -> PairedRatio {
    let low = ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let high = ratios.iter().copied().fold(0.0, f64::max);
    PairedRatio {
        median: median(&mut ratios),
        low,
        high,
        a_us: median(&mut a_us),
        b_us: median(&mut b_us),
    }
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Bytes streamed through to evict the caches before a cold call: several
/// times any last-level cache of the machines the benches run on.
const EVICT_BYTES: usize = 128 << 20;

/// Evicts the caches as a frame's other work does between two calls of a
/// query: writes and reads back a buffer several times the last-level
/// cache, one word per cache line.
pub fn evict_caches(buffer: &mut Vec<u64>) {
    if buffer.is_empty() {
        buffer.resize(EVICT_BYTES / 8, 0);
    }
    for line in buffer.chunks_mut(8) {
        line[0] = line[0].wrapping_add(1);
    }
    let sum: u64 = buffer.chunks(8).map(|line| line[0]).sum();
    black_box(sum);
}

/// [`paired_ratio`] with cold caches: each round times one call of `a` and
/// one of `b` on input `round`, each right after [`evict_caches`], in an
/// order that alternates; returns the ratios `a ÷ b` of the two calls.
pub fn paired_ratio_cold<A, B>(
    rounds: usize,
    mut a: impl FnMut(usize) -> A,
    mut b: impl FnMut(usize) -> B,
) -> PairedRatio {
    let mut buffer = Vec::new();
    let mut timed = |f: &mut dyn FnMut(usize), input: usize| {
        evict_caches(&mut buffer);
        let start = Instant::now();
        f(input);
        start.elapsed().as_secs_f64() * 1e6
    };
    let mut a = |i: usize| {
        black_box(a(i));
    };
    let mut b = |i: usize| {
        black_box(b(i));
    };
    let (mut ratios, mut a_us, mut b_us) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..rounds {
        let (ta, tb) = if round % 2 == 0 {
            let ta = timed(&mut a, round);
            (ta, timed(&mut b, round))
        } else {
            let tb = timed(&mut b, round);
            (timed(&mut a, round), tb)
        };
        ratios.push(ta / tb);
        a_us.push(ta);
        b_us.push(tb);
    }
    summarize(ratios, a_us, b_us)
}
