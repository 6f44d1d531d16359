//! Stable handles to entries and the per-entry record behind them.

use crate::geometry::Aabb;

use super::node::NIL;

/// A stable handle to one entry of an [`RTree`](super::RTree).
///
/// Returned by insert; every later update or removal uses it, so the tree
/// never searches for an entry. A handle carries a generation: once its entry
/// is removed the handle is refused with
/// [`SpatialError::UnknownProxy`](crate::SpatialError::UnknownProxy), even
/// after the slot is reused by a new entry.
///
/// A handle means something only to the tree that issued it, as a key of
/// a slot map does: given to another tree, it is refused where it names
/// none of that tree's live entries, and otherwise taken for the entry in
/// that slot. Keep each tree's handles with it (why handles do not name
/// their tree: docs/performance.md). Either way nothing panics and the
/// tree stays valid.
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
// Opaque: a handle is only meaningful as the index issued it.
#[cfg_attr(feature = "reflect", reflect(opaque, Debug, PartialEq, Clone))]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ProxyId {
    pub(crate) index: u32,
    pub(crate) generation: u32,
}

impl ProxyId {
    /// The slot index, dense from 0 (useful to key side tables).
    pub fn index(self) -> u32 {
        self.index
    }
}

/// What the tree knows about one entry besides its exact box (in its leaf
/// lane), its key (in the tree's dense key array, which traversals read) and
/// its [`Stamp`] (in a dense array of its own).
///
/// 32 bytes, aligned to 32 so that no record straddles two cache lines: a
/// move reads its record in one line.
#[derive(Clone, Debug)]
#[repr(C, align(32))]
pub(crate) struct Proxy {
    /// The enlarged box the tree's structure is built from (contains the
    /// exact box). Small moves inside it change nothing structural.
    pub fat: Aabb,
    /// The leaf holding the entry, or `NIL` when this slot is free.
    pub leaf: u32,
    /// The lane within that leaf.
    pub lane: u32,
}

const _: () = assert!(std::mem::size_of::<Proxy>() == 32);

impl Proxy {
    #[inline]
    pub fn is_live(&self) -> bool {
        self.leaf != NIL
    }
}

/// A slot's generation and whether it is live, in one word
/// (`generation << 1 | live`).
///
/// Stamps live in a dense array apart from the [`Proxy`] records, so that
/// checking a frame's handles reads 4 bytes per handle: 400 KB for 100,000
/// entries, which stays in cache, where the records would take 3.2 MB.
/// Generations count to 2^31 - 1; a slot whose generation would wrap to 0
/// is retired for good instead ([`Stamp::is_exhausted`]), so that a removed
/// handle is refused for the life of the tree, however often slots are
/// reused. A record's `leaf == NIL` says the same as
/// a stamp that is not live, for code that walks the records;
/// [`RTree::validate`](super::RTree::validate) checks that the two agree.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Stamp(u32);

impl Stamp {
    /// The stamp of a slot never used before: generation 0, not live.
    pub const FRESH: Stamp = Stamp(0);

    /// Whether `id` is a live handle of this slot.
    #[inline]
    pub fn admits(self, id: ProxyId) -> bool {
        self.is_live() && self.generation() == id.generation
    }

    #[inline]
    pub fn is_live(self) -> bool {
        self.0 & 1 == 1
    }

    /// The generation handed out with this slot's current entry.
    #[inline]
    pub fn generation(self) -> u32 {
        self.0 >> 1
    }

    /// The slot now holds an entry, of the current generation.
    #[must_use]
    pub fn revived(self) -> Stamp {
        Stamp(self.0 | 1)
    }

    /// The slot's entry is gone: not live, and the next generation, so the
    /// handles issued so far are refused from now on.
    #[must_use]
    pub fn retired(self) -> Stamp {
        Stamp((self.generation().wrapping_add(1)) << 1)
    }

    /// A free slot whose next entry takes the last generation, as after
    /// `2^31 - 1` entries came and went (for tests that cannot wait for
    /// them).
    #[cfg(test)]
    pub const LAST_FREE: Stamp = Stamp(u32::MAX - 1);

    /// Whether this retired slot ran through every generation: its next
    /// entry would get generation 0 again, which handles of its first
    /// entry still carry, so it must never be reused. (Every slot's first
    /// entry takes generation 0, so a free slot of generation 0 can only
    /// have wrapped.)
    #[inline]
    pub fn is_exhausted(self) -> bool {
        self.0 == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn handle(generation: u32) -> ProxyId {
        ProxyId {
            index: 0,
            generation,
        }
    }

    #[test]
    fn a_stamp_admits_only_its_live_generation() {
        let fresh = Stamp::FRESH;
        assert!(!fresh.admits(handle(0)), "a free slot admits nothing");
        let live = fresh.revived();
        assert!(live.admits(handle(0)));
        assert!(!live.admits(handle(1)));
        let retired = live.retired();
        assert!(!retired.admits(handle(0)) && !retired.admits(handle(1)));
        let reused = retired.revived();
        assert!(reused.admits(handle(1)) && !reused.admits(handle(0)));
    }

    #[test]
    fn generations_wrap_within_31_bits_without_touching_liveness() {
        let last = Stamp(u32::MAX); // generation 2^31 - 1, live
        assert_eq!(last.generation(), (1 << 31) - 1);
        let wrapped = last.retired();
        assert!(!wrapped.is_live());
        assert_eq!(wrapped.generation(), 0);
        assert!(wrapped.is_exhausted(), "such a slot must not be reused");
        assert!(!last.is_exhausted() && !Stamp(2).is_exhausted());
    }
}
