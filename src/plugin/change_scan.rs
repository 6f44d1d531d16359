//! Bevy's `Changed` and `Added` tests over a table's change ticks, a block
//! of rows at a time.
//!
//! The syncs scan every indexed entity each frame for the few that moved.
//! Through Bevy's row-by-row iteration each row costs a call and a branch;
//! here a table's tick slices (Bevy's contiguous queries) are compared a
//! block at a time (with SSE2 on x86-64, `sse2.rs`: the portable loop
//! compiles there to a compare and a shift per row), 64 rows become one
//! bit mask, and only the rows of its set bits are visited.

use bevy_ecs::change_detection::{MAX_CHANGE_AGE, Tick};

#[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
mod sse2;

/// Rows whose ticks are compared into one bit mask before any row is
/// looked at.
const BLOCK: usize = 64;

/// Rows packed into one byte of a block's mask by the portable loop (a
/// table's last, partial block, or a target without SSE2).
const BYTE: usize = 8;

/// The test a system's `Changed<T>` filter applies to a tick: newer than the
/// system's last run (or another start, such as an index's last sync), as
/// seen from this run (ticks wrap, and ages are capped at `MAX_CHANGE_AGE`
/// the way Bevy caps them).
#[derive(Clone, Copy)]
pub(crate) struct ChangeTest {
    this_run: u32,
    since_system: u32,
}

impl ChangeTest {
    /// The test of a system that last ran at `last_run` and runs now at
    /// `this_run`.
    pub(crate) fn new(last_run: Tick, this_run: Tick) -> Self {
        let this_run = this_run.get();
        ChangeTest {
            this_run,
            since_system: this_run.wrapping_sub(last_run.get()).min(MAX_CHANGE_AGE),
        }
    }

    /// Whether `tick` is newer than the system's last run.
    #[inline]
    pub(crate) fn newer(self, tick: &Tick) -> bool {
        self.this_run.wrapping_sub(tick.get()).min(MAX_CHANGE_AGE) < self.since_system
    }

    /// Calls `row` with each row where any of `columns`' ticks is newer
    /// than the system's last run, in row order. The columns are one
    /// table's, of equal length.
    ///
    /// Each block of rows becomes one bit mask, and only its set bits are
    /// visited: with a tenth of the rows changed, a run of eight rows holds
    /// a change more often than not, and the branch on each row of such a
    /// run was mispredicted about as often as the change is rare.
    #[inline]
    pub(crate) fn for_each_changed<const N: usize>(
        self,
        columns: [&[Tick]; N],
        mut row: impl FnMut(usize),
    ) {
        let len = columns.first().map_or(0, |c| c.len());
        debug_assert!(columns.iter().all(|c| c.len() == len));
        for start in (0..len).step_by(BLOCK) {
            let end = (start + BLOCK).min(len);
            let mut changed = columns.iter().fold(0u64, |mask, ticks| {
                mask | self.newer_mask(&ticks[start..end])
            });
            while changed != 0 {
                row(start + changed.trailing_zeros() as usize);
                changed &= changed - 1;
            }
        }
    }

    /// Bit `i` set where `ticks[i]` is newer than the system's last run
    /// (at most [`BLOCK`] ticks): a whole block with SSE2 where the target
    /// has it (`sse2.rs`), the rest row by row.
    #[inline]
    fn newer_mask(self, ticks: &[Tick]) -> u64 {
        #[cfg(all(target_arch = "x86_64", target_feature = "sse2"))]
        if let Ok(block) = <&[Tick; BLOCK]>::try_from(ticks) {
            #[allow(unsafe_code)]
            // SAFETY: the function needs SSE2, and this line is compiled
            // only for targets that have it (every x86-64 target does).
            return unsafe { sse2::newer_mask_of_block(self, block) };
        }
        self.newer_mask_row_by_row(ticks)
    }

    /// [`Self::newer_mask`] in portable code, one row at a time.
    #[inline]
    fn newer_mask_row_by_row(self, ticks: &[Tick]) -> u64 {
        debug_assert!(ticks.len() <= BLOCK);
        let mut mask = 0u64;
        let mut bytes = ticks.chunks_exact(BYTE);
        for (i, byte) in bytes.by_ref().enumerate() {
            let bits = (0..BYTE).fold(0u64, |bits, b| {
                bits | (u64::from(self.newer(&byte[b])) << b)
            });
            mask |= bits << (i * BYTE);
        }
        let done = ticks.len() - bytes.remainder().len();
        for (b, tick) in bytes.remainder().iter().enumerate() {
            mask |= u64::from(self.newer(tick)) << (done + b);
        }
        mask
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The test against Bevy's own `Tick::is_newer_than`, over ticks around
    /// the last run, far in the past, and across the wrap of the counter.
    #[test]
    fn newer_is_bevys_is_newer_than() {
        let runs = [
            (0u32, 1u32),
            (5, 10),
            (u32::MAX - 3, 4),
            (100, 100 + MAX_CHANGE_AGE + 50),
        ];
        for (last, now) in runs {
            let test = ChangeTest::new(Tick::new(last), Tick::new(now));
            let around = [
                0,
                1,
                last.wrapping_sub(1),
                last,
                last.wrapping_add(1),
                now.wrapping_sub(1),
                now,
                now.wrapping_add(1),
                now.wrapping_sub(MAX_CHANGE_AGE),
                now.wrapping_sub(MAX_CHANGE_AGE).wrapping_add(1),
                u32::MAX,
            ];
            for t in around {
                let tick = Tick::new(t);
                assert_eq!(
                    test.newer(&tick),
                    tick.is_newer_than(Tick::new(last), Tick::new(now)),
                    "tick {t}, last run {last}, this run {now}"
                );
            }
        }
    }

    /// A whole block's mask (the SSE2 path on x86-64) is the row-by-row
    /// mask, and each bit is Bevy's own `is_newer_than`: ticks drawn around
    /// the last run, this run, the age cap and anywhere, for runs across
    /// the counter's wrap and past the cap.
    #[test]
    fn a_block_s_mask_is_the_row_by_row_mask_and_bevy_s_answer() {
        let runs = [
            (5u32, 10u32),
            (u32::MAX - 3, 4),
            (100, 100 + MAX_CHANGE_AGE + 50),
            (7, 7),
        ];
        let mut state = 0x5EED_u64;
        let mut next = move || {
            // splitmix64: enough spread for tick values.
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        for (last, now) in runs {
            let test = ChangeTest::new(Tick::new(last), Tick::new(now));
            let near = [last, now, now.wrapping_sub(MAX_CHANGE_AGE)];
            for _ in 0..200 {
                let ticks: Vec<Tick> = (0..BLOCK)
                    .map(|_| {
                        let r = next();
                        let around = near[(r % 3) as usize];
                        let t = match (r >> 8) % 3 {
                            0 => around.wrapping_add((r >> 16) as u32 % 5).wrapping_sub(2),
                            1 => (r >> 32) as u32,
                            _ => around,
                        };
                        Tick::new(t)
                    })
                    .collect();
                let mask = test.newer_mask(&ticks);
                assert_eq!(mask, test.newer_mask_row_by_row(&ticks));
                for (i, tick) in ticks.iter().enumerate() {
                    let bevy = tick.is_newer_than(Tick::new(last), Tick::new(now));
                    assert_eq!(mask >> i & 1 == 1, bevy, "tick {tick:?}, run {last}..{now}");
                }
            }
        }
    }

    /// Every changed row is reported once, in order, whichever column
    /// changed and wherever it falls in a block or a byte of its mask.
    #[test]
    fn for_each_changed_reports_exactly_the_changed_rows() {
        let (last, now) = (10, 20);
        let test = ChangeTest::new(Tick::new(last), Tick::new(now));
        for len in [0, 1, 7, 8, 9, 17, 40, 63, 64, 65, 130, 200] {
            let a: Vec<Tick> = (0..len)
                .map(|i| Tick::new(if i % 5 == 3 { 15 } else { 5 }))
                .collect();
            let b: Vec<Tick> = (0..len)
                .map(|i| Tick::new(if i % 7 == 6 { 20 } else { 10 }))
                .collect();
            let mut seen = Vec::new();
            test.for_each_changed([&a, &b], |r| seen.push(r));
            let expected: Vec<usize> = (0..len)
                .filter(|&i| {
                    a[i].is_newer_than(Tick::new(last), Tick::new(now))
                        || b[i].is_newer_than(Tick::new(last), Tick::new(now))
                })
                .collect();
            assert_eq!(seen, expected, "{len} rows");
        }
    }
}
