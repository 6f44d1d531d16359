//! Culling with proof: the entries a frustum may see, and which of them a
//! smaller frustum contains, in one traversal (for serving another
//! engine's culling, whose exact test then decides only the unproven).

use super::QueryWorkspace;
use super::frustum::{CullMode, PreparedView};
use super::frustum_levels::KEYS_AHEAD;
use crate::geometry::Frustum;
use crate::tree::RTree;

impl<K: Copy + Ord, const W: usize> RTree<K, W> {
    /// Calls `visit(key, contained)` for every entry that the conservative
    /// test of `loose` accepts ([contract S7](crate::contract)), with `contained` true iff
    /// `tight` contains its box (every corner strictly inside every plane,
    /// as [`frustum_contains`](crate::geometry::predicates::frustum_contains)
    /// decides), in no particular order.
    ///
    /// `tight` must lie within `loose` plane by plane (same normals, offsets
    /// no larger): then a contained box is also accepted, and a node that
    /// `tight` contains is reported whole, as contained, without a test.
    #[cfg_attr(not(feature = "bevy_camera"), allow(dead_code))]
    pub(crate) fn visit_visible_proving(
        &self,
        loose: &Frustum,
        tight: &Frustum,
        ws: &mut QueryWorkspace,
        mut visit: impl FnMut(K, bool),
    ) {
        debug_assert!(
            tight_within(tight, loose),
            "`tight` must lie within `loose` plane by plane"
        );
        let loose = PreparedView::new(loose, CullMode::Conservative);
        let tight = PreparedView::new(tight, CullMode::Conservative);
        if self.is_empty() {
            return;
        }
        // Items: a node and the planes of `tight` it is not yet inside.
        ws.cull_stack.clear();
        ws.cull_stack
            .push((self.root(), u64::from(tight.active_planes)));
        while let Some((index, tight_planes)) = ws.cull_stack.pop() {
            if tight_planes == 0 {
                self.report_contained(index, ws, &mut visit);
                continue;
            }
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            let (seen, _) = loose.test_lanes::<W, false>(node, loose.active_planes);
            let (_, remaining) = tight.test_lanes::<W, true>(node, tight_planes as u8);
            let mut lanes = seen & node.used_lanes();
            if node.is_leaf() {
                ws.stats.entries_tested += node.len() as u64;
            }
            while lanes != 0 {
                let lane = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                if node.is_leaf() {
                    visit(self.key_of(node.child[lane]), remaining[lane] == 0);
                } else {
                    // Requested now so that the loads overlap; a child
                    // contained whole is read for its links only.
                    let child = node.child[lane];
                    if remaining[lane] == 0 {
                        self.prefetch_node_links(child);
                    } else {
                        self.prefetch_node(child);
                    }
                    ws.cull_stack.push((child, u64::from(remaining[lane])));
                }
            }
        }
    }

    /// Reports every entry below `index` as contained, in two passes: the
    /// internal nodes first, their children's links requested and the
    /// leaves gathered; then the leaves, the keys of the leaf
    /// [`KEYS_AHEAD`] places on requested as each is reported.
    #[cfg_attr(not(feature = "bevy_camera"), allow(dead_code))]
    fn report_contained(
        &self,
        index: u32,
        ws: &mut QueryWorkspace,
        visit: &mut impl FnMut(K, bool),
    ) {
        let mut stack = std::mem::take(&mut ws.stack);
        let mut leaves = std::mem::take(&mut ws.leaves);
        stack.clear();
        leaves.clear();
        stack.push(index);
        while let Some(index) = stack.pop() {
            let node = self.node(index);
            ws.stats.nodes_visited += 1;
            if node.is_leaf() {
                leaves.push(index);
                continue;
            }
            let children = &node.child[..node.len()];
            for &child in children {
                self.prefetch_node_links(child);
            }
            stack.extend_from_slice(children);
        }
        for (n, &leaf) in leaves.iter().enumerate() {
            if let Some(&ahead) = leaves.get(n + KEYS_AHEAD) {
                self.prefetch_keys_of_leaf(self.node(ahead));
            }
            for &proxy in &self.node(leaf).child[..self.node(leaf).len()] {
                visit(self.key_of(proxy), true);
            }
        }
        ws.stack = stack;
        ws.leaves = leaves;
    }
}

/// The precondition of [`RTree::visit_visible_proving`]: the same eye, and
/// each plane of `tight` the plane of `loose` with the same normal and an
/// offset no larger (so a plane is inactive in both or in neither), so
/// that `tight` contains nothing `loose` culls.
fn tight_within(tight: &Frustum, loose: &Frustum) -> bool {
    tight.eye() == loose.eye()
        && tight
            .planes()
            .iter()
            .zip(loose.planes())
            .all(|(t, l)| t.normal == l.normal && t.offset <= l.offset)
}

#[cfg(test)]
mod tests {
    use glam::{Quat, Vec3};

    /// A tight frustum that is not within the loose one is refused in
    /// debug builds: here the loose one sees only x > 5, the tight one
    /// everything.
    #[test]
    #[cfg(debug_assertions)]
    #[should_panic(expected = "must lie within")]
    fn a_tight_frustum_outside_the_loose_one_is_refused() {
        let tree = crate::RTree::<u32>::new();
        let only_beyond_5 = HalfSpace {
            normal: Vec3::X,
            offset: -5.0,
        };
        let i = HalfSpace::INACTIVE;
        let loose = Frustum::new(Vec3::ZERO, [only_beyond_5, i, i, i, i, i]).unwrap();
        let everything = Frustum::new(Vec3::ZERO, [i; 6]).unwrap();
        tree.visit_visible_proving(
            &loose,
            &everything,
            &mut QueryWorkspace::default(),
            |_, _| {},
        );
    }

    use crate::geometry::predicates::{frustum_conservative, frustum_contains};
    use crate::geometry::{Aabb, Frustum, HalfSpace};
    use crate::query::QueryWorkspace;
    use crate::scene::{SceneRng, TownScene};

    /// Reported exactly the entries the loose frustum's conservative test
    /// accepts, each with the scalar containment test's answer for the
    /// tight frustum, on the standard town with views all around it.
    #[test]
    fn candidates_and_proofs_agree_with_the_scalar_predicates() {
        let scene = TownScene::new(20_000, 4);
        let (tree, _) = scene.bulk_loaded_tree();
        let mut rng = SceneRng::new(9);
        let mut ws = QueryWorkspace::default();
        let mut proven = 0;
        for _ in 0..40 {
            let eye = Vec3::new(
                rng.range(0.0, 2000.0),
                rng.range(0.0, 100.0),
                rng.range(0.0, 2000.0),
            );
            let turn = Quat::from_rotation_y(rng.range(0.0, 6.3));
            let view = Frustum::perspective(eye, turn, 1.0, 1.7, 0.1, 300.0).unwrap();
            let slack = rng.range(0.0, 2.0);
            let moved = |by: f32| {
                let planes = view.planes().map(|p| {
                    if p.is_inactive() {
                        p
                    } else {
                        HalfSpace {
                            offset: p.offset + by,
                            ..p
                        }
                    }
                });
                Frustum::new(eye, planes).unwrap()
            };
            let (loose, tight) = (moved(slack), moved(-slack));
            let mut got = Vec::new();
            tree.visit_visible_proving(&loose, &tight, &mut ws, |key, contained| {
                got.push((key, contained))
            });
            got.sort_unstable();
            let mut want: Vec<(u32, bool)> = scene
                .boxes()
                .iter()
                .enumerate()
                .filter(|(_, b)| frustum_conservative(&loose, b))
                .map(|(i, b): (usize, &Aabb)| (i as u32, frustum_contains(&tight, b)))
                .collect();
            want.sort_unstable();
            assert_eq!(got, want);
            proven += got.iter().filter(|g| g.1).count();
        }
        assert!(proven > 10_000, "containment is exercised: {proven}");
    }
}
