//! Bevy's camera visibility from the index: the tree gives each camera its
//! candidates, and Bevy's own tests decide what the tree cannot prove.

use std::any::TypeId;

use bevy_camera::Camera;
use bevy_camera::primitives::{Aabb as BevyAabb, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, SetViewVisibility,
    ViewVisibility, VisibilityClass, VisibilityRange, VisibleEntities, VisibleEntityRanges,
};
use bevy_ecs::prelude::*;
use bevy_ecs::query::QueryData;
use bevy_transform::prelude::GlobalTransform;
use glam::Vec3;

use super::{BevyVisibilitySettings, Renderable};
use crate::geometry::{Frustum, HalfSpace};
use crate::plugin::diagnostics::DiagnosticsSink;
use crate::plugin::index::SpatialIndex;
use crate::query::QueryWorkspace;

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

type CulledItem<'w, 's> = <Culled<'static> as QueryData>::Item<'w, 's>;

/// What a candidate the tree proved inside needs read: everything but
/// its box and transform. A look-up binds each term of its query to the
/// entity's table, so the fewer, the cheaper.
type Proven<'a> = (
    &'a InheritedVisibility,
    &'a mut ViewVisibility,
    Option<&'a VisibilityClass>,
    Option<&'a RenderLayers>,
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

/// How many candidates ahead of the one decided are read, so that their
/// cache misses overlap with the decisions in between (in a 1,000,000
/// entity map the look-ups of 20,000 candidates took 3.6 ms without and
/// 3.15 ms with).
const LOOK_AHEAD: usize = 8;

/// Cameras decided in one pass over the entities (two bits each in a
/// `u16` per entity: candidate, and proven inside).
const VIEWS_PER_PASS: usize = 8;

/// One active camera as Bevy's culling sees it, and what it saw.
struct View {
    camera: Entity,
    frustum: BevyFrustum,
    mask: RenderLayers,
    /// The camera has `NoCpuCulling`: no frustum test at all.
    no_culling: bool,
    /// Its candidates from the tree, and whether the tree proved each
    /// inside every plane Bevy tests (empty for `no_culling`).
    candidates: Vec<(Entity, bool)>,
    /// Its visible entities per visibility class.
    visible: Vec<(TypeId, Vec<Entity>)>,
}

impl View {
    fn push(&mut self, entity: Entity, class: TypeId) {
        match self.visible.iter_mut().find(|(c, _)| *c == class) {
            Some((_, list)) => list.push(entity),
            None => self.visible.push((class, vec![entity])),
        }
    }
}

/// Scratch kept from frame to frame.
#[derive(Default)]
pub(super) struct Scratch {
    workspace: QueryWorkspace,
    views: Vec<View>,
    /// Per entity index, for a pass over all entities: two bits per view
    /// of the pass (candidate, proven inside).
    marks: Vec<u16>,
    /// The entities outside the tree, tested by every view.
    one_by_one: Vec<Entity>,
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
    mut entities: ParamSet<(
        Query<Culled<'_>, Without<NoCpuCulling>>,
        Query<Proven<'_>, Without<NoCpuCulling>>,
    )>,
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
        let mut view = spare.pop().unwrap_or_else(|| View {
            camera,
            frustum: *frustum,
            mask: RenderLayers::default(),
            no_culling,
            candidates: Vec::new(),
            visible: Vec::new(),
        });
        view.camera = camera;
        view.frustum = *frustum;
        view.mask = mask.cloned().unwrap_or_default();
        view.no_culling = no_culling;
        view.candidates.clear();
        view.visible.iter_mut().for_each(|(_, list)| list.clear());
        if !no_culling {
            let eye = transform.map_or(Vec3::ZERO, GlobalTransform::translation);
            candidates(
                &index,
                frustum,
                UNTESTED_BY_CAMERAS,
                eye,
                &mut scratch.workspace,
                &mut view.candidates,
            );
            if !settings.prove_inside {
                view.candidates.iter_mut().for_each(|c| c.1 = false);
            }
        }
        views.push(view);
    }
    let count = entities.p0().iter().len();
    let candidates: usize = views.iter().map(|v| v.candidates.len()).sum();
    let mut one_by_one = std::mem::take(&mut scratch.one_by_one);
    one_by_one.clear();
    one_by_one.extend(outside_the_tree.iter().chain(index.unindexed()));
    let any_all = views.iter().any(|v| v.no_culling);
    // A pass over every entity costs a few nanoseconds per entity; a look-up
    // by `Entity` some tens per candidate.
    if any_all || candidates * 8 > count {
        let mut culled = entities.p0();
        for pass in views.chunks_mut(VIEWS_PER_PASS) {
            decide_in_storage_order(pass, &one_by_one, &mut culled, ranges, &mut scratch.marks);
        }
    } else {
        for view in &mut views {
            let mut candidates = std::mem::take(&mut view.candidates);
            // In entity order, which follows storage order where entities
            // were spawned together: neighbouring look-ups share cache
            // lines and pages.
            candidates.sort_unstable_by_key(|c| c.0.index_u32());
            let mut proven = entities.p1();
            for (i, &(entity, inside)) in candidates.iter().enumerate() {
                if let Some(&(ahead, _)) = candidates.get(i + LOOK_AHEAD)
                    && let Ok(item) = proven.get(ahead)
                {
                    std::hint::black_box((item.0, item.1));
                }
                if inside && let Ok(item) = proven.get_mut(entity) {
                    decide_proven(view, entity, item, ranges);
                }
            }
            let mut culled = entities.p0();
            for &(entity, inside) in &candidates {
                if !inside && let Ok(mut item) = culled.get_mut(entity) {
                    decide(view, &mut item, false, ranges);
                }
            }
            for &entity in &one_by_one {
                if let Ok(mut item) = culled.get_mut(entity) {
                    decide(view, &mut item, false, ranges);
                }
            }
            view.candidates = candidates;
        }
    }
    let culled_views = views.iter().filter(|v| !v.no_culling).count();
    for view in &mut views {
        let Ok((_, mut visible, ..)) = cameras.get_mut(view.camera) else {
            continue;
        };
        visible.clear_all();
        for (class, list) in &mut view.visible {
            // Sorted, as Bevy's diffing of visible lists needs.
            list.sort_unstable();
            list.dedup();
            std::mem::swap(visible.get_mut(*class), list);
        }
    }
    scratch.views = views;
    scratch.one_by_one = one_by_one;
    scratch.views.append(&mut spare);
    if culled_views > 0 {
        let ws = &mut scratch.workspace;
        sink.add(|d| d.culling.record_workspace(culled_views, ws));
    }
}

/// Decides the views of one pass together, walking the entities in
/// storage order and testing each against the views that have it as a
/// candidate (every view that culls nothing, and every view for the
/// entities outside the tree).
fn decide_in_storage_order(
    views: &mut [View],
    one_by_one: &[Entity],
    culled: &mut Query<Culled<'_>, Without<NoCpuCulling>>,
    ranges: Option<&VisibleEntityRanges>,
    marks: &mut Vec<u16>,
) {
    const CANDIDATE: u16 = 0b01;
    const PROVEN: u16 = 0b10;
    let mut mark = |entity: Entity, bits: u16| {
        let at = entity.index_u32() as usize;
        if marks.len() <= at {
            marks.resize(at + 1, 0);
        }
        marks[at] |= bits;
    };
    let mut all = 0u16;
    for (v, view) in views.iter().enumerate() {
        let shift = 2 * v;
        if view.no_culling {
            all |= CANDIDATE << shift;
        }
        for &(entity, proven) in &view.candidates {
            mark(
                entity,
                (CANDIDATE | if proven { PROVEN } else { 0 }) << shift,
            );
        }
        for &entity in one_by_one {
            mark(entity, CANDIDATE << shift);
        }
    }
    for mut item in culled.iter_mut() {
        let at = item.0.index_u32() as usize;
        let mut bits = all | marks.get(at).copied().unwrap_or(0);
        while bits != 0 {
            let v = bits.trailing_zeros() as usize / 2;
            let proven = bits >> (2 * v) & PROVEN != 0;
            bits &= !(0b11 << (2 * v));
            decide(&mut views[v], &mut item, proven, ranges);
        }
    }
    // Cleared mark by mark, not by walking the entities: a marked entity
    // the walk did not meet must not carry its marks into the next pass.
    for view in views.iter() {
        for &(entity, _) in &view.candidates {
            marks[entity.index_u32() as usize] = 0;
        }
    }
    for &entity in one_by_one {
        marks[entity.index_u32() as usize] = 0;
    }
}

/// [`decide`] for an entity the tree proved inside every plane: Bevy's
/// other checks, through the narrower [`Proven`] query.
fn decide_proven(
    view: &mut View,
    entity: Entity,
    item: <Proven<'static> as QueryData>::Item<'_, '_>,
    ranges: Option<&VisibleEntityRanges>,
) {
    let (inherited, mut view_visibility, class, mask, has_range) = item;
    if may_be_seen(view, entity, inherited, mask, has_range, ranges) {
        see(view, entity, &mut view_visibility, class);
    }
}

/// Bevy's own decision for one entity and one view, as its culling system
/// makes it; `proven` skips the frustum tests for an entity the tree has
/// shown to lie inside every plane they test.
fn decide(
    view: &mut View,
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
    if !may_be_seen(view, entity, inherited, *mask, *has_range, ranges) {
        return;
    }
    if !proven && !*no_frustum_culling && !view.no_culling {
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
    see(view, entity, view_visibility, *class);
}

/// Bevy's checks before any frustum test: visible in the hierarchy, on a
/// layer the camera renders, within its visibility range of the camera.
fn may_be_seen(
    view: &View,
    entity: Entity,
    inherited: &InheritedVisibility,
    mask: Option<&RenderLayers>,
    has_range: bool,
    ranges: Option<&VisibleEntityRanges>,
) -> bool {
    inherited.get()
        && view.mask.intersects(mask.unwrap_or_default())
        && !(has_range
            && ranges.is_some_and(|r| !r.entity_is_in_range_of_view(entity, view.camera)))
}

/// Marks `entity` seen by some view, and lists it for this one under each
/// of its visibility classes.
fn see(
    view: &mut View,
    entity: Entity,
    view_visibility: &mut Mut<ViewVisibility>,
    class: Option<&VisibilityClass>,
) {
    view_visibility.set_visible();
    if let Some(class) = class {
        for &id in class.iter() {
            view.push(entity, id);
        }
    }
}

/// The plane of a Bevy frustum that its camera culling does not test: the
/// far plane.
const UNTESTED_BY_CAMERAS: usize = 5;

/// The plane of a shadow cascade that Bevy's directional light visibility
/// does not test: the near plane (a caster before it still casts).
#[cfg_attr(not(feature = "bevy_light"), allow(dead_code))]
pub(super) const UNTESTED_BY_CASCADES: usize = 4;

/// The tree's candidates for a Bevy frustum: every entry whose box passes
/// its planes (all but `untested`, the one plane Bevy's test skips: far for
/// cameras, near for shadow cascades), loosened by [`slack`] so that no box
/// Bevy's own test accepts is missed; and whether each box lies inside the
/// planes tightened by the same slack, which proves Bevy's tests would pass.
pub(super) fn candidates(
    index: &SpatialIndex<Renderable>,
    frustum: &BevyFrustum,
    untested: usize,
    eye: Vec3,
    ws: &mut QueryWorkspace,
    out: &mut Vec<(Entity, bool)>,
) {
    let tree = index.tree();
    let Some(bounds) = tree.bounds() else { return };
    let reach =
        bounds.min.abs().max(bounds.max.abs()).max_element() * 3.0 + eye.abs().max_element();
    let (Some(loose), Some(tight)) = (
        rebased(frustum, untested, eye, reach, 1.0),
        rebased(frustum, untested, eye, reach, -1.0),
    ) else {
        // A frustum Bevy's tests cannot decide either (NaN planes): every
        // entry is a candidate, and Bevy's tests say what they say.
        out.extend(tree.iter().map(|(_, entity, _)| (entity, false)));
        return;
    };
    tree.visit_visible_proving(&loose, &tight, ws, |entity, proven| {
        out.push((entity, proven))
    });
}

/// Bevy's planes but `untested`, re-based on `eye` and moved outward
/// (`side = 1`) or inward (`-1`) by [`slack`].
fn rebased(
    frustum: &BevyFrustum,
    untested: usize,
    eye: Vec3,
    reach: f32,
    side: f64,
) -> Option<Frustum> {
    let mut planes = [HalfSpace::INACTIVE; 6];
    for (i, (plane, half_space)) in planes.iter_mut().zip(&frustum.half_spaces).enumerate() {
        if i == untested {
            continue;
        }
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
pub(super) fn slack(normal: Vec3, d: f32, reach: f32) -> f64 {
    let magnitude = normal.length() as f64 * reach as f64 + (d as f64).abs();
    magnitude / 65_536.0
}
