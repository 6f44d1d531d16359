//! Everything an app needs, for one glob import.
//!
//! ```
//! use bevy_app::prelude::*;
//! use bevy_rtree::prelude::*;
//!
//! let mut app = App::new();
//! app.add_plugins(SpatialIndexPlugin::default());
//! let crate_box = Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, -5.0), Vec3::splat(0.5))?;
//! app.world_mut().spawn(SpatialBounds(crate_box));
//! let ray = Ray::new(Vec3::ZERO, Vec3::NEG_Z, 100.0)?;
//! let eye = app.world_mut().spawn(RayCaster::new(ray, RayMode::First)).id();
//! app.update();
//! assert!(app.world().get::<RayCasterHits>(eye).unwrap().any());
//! # Ok::<(), SpatialError>(())
//! ```
//!
//! It re-exports the crate's math types at the version Bevy 0.20 uses
//! (`Vec3`, `Quat`, `Affine3A`), which glob-import alongside
//! `bevy::prelude::*` without a clash: they are the same types.

pub use crate::geometry::{Aabb, Frustum, HalfSpace, MAX_COORD, Ray, SpatialError};
#[cfg(feature = "bevy")]
pub use crate::plugin::LocalBounds;
#[cfg(feature = "bevy_camera")]
pub use crate::plugin::{
    BevyVisibilityPlugin, BevyVisibilitySettings, FollowBevyFrustum, Renderable,
    RenderableSyncSystems,
};
#[cfg(feature = "plugin")]
pub use crate::plugin::{
    CullingCamera, NoSpatialIndex, PairEnded, PairStarted, RayCaster, RayCasterHits, RebuildMode,
    SpatialAppExt, SpatialBounds, SpatialDiagnostics, SpatialIndex, SpatialIndexPlugin,
    SpatialIndexSystems, SpatialJoin, SpatialQuery, SpatialQueryFilter, VisibleEntityList,
};
pub use crate::query::{CullMode, JoinMode, Neighbor, QueryWorkspace, RayHit, RayMode};
pub use crate::tree::{ProxyId, RTree, TreeSettings};
pub use glam::{Affine3A, Quat, Vec3};
