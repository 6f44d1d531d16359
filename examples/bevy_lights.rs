//! Bevy's camera and shadow visibility served by the index, headless: a
//! street of houses with Bevy's `Aabb`, lamps (shadow-casting point
//! lights of 15 m range) along it, a moon (a directional light with four
//! shadow cascades), a camera that drives down the street, a hidden house
//! with its chimney, a sign on another render layer, a bush that casts no
//! shadow and a sky dome with `NoFrustumCulling`. Each frame prints what
//! Bevy would draw and what each light would render into its shadow maps:
//! the renderer reads the same `ViewVisibility`, `VisibleEntities`,
//! `CubemapVisibleEntities` and `CascadesVisibleEntities` it reads with
//! Bevy's own systems.
//!
//! Run with `cargo run --example bevy_lights --features bevy_light`.

use bevy_app::prelude::*;
use bevy_asset::{AssetApp, AssetPlugin, Assets};
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, NoFrustumCulling, RenderLayers,
    ViewVisibility, Visibility,
};
use bevy_camera::{Camera3d, CameraPlugin};
use bevy_ecs::prelude::*;
use bevy_light::{DirectionalLight, LightPlugin, NotShadowCaster, PointLight};
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_rtree::plugin::{BevyVisibilityPlugin, SpatialIndexPlugin};
use bevy_transform::prelude::*;
use glam::{Vec3, Vec3A};

/// The app and the entities the example talks about.
pub struct Street {
    pub app: App,
    pub camera: Entity,
    pub houses: Vec<Entity>,
    pub lamps: Vec<Entity>,
    pub moon: Entity,
    pub hidden_house: Entity,
    pub chimney: Entity,
    pub sign_on_layer_one: Entity,
    pub bush: Entity,
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
    // A real game has DefaultPlugins here; headless, Bevy's transforms,
    // cameras and lights and the asset stores their systems read.
    app.add_plugins((
        TaskPoolPlugin::default(),
        AssetPlugin::default(),
        TransformPlugin,
        CameraPlugin,
        LightPlugin,
    ))
    .insert_resource(Assets::<Mesh>::default())
    .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
    .init_asset::<bevy_image::Image>()
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
    // A lamp in the middle of the street every 28 m.
    let lamps = (0..50)
        .map(|i| {
            world
                .spawn((
                    PointLight {
                        range: 15.0,
                        shadow_maps_enabled: true,
                        ..PointLight::default()
                    },
                    Transform::from_xyz(0.0, 5.0, -(i as f32) * 28.0 - 7.0),
                ))
                .id()
        })
        .collect();
    let moon = world
        .spawn((
            DirectionalLight {
                shadow_maps_enabled: true,
                ..DirectionalLight::default()
            },
            Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
        ))
        .id();
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
    let bush = world
        .spawn((
            Mesh3d::default(),
            Aabb {
                center: Vec3A::ZERO,
                half_extents: Vec3A::splat(0.5),
            },
            Transform::from_xyz(3.0, 0.5, -7.0),
            NotShadowCaster,
        ))
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
        lamps,
        moon,
        hidden_house,
        chimney,
        sign_on_layer_one,
        bush,
        sky,
    }
}

/// Whether Bevy would draw `entity` this frame (for a camera or a shadow).
pub fn drawn(street: &Street, entity: Entity) -> bool {
    street
        .app
        .world()
        .get::<ViewVisibility>(entity)
        .is_some_and(|v| v.get())
}

/// Whether `entity` is in a shadow map of the lamp `lamp` this frame (any
/// cube face).
pub fn in_lamp_shadow(street: &Street, lamp: Entity, entity: Entity) -> bool {
    let faces = street.app.world().get::<CubemapVisibleEntities>(lamp);
    faces.is_some_and(|f| f.iter().any(|face| face.entities.contains(&entity)))
}

/// The entities in any of the moon's shadow cascades this frame.
pub fn in_moon_shadow(street: &Street) -> Vec<Entity> {
    let cascades = street
        .app
        .world()
        .get::<CascadesVisibleEntities>(street.moon);
    let mut all: Vec<Entity> = cascades
        .into_iter()
        .flat_map(|c| c.entities.values().flatten())
        .flat_map(|list| list.entities.iter().copied())
        .collect();
    all.sort_unstable();
    all.dedup();
    all
}

fn main() {
    let mut street = build();
    for frame in 0..30 {
        street.app.update();
        let drawn_houses = street.houses.iter().filter(|&&h| drawn(&street, h));
        let lamp_casters: usize = street
            .lamps
            .iter()
            .map(|&lamp| {
                let houses = street.houses.iter();
                houses
                    .filter(|&&h| in_lamp_shadow(&street, lamp, h))
                    .count()
            })
            .sum();
        println!(
            "frame {frame:2}: {:3} of {} houses drawn, {lamp_casters} house shadows from lamps, \
             {} casters under the moon; hidden house {}, its chimney {}, sign on layer 1 {}, \
             bush {} (casts no shadow), sky {}",
            drawn_houses.count(),
            street.houses.len(),
            in_moon_shadow(&street).len(),
            drawn(&street, street.hidden_house),
            drawn(&street, street.chimney),
            drawn(&street, street.sign_on_layer_one),
            drawn(&street, street.bush),
            drawn(&street, street.sky),
        );
    }
}
