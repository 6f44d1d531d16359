//! Random Bevy transforms, boxes and visibilities for the twin-App tests
//! (feature `bevy_camera`).
#![allow(dead_code)]

use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::Visibility;
use bevy_rtree::scene::SceneRng;
use bevy_transform::prelude::Transform;
use glam::{Quat, Vec3, Vec3A};

/// Anywhere in a square `2 * spread` wide at a height in `heights`, turned
/// and tilted, one in four scaled unevenly.
pub fn random_transform(rng: &mut SceneRng, spread: f32, heights: (f32, f32)) -> Transform {
    let at = Vec3::new(
        rng.range(-spread, spread),
        rng.range(heights.0, heights.1),
        rng.range(-spread, spread),
    );
    let turn = Quat::from_euler(
        glam::EulerRot::YXZ,
        rng.range(0.0, 6.3),
        rng.range(-1.0, 1.0),
        0.0,
    );
    let scale = if rng.below(4) == 0 {
        Vec3::new(
            rng.range(0.2, 3.0),
            rng.range(0.2, 3.0),
            rng.range(0.2, 3.0),
        )
    } else {
        Vec3::ONE
    };
    Transform {
        translation: at,
        rotation: turn,
        scale,
    }
}

/// A local box off the origin, flat on some axes now and then.
pub fn random_aabb(rng: &mut SceneRng) -> Aabb {
    let center = Vec3A::new(
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
    );
    let half = Vec3A::new(
        rng.range(0.0, 3.0),
        rng.range(0.0, 3.0),
        rng.range(0.0, 3.0),
    );
    Aabb {
        center,
        half_extents: half,
    }
}

/// Mostly inherited, sometimes hidden or visible.
pub fn random_visibility(rng: &mut SceneRng) -> Visibility {
    [
        Visibility::Inherited,
        Visibility::Inherited,
        Visibility::Inherited,
        Visibility::Hidden,
        Visibility::Visible,
    ][rng.below(5)]
}
