//! Bevy's camera visibility from the index: the tree gives each camera its
//! candidates, and Bevy's own tests decide what the tree cannot prove.

use std::any::TypeId;

use bevy_camera::Camera;
use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, SetViewVisibility,
    ViewVisibility, VisibilityClass, VisibilityRange, VisibleEntities, VisibleEntityRanges,
};
use bevy_ecs::entity::Entities;
use bevy_ecs::prelude::*;
use bevy_ecs::query::QueryData;
use bevy_tasks::ComputeTaskPool;
use bevy_transform::prelude::GlobalTransform;
use bevy_utils::Parallel;
use glam::Vec3;

use super::frustum_candidates::{UNTESTED_BY_CAMERAS, candidates};
use super::layers::ViewLayers;
use super::radix;
use super::rows::{RowScratch, decide_proven_by_rows};
use super::seen::Seen;
use super::storage_order::decide_in_storage_order;
use super::{BevyVisibilitySettings, Renderable};
use crate::plugin::diagnostics::DiagnosticsSink;
use crate::plugin::index::SpatialIndex;
use crate::query::QueryWorkspace;

/// What Bevy's culling reads of an entity (the same query as its own).
pub(super) type Culled<'a> = (
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

type CulledItem<'w, 's> = <Culled<'static> as QueryData>::Item<'w, 's>;

/// The entities of Bevy's culling set that are not in the tree by
/// construction: no `Aabb`, or `NoFrustumCulling`.
type OutsideTheTree = (
    With<InheritedVisibility>,
    With<ViewVisibility>,
    With<GlobalTransform>,
    Without<NoCpuCulling>,
    Or<(Without<BevyAabb>, With<NoFrustumCulling>)>,
);

/// Cameras decided in one pass over the entities (two bits each in a
/// `u16` per entity: candidate, and proven inside).
const VIEWS_PER_PASS: usize = 8;

/// What Bevy's tests read of one active camera.
pub(super) struct Sight {
    frustum: BevyFrustum,
    layers: ViewLayers,
    /// The camera has `NoCpuCulling`: no frustum test at all.
    pub(super) no_culling: bool,
}

impl Sight {
    /// The camera's entity (its layers' view).
    fn camera(&self) -> Entity {
        self.layers.view()
    }
}

/// One active camera as Bevy's culling sees it, and what it saw.
pub(super) struct View {
    pub(super) sight: Sight,
    /// Where the camera is, which the tree's cull is rebased on.
    eye: Vec3,
    /// How many of its candidates the tree proved inside.
    proven: usize,
    /// Its candidates from the tree, and whether the tree proved each
    /// inside every plane Bevy tests (empty for `no_culling`).
    pub(super) candidates: Vec<(Entity, bool)>,
    /// Its visible entities per visibility class.
    pub(super) visible: Seen,
}

/// Scratch kept from frame to frame.
#[derive(Default)]
pub(super) struct Scratch {
    /// One per view, so that views can be culled in parallel.
    workspaces: Vec<QueryWorkspace>,
    views: Vec<View>,
    /// Per entity index, for a pass over all entities: two bits per view
    /// of the pass (candidate, proven inside).
    marks: Vec<std::sync::atomic::AtomicU16>,
    /// The entities outside the tree, tested by every view.
    one_by_one: Vec<Entity>,
    /// Per thread of the pass in storage order, what each view saw.
    seen: Parallel<Vec<Seen>>,
    /// The look-ups by row's buffers.
    rows: RowScratch,
    /// Working space of the candidates' sort.
    sort_spare: Vec<(Entity, bool)>,
    /// Working space of the visible lists' sort.
    list_spare: Vec<Entity>,
    /// Every visibility class any view has listed an entity of, so far:
    /// Bevy's per-thread queues keep a key for each, and each active camera
    /// gets a list for each, empty or not (extraction sees only the
    /// classes a camera has a list for).
    classes: Vec<TypeId>,
}

/// Replaces Bevy's `check_visibility_cpu_culling`, in
/// `VisibilitySystems::CheckVisibility`.
///
/// Each camera's candidates come from the tree; then, where they are a
/// large part of all entities, the cameras are decided together in one
/// pass over the entities in storage order (as Bevy's own loop reads
/// them, once for all cameras instead of once per camera); otherwise each
/// candidate is looked up by its `Entity`.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn check_visibility_from_index(
    mut cameras: Query<(
        Entity,
        &mut VisibleEntities,
        &BevyFrustum,
        Option<&RenderLayers>,
        &Camera,
        Has<NoCpuCulling>,
        Option<&GlobalTransform>,
    )>,
    mut culled: Query<Culled<'_>, Without<NoCpuCulling>>,
    bevy_entities: &Entities,
    outside_the_tree: Query<Entity, OutsideTheTree>,
    index: Res<SpatialIndex<Renderable>>,
    ranges: Option<Res<VisibleEntityRanges>>,
    settings: Res<BevyVisibilitySettings>,
    mut scratch: Local<Scratch>,
    sink: Res<DiagnosticsSink>,
) {
    let ranges = ranges.as_deref();
    let scratch = &mut *scratch;
    let mut spare: Vec<View> = std::mem::take(&mut scratch.views);
    let mut views = Vec::new();
    for (camera, _, frustum, mask, state, no_culling, transform) in &cameras {
        if !state.is_active {
            continue;
        }
        let sight = Sight {
            frustum: *frustum,
            layers: ViewLayers::new(camera, mask),
            no_culling,
        };
        let (mut listed, mut visible) = spare
            .pop()
            .map_or_else(Default::default, |v| (v.candidates, v.visible));
        listed.clear();
        visible.clear();
        views.push(View {
            sight,
            eye: transform.map_or(Vec3::ZERO, GlobalTransform::translation),
            proven: 0,
            candidates: listed,
            visible,
        });
    }
    let parallel = settings.on_several_threads();
    cull_views(&index, &mut views, &mut scratch.workspaces, parallel);
    if !settings.prove_inside {
        for view in &mut views {
            view.candidates.iter_mut().for_each(|c| c.1 = false);
            view.proven = 0;
        }
    }
    let count = culled.iter().len();
    let candidates: usize = views.iter().map(|v| v.candidates.len()).sum();
    let mut one_by_one = std::mem::take(&mut scratch.one_by_one);
    one_by_one.clear();
    one_by_one.extend(outside_the_tree.iter().chain(index.unindexed()));
    // Each once, whichever way it came: a visible entity is listed once per
    // visibility class it names, as in Bevy's lists.
    one_by_one.sort_unstable();
    one_by_one.dedup();
    let any_all = views.iter().any(|v| v.sight.no_culling);
    // A pass over every entity costs a few nanoseconds per entity; a look-up
    // by `Entity` some tens per candidate.
    if any_all || candidates * 8 > count {
        for pass in views.chunks_mut(VIEWS_PER_PASS) {
            decide_in_storage_order(
                pass,
                &one_by_one,
                &mut culled,
                ranges,
                &mut scratch.marks,
                &mut scratch.seen,
                parallel,
            );
        }
    } else {
        for view in &mut views {
            let mut candidates = std::mem::take(&mut view.candidates);
            // In `Entity` order (by generation, then by index from the
            // highest down), which Bevy's lists are kept in and which
            // follows storage order backwards where entities were spawned
            // together: neighbouring look-ups share cache lines and pages.
            radix::sort_by_key(&mut candidates, &mut scratch.sort_spare, |c| c.0.to_bits());
            decide_proven_by_rows(
                &mut culled,
                bevy_entities,
                &view.sight,
                &mut view.visible,
                &candidates,
                &mut scratch.rows,
                ranges,
                parallel,
            );
            for &(entity, inside) in &candidates {
                if !inside && let Ok(mut item) = culled.get_mut(entity) {
                    decide(&view.sight, &mut view.visible, &mut item, false, ranges);
                }
            }
            for &entity in &one_by_one {
                if let Ok(mut item) = culled.get_mut(entity) {
                    decide(&view.sight, &mut view.visible, &mut item, false, ranges);
                }
            }
            view.candidates = candidates;
        }
    }
    let culled_views = views.iter().filter(|v| !v.sight.no_culling).count();
    let classes = &mut scratch.classes;
    // In Bevy's order of the cameras (the query's, as `views` was built):
    // Bevy drains its queues after each camera, so a camera gets a list for
    // every class seen so far, by it, by the cameras before it this frame,
    // or in any earlier frame.
    for view in &mut views {
        for (class, list) in view.visible.lists() {
            if !list.is_empty() && !classes.contains(class) {
                classes.push(*class);
            }
        }
        let Ok((_, mut visible, ..)) = cameras.get_mut(view.sight.camera()) else {
            continue;
        };
        visible.clear_all();
        view.visible.sort(&mut scratch.list_spare);
        for (class, list) in view.visible.lists_to_hand_over() {
            std::mem::swap(visible.get_mut(*class), list);
        }
        for class in classes.iter() {
            visible.get_mut(*class);
        }
    }
    if culled_views > 0 {
        let culling = views.iter().filter(|v| !v.sight.no_culling);
        let candidates: usize = culling.clone().map(|v| v.candidates.len()).sum();
        let proven: usize = culling.map(|v| v.proven).sum();
        let tested = candidates - proven + one_by_one.len() * culled_views;
        let workspaces = &mut scratch.workspaces;
        sink.add(|d| {
            d.culling.record_workspaces(culled_views, workspaces);
            let work = &mut d.bevy_visibility;
            work.candidates += candidates as u64;
            work.proven += proven as u64;
            work.tested += tested as u64;
        });
    }
    scratch.views = views;
    scratch.one_by_one = one_by_one;
    scratch.views.append(&mut spare);
}

/// Each culling view's candidates from the tree; on a task pool of several
/// threads, the views in parallel (one task each, with its own workspace).
fn cull_views(
    index: &SpatialIndex<Renderable>,
    views: &mut [View],
    workspaces: &mut Vec<QueryWorkspace>,
    parallel: bool,
) {
    if workspaces.len() < views.len() {
        workspaces.resize_with(views.len(), QueryWorkspace::default);
    }
    let cull = |view: &mut View, ws: &mut QueryWorkspace| {
        if !view.sight.no_culling {
            let frustum = &view.sight.frustum;
            view.proven = candidates(
                index,
                frustum,
                UNTESTED_BY_CAMERAS,
                view.eye,
                ws,
                &mut view.candidates,
            );
        }
    };
    let culling = views.iter().filter(|v| !v.sight.no_culling).count();
    if parallel && culling > 1 {
        ComputeTaskPool::get().scope(|scope| {
            for (view, ws) in views.iter_mut().zip(workspaces.iter_mut()) {
                scope.spawn(async move { cull(view, ws) });
            }
        });
    } else {
        for (view, ws) in views.iter_mut().zip(workspaces.iter_mut()) {
            cull(view, ws);
        }
    }
}

/// Bevy's own decision for one entity and one view, as its culling system
/// makes it; `proven` skips the frustum tests for an entity the tree has
/// shown to lie inside every plane they test.
pub(super) fn decide(
    sight: &Sight,
    seen: &mut Seen,
    item: &mut CulledItem<'_, '_>,
    proven: bool,
    ranges: Option<&VisibleEntityRanges>,
) {
    let (
        entity,
        inherited,
        view_visibility,
        class,
        mask,
        aabb,
        sphere,
        transform,
        no_frustum_culling,
        has_range,
    ) = item;
    let entity = *entity;
    if !may_be_seen(sight, entity, inherited, *mask, *has_range, ranges) {
        return;
    }
    if proven || passes_frustum(sight, *aabb, *sphere, transform, *no_frustum_culling) {
        see(seen, entity, view_visibility, *class);
    }
}

/// Bevy's frustum tests for one entity and one view: its sphere test,
/// then its oriented-box test without the far plane (for an entity with
/// an `Aabb`), its sphere test alone (with a `Sphere` only), none (neither,
/// `NoFrustumCulling`, or a camera with `NoCpuCulling`).
pub(super) fn passes_frustum(
    sight: &Sight,
    aabb: Option<&BevyAabb>,
    sphere: Option<&Sphere>,
    transform: &GlobalTransform,
    no_frustum_culling: bool,
) -> bool {
    if no_frustum_culling || sight.no_culling {
        return true;
    }
    if let Some(aabb) = aabb {
        let world_from_local = transform.affine();
        let sphere = Sphere {
            center: world_from_local.transform_point3a(aabb.center),
            radius: transform.radius_vec3a(aabb.half_extents),
        };
        sight.frustum.intersects_sphere(&sphere, false)
            && sight
                .frustum
                .intersects_obb(aabb, &world_from_local, true, false)
    } else if let Some(sphere) = sphere {
        sight.frustum.intersects_sphere(sphere, false)
    } else {
        true
    }
}

/// Bevy's checks before any frustum test: visible in the hierarchy, on a
/// layer the camera renders, within its visibility range of the camera.
#[inline]
pub(super) fn may_be_seen(
    sight: &Sight,
    entity: Entity,
    inherited: &InheritedVisibility,
    mask: Option<&RenderLayers>,
    has_range: bool,
    ranges: Option<&VisibleEntityRanges>,
) -> bool {
    inherited.get()
        && sight.layers.renders(entity, mask)
        && !(has_range
            && ranges.is_some_and(|r| !r.entity_is_in_range_of_view(entity, sight.camera())))
}

/// Marks `entity` seen by some view, and lists it for this one under each
/// of its visibility classes.
fn see(
    seen: &mut Seen,
    entity: Entity,
    view_visibility: &mut Mut<ViewVisibility>,
    class: Option<&VisibilityClass>,
) {
    view_visibility.set_visible();
    seen.push_classes(entity, class);
}
