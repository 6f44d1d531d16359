//! The town frame on bare trees: the core path the plugin's frame is
//! measured against, with every buffer kept between frames.

use super::INCOHERENT_RAYS;
use bevy_rtree::plugin::SpatialIndexPlugin;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, ProxyId, QueryWorkspace, RTree, Ray, RayMode, RayResults,
};
use std::ops::Range;

// The core path.

/// The town frame on bare trees, with every buffer kept between frames (as
/// the plugin keeps its scratch in `Local`s and resources).
pub(crate) struct CoreTown {
    pub(crate) scene: TownScene,
    pub(crate) all: RTree<u32>,
    pub(crate) all_ids: Vec<ProxyId>,
    pub(crate) enemies: RTree<u32>,
    pub(crate) enemy_ids: Vec<ProxyId>,
    pub(crate) barrels: RTree<u32>,
    pub(crate) barrel_ids: Vec<ProxyId>,
    pub(crate) optimize_budget: usize,
    /// Nodes repacked by `optimize` so far, to compare with the plugin's.
    pub(crate) repacked: u64,
    pub(crate) frustum: Frustum,
    pub(crate) rays: Vec<Ray>,
    pub(crate) cull_ws: QueryWorkspace,
    pub(crate) ray_ws: QueryWorkspace,
    pub(crate) join_ws: QueryWorkspace,
    pub(crate) visible: Vec<Vec<u32>>,
    pub(crate) hits: RayResults<u32>,
    pub(crate) pairs: Vec<(u32, u32)>,
    /// A frame's moves per tree (all, enemies, barrels), for `update_batch`.
    pub(crate) moves: [Vec<(ProxyId, Aabb)>; 3],
}

/// A tree of the scene's entities in `range`, keyed by scene index, and the
/// handle of each (`ids[i - range.start]`).
pub(crate) fn layer_tree(scene: &TownScene, range: Range<usize>) -> (RTree<u32>, Vec<ProxyId>) {
    let mut tree = RTree::new();
    let ids = tree
        .insert_bulk(range.map(|i| (i as u32, scene.boxes()[i])))
        .expect("scene boxes are valid");
    (tree, ids)
}

impl CoreTown {
    /// The scene of `town::build(count, seed)`, bulk loaded before its first
    /// frame (the plugin bulk loads on its first frame, after the first moves;
    /// answers depend only on the boxes, and both are churned before timing).
    pub(crate) fn new(count: usize, seed: u64) -> Self {
        let scene = TownScene::new(count, seed);
        let (all, all_ids) = scene.bulk_loaded_tree();
        let (enemies, enemy_ids) = layer_tree(&scene, TownScene::ENEMIES);
        let (barrels, barrel_ids) = layer_tree(&scene, TownScene::BARRELS);
        let frustum = scene.frustum();
        CoreTown {
            scene,
            all,
            all_ids,
            enemies,
            enemy_ids,
            barrels,
            barrel_ids,
            optimize_budget: SpatialIndexPlugin::default().optimize_budget,
            repacked: 0,
            frustum,
            rays: Vec::new(),
            cull_ws: QueryWorkspace::default(),
            ray_ws: QueryWorkspace::default(),
            join_ws: QueryWorkspace::default(),
            visible: vec![Vec::new()],
            hits: RayResults::default(),
            pairs: Vec::new(),
            moves: Default::default(),
        }
    }

    /// The example's `Update` systems: the scene moves, the camera turns and
    /// the rays are re-aimed (same calls, same order, so the scene's random
    /// stream stays in step with the App's).
    pub(crate) fn move_and_aim(&mut self) {
        self.scene.advance_frame();
        self.frustum = self.scene.frustum();
        self.rays = self.scene.incoherent_rays(INCOHERENT_RAYS);
        self.rays.extend(self.scene.coherent_rays());
    }

    /// The plugin's sync: every moved box into every tree that holds it,
    /// as one `update_batch` per tree.
    pub(crate) fn sync(&mut self) {
        let CoreTown {
            scene,
            all,
            all_ids,
            enemies,
            enemy_ids,
            barrels,
            barrel_ids,
            moves: [all_moves, enemy_moves, barrel_moves],
            ..
        } = self;
        let boxes = scene.boxes();
        for batch in [&mut *all_moves, &mut *enemy_moves, &mut *barrel_moves] {
            batch.clear();
        }
        for &index in scene.moved() {
            let i = index as usize;
            let aabb = boxes[i];
            all_moves.push((all_ids[i], aabb));
            if TownScene::ENEMIES.contains(&i) {
                enemy_moves.push((enemy_ids[i - TownScene::ENEMIES.start], aabb));
            } else if TownScene::BARRELS.contains(&i) {
                barrel_moves.push((barrel_ids[i - TownScene::BARRELS.start], aabb));
            }
        }
        for (tree, batch) in [
            (all, all_moves),
            (enemies, enemy_moves),
            (barrels, barrel_moves),
        ] {
            tree.update_batch(batch).expect("live handles, valid boxes");
        }
    }

    /// The plugin's maintenance: it runs only where repairs are pending.
    pub(crate) fn maintain(&mut self) {
        for tree in [&mut self.all, &mut self.enemies, &mut self.barrels] {
            if tree.pending_repairs() > 0 {
                self.repacked += tree.optimize(self.optimize_budget) as u64;
            }
        }
    }

    /// Culling, with the plugin's sorting of the visible list.
    pub(crate) fn cull(&mut self) {
        self.visible[0].clear();
        self.all.visible_into(
            std::slice::from_ref(&self.frustum),
            CullMode::Conservative,
            &mut self.cull_ws,
            &mut self.visible,
        );
        self.visible[0].sort_unstable();
    }

    /// The frame's rays, one batch, first hit.
    pub(crate) fn cast(&mut self) {
        self.all
            .cast_rays(&self.rays, RayMode::First, &mut self.ray_ws, &mut self.hits);
    }

    /// The enemy-barrel join, with the plugin's sorting of the pairs.
    pub(crate) fn join(&mut self) {
        self.pairs.clear();
        self.enemies
            .cross_join_into(
                &self.barrels,
                TownScene::JOIN_DISTANCE,
                JoinMode::Euclidean,
                &mut self.join_ws,
                &mut self.pairs,
            )
            .expect("the join distance is valid");
        self.pairs.sort_unstable();
    }

    pub(crate) fn queries(&mut self) {
        self.cull();
        self.cast();
        self.join();
    }

    pub(crate) fn frame(&mut self) {
        self.move_and_aim();
        self.sync();
        self.maintain();
        self.queries();
    }
}
