//! Helpers shared by the integration tests.
#![allow(dead_code)]

#[cfg(feature = "plugin")]
pub mod plugin_scene;

use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, ProxyId, RTree};
use glam::Vec3;
use proptest::prelude::*;

/// A box on a coarse dyadic grid (multiples of 0.25 within [-8, 8]) so that
/// faces coincide, boxes touch and points sit exactly on faces often.
pub fn grid_box() -> impl Strategy<Value = Aabb> {
    let coord = -32i32..=32;
    let extent = 0i32..=8;
    (
        coord.clone(),
        coord.clone(),
        coord,
        extent.clone(),
        extent.clone(),
        extent,
    )
        .prop_map(|(x, y, z, ex, ey, ez)| {
            let min = Vec3::new(x as f32, y as f32, z as f32) * 0.25;
            let max = min + Vec3::new(ex as f32, ey as f32, ez as f32) * 0.25;
            Aabb::new(min, max).expect("grid boxes are valid")
        })
}

/// A grid point.
pub fn grid_point() -> impl Strategy<Value = Vec3> {
    (-40i32..=40, -40i32..=40, -40i32..=40)
        .prop_map(|(x, y, z)| Vec3::new(x as f32, y as f32, z as f32) * 0.25)
}

/// Box with corners `min` and `max`, panicking on invalid input (tests only).
pub fn aabb(min: [f32; 3], max: [f32; 3]) -> Aabb {
    Aabb::new(Vec3::from(min), Vec3::from(max)).expect("valid test box")
}

/// The eight corners of `b`.
pub fn corners(b: &Aabb) -> impl Iterator<Item = Vec3> + '_ {
    (0..8).map(move |i| {
        Vec3::new(
            if i & 1 == 0 { b.min.x } else { b.max.x },
            if i & 2 == 0 { b.min.y } else { b.max.y },
            if i & 4 == 0 { b.min.z } else { b.max.z },
        )
    })
}

/// Boxes that are not valid: NaN, infinite, inverted, beyond MAX_COORD.
pub fn invalid_boxes() -> Vec<Aabb> {
    let ok = Vec3::ONE;
    vec![
        Aabb {
            min: Vec3::new(f32::NAN, 0.0, 0.0),
            max: ok,
        },
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(1.0, f32::NAN, 1.0),
        },
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(1.0, 1.0, f32::INFINITY),
        },
        Aabb {
            min: Vec3::new(f32::NEG_INFINITY, 0.0, 0.0),
            max: ok,
        },
        Aabb {
            min: ok,
            max: Vec3::ZERO,
        },
        Aabb {
            min: Vec3::new(0.0, 2.0, 0.0),
            max: Vec3::new(1.0, 1.0, 1.0),
        },
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::new(2e15, 1.0, 1.0),
        },
        Aabb {
            min: Vec3::new(-1.5e15, 0.0, 0.0),
            max: ok,
        },
        Aabb::INVERTED,
    ]
}

/// A town scene of `count` entities and a tree bulk-loaded from it, keyed by
/// entity index, with the handle of each entity.
pub fn town_tree(count: usize, seed: u64) -> (TownScene, RTree<u32>, Vec<ProxyId>) {
    let scene = TownScene::new(count, seed);
    let (tree, ids) = scene.bulk_loaded_tree();
    (scene, tree, ids)
}
