//! The frame's batched queries as the plugin's systems run them: on the
//! calling thread, or split over the task pool with feature `parallel`.
//! Either way the answers are the same; only the time differs.

use bevy_ecs::entity::Entity;

use crate::query::{CullMode, JoinMode, RayMode, RayResults};
use crate::tree::RTree;
use crate::{Frustum, Ray, SpatialError};

/// The workspace each query system keeps from frame to frame.
#[cfg(feature = "parallel")]
pub(crate) type FrameWorkspace = crate::query::ParallelWorkspace<Entity>;
/// The workspace each query system keeps from frame to frame.
#[cfg(not(feature = "parallel"))]
pub(crate) type FrameWorkspace = crate::query::QueryWorkspace;

type Tree = RTree<Entity>;

pub(crate) fn cast_rays(
    tree: &Tree,
    rays: &[Ray],
    mode: RayMode,
    ws: &mut FrameWorkspace,
    out: &mut RayResults<Entity>,
) {
    #[cfg(feature = "parallel")]
    tree.par_cast_rays(rays, mode, ws, out);
    #[cfg(not(feature = "parallel"))]
    tree.cast_rays(rays, mode, ws, out);
}

pub(crate) fn visible_into(
    tree: &Tree,
    frustums: &[Frustum],
    mode: CullMode,
    ws: &mut FrameWorkspace,
    out: &mut Vec<Vec<Entity>>,
) {
    #[cfg(feature = "parallel")]
    tree.par_visible_into(frustums, mode, ws, out);
    #[cfg(not(feature = "parallel"))]
    tree.visible_into(frustums, mode, ws, out);
}

pub(crate) fn self_join_into(
    tree: &Tree,
    distance: f32,
    mode: JoinMode,
    ws: &mut FrameWorkspace,
    out: &mut Vec<(Entity, Entity)>,
) -> Result<(), SpatialError> {
    #[cfg(feature = "parallel")]
    return tree.par_self_join_into(distance, mode, ws, out);
    #[cfg(not(feature = "parallel"))]
    return tree.self_join_into(distance, mode, ws, out);
}

pub(crate) fn cross_join_into(
    tree: &Tree,
    other: &Tree,
    distance: f32,
    mode: JoinMode,
    ws: &mut FrameWorkspace,
    out: &mut Vec<(Entity, Entity)>,
) -> Result<(), SpatialError> {
    #[cfg(feature = "parallel")]
    return tree.par_cross_join_into(other, distance, mode, ws, out);
    #[cfg(not(feature = "parallel"))]
    return tree.cross_join_into(other, distance, mode, ws, out);
}
