//! The plugin tests' shared scene: an App with the index, unit boxes
//! along x, the layers' markers, a camera looking at them, and the
//! index's sorted contents.

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::Aabb;
use bevy_rtree::Frustum;
use bevy_rtree::plugin::{
    CullingCamera, SpatialBounds, SpatialDiagnostics, SpatialIndex, SpatialIndexPlugin,
};
use glam::{Quat, Vec3};

#[derive(Component)]
pub struct Enemy;

#[derive(Component)]
pub struct Barrel;

pub fn app() -> App {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    app
}

pub fn unit_at(x: f32) -> SpatialBounds {
    SpatialBounds(Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 1.0, 1.0)).unwrap())
}

/// The entities the main index holds, sorted, after checking its invariants.
pub fn indexed(app: &App) -> Vec<Entity> {
    indexed_in::<SpatialBounds>(app)
}

/// The same for the index of layer `L`.
pub fn indexed_in<L: Component>(app: &App) -> Vec<Entity> {
    let index = app.world().resource::<SpatialIndex<L>>();
    index.validate().expect("index invariants");
    let mut all: Vec<Entity> = index.tree().iter().map(|(_, e, _)| e).collect();
    all.sort_unstable();
    all
}

pub fn sorted<const N: usize>(mut entities: [Entity; N]) -> [Entity; N] {
    entities.sort_unstable();
    entities
}

pub fn diagnostics(app: &App) -> SpatialDiagnostics {
    *app.world().resource::<SpatialDiagnostics>()
}

/// Looking down -Z from z = 10 at the unit boxes along x.
pub fn camera() -> CullingCamera {
    CullingCamera::new(
        Frustum::perspective(
            Vec3::new(0.0, 0.0, 10.0),
            Quat::IDENTITY,
            1.2,
            1.0,
            0.1,
            100.0,
        )
        .unwrap(),
    )
}
