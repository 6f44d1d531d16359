//! The tree under random operation sequences, checked after every step
//! against the brute-force oracle and `validate()`.

mod common;

use std::collections::BTreeMap;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, ProxyId, QueryWorkspace, RTree, Ray, SplitStrategy,
    TreeSettings,
};
use glam::{Quat, Vec3};
use proptest::prelude::*;

#[derive(Clone, Debug)]
enum Op {
    Insert(Aabb),
    /// Insert a box identical to an existing entry's box.
    InsertIdentical(usize),
    /// A small move: the entry's box shifted by a grid step.
    Nudge(usize, Vec3),
    /// Move to an arbitrary new box.
    Update(usize, Aabb),
    /// A teleport a million metres away.
    Teleport(usize, Aabb),
    /// One `update_batch` call; the same entry may appear more than once.
    Batch(Vec<(usize, Aabb)>),
    Remove(usize),
    /// Remove and reinsert in one frame.
    RemoveReinsert(usize),
    Bulk(Vec<Aabb>),
    Optimize,
    Rebuild,
    /// A rebuild started if none is under way, then this many units of its
    /// work: the other operations then land while it runs, and the swap
    /// comes at some later step.
    RebuildSteps(usize),
}

fn op() -> impl Strategy<Value = Op> {
    let nudge = (-2i32..=2, -2i32..=2, -2i32..=2)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32) * 0.125);
    prop_oneof![
        6 => common::grid_box().prop_map(Op::Insert),
        1 => any::<usize>().prop_map(Op::InsertIdentical),
        5 => (any::<usize>(), nudge).prop_map(|(i, d)| Op::Nudge(i, d)),
        2 => (any::<usize>(), common::grid_box()).prop_map(|(i, b)| Op::Update(i, b)),
        1 => (any::<usize>(), common::grid_box())
            .prop_map(|(i, b)| Op::Teleport(i, Aabb { min: b.min + 1e6, max: b.max + 1e6 })),
        2 => prop::collection::vec((any::<usize>(), common::grid_box()), 0..12).prop_map(Op::Batch),
        3 => any::<usize>().prop_map(Op::Remove),
        1 => any::<usize>().prop_map(Op::RemoveReinsert),
        1 => prop::collection::vec(common::grid_box(), 0..40).prop_map(Op::Bulk),
        1 => Just(Op::Optimize),
        1 => Just(Op::Rebuild),
        2 => (1usize..6).prop_map(Op::RebuildSteps),
    ]
}

/// The tree, the oracle and the handle of each live key, kept in step.
struct Model<const W: usize> {
    tree: RTree<u32, W>,
    oracle: BruteForce<u32>,
    handles: BTreeMap<u32, ProxyId>,
    next_key: u32,
}

impl<const W: usize> Model<W> {
    fn new(settings: TreeSettings) -> Self {
        Model {
            tree: RTree::with_settings(settings).unwrap(),
            oracle: BruteForce::default(),
            handles: BTreeMap::new(),
            next_key: 0,
        }
    }

    fn pick(&self, i: usize) -> Option<(u32, ProxyId)> {
        if self.handles.is_empty() {
            return None;
        }
        self.handles
            .iter()
            .nth(i % self.handles.len())
            .map(|(k, h)| (*k, *h))
    }

    fn insert(&mut self, aabb: Aabb) {
        let key = self.next_key;
        self.next_key += 1;
        let id = self.tree.insert(key, aabb).unwrap();
        self.oracle.insert(key, aabb);
        self.handles.insert(key, id);
    }

    fn apply(&mut self, op: &Op) {
        match op {
            Op::Insert(aabb) => self.insert(*aabb),
            Op::InsertIdentical(i) => {
                if let Some((_, id)) = self.pick(*i) {
                    let (_, aabb) = self.tree.get(id).unwrap();
                    self.insert(aabb);
                }
            }
            Op::Nudge(i, delta) => {
                if let Some((key, id)) = self.pick(*i) {
                    let (_, old) = self.tree.get(id).unwrap();
                    let moved = Aabb {
                        min: old.min + *delta,
                        max: old.max + *delta,
                    };
                    self.tree.update(id, moved).unwrap();
                    self.oracle.update(key, moved);
                }
            }
            Op::Update(i, aabb) | Op::Teleport(i, aabb) => {
                if let Some((key, id)) = self.pick(*i) {
                    self.tree.update(id, *aabb).unwrap();
                    self.oracle.update(key, *aabb);
                }
            }
            Op::Batch(moves) => {
                let mut batch = Vec::new();
                for (i, aabb) in moves {
                    if let Some((key, id)) = self.pick(*i) {
                        batch.push((id, *aabb));
                        // In order, so a repeated entry ends at its last box.
                        self.oracle.update(key, *aabb);
                    }
                }
                self.tree.update_batch(&batch).unwrap();
            }
            Op::Remove(i) => {
                if let Some((key, id)) = self.pick(*i) {
                    assert_eq!(self.tree.remove(id), Ok(key));
                    self.oracle.remove(key);
                    self.handles.remove(&key);
                    assert!(self.tree.get(id).is_err(), "a removed handle stays dead");
                }
            }
            Op::RemoveReinsert(i) => {
                if let Some((key, id)) = self.pick(*i) {
                    let (_, aabb) = self.tree.get(id).unwrap();
                    self.tree.remove(id).unwrap();
                    let again = self.tree.insert(key, aabb).unwrap();
                    assert_ne!(again, id, "a reused slot gets a new generation");
                    self.handles.insert(key, again);
                }
            }
            Op::Bulk(boxes) => {
                let first = self.next_key;
                let keys: Vec<u32> = (first..first + boxes.len() as u32).collect();
                self.next_key += boxes.len() as u32;
                let entries = keys.iter().copied().zip(boxes.iter().copied());
                // Leaves packed full, or with room, by the batch's length.
                let ids = if boxes.len().is_multiple_of(2) {
                    self.tree.insert_bulk(entries)
                } else {
                    self.tree.insert_bulk_with_room(entries)
                };
                let ids = ids.unwrap();
                for ((key, aabb), id) in keys.into_iter().zip(boxes).zip(ids) {
                    self.oracle.insert(key, *aabb);
                    self.handles.insert(key, id);
                }
            }
            Op::Optimize => {
                self.tree.optimize(usize::MAX);
            }
            Op::Rebuild => self.tree.rebuild(),
            Op::RebuildSteps(units) => {
                if !self.tree.rebuild_pending() {
                    self.tree.start_rebuild();
                }
                self.tree.step_rebuild_units(*units);
            }
        }
    }

    fn check(&self, query: &Aabb, point: Vec3) {
        self.tree.validate().unwrap();
        assert_eq!(self.tree.len(), self.oracle.len());
        assert_eq!(self.tree.overlapping(query), self.oracle.overlapping(query));
        assert_eq!(
            self.tree.containing_point(point),
            self.oracle.containing_point(point)
        );
        let mut ws = QueryWorkspace::default();
        assert_eq!(
            self.tree.any_overlapping(query, &mut ws),
            !self.oracle.overlapping(query).is_empty()
        );
        let boxes: BTreeMap<u32, Aabb> = self.oracle.entries().iter().copied().collect();
        for (key, id) in &self.handles {
            assert_eq!(self.tree.get(*id), Ok((*key, boxes[key])));
        }
    }

    /// Every other query family on the same mutated tree: a ray from `point`
    /// towards the query box, a view from `point`, a self join, and the
    /// neighbours of `point`.
    fn check_other_queries(&self, query: &Aabb, point: Vec3) {
        let ws = &mut QueryWorkspace::default();
        let towards = (query.min + query.max) * 0.5 - point;
        if let Ok(ray) = Ray::new(point, towards, 1.5) {
            assert_eq!(self.tree.cast_ray(&ray, ws), self.oracle.ray_first(&ray));
            let mut hits = Vec::new();
            let all = self.tree.cast_ray_all(&ray, None, ws, &mut hits);
            assert_eq!(all.map(|()| hits), self.oracle.ray_hits(&ray));
        }
        let view = Frustum::perspective(point, Quat::IDENTITY, 1.5, 1.3, 0.25, 12.0).unwrap();
        for mode in [CullMode::Conservative, CullMode::Exact] {
            assert_eq!(
                self.tree.visible(&view, mode),
                self.oracle.visible(&view, mode)
            );
        }
        for mode in [JoinMode::Euclidean, JoinMode::Chebyshev] {
            assert_eq!(
                self.tree.self_join(0.5, mode),
                self.oracle.self_join(0.5, mode)
            );
        }
        assert_eq!(
            self.tree.nearest(point, 3, None),
            self.oracle.nearest(point, 3, None)
        );
        assert_eq!(
            self.tree.within_radius(point, 3.0),
            self.oracle.within_radius(point, 3.0)
        );
    }
}

fn run<const W: usize>(settings: TreeSettings, ops: &[(Op, Aabb, Vec3)]) {
    let mut model = Model::<W>::new(settings);
    for (step, (op, query, point)) in ops.iter().enumerate() {
        model.apply(op);
        model.check(query, *point);
        // The other families cost more per step (the exact frustum test's
        // preparation above all); every fourth step and the last keep the
        // run to seconds.
        if step % 4 == 3 || step + 1 == ops.len() {
            model.check_other_queries(query, *point);
        }
    }
}

fn ops() -> impl Strategy<Value = Vec<(Op, Aabb, Vec3)>> {
    prop::collection::vec((op(), common::grid_box(), common::grid_point()), 1..160)
}

/// Small repack threshold so `optimize` really repacks in short sequences.
fn eager_settings() -> TreeSettings {
    TreeSettings {
        // Repack after every restructuring move.
        repack_fraction: f32::MIN_POSITIVE,
        ..TreeSettings::default()
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn width_4_matches_oracle_after_every_operation(ops in ops()) {
        run::<4>(eager_settings(), &ops);
    }

    #[test]
    fn width_8_matches_oracle_after_every_operation(ops in ops()) {
        run::<8>(TreeSettings::default(), &ops);
    }

    /// A width that is a multiple of four but of no wider lane test: the
    /// four-lane paths alone.
    #[test]
    fn width_12_matches_oracle_after_every_operation(ops in ops()) {
        run::<12>(TreeSettings::default(), &ops);
    }

    /// The default width with the default settings.
    #[test]
    fn width_16_matches_oracle_after_every_operation(ops in ops()) {
        run::<16>(TreeSettings::default(), &ops);
    }

    #[test]
    fn width_16_without_margin_matches_oracle(ops in ops()) {
        let settings = TreeSettings { margin: 0.0, displacement_factor: 0.0, ..eager_settings() };
        run::<16>(settings, &ops);
    }

    /// Width 4 splits often, so each strategy divides many nodes here.
    #[test]
    fn every_split_strategy_matches_oracle(
        ops in ops(),
        split in prop_oneof![Just(SplitStrategy::Quadratic), Just(SplitStrategy::Median)],
    ) {
        run::<4>(TreeSettings { split, ..eager_settings() }, &ops);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Bulk loads large enough that level-1 nodes keep room for more leaves
    /// (more than 28 leaves at width 16), then a batch of moves and a
    /// repack: `validate()` and the oracle after each step.
    #[test]
    fn large_bulk_loads_match_the_oracle_through_moves(
        boxes in prop::collection::vec(common::grid_box(), 450..1200),
        moves in prop::collection::vec((any::<usize>(), common::grid_box()), 0..300),
        queries in prop::collection::vec(common::grid_box(), 8),
    ) {
        let mut tree: RTree<u32> = RTree::new();
        let mut oracle = BruteForce::default();
        let ids = tree
            .insert_bulk(boxes.iter().enumerate().map(|(i, b)| (i as u32, *b)))
            .unwrap();
        for (i, b) in boxes.iter().enumerate() {
            oracle.insert(i as u32, *b);
        }
        let agree = |tree: &RTree<u32>, oracle: &BruteForce<u32>| {
            tree.validate().unwrap();
            for query in &queries {
                assert_eq!(tree.overlapping(query), oracle.overlapping(query));
            }
        };
        agree(&tree, &oracle);
        let batch: Vec<(ProxyId, Aabb)> = moves
            .iter()
            .map(|&(i, b)| (ids[i % ids.len()], b))
            .collect();
        for &(i, b) in &moves {
            oracle.update((i % ids.len()) as u32, b);
        }
        tree.update_batch(&batch).unwrap();
        agree(&tree, &oracle);
        tree.optimize(usize::MAX);
        agree(&tree, &oracle);
    }
}
