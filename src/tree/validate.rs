//! The invariant checker ([contract S10](crate::contract)).

use std::fmt;

use super::RTree;
use super::node::{FREE_LEVEL, NIL};
use super::rebuild::Phase;
use crate::geometry::Aabb;

/// A broken invariant found by [`RTree::validate`]; the text says which.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InvariantViolation(pub String);

impl fmt::Display for InvariantViolation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "R-tree invariant violated: {}", self.0)
    }
}

impl std::error::Error for InvariantViolation {}

macro_rules! ensure {
    ($cond:expr, $($msg:tt)+) => {
        if !$cond {
            return Err(InvariantViolation(format!($($msg)+)));
        }
    };
}

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Checks every structural invariant; cheap enough to call after every
    /// mutation in tests (linear in the tree's size).
    ///
    /// Checked: parent and child links agree, there are no cycles and every
    /// node is reachable exactly once; every lane box contains its child's
    /// bound (for a leaf entry: its enlarged box contains its exact box);
    /// fan-out is within `[MIN_FILL, W]` except at the root, and an internal
    /// root has at least two children; all leaves are at the same depth;
    /// unused lanes are inverted; the number of leaf entries equals `len()`
    /// and the number of live handles, and each handle points at the lane
    /// that holds it; every stored exact and enlarged box is valid; each
    /// node's copy of the bound its parent holds for it matches that lane
    /// (all space for the root); free nodes plus live nodes make up the
    /// pool, and free slots plus live and retired ones the slots, each listed
    /// once; inner lanes hold valid boxes. Of a rebuild under way: its
    /// marks agree, and until its catch-up begins (and while its work is
    /// here), the entries its new leaves hold unmarked are the tree's,
    /// with their current boxes.
    pub fn validate(&self) -> Result<(), InvariantViolation> {
        let root = self.root;
        ensure!(
            (root as usize) < self.nodes.len(),
            "root {root} out of the pool"
        );
        ensure!(
            self.held_bounds.len() == self.nodes.len() && self.churn.len() == self.nodes.len(),
            "{} held bounds and {} churn counts for {} nodes",
            self.held_bounds.len(),
            self.churn.len(),
            self.nodes.len()
        );
        ensure!(self.nodes[root as usize].parent == NIL, "root has a parent");
        ensure!(
            self.held_bounds[root as usize] == Aabb::EVERYWHERE,
            "the root's copy of its bound is {:?}, not all space",
            self.held_bounds[root as usize]
        );
        let mut seen = vec![false; self.nodes.len()];
        let mut stack = vec![root];
        let mut entries = 0usize;
        let mut live_nodes = 0usize;
        while let Some(index) = stack.pop() {
            ensure!(
                !seen[index as usize],
                "node {index} reached twice (cycle or shared child)"
            );
            seen[index as usize] = true;
            live_nodes += 1;
            let node = &self.nodes[index as usize];
            ensure!(
                node.level != FREE_LEVEL,
                "free node {index} is linked into the tree"
            );
            let len = node.len();
            ensure!(len <= W, "node {index} holds {len} > {W} lanes");
            if index == root {
                ensure!(
                    node.is_leaf() || len >= 2,
                    "internal root has {len} children"
                );
            } else {
                ensure!(
                    len >= Self::MIN_FILL,
                    "node {index} underfull: {len} < {}",
                    Self::MIN_FILL
                );
            }
            if !node.is_leaf() {
                for (axis, order) in node.order.iter().enumerate() {
                    let mut lanes: Vec<u8> = order[..len].to_vec();
                    lanes.sort_unstable();
                    let permutation = lanes.iter().enumerate().all(|(i, &l)| i == l as usize);
                    ensure!(
                        permutation,
                        "node {index} order on axis {axis} is not a permutation of its lanes"
                    );
                }
            }
            for lane in len..W {
                let unused = node.lane_box(lane) == Aabb::INVERTED && node.child[lane] == NIL;
                ensure!(unused, "node {index} lane {lane} is unused but not cleared");
            }
            for lane in 0..len {
                let child = node.child[lane];
                let lane_box = node.lane_box(lane);
                if node.is_leaf() {
                    entries += 1;
                    let proxy = self.proxies.get(child as usize);
                    ensure!(proxy.is_some(), "leaf {index} names missing proxy {child}");
                    let proxy = proxy.unwrap();
                    ensure!(
                        proxy.leaf == index && proxy.lane as usize == lane,
                        "proxy {child} points at ({}, {}) but lives in ({index}, {lane})",
                        proxy.leaf,
                        proxy.lane
                    );
                    ensure!(
                        lane_box.is_valid(),
                        "proxy {child} has invalid box {lane_box:?}"
                    );
                    ensure!(
                        proxy.fat.is_valid() && proxy.fat.contains(&lane_box),
                        "proxy {child}: enlarged box {:?} is invalid or misses exact box",
                        proxy.fat
                    );
                } else {
                    ensure!(
                        (child as usize) < self.nodes.len(),
                        "node {index} names missing node {child}"
                    );
                    let c = &self.nodes[child as usize];
                    ensure!(
                        c.parent == index,
                        "node {child} has parent {} but hangs under {index}",
                        c.parent
                    );
                    ensure!(
                        self.held_bounds[child as usize] == lane_box,
                        "node {child}'s copy of its bound {:?} is not the {lane_box:?} node {index} holds",
                        self.held_bounds[child as usize]
                    );
                    ensure!(
                        c.level != FREE_LEVEL && c.level + 1 == node.level,
                        "node {child} at level {} under level {}",
                        c.level,
                        node.level
                    );
                    // Valid too: an unbounded lane (all space leaking in
                    // from the root's copy, say) would make every query
                    // visit the whole subtree without a wrong answer.
                    ensure!(
                        lane_box.is_valid(),
                        "node {index} lane {lane} holds invalid box {lane_box:?}"
                    );
                    let bound = self.node_bound(child);
                    ensure!(
                        lane_box.contains(&bound),
                        "node {index} lane {lane} does not contain child {child}"
                    );
                    stack.push(child);
                }
            }
        }
        ensure!(
            entries == self.len,
            "{entries} leaf entries but len() = {}",
            self.len
        );
        let live_proxies = self.proxies.iter().filter(|p| p.is_live()).count();
        ensure!(
            self.stamps.len() == self.proxies.len(),
            "{} stamps for {} proxy slots",
            self.stamps.len(),
            self.proxies.len()
        );
        for (index, (proxy, stamp)) in self.proxies.iter().zip(&self.stamps).enumerate() {
            ensure!(
                proxy.is_live() == stamp.is_live(),
                "proxy {index} is live in its record but not in its stamp, or the reverse"
            );
        }
        ensure!(
            live_proxies == self.len,
            "{live_proxies} live handles but len() = {}",
            self.len
        );
        let exhausted = self.stamps.iter().filter(|s| s.is_exhausted()).count();
        ensure!(
            live_proxies + self.free_proxies.len() + exhausted == self.proxies.len(),
            "proxy free list, live and exhausted proxies do not add up"
        );
        ensure!(
            self.keys.len() == self.proxies.len(),
            "{} keys for {} proxy slots",
            self.keys.len(),
            self.proxies.len()
        );
        // Counts alone would pass a slot listed twice beside one missing.
        let mut listed = vec![false; self.proxies.len()];
        for &free in &self.free_proxies {
            let stamp = self.stamps.get(free as usize);
            ensure!(
                stamp.is_some_and(|s| !s.is_live() && !s.is_exhausted()),
                "free proxy slot {free} is live, exhausted or missing"
            );
            ensure!(
                !std::mem::replace(&mut listed[free as usize], true),
                "free proxy slot {free} is listed twice"
            );
        }
        for &free in &self.free_nodes {
            ensure!(
                !seen[free as usize],
                "free node {free} is reachable or listed twice"
            );
            seen[free as usize] = true;
            ensure!(
                self.nodes[free as usize].level == FREE_LEVEL,
                "free node {free} is not marked free"
            );
        }
        ensure!(
            self.dirty.is_consistent(),
            "the repair queue's places disagree with its nodes"
        );
        for &queued in self.dirty.nodes() {
            let node = self.nodes.get(queued as usize);
            ensure!(
                node.is_some_and(|n| n.level == 1),
                "queued node {queued} is not a live level-1 node"
            );
        }
        ensure!(
            live_nodes + self.free_nodes.len() == self.nodes.len(),
            "{live_nodes} live + {} free nodes != pool of {}",
            self.free_nodes.len(),
            self.nodes.len()
        );
        self.validate_rebuild_under_way()
    }

    /// The rebuild under way, which answers nothing until it is swapped
    /// in, so that a fault in it would show only then: its marks are each
    /// listed once; and before the catch-up, every entry the new structure
    /// holds unmarked is the same entry as in the snapshot, at the lane its
    /// record names, with the tree's current exact box, inside its enlarged
    /// box, inside its new leaf's bound.
    fn validate_rebuild_under_way(&self) -> Result<(), InvariantViolation> {
        let Some(job) = self.rebuild_job.as_deref() else {
            return Ok(());
        };
        let marked = |slot: usize| job.is_marked.get(slot).copied().unwrap_or(false);
        for &slot in &job.marked {
            ensure!(
                marked(slot as usize),
                "slot {slot} listed as marked, not marked"
            );
        }
        let marks = job.is_marked.iter().filter(|&&m| m).count();
        ensure!(
            marks == job.marked.len(),
            "{marks} slots marked, {} listed",
            job.marked.len()
        );
        if matches!(job.phase, Phase::Away | Phase::CatchUp(_)) {
            return Ok(());
        }
        for (slot, &(leaf, lane, fat)) in job.placed.iter().enumerate() {
            if leaf == NIL || marked(slot) {
                continue;
            }
            ensure!(
                job.snapshot_stamps.get(slot) == self.stamps.get(slot),
                "slot {slot} changed hands since the snapshot, unmarked"
            );
            let record = &self.proxies[slot];
            let exact = self.nodes[record.leaf as usize].lane_box(record.lane as usize);
            let new_leaf = &job.nodes[leaf as usize];
            ensure!(
                new_leaf.child[lane as usize] == slot as u32,
                "slot {slot} placed at ({leaf}, {lane}), which holds {}",
                new_leaf.child[lane as usize]
            );
            ensure!(
                new_leaf.lane_box(lane as usize) == exact && fat.contains(&exact),
                "slot {slot}: the new leaf holds {:?}, enlarged {fat:?}, the tree {exact:?}",
                new_leaf.lane_box(lane as usize)
            );
            ensure!(
                job.leaf_bounds[leaf as usize].contains(&fat),
                "slot {slot}: enlarged box {fat:?} outside its new leaf's bound"
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    /// A tree of 500 unit boxes on a line: three levels at width 16.
    fn tree() -> RTree<u32> {
        let mut tree = RTree::new();
        for i in 0..500u32 {
            let p = Vec3::new(i as f32, 0.0, 0.0);
            tree.insert(i, Aabb::new(p, p + Vec3::ONE).unwrap())
                .unwrap();
        }
        tree
    }

    #[test]
    fn a_stale_copy_of_a_held_bound_is_reported() {
        let mut tree = tree();
        tree.validate().unwrap();
        let root = tree.nodes[tree.root as usize].clone();
        assert!(!root.is_leaf());
        let child = root.child[0] as usize;
        tree.held_bounds[child].max.x += 1.0;
        let broken = tree.validate().unwrap_err();
        assert!(broken.0.contains("copy of its bound"), "{broken}");
    }

    /// Each invariant, broken alone in a valid tree, is reported by its
    /// own message: the random-operation tests rely on `validate` as their
    /// structural oracle.
    #[test]
    fn every_broken_invariant_is_reported() {
        type Break = fn(&mut RTree<u32>);
        fn first_child(tree: &RTree<u32>) -> usize {
            tree.nodes[tree.root as usize].child[0] as usize
        }
        fn first_leaf(tree: &RTree<u32>) -> usize {
            let mut node = tree.root as usize;
            while !tree.nodes[node].is_leaf() {
                node = tree.nodes[node].child[0] as usize;
            }
            node
        }
        let cases: [(&str, Break, &str); 12] = [
            (
                "a parent link",
                |t| {
                    let child = first_child(t);
                    t.nodes[child].parent = 12_345;
                },
                "has parent",
            ),
            (
                "a lane that misses its child",
                |t| {
                    let root = t.root as usize;
                    let child = first_child(t);
                    let mut lane = t.nodes[root].lane_box(0);
                    lane.max.x = lane.min.x;
                    t.nodes[root].set_lane_box(0, &lane);
                    t.held_bounds[child] = lane;
                },
                "does not contain child",
            ),
            (
                "an underfull node",
                |t| {
                    let leaf = first_leaf(t);
                    t.nodes[leaf].len = 1;
                },
                "underfull",
            ),
            (
                "a handle's lane",
                |t| {
                    let leaf = first_leaf(t);
                    let proxy = t.nodes[leaf].child[0] as usize;
                    t.proxies[proxy].lane += 1;
                },
                "points at",
            ),
            ("the length", |t| t.len += 1, "but len()"),
            (
                "an exact box outside its enlarged box",
                |t| {
                    let leaf = first_leaf(t);
                    let proxy = t.nodes[leaf].child[0] as usize;
                    t.proxies[proxy].fat.max.x = t.proxies[proxy].fat.min.x;
                },
                "misses exact box",
            ),
            (
                "a visiting order",
                |t| {
                    let root = t.root as usize;
                    t.nodes[root].order[0][0] = t.nodes[root].order[0][1];
                },
                "not a permutation",
            ),
            (
                "an unused lane",
                |t| {
                    let root = t.root as usize;
                    let len = t.nodes[root].len();
                    t.nodes[root].child[len] = 0;
                },
                "unused but not cleared",
            ),
            (
                "a child's level",
                |t| {
                    let child = first_child(t);
                    t.nodes[child].level += 1;
                },
                "at level",
            ),
            ("the keys' length", |t| t.keys.push(7), "keys for"),
            (
                "a live node on the free list",
                |t| {
                    let child = first_child(t) as u32;
                    t.free_nodes.push(child);
                },
                "reachable or listed twice",
            ),
            (
                "a free slot listed twice",
                |t| {
                    let last = t.free_proxies.len() - 1;
                    t.free_proxies[last] = t.free_proxies[0];
                },
                "listed twice",
            ),
        ];
        for (what, break_it, message) in cases {
            let mut tree = tree();
            // Two free slots for the free list's case.
            for key in [10u32, 20] {
                let id = tree.iter().find(|(_, k, _)| *k == key).unwrap().0;
                tree.remove(id).unwrap();
            }
            tree.validate().unwrap();
            break_it(&mut tree);
            let broken = tree.validate().unwrap_err();
            assert!(broken.0.contains(message), "{what}: {broken}");
        }
    }

    #[test]
    fn a_root_whose_copy_is_not_all_space_is_reported() {
        let mut tree = tree();
        let root = tree.root as usize;
        tree.held_bounds[root] = Aabb::INVERTED;
        let broken = tree.validate().unwrap_err();
        assert!(broken.0.contains("root's copy"), "{broken}");
    }

    /// An inner lane that holds all space (with its child's copy, so that
    /// the two agree) is reported: queries would visit the whole subtree.
    #[test]
    fn an_unbounded_inner_lane_is_reported() {
        let mut tree = tree();
        let root = tree.root as usize;
        let child = tree.nodes[root].child[0] as usize;
        tree.nodes[root].set_lane_box(0, &Aabb::EVERYWHERE);
        tree.held_bounds[child] = Aabb::EVERYWHERE;
        let broken = tree.validate().unwrap_err();
        assert!(broken.0.contains("invalid box"), "{broken}");
    }

    /// Faults in a rebuild under way are reported before its swap: an
    /// entry of a new leaf whose box is not the tree's, and a mark not
    /// listed.
    #[test]
    fn a_rebuild_under_way_that_went_wrong_is_reported() {
        let under_way = || {
            let mut tree = tree();
            tree.start_rebuild();
            // Every leaf filled, the levels above not yet.
            while tree
                .rebuild_job
                .as_ref()
                .unwrap()
                .placed
                .iter()
                .any(|p| p.0 == NIL)
            {
                RTree::<u32>::advance(None, tree.rebuild_job.as_mut().unwrap());
            }
            assert!(!matches!(
                tree.rebuild_job.as_ref().unwrap().phase,
                Phase::Done { .. }
            ));
            tree.validate().unwrap();
            tree
        };
        let mut tree = under_way();
        let job = tree.rebuild_job.as_mut().unwrap();
        let (leaf, lane, _) = job.placed[7];
        let mut moved = job.nodes[leaf as usize].lane_box(lane as usize);
        moved.max.y += 0.5;
        job.nodes[leaf as usize].set_lane_box(lane as usize, &moved);
        let broken = tree.validate().unwrap_err();
        assert!(broken.0.contains("slot 7: the new leaf holds"), "{broken}");

        let mut tree = under_way();
        let job = tree.rebuild_job.as_mut().unwrap();
        job.is_marked.resize(8, false);
        job.is_marked[7] = true;
        let broken = tree.validate().unwrap_err();
        assert!(broken.0.contains("1 slots marked, 0 listed"), "{broken}");
    }
}
