//! Insertion: choose a subtree, add to a node, split it when full.

use smallvec::SmallVec;

use super::node::NIL;
use super::{Entry, RTree};
use crate::geometry::{Aabb, SpatialError};
use crate::tree::ProxyId;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Inserts an entry and returns its stable handle.
    ///
    /// Fails with [`SpatialError::InvalidBox`] (and changes nothing) when the
    /// box is not valid. Keys need not be unique: two entries with the same key
    /// are two entries, and answers report each of them by that key (a self
    /// join pairs them as `(k, k)`). Give each entry its own key where answers
    /// must tell entries apart, as the plugin does with `Entity`. A cross join
    /// never pairs a key with itself: across two trees one key stands for one
    /// thing in both sets (S8, `a != b`).
    ///
    /// ```
    /// use bevy_rtree::{Aabb, RTree, SpatialError};
    /// use bevy_rtree::glam::Vec3;
    ///
    /// let mut tree = RTree::new();
    /// let id = tree.insert(7u32, Aabb::new(Vec3::ZERO, Vec3::ONE)?)?;
    /// assert_eq!(tree.get(id)?.0, 7);
    /// let nan = Aabb { min: Vec3::NAN, max: Vec3::ONE };
    /// assert_eq!(tree.insert(8, nan), Err(SpatialError::InvalidBox));
    /// assert_eq!(tree.len(), 1);
    /// # Ok::<(), SpatialError>(())
    /// ```
    pub fn insert(&mut self, key: K, aabb: Aabb) -> Result<ProxyId, SpatialError> {
        aabb.validate()?;
        let fat = self.settings.fatten(&aabb, glam::Vec3::ZERO);
        let proxy = self.alloc_proxy(key, fat);
        self.insert_entry(
            Entry {
                lane_box: aabb,
                bound: fat,
                child: proxy,
            },
            0,
        );
        self.len += 1;
        self.maintenance.inserts += 1;
        self.wear += 1;
        self.note_change(proxy, None);
        Ok(self.handle(proxy))
    }

    /// Adds `entry` to a node at `level` (0 for proxies, `l + 1` for a node
    /// of level `l`), growing the path's bounds and splitting as needed.
    /// Returns the node the entry landed in.
    pub(super) fn insert_entry(&mut self, entry: Entry, level: u16) -> u32 {
        debug_assert!(level <= self.nodes[self.root as usize].level);
        let target = self.choose_path(&entry.bound, level);
        self.add_to_node(target, entry)
    }

    /// Descends from the root to a node at `level`, choosing at each step the
    /// child whose bound grows least, and grows that child's lane on the way
    /// down so the path contains `bound` afterwards.
    fn choose_path(&mut self, bound: &Aabb, level: u16) -> u32 {
        let mut current = self.root;
        while self.nodes[current as usize].level > level {
            let node = &self.nodes[current as usize];
            let lane = node.least_growth_lane(bound);
            let grown = node.lane_box(lane).union(bound);
            let child = node.child[lane];
            self.set_child_bound(current, lane, &grown);
            current = child;
        }
        current
    }

    /// Puts `entry` into `node`, splitting the node (and, in turn, its
    /// ancestors) when it is full. Returns the node holding the entry.
    pub(super) fn add_to_node(&mut self, node: u32, entry: Entry) -> u32 {
        let len = self.nodes[node as usize].len();
        if len < W {
            self.write_lane(node, len, &entry);
            let n = &mut self.nodes[node as usize];
            n.len += 1;
            n.order_new_lane();
            return node;
        }
        self.split_and_add(node, entry)
    }

    /// Writes `entry` into `lane` of `node` and links it back.
    #[inline]
    pub(super) fn write_lane(&mut self, node: u32, lane: usize, entry: &Entry) {
        let n = &mut self.nodes[node as usize];
        n.set_lane_box(lane, &entry.lane_box);
        n.child[lane] = entry.child;
        self.link(node, lane);
    }

    /// Splits the full `node` plus `entry` into `node` and a new sibling,
    /// then hangs the sibling under the parent (or a new root).
    fn split_and_add(&mut self, node: u32, entry: Entry) -> u32 {
        self.maintenance.splits += 1;
        let mut entries: SmallVec<[Entry; 17]> = self.node_entries(node);
        entries.push(entry);
        let cut = super::split::choose_split(&mut entries, Self::MIN_FILL, self.settings.split);

        let level = self.nodes[node as usize].level;
        let parent = self.nodes[node as usize].parent;
        let sibling = self.alloc_node(level, parent);
        self.fill_node(node, &entries[..cut]);
        self.fill_node(sibling, &entries[cut..]);
        let holder = if entries[..cut].iter().any(|e| e.child == entry.child) {
            node
        } else {
            sibling
        };

        let node_bound = self.node_bound(node);
        let sibling_entry = self.node_entry(sibling);
        if parent == NIL {
            let root = self.alloc_node(level + 1, NIL);
            self.write_lane(
                root,
                0,
                &Entry {
                    lane_box: node_bound,
                    bound: node_bound,
                    child: node,
                },
            );
            self.write_lane(root, 1, &sibling_entry);
            self.nodes[root as usize].len = 2;
            self.nodes[root as usize].refresh_order();
            self.root = root;
        } else {
            let lane = self.nodes[parent as usize]
                .lane_of(node)
                .expect("parent links its child");
            self.set_child_bound(parent, lane, &node_bound);
            self.add_to_node(parent, sibling_entry);
        }
        holder
    }

    /// The entries currently in `node`'s lanes.
    pub(super) fn node_entries(&self, node: u32) -> SmallVec<[Entry; 17]> {
        let n = &self.nodes[node as usize];
        (0..n.len())
            .map(|lane| {
                let lane_box = n.lane_box(lane);
                let child = n.child[lane];
                let bound = if n.is_leaf() {
                    self.proxies[child as usize].fat
                } else {
                    lane_box
                };
                Entry {
                    lane_box,
                    bound,
                    child,
                }
            })
            .collect()
    }

    /// `node` as an entry for its parent.
    pub(super) fn node_entry(&self, node: u32) -> Entry {
        let bound = self.node_bound(node);
        Entry {
            lane_box: bound,
            bound,
            child: node,
        }
    }

    /// Replaces all lanes of `node` with `entries` (at most `W`).
    pub(super) fn fill_node(&mut self, node: u32, entries: &[Entry]) {
        debug_assert!(entries.len() <= W);
        for (lane, entry) in entries.iter().enumerate() {
            self.write_lane(node, lane, entry);
        }
        let n = &mut self.nodes[node as usize];
        for lane in entries.len()..W {
            n.clear_lane(lane);
        }
        n.len = entries.len() as u16;
        n.refresh_order();
    }
}
