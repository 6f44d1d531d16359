//! Bevy's own visibility served by the index, headless: a street of
//! houses with Bevy's `Aabb`, a camera that drives down it, a hidden house
//! with its chimney, a sign on another render layer and a sky dome with
//! `NoFrustumCulling`. Each frame prints what Bevy would draw: the
//! renderer reads the same `ViewVisibility` and `VisibleEntities` it
//! reads with Bevy's own culling.
//!
//! Run with `cargo run --example bevy_visibility --features bevy_camera`.

use std::any::TypeId;

use bevy_app::prelude::*;
use bevy_asset::Assets;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{
    NoFrustumCulling, RenderLayers, ViewVisibility, Visibility, VisibleEntities,
};
use bevy_camera::{Camera3d, CameraPlugin};
use bevy_ecs::prelude::*;
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_rtree::plugin::{BevyVisibilityPlugin, Renderable, SpatialIndex, SpatialIndexPlugin};
use bevy_transform::prelude::*;
use glam::{Vec3, Vec3A};

/// The app and the entities the example talks about.
pub struct Street {
    pub app: App,
    pub camera: Entity,
    pub houses: Vec<Entity>,
    pub hidden_house: Entity,
    pub chimney: Entity,
    pub sign_on_layer_one: Entity,
    pub sky: Entity,
}

/// Moves the camera 2 m down the street each frame.
fn drive(mut cameras: Query<&mut Transform, With<Camera3d>>) {
    for mut camera in &mut cameras {
        camera.translation.z -= 2.0;
    }
}

pub fn build() -> Street {
    let mut app = App::new();
    // A real game has DefaultPlugins here; headless, Bevy's transforms and
    // cameras and the asset stores its visibility systems read.
    app.add_plugins((TransformPlugin, CameraPlugin))
        .insert_resource(Assets::<Mesh>::default())
        .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
        .add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin))
        .add_systems(Update, drive);
    let world = app.world_mut();
    // Nothing of ours on these: Bevy's mesh, box and transform only.
    let house = |x: f32, z: f32| {
        (
            Mesh3d::default(),
            Aabb {
                center: Vec3A::new(0.0, 4.0, 0.0),
                half_extents: Vec3A::new(4.0, 4.0, 5.0),
            },
            Transform::from_xyz(x, 0.0, z),
        )
    };
    let houses = (0..200)
        .map(|i| {
            let side = if i % 2 == 0 { -12.0 } else { 12.0 };
            world.spawn(house(side, -(i / 2) as f32 * 14.0)).id()
        })
        .collect();
    let hidden_house = world.spawn((house(-12.0, -40.0), Visibility::Hidden)).id();
    let chimney = world
        .spawn((
            Mesh3d::default(),
            Aabb {
                center: Vec3A::ZERO,
                half_extents: Vec3A::new(0.5, 1.5, 0.5),
            },
            Transform::from_xyz(2.0, 9.0, 0.0),
            ChildOf(hidden_house),
        ))
        .id();
    let sign_on_layer_one = world
        .spawn((house(0.0, -30.0), RenderLayers::layer(1)))
        .id();
    let sky = world.spawn((house(0.0, 500.0), NoFrustumCulling)).id();
    let camera = world
        .spawn((
            Camera3d::default(),
            Transform::from_xyz(0.0, 2.0, 10.0).looking_at(Vec3::new(0.0, 2.0, -100.0), Vec3::Y),
        ))
        .id();
    Street {
        app,
        camera,
        houses,
        hidden_house,
        chimney,
        sign_on_layer_one,
        sky,
    }
}

/// Whether Bevy would draw `entity` this frame.
pub fn drawn(street: &Street, entity: Entity) -> bool {
    street
        .app
        .world()
        .get::<ViewVisibility>(entity)
        .is_some_and(|v| v.get())
}

/// The meshes in the camera's list this frame.
pub fn listed(street: &Street) -> usize {
    let lists = street
        .app
        .world()
        .get::<VisibleEntities>(street.camera)
        .unwrap();
    lists.get(TypeId::of::<Mesh3d>()).len()
}

fn main() {
    let mut street = build();
    for frame in 0..30 {
        street.app.update();
        let houses_drawn = street.houses.iter().filter(|&&h| drawn(&street, h)).count();
        let index = street.app.world().resource::<SpatialIndex<Renderable>>();
        println!(
            "frame {frame:2}: {houses_drawn:3} of {} houses drawn, {} meshes listed, {} indexed; \
             hidden house {}, its chimney {}, sign on layer 1 {}, sky {}",
            street.houses.len(),
            listed(&street),
            index.len(),
            drawn(&street, street.hidden_house),
            drawn(&street, street.chimney),
            drawn(&street, street.sign_on_layer_one),
            drawn(&street, street.sky),
        );
    }
}
