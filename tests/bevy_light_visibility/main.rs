//! Bevy's light shadow visibility served by the index, against Bevy
//! itself: twin Apps from one seed with Bevy's `LightPlugin`, one running
//! Bevy's own `check_point_light_mesh_visibility` and
//! `check_dir_light_mesh_visibility`, the other with `BevyVisibilityPlugin`;
//! after every frame every caster's `ViewVisibility` and every light's
//! lists (cube faces, spot, cascades per view) must be the same.
#![cfg(feature = "bevy_light")]

#[path = "../common/bevy_random.rs"]
mod bevy_random;

use std::collections::HashMap;

use bevy_app::prelude::*;
use bevy_asset::{AssetApp, AssetPlugin, Assets};
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, NoCpuCulling, NoFrustumCulling, RenderLayers,
    ViewVisibility, VisibilityRange, VisibilitySystems, VisibleMeshEntities,
};
use bevy_camera::{Camera, Camera3d, CameraPlugin};
use bevy_ecs::prelude::*;
use bevy_light::{DirectionalLight, LightPlugin, NotShadowCaster, PointLight, SpotLight};
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_random::{random_aabb, random_transform, random_visibility};
use bevy_rtree::plugin::{
    BevyVisibilityPlugin, BevyVisibilitySettings, Renderable, SpatialIndex, SpatialIndexPlugin,
};
use bevy_rtree::scene::SceneRng;
use bevy_transform::prelude::*;
use glam::{Quat, Vec3};

/// A headless App with Bevy's transforms, cameras and lights, and with the
/// index serving visibility if `ours`.
fn app(ours: bool) -> App {
    let mut app = App::new();
    app.add_plugins((
        TaskPoolPlugin::default(),
        AssetPlugin::default(),
        TransformPlugin,
        CameraPlugin,
        LightPlugin,
    ))
    .insert_resource(Assets::<Mesh>::default())
    .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
    .init_asset::<bevy_image::Image>();
    if ours {
        app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    }
    app.finish();
    app.cleanup();
    app
}

/// Inserts `C` where the entity lacks it, removes it where it has it.
fn toggle<C: Component + Default>(entity: &mut EntityWorldMut) {
    if entity.contains::<C>() {
        entity.remove::<C>();
    } else {
        entity.insert(C::default());
    }
}

mod hard_cases;
mod random_scenes;
mod schedule;
mod twins;

use twins::{LightKind, Twins};
