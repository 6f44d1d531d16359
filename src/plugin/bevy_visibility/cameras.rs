//! Bevy's camera visibility from the index: the tree gives each camera its
//! candidates, and Bevy's own tests decide what the tree cannot prove.

use std::ops::ControlFlow;

use bevy_camera::Camera;
use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, SetViewVisibility,
    ViewVisibility, VisibilityClass, VisibilityRange, VisibleEntities, VisibleEntityRanges,
};
use bevy_ecs::prelude::*;
use bevy_transform::prelude::GlobalTransform;
use glam::Vec3;

use super::Renderable;
use crate::geometry::predicates::frustum_contains;
use crate::geometry::{Frustum, HalfSpace};
use crate::plugin::diagnostics::DiagnosticsSink;
use crate::plugin::index::SpatialIndex;
use crate::query::{CullMode, QueryWorkspace};

/// What Bevy's culling reads of an entity (the same query as its own).
type Culled<'a> = (
    Entity,
    &'a InheritedVisibility,
    &'a mut ViewVisibility,
    Option<&'a VisibilityClass>,
    Option<&'a RenderLayers>,
    Option<&'a BevyAabb>,
    Option<&'a Sphere>,
    &'a GlobalTransform,
    Has<NoFrustumCulling>,
    Has<VisibilityRange>,
);

/// The entities of Bevy's culling set that are not in the tree by
/// construction: no `Aabb`, or `NoFrustumCulling`.
type OutsideTheTree = (
    With<InheritedVisibility>,
    With<ViewVisibility>,
    With<GlobalTransform>,
    Without<NoCpuCulling>,
    Or<(Without<BevyAabb>, With<NoFrustumCulling>)>,
);

/// One camera as Bevy's culling sees it.
struct View<'a> {
    entity: Entity,
    frustum: &'a BevyFrustum,
    mask: &'a RenderLayers,
    /// The camera has `NoCpuCulling`: no frustum test at all.
    no_culling: bool,
}

/// Scratch kept from frame to frame.
#[derive(Default)]
pub(super) struct Scratch {
    workspace: QueryWorkspace,
    /// This camera's candidates from the tree, and whether the tree proved
    /// each inside every plane.
    candidates: Vec<(Entity, bool)>,
}

/// Replaces Bevy's `check_visibility_cpu_culling`, in
/// `VisibilitySystems::CheckVisibility`.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn check_visibility_from_index(
    mut views: Query<(
        Entity,
        &mut VisibleEntities,
        &BevyFrustum,
        Option<&RenderLayers>,
        &Camera,
        Has<NoCpuCulling>,
        Option<&GlobalTransform>,
    )>,
    mut culled: Query<Culled<'_>, Without<NoCpuCulling>>,
    outside_the_tree: Query<Entity, OutsideTheTree>,
    index: Res<SpatialIndex<Renderable>>,
    ranges: Option<Res<VisibleEntityRanges>>,
    mut scratch: Local<Scratch>,
    sink: Res<DiagnosticsSink>,
) {
    let ranges = ranges.as_deref();
    let scratch = &mut *scratch;
    let mut culled_views = 0;
    for (entity, mut visible, frustum, mask, camera, no_culling, transform) in &mut views {
        if !camera.is_active {
            continue;
        }
        let view = View {
            entity,
            frustum,
            mask: mask.unwrap_or_default(),
            no_culling,
        };
        visible.clear_all();
        if no_culling {
            // Every entity passes the frustum: Bevy's loop over all of them.
            for item in &mut culled {
                decide(&view, item, true, ranges, &mut visible);
            }
        } else {
            culled_views += 1;
            let eye = transform.map_or(Vec3::ZERO, GlobalTransform::translation);
            candidates(&index, frustum, eye, scratch);
            for &(entity, inside) in &scratch.candidates {
                if let Ok(item) = culled.get_mut(entity) {
                    decide(&view, item, inside, ranges, &mut visible);
                }
            }
            let one_by_one = outside_the_tree.iter().chain(index.unindexed());
            for entity in one_by_one {
                if let Ok(item) = culled.get_mut(entity) {
                    decide(&view, item, false, ranges, &mut visible);
                }
            }
        }
        // Sorted, as Bevy's diffing of visible lists needs.
        for list in visible.entities.values_mut() {
            list.sort_unstable();
            list.dedup();
        }
    }
    if culled_views > 0 {
        let ws = &mut scratch.workspace;
        sink.add(|d| d.culling.record_workspace(culled_views, ws));
    }
}

/// Bevy's own decision for one entity and one view, as its culling system
/// makes it; `proven` skips the frustum tests for an entity the tree has
/// shown to lie inside every plane they test.
fn decide(
    view: &View<'_>,
    item: <Culled<'_> as bevy_ecs::query::QueryData>::Item<'_, '_>,
    proven: bool,
    ranges: Option<&VisibleEntityRanges>,
    visible: &mut VisibleEntities,
) {
    let (
        entity,
        inherited,
        mut view_visibility,
        class,
        mask,
        aabb,
        sphere,
        transform,
        no_frustum_culling,
        has_range,
    ) = item;
    if !inherited.get() || !view.mask.intersects(mask.unwrap_or_default()) {
        return;
    }
    if has_range && ranges.is_some_and(|r| !r.entity_is_in_range_of_view(entity, view.entity)) {
        return;
    }
    if !proven && !no_frustum_culling && !view.no_culling {
        if let Some(aabb) = aabb {
            let world_from_local = transform.affine();
            let sphere = Sphere {
                center: world_from_local.transform_point3a(aabb.center),
                radius: transform.radius_vec3a(aabb.half_extents),
            };
            if !view.frustum.intersects_sphere(&sphere, false)
                || !view
                    .frustum
                    .intersects_obb(aabb, &world_from_local, true, false)
            {
                return;
            }
        } else if let Some(sphere) = sphere
            && !view.frustum.intersects_sphere(sphere, false)
        {
            return;
        }
    }
    view_visibility.set_visible();
    if let Some(class) = class {
        for &id in class.iter() {
            visible.push(entity, id);
        }
    }
}

/// The tree's candidates for a camera: every entry whose box passes the
/// camera's planes (all but the far plane, which Bevy's camera culling does
/// not test), loosened by [`slack`] so that no box Bevy's own test accepts
/// is missed; and whether each box lies inside the planes tightened by the
/// same slack, which proves Bevy's tests would pass.
fn candidates(
    index: &SpatialIndex<Renderable>,
    frustum: &BevyFrustum,
    eye: Vec3,
    scratch: &mut Scratch,
) {
    scratch.candidates.clear();
    let tree = index.tree();
    let Some(bounds) = tree.bounds() else { return };
    let reach =
        bounds.min.abs().max(bounds.max.abs()).max_element() * 3.0 + eye.abs().max_element();
    let (Some(loose), Some(tight)) = (
        rebased(frustum, eye, reach, 1.0),
        rebased(frustum, eye, reach, -1.0),
    ) else {
        // A frustum Bevy's tests cannot decide either (NaN planes): every
        // entry is a candidate, and Bevy's tests say what they say.
        tree.iter()
            .for_each(|(_, entity, _)| scratch.candidates.push((entity, false)));
        return;
    };
    let candidates = &mut scratch.candidates;
    tree.visit_visible(
        std::slice::from_ref(&loose),
        CullMode::Conservative,
        &mut scratch.workspace,
        |_, entity, aabb| {
            candidates.push((entity, frustum_contains(&tight, aabb)));
            ControlFlow::Continue(())
        },
    );
}

/// Bevy's planes but the far one, re-based on `eye` and moved outward
/// (`side = 1`) or inward (`-1`) by [`slack`].
fn rebased(frustum: &BevyFrustum, eye: Vec3, reach: f32, side: f64) -> Option<Frustum> {
    let mut planes = [HalfSpace::INACTIVE; 6];
    for (plane, half_space) in planes.iter_mut().zip(&frustum.half_spaces[..5]) {
        let normal = Vec3::from(half_space.normal());
        let d = half_space.d();
        let offset = d as f64 + normal.as_dvec3().dot(eye.as_dvec3());
        let moved = offset + side * slack(normal, d, reach);
        *plane = HalfSpace {
            normal,
            offset: moved as f32,
        };
    }
    Frustum::new(eye, planes).ok()
}

/// How far a plane is moved so that rounding cannot make the tree's test
/// and Bevy's disagree: Bevy evaluates `n·c + d + r` in `f32` at world
/// coordinates, with an error of a few `2^-24` of `|n|·|c| + |d| + r`; the
/// tree's box test errs likewise at eye-relative coordinates. `reach`
/// bounds `|c|`, `r` and the eye's distance from the origin (three times
/// the largest coordinate of the index, plus the eye's), and `2^-16` of
/// the magnitudes is over a hundred times both errors: a few centimetres
/// on a 2 km map, candidates the exact test then decides.
fn slack(normal: Vec3, d: f32, reach: f32) -> f64 {
    let magnitude = normal.length() as f64 * reach as f64 + (d as f64).abs();
    magnitude / 65_536.0
}
