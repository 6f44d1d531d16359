//! The cull's walk, one level of the tree at a time, reporting in the order
//! of a depth-first walk.
//!
//! A depth-first walk waits on memory at every step down: the child it
//! visits next was asked for only when its parent was read. Walking level
//! by level (seed 002's breadth-first queue), every node of a level is
//! known, and asked for, before the first of them is read, so their loads
//! overlap. The order of what is reported is kept: each level's list is in
//! the order a depth-first stack would hold it (children in lane order, the
//! last reported first), so the leaves' list read backwards is the
//! depth-first reporting order, and the parallel cull, which runs the
//! subtrees of a frontier each on their own, gives the same answers in the
//! same order.

use std::ops::ControlFlow;

use super::QueryWorkspace;
use super::frustum::{CullItem, PreparedView, alive_views, fully_inside};
use crate::tree::RTree;

/// How many leaves ahead of the one reported the walk asks for the keys
/// (keys live apart from the leaves, one line each when the tree is cold
/// and not loaded in leaf order).
pub(super) const KEYS_AHEAD: usize = 8;

/// How many leaves ahead of the one reported the walk asks for the leaf
/// itself: far enough that its links are in when its keys are asked for.
const NODES_AHEAD: usize = 16;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Reports every entry below `start` that a view alive in its mask sees
    /// (`visit(view, key, box)`), in the order of a depth-first stack (the
    /// last child first, a leaf's entries in lane order), until `visit`
    /// breaks.
    ///
    /// The internal levels are walked first, each from the list of the
    /// level above, a node every view contains expanded without a test;
    /// then the leaves, each tested (or, where contained, reported whole)
    /// while the keys of the leaf [`KEYS_AHEAD`] places on load. With
    /// `BOXES` false the visitor is given `Aabb::EVERYWHERE` for an entry
    /// of a contained leaf, and contained nodes are read for their links
    /// only: two lines of a leaf's eight.
    pub(crate) fn cull_subtree<const BOXES: bool, V>(
        &self,
        views: &[PreparedView],
        start: CullItem,
        ws: &mut QueryWorkspace,
        visit: &mut V,
    ) -> ControlFlow<()>
    where
        V: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        let mut level = std::mem::take(&mut ws.cull_stack);
        let mut next = std::mem::take(&mut ws.cull_level);
        level.clear();
        level.push(start);
        // Leaves are all on one level: a list holds leaves or no leaf.
        while level
            .first()
            .is_some_and(|&(index, _)| !self.node(index).is_leaf())
        {
            next.clear();
            debug_assert!(
                level
                    .iter()
                    .all(|&(index, _)| self.node(index).level == self.node(level[0].0).level),
                "a level's list holds nodes of one level"
            );
            // Leaves are asked for as they come near in `report_leaves`:
            // asked for all at once, the first would leave the first-level
            // cache before their turn.
            let prefetch = self.node(level[0].0).level > 1;
            for &item in &level {
                ws.stats.nodes_visited += 1;
                self.push_visible_children::<BOXES>(views, item, prefetch, &mut next);
            }
            std::mem::swap(&mut level, &mut next);
        }
        let flow = self.report_leaves::<BOXES, V>(views, &level, ws, visit);
        ws.cull_stack = level;
        ws.cull_level = next;
        flow
    }

    /// The leaves of [`RTree::cull_subtree`], given in stack order (the
    /// last reported first).
    fn report_leaves<const BOXES: bool, V>(
        &self,
        views: &[PreparedView],
        leaves: &[CullItem],
        ws: &mut QueryWorkspace,
        visit: &mut V,
    ) -> ControlFlow<()>
    where
        V: FnMut(usize, K, &crate::Aabb) -> ControlFlow<()>,
    {
        for &item in leaves.iter().rev().take(NODES_AHEAD) {
            self.prefetch_cull_item::<BOXES>(item);
        }
        for &(leaf, _) in leaves.iter().rev().take(KEYS_AHEAD) {
            self.prefetch_keys_of_leaf(self.node(leaf));
        }
        for n in (0..leaves.len()).rev() {
            if let Some(ahead) = n.checked_sub(NODES_AHEAD) {
                self.prefetch_cull_item::<BOXES>(leaves[ahead]);
            }
            if let Some(ahead) = n.checked_sub(KEYS_AHEAD) {
                self.prefetch_keys_of_leaf(self.node(leaves[ahead].0));
            }
            let (index, mask) = leaves[n];
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            if !fully_inside(mask) {
                self.cull_leaf(views, mask, node, ws, visit)?;
                continue;
            }
            let alive = alive_views(mask);
            for lane in 0..node.len() {
                let key = self.key_of(node.child[lane]);
                let aabb = if BOXES {
                    node.lane_box(lane)
                } else {
                    crate::Aabb::EVERYWHERE
                };
                let mut views = alive;
                while views != 0 {
                    let view = views.trailing_zeros() as usize;
                    views &= views - 1;
                    visit(view, key, &aabb)?;
                }
            }
        }
        ControlFlow::Continue(())
    }
}

#[cfg(test)]
mod tests {
    use std::ops::ControlFlow;

    use glam::{Quat, Vec3};

    use crate::geometry::predicates::{frustum_conservative, frustum_exact};
    use crate::geometry::{Frustum, FrustumSat};
    use crate::query::QueryWorkspace;
    use crate::query::frustum::CullMode;
    use crate::scene::{SceneRng, TownScene};
    use crate::tree::RTree;

    /// Every entry below `index` in the order of a depth-first stack:
    /// children pushed in lane order, so the last child first, and a
    /// leaf's entries in lane order; each with its box.
    fn depth_first(tree: &RTree<u32>, index: u32, out: &mut Vec<(u32, crate::Aabb)>) {
        let node = tree.node(index);
        if node.is_leaf() {
            for lane in 0..node.len() {
                out.push((tree.key_of(node.child[lane]), node.lane_box(lane)));
            }
            return;
        }
        for lane in (0..node.len()).rev() {
            depth_first(tree, node.child[lane], out);
        }
    }

    /// Whether `mode`'s scalar test accepts `aabb` in `view` (`sat`: the
    /// view's separating axes, built once per view).
    fn accepts(view: &Frustum, sat: &FrustumSat, mode: CullMode, aabb: &crate::Aabb) -> bool {
        match mode {
            CullMode::Conservative => frustum_conservative(view, aabb),
            CullMode::Exact => frustum_exact(view, sat, aabb),
        }
    }

    /// Walked level by level, the cull reports what the scalar test
    /// accepts, in the depth-first order, each key with its own box, on a
    /// maintained tree (entries moved between leaves), in both modes, with
    /// one pass of views and with two; and a visitor that breaks gets
    /// exactly the reports before its break.
    #[test]
    fn reports_in_depth_first_order_what_the_scalar_test_accepts() {
        let mut scene = TownScene::new(20_000, 5);
        let (mut tree, ids) = scene.bulk_loaded_tree();
        for _ in 0..20 {
            scene.advance_frame();
            for &i in scene.moved() {
                tree.update(ids[i as usize], scene.boxes()[i as usize])
                    .unwrap();
            }
            tree.optimize(usize::MAX);
        }
        tree.validate().unwrap();
        let mut all = Vec::new();
        depth_first(&tree, tree.root(), &mut all);
        let mut rng = SceneRng::new(17);
        let mut ws = QueryWorkspace::default();
        let mut reported = 0;
        let mut breaks = 0;
        for round in 0..12 {
            let (mode, count) = match round % 3 {
                0 => (CullMode::Conservative, 3),
                1 => (CullMode::Exact, 8),
                _ => (CullMode::Conservative, 9),
            };
            let views: Vec<Frustum> = (0..count)
                .map(|_| {
                    let eye = rng.point_in_world() + Vec3::Y * rng.range(0.0, 80.0);
                    let turn = Quat::from_rotation_y(rng.range(0.0, 6.3));
                    let far = rng.range(50.0, 600.0);
                    Frustum::perspective(eye, turn, 1.0, 1.7, 0.1, far).unwrap()
                })
                .collect();
            let want: Vec<Vec<(u32, crate::Aabb)>> = views
                .iter()
                .map(|view| {
                    let sat = FrustumSat::new(view);
                    let seen = all
                        .iter()
                        .filter(|(_, aabb)| accepts(view, &sat, mode, aabb));
                    seen.copied().collect()
                })
                .collect();
            let mut keys = Vec::new();
            tree.visible_into(&views, mode, &mut ws, &mut keys);
            let mut with_boxes = vec![Vec::new(); views.len()];
            let mut sequence = Vec::new();
            tree.visit_visible(&views, mode, &mut ws, |view, key, aabb| {
                with_boxes[view].push((key, *aabb));
                sequence.push((view, key));
                ControlFlow::Continue(())
            });
            for (view, want) in want.iter().enumerate() {
                let want_keys: Vec<u32> = want.iter().map(|w| w.0).collect();
                assert_eq!(keys[view], want_keys, "round {round} view {view}");
                assert_eq!(&with_boxes[view], want, "round {round} view {view}");
                reported += want.len();
            }
            // Broken off at a random report: the same reports up to it.
            if sequence.is_empty() {
                continue;
            }
            let cut = rng.below(sequence.len());
            let mut before = Vec::new();
            tree.visit_visible(&views, mode, &mut ws, |view, key, _| {
                before.push((view, key));
                if before.len() > cut {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
            assert_eq!(before, sequence[..=cut], "round {round}");
            breaks += 1;
        }
        assert!(reported > 10_000, "the views see enough: {reported}");
        assert!(breaks >= 10, "breaks tried: {breaks}");
    }
}
