//! Bulk loading: entries are tiled into compact groups by median cuts on
//! their widest axis, and packed bottom-up into nearly full nodes.

use super::node::NIL;
use super::{Entry, RTree};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::ProxyId;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Inserts many entries at once and rebuilds the whole tree, grouping
    /// entries by median cuts on their widest axis.
    ///
    /// Much faster than inserting one by one and gives a better tree; existing
    /// handles stay valid. All boxes are checked first: if any is invalid,
    /// nothing is inserted and the error is returned.
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree};
    /// use glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let ids = tree.insert_bulk((0..1000u32).map(|i| {
    ///     let p = Vec3::new(i as f32, 0.0, 0.0);
    ///     (i, Aabb::new(p, p + Vec3::ONE).unwrap())
    /// }))?;
    /// assert_eq!(ids.len(), 1000);
    /// assert_eq!(tree.len(), 1000);
    /// tree.validate().unwrap();
    /// # Ok::<(), bevy_rtree::SpatialError>(())
    /// ```
    pub fn insert_bulk(
        &mut self,
        entries: impl IntoIterator<Item = (K, Aabb)>,
    ) -> Result<Vec<ProxyId>, SpatialError> {
        let entries: Vec<(K, Aabb)> = entries.into_iter().collect();
        if let Some(bad) = entries.iter().find(|(_, aabb)| !aabb.is_valid()) {
            bad.1.validate()?;
        }
        let mut ids = Vec::with_capacity(entries.len());
        let mut exact: Vec<Aabb> = self.collect_exact_boxes();
        for (key, aabb) in entries {
            let fat = self.settings.fatten(&aabb, glam::Vec3::ZERO);
            let proxy = self.alloc_proxy(key, fat);
            if exact.len() <= proxy as usize {
                exact.resize(proxy as usize + 1, Aabb::INVERTED);
            }
            exact[proxy as usize] = aabb;
            // Mark live now so the rebuild below picks it up.
            self.proxies[proxy as usize].leaf = 0;
            ids.push(self.handle(proxy));
            self.len += 1;
        }
        self.rebuild_from(&exact);
        Ok(ids)
    }

    /// Rebuilds the whole tree by bulk loading from the entries' current boxes.
    /// Handles stay valid; answers do not change.
    pub fn rebuild(&mut self) {
        let exact = self.collect_exact_boxes();
        self.rebuild_from(&exact);
    }

    /// Exact box per proxy index (inverted for free slots).
    fn collect_exact_boxes(&self) -> Vec<Aabb> {
        self.proxies
            .iter()
            .map(|p| {
                if p.is_live() {
                    self.nodes[p.leaf as usize].lane_box(p.lane as usize)
                } else {
                    Aabb::INVERTED
                }
            })
            .collect()
    }

    /// Packs every live proxy (exact boxes from `exact`) into a new tree.
    fn rebuild_from(&mut self, exact: &[Aabb]) {
        let mut level_entries: Vec<Entry> = self
            .proxies
            .iter()
            .enumerate()
            .filter(|(_, p)| p.is_live())
            .map(|(i, p)| Entry {
                lane_box: exact[i],
                bound: p.fat,
                child: i as u32,
            })
            .collect();
        self.nodes.clear();
        self.churn.clear();
        self.free_nodes.clear();
        self.dirty.clear();
        let mut level = 0u16;
        loop {
            if level_entries.len() <= W {
                let root = self.alloc_node(level, NIL);
                self.fill_node(root, &level_entries);
                self.root = root;
                return;
            }
            let groups = level_entries.len().div_ceil(W);
            tile_partition(&mut level_entries, groups);
            let mut next = Vec::with_capacity(groups);
            for group in 0..groups {
                let range = group_range(level_entries.len(), groups, group);
                let node = self.alloc_node(level, NIL);
                self.fill_node(node, &level_entries[range]);
                next.push(self.node_entry(node));
            }
            level_entries = next;
            level += 1;
        }
    }

    /// Reserves room for `additional` more entries and their nodes.
    pub fn reserve(&mut self, additional: usize) {
        self.proxies.reserve(additional);
        self.nodes.reserve(additional * 2 / W + 1);
    }
}

/// The entries of group `g` when `n` entries are split into `groups` groups
/// as evenly as possible (sizes differ by at most one).
pub(super) fn group_range(n: usize, groups: usize, g: usize) -> std::ops::Range<usize> {
    (n * g / groups)..(n * (g + 1) / groups)
}

/// Orders `entries` so that `group_range(len, groups, g)` is a spatially
/// compact tile for every `g`.
///
/// The entries are cut in two at a median, along the axis on which their
/// centres spread widest, with as many groups on each side as the two
/// halves hold; each half is cut again until every group stands alone (a
/// k-d tiling). Cutting the widest axis adapts the tiles to the data: on a
/// world 20 times wider than tall, fixed slab counts per axis (sort-tile-
/// recursive) cut thin slices in height, whereas this cuts height only
/// where boxes are stacked. On the standard scene it halves the nodes a
/// ray or a join visits (see the README's performance section).
pub(super) fn tile_partition(entries: &mut [Entry], groups: usize) {
    let n = entries.len();
    halve(entries, 0, groups, n, groups);
}

/// Tiles the groups `first..first + count` (of `total_groups` over
/// `total_entries`), whose entries are exactly `entries`.
fn halve(
    entries: &mut [Entry],
    first: usize,
    count: usize,
    total_entries: usize,
    total_groups: usize,
) {
    if count <= 1 {
        return;
    }
    let axis = widest_centre_axis(entries);
    let left = count / 2;
    let start = group_range(total_entries, total_groups, first).start;
    let cut = group_range(total_entries, total_groups, first + left).start - start;
    entries.select_nth_unstable_by(cut, |a, b| {
        centre_key(&a.bound, axis).total_cmp(&centre_key(&b.bound, axis))
    });
    let (low, high) = entries.split_at_mut(cut);
    halve(low, first, left, total_entries, total_groups);
    halve(
        high,
        first + left,
        count - left,
        total_entries,
        total_groups,
    );
}

/// The axis along which the entries' centres spread widest (ties go to the
/// lower axis).
pub(super) fn widest_centre_axis(entries: &[Entry]) -> usize {
    let (mut lo, mut hi) = (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY);
    for entry in entries {
        let centre = entry.bound.min + entry.bound.max;
        lo = lo.min(centre);
        hi = hi.max(centre);
    }
    let spread = hi - lo;
    if spread.x >= spread.y && spread.x >= spread.z {
        0
    } else if spread.y >= spread.z {
        1
    } else {
        2
    }
}

/// Twice the centre along `axis` (halving would not change the order).
#[inline]
pub(super) fn centre_key(aabb: &Aabb, axis: usize) -> f32 {
    aabb.min[axis] + aabb.max[axis]
}
