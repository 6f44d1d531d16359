//! The smallest complete app: three boxes, a camera and a ray.
//!
//! Run with `cargo run --example minimal`.

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::{Aabb, Ray, RayMode};
use glam::{Quat, Vec3};

/// The app after setup, and the entities a reader looks at.
pub struct Minimal {
    pub app: App,
    pub boxes: [Entity; 3],
    pub camera: Entity,
    pub eye: Entity,
}

pub fn build() -> Minimal {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let world = app.world_mut();
    // Three crates along -Z; the last one is behind the camera.
    let at = |z: f32| {
        SpatialBounds(
            Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, z), Vec3::splat(0.5)).unwrap(),
        )
    };
    let boxes = [
        world.spawn(at(-5.0)).id(),
        world.spawn(at(-10.0)).id(),
        world.spawn(at(5.0)).id(),
    ];
    // A camera at the origin looking down -Z (Bevy's convention).
    let camera =
        CullingCamera::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 16.0 / 9.0, 0.1, 100.0)
            .expect("a valid camera");
    let camera = world.spawn(camera).id();
    // A ray along -Z, first hit.
    let ray = Ray::new(Vec3::ZERO, Vec3::NEG_Z, 100.0).expect("a valid ray");
    let eye = world.spawn(RayCaster::new(ray, RayMode::First)).id();
    Minimal {
        app,
        boxes,
        camera,
        eye,
    }
}

#[allow(dead_code)]
fn main() {
    let mut minimal = build();
    minimal.app.update();
    let world = minimal.app.world();
    let visible = world
        .get::<VisibleEntityList>(minimal.camera)
        .expect("camera");
    let hit = world
        .get::<RayCasterHits>(minimal.eye)
        .expect("caster")
        .first();
    println!("boxes: {:?}", minimal.boxes);
    println!("the camera sees {:?}", visible.entities());
    println!("the ray first hits {:?}", hit.map(|h| (h.key, h.t)));
}
