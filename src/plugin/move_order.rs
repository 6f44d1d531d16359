//! The order a frame's moves are applied in: by the slot of their entry,
//! in coarse buckets.
//!
//! A bulk load gives the entries their slots in the order of the leaves,
//! and the leaves their places in the node pool in the same order, so moves
//! taken in slot order walk the records, the keys and the leaves forwards
//! through memory, and the movers of one leaf meet it while it is still in
//! cache. In the order the ECS finds them (its storage order, unrelated to
//! place), each move misses on its own lines.

/// Bucket bits: 2,048 buckets, about four leaves each for 100,000
/// entries, which is as much order as the moves need; a full sort by slot
/// would take three passes instead of one.
const BUCKET_BITS: u32 = 11;

/// Fewer moves than this keep their order: their lines are few.
const FEW: usize = 256;

/// Working space kept between frames: the reordered moves are built in
/// `spare`, the buckets counted in `starts`.
pub(crate) struct BucketSpace<T> {
    spare: Vec<T>,
    starts: Vec<u32>,
}

// Not derived: empty space needs no default move.
impl<T> Default for BucketSpace<T> {
    fn default() -> Self {
        BucketSpace {
            spare: Vec::new(),
            starts: Vec::new(),
        }
    }
}

/// Reorders `moves` by the high bits of `slot(move)`, for slots below
/// `slots`: one counting pass and one scatter, moves of a bucket keeping
/// their order.
pub(crate) fn bucket_by_slot<T: Copy>(
    moves: &mut Vec<T>,
    space: &mut BucketSpace<T>,
    slots: u32,
    slot: impl Fn(&T) -> u32,
) {
    if moves.len() < FEW {
        return;
    }
    let shift = (u32::BITS - slots.leading_zeros()).saturating_sub(BUCKET_BITS);
    // A slot at or past `slots` (a stale handle's) lands in the last bucket.
    let bucket = |m: &T| ((slot(m) >> shift) as usize).min((1 << BUCKET_BITS) - 1);
    let BucketSpace { spare, starts } = space;
    starts.clear();
    starts.resize(1 << BUCKET_BITS, 0);
    let start = starts;
    for m in moves.iter() {
        start[bucket(m)] += 1;
    }
    let mut at = 0;
    for first in start.iter_mut() {
        let count = *first;
        *first = at;
        at += count;
    }
    spare.clear();
    spare.resize(moves.len(), moves[0]);
    for m in moves.iter() {
        let b = bucket(m);
        spare[start[b] as usize] = *m;
        start[b] += 1;
    }
    std::mem::swap(moves, spare);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneRng;

    /// The moves come out as a permutation, in bucket order, each bucket
    /// in its first order; few moves are left as they are.
    #[test]
    fn moves_come_out_bucketed_in_their_first_order() {
        let mut rng = SceneRng::new(3);
        for (len, slots) in [
            (10usize, 100u32),
            (300, 100),
            (5_000, 100_000),
            (5_000, u32::MAX),
        ] {
            // (slot, first position)
            let moves: Vec<(u32, usize)> = (0..len)
                .map(|i| ((rng.next_u64() % u64::from(slots)) as u32, i))
                .collect();
            let mut ours = moves.clone();
            let mut space = BucketSpace::default();
            bucket_by_slot(&mut ours, &mut space, slots, |m| m.0);
            if len < FEW {
                assert_eq!(ours, moves);
                continue;
            }
            let shift = (32 - slots.leading_zeros()).saturating_sub(BUCKET_BITS);
            let mut expected = moves;
            expected.sort_by_key(|m| m.0 >> shift);
            assert_eq!(ours, expected, "{len} moves over {slots} slots");
        }
    }
}
