//! Ratios of two contenders timed in alternating blocks.
//!
//! Criterion times one contender for a few seconds, then the next, and on a
//! shared machine the speed of the whole machine drifts between the two:
//! in five runs of the queries bench on unchanged code, parry3d's self join
//! took 5.64 to 6.57 ms. Here the two run in turn, a short block of
//! iterations each, so that both see the same machine, and each round's
//! ratio compares neighbours in time. The order within a round alternates,
//! so neither always runs on the caches the other left.

use std::time::Instant;

/// Each block starts with untimed iterations, at least this many and for
/// at least [`MIN_WARM_UP`]: long enough to run through a cycle of inputs
/// (the frustum group's 60 camera yaws) and bring their nodes back into
/// cache.
const MIN_WARM_UP_ITERATIONS: usize = 2;
/// See [`MIN_WARM_UP_ITERATIONS`].
const MIN_WARM_UP: std::time::Duration = std::time::Duration::from_millis(3);

/// The ratio `ours ÷ peer` over all rounds: the median and the range.
#[derive(Clone, Copy, Debug)]
pub struct PairedRatio {
    pub median: f64,
    pub low: f64,
    pub high: f64,
    /// Medians of each side's per-iteration times over all rounds, in µs.
    pub ours_us: f64,
    pub peer_us: f64,
}

/// Times `ours` and `peer` in `rounds` rounds of `per_block` iterations
/// each (after untimed ones, see [`MIN_WARM_UP_ITERATIONS`]), alternating which goes
/// first, and returns the ratios of the two blocks' median iteration times.
pub fn paired_ratio(
    rounds: usize,
    per_block: usize,
    mut ours: impl FnMut(),
    mut peer: impl FnMut(),
) -> PairedRatio {
    let block = |f: &mut dyn FnMut()| {
        // Untimed first, as criterion warms up: the other contender's block
        // has just filled the caches with its own data.
        let warm_up = Instant::now();
        let mut warmed = 0;
        while warmed < MIN_WARM_UP_ITERATIONS || warm_up.elapsed() < MIN_WARM_UP {
            f();
            warmed += 1;
        }
        let mut times: Vec<f64> = (0..per_block)
            .map(|_| {
                let start = Instant::now();
                f();
                start.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        median(&mut times)
    };
    // One untimed round, so that both have run before the first timed one.
    block(&mut ours);
    block(&mut peer);
    let (mut ratios, mut ours_us, mut peer_us) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..rounds {
        let (a, b) = if round % 2 == 0 {
            let a = block(&mut ours);
            (a, block(&mut peer))
        } else {
            let b = block(&mut peer);
            (block(&mut ours), b)
        };
        ratios.push(a / b);
        ours_us.push(a);
        peer_us.push(b);
    }
    let low = ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let high = ratios.iter().copied().fold(0.0, f64::max);
    PairedRatio {
        median: median(&mut ratios),
        low,
        high,
        ours_us: median(&mut ours_us),
        peer_us: median(&mut peer_us),
    }
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}
