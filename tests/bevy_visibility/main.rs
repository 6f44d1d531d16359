//! Bevy's own visibility served by the index, against Bevy itself: twin
//! Apps from one seed, one running Bevy's `check_visibility_cpu_culling`,
//! the other with `BevyVisibilityPlugin`; after every frame every entity's
//! `ViewVisibility` and every camera's `VisibleEntities` must be the same.
#![cfg(feature = "bevy_camera")]

#[path = "../common/bevy_random.rs"]
mod bevy_random;

use std::any::TypeId;

use bevy_app::prelude::*;
use bevy_asset::Assets;
use bevy_camera::primitives::{Aabb, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, ViewVisibility, Visibility,
    VisibilityClass, VisibilityRange, VisibleEntities,
};
use bevy_camera::{Camera, Camera3d, CameraPlugin, OrthographicProjection, Projection};
use bevy_ecs::change_detection::Tick;
use bevy_ecs::entity_disabling::Disabled;
use bevy_ecs::prelude::*;
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_random::{random_aabb, random_transform, random_visibility};
use bevy_rtree::plugin::{
    BevyVisibilityPlugin, BevyVisibilitySettings, Renderable, RenderableHandle, SpatialDiagnostics,
    SpatialIndex, SpatialIndexPlugin,
};
use bevy_rtree::scene::SceneRng;
use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use bevy_transform::prelude::*;
use glam::{Quat, Vec3, Vec3A};

/// A visibility class of the app's own, beside Bevy's `Mesh3d`.
struct AppClass;

/// Bevy's compute pool with three threads (where bevy_tasks has threads:
/// features `parallel` or `multi_threaded`), so that the plugin's parallel
/// paths run even on a machine of two cores.
fn three_threads() {
    let pool = ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(3).build());
    if cfg!(any(feature = "parallel", feature = "multi_threaded")) {
        assert_eq!(pool.thread_num(), 3);
    }
}

/// A headless App with Bevy's transforms and cameras, and with the index
/// serving visibility if `ours`.
fn app(ours: bool) -> App {
    three_threads();
    let mut app = App::new();
    app.add_plugins((TransformPlugin, CameraPlugin))
        .insert_resource(Assets::<Mesh>::default())
        .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default());
    if ours {
        app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    }
    app
}

mod app_setup;
mod hard_cases;
mod hard_changes;
mod membership;
mod random_scenes;
mod twins;

use twins::Twins;
