//! Bevy's shadow visibility of point and spot lights from the index
//! (feature `bevy_light`): the tree gives each light the shadow casters
//! its range may reach; Bevy's own tests decide every candidate, so the
//! lists are Bevy's. The directional lights' cascades are in `cascades`,
//! which shares the casters' filters kept here.

use std::any::TypeId;

use bevy_camera::primitives::{Aabb as BevyAabb, CubemapFrusta, Frustum as BevyFrustum, Sphere};
use bevy_camera::visibility::{
    CubemapVisibleEntities, InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers,
    SetViewVisibility, ViewVisibility, VisibilityRange, VisibleEntities, VisibleEntityRanges,
    VisibleMeshEntities,
};
use bevy_camera::{Camera, RenderTarget, ShadowLodOrigin};
use bevy_ecs::entity::EntityHashSet;
use bevy_ecs::prelude::*;
use bevy_ecs::query::QueryData;
use bevy_light::cluster::ClusterVisibilityClass;
use bevy_light::{DirectionalLight, NotShadowCaster, PointLight, SpotLight, get_shadow_lod_origin};
use bevy_mesh::Mesh3d;
use bevy_transform::prelude::GlobalTransform;
use glam::{DVec3, Vec3, Vec3A};

use super::Renderable;
use super::layers::ViewLayers;
use crate::plugin::index::SpatialIndex;
use crate::query::QueryWorkspace;

/// The entities Bevy's light visibility tests: meshes that cast shadows.
pub(super) type CasterFilter = (
    Without<NotShadowCaster>,
    Without<DirectionalLight>,
    Without<NoCpuCulling>,
    With<Mesh3d>,
);

/// What Bevy's light visibility reads of a caster (its own query; point
/// and spot lights skip casters without `ViewVisibility`).
type Caster<'a> = (
    Entity,
    &'a InheritedVisibility,
    Option<&'a mut ViewVisibility>,
    Option<&'a RenderLayers>,
    Option<&'a BevyAabb>,
    Option<&'a GlobalTransform>,
    Has<VisibilityRange>,
    Has<NoFrustumCulling>,
);

type CasterItem<'w, 's> = <Caster<'static> as QueryData>::Item<'w, 's>;

/// The casters that are not in the tree by construction (the tree holds
/// only entities with a box, a transform, `ViewVisibility` and frustum
/// culling): each light tests them one by one, as Bevy does.
pub(super) type OutsideTheTree = (
    CasterFilter,
    Or<(
        Without<BevyAabb>,
        Without<GlobalTransform>,
        Without<ViewVisibility>,
        With<NoFrustumCulling>,
    )>,
);

/// Scratch kept from frame to frame.
#[derive(Default)]
pub(super) struct LightScratch {
    pub(super) workspace: QueryWorkspace,
    pub(super) candidates: Vec<(Entity, bool)>,
    pub(super) one_by_one: Vec<Entity>,
    checked: EntityHashSet,
    pub(super) faces: [Vec<Entity>; 6],
}

impl LightScratch {
    /// The casters Bevy's tests decide without the tree: those outside it
    /// by construction, and entries whose box the index refused.
    pub(super) fn gather_one_by_one(
        &mut self,
        outside_the_tree: &Query<Entity, OutsideTheTree>,
        index: &SpatialIndex<Renderable>,
    ) {
        self.one_by_one.clear();
        self.one_by_one.extend(outside_the_tree.iter());
        self.one_by_one.extend(index.unindexed());
        self.one_by_one.sort_unstable();
        self.one_by_one.dedup();
    }
}

/// How a point or spot light's shadow views see a caster that passes
/// Bevy's non-geometric checks.
enum Shape<'a> {
    /// A point light: the range sphere, then the six cube faces.
    Point(&'a Sphere, &'a CubemapFrusta),
    /// A spot light: the range sphere, then its frustum.
    Spot(&'a Sphere, &'a BevyFrustum),
}

/// Replaces bevy_light's `check_point_light_mesh_visibility`, in
/// `SimulationLightSystems::CheckLightVisibility`: the same lists of every
/// point and spot light, in the same order (sorted), and the same
/// `ViewVisibility` for every caster.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn check_point_light_visibility_from_index(
    seen_by_cameras: Query<&VisibleEntities>,
    mut point_lights: Query<(
        &PointLight,
        &GlobalTransform,
        &CubemapFrusta,
        &mut CubemapVisibleEntities,
        Option<&RenderLayers>,
    )>,
    mut spot_lights: Query<(
        &SpotLight,
        &GlobalTransform,
        &BevyFrustum,
        &mut VisibleMeshEntities,
        Option<&RenderLayers>,
    )>,
    mut casters: Query<Caster<'_>, CasterFilter>,
    outside_the_tree: Query<Entity, OutsideTheTree>,
    mut lod_cameras: Query<(Entity, &RenderTarget), With<Camera>>,
    mut lod_origins: Query<Entity, With<ShadowLodOrigin>>,
    mut point_and_spot: Query<Entity, Or<(With<PointLight>, With<SpotLight>)>>,
    index: Res<SpatialIndex<Renderable>>,
    ranges: Option<Res<VisibleEntityRanges>>,
    mut scratch: Local<LightScratch>,
) {
    let ranges = ranges.as_deref();
    let scratch = &mut *scratch;
    scratch.gather_one_by_one(&outside_the_tree, &index);
    let lod_origin = get_shadow_lod_origin(
        lod_cameras.transmute_lens_filtered(),
        lod_origins.transmute_lens_filtered(),
        point_and_spot.transmute_lens_filtered(),
    );
    // What a caster's visibility range is measured against: from where
    // (the shadow level-of-detail origin), and the ranges.
    let in_range = (lod_origin, ranges);

    // Point and spot lights, each once, as the cameras list them.
    scratch.checked.clear();
    for seen in &seen_by_cameras {
        for &light in seen.get(TypeId::of::<ClusterVisibilityClass>()) {
            if !scratch.checked.insert(light) {
                continue;
            }
            if let Ok((point, transform, frusta, mut visible, mask)) = point_lights.get_mut(light) {
                // A light without shadow maps keeps its lists, as in Bevy.
                if !point.shadow_maps_enabled {
                    continue;
                }
                let sphere = range_sphere(transform, point.range);
                let shape = Shape::Point(&sphere, frusta);
                let layers = ViewLayers::new(light, mask);
                decide_all(&index, &mut casters, scratch, &shape, &layers, in_range);
                for (face, list) in scratch.faces.iter_mut().enumerate() {
                    list.sort_unstable();
                    let dest = &mut visible.get_mut(face).entities;
                    dest.clear();
                    dest.append(list);
                }
            }
            if let Ok((spot, transform, frustum, mut visible, mask)) = spot_lights.get_mut(light) {
                if !spot.shadow_maps_enabled {
                    continue;
                }
                let sphere = range_sphere(transform, spot.range);
                let shape = Shape::Spot(&sphere, frustum);
                let layers = ViewLayers::new(light, mask);
                decide_all(&index, &mut casters, scratch, &shape, &layers, in_range);
                let list = &mut scratch.faces[0];
                list.sort_unstable();
                visible.entities.clear();
                visible.entities.append(list);
            }
        }
    }
}

/// A light's range sphere, as Bevy's test builds it.
fn range_sphere(transform: &GlobalTransform, range: f32) -> Sphere {
    Sphere {
        center: Vec3A::from(transform.translation()),
        radius: range,
    }
}

/// Takes from the tree the candidates of a point or spot light's range
/// sphere and decides them (and every caster outside the tree), filling
/// `scratch.faces`.
fn decide_all(
    index: &SpatialIndex<Renderable>,
    casters: &mut Query<Caster<'_>, CasterFilter>,
    scratch: &mut LightScratch,
    shape: &Shape<'_>,
    layers: &ViewLayers,
    in_range: (Option<Entity>, Option<&VisibleEntityRanges>),
) {
    let (Shape::Point(sphere, _) | Shape::Spot(sphere, _)) = shape;
    sphere_candidates(index, sphere, scratch);
    scratch.faces.iter_mut().for_each(Vec::clear);
    let one_by_one = scratch.one_by_one.iter();
    for entity in scratch.candidates.iter().map(|c| &c.0).chain(one_by_one) {
        let Ok(mut item) = casters.get_mut(*entity) else {
            continue;
        };
        // Point and spot lights test only casters with `ViewVisibility`.
        if item.2.is_none() {
            continue;
        }
        decide_faces(&mut item, shape, layers, in_range, &mut scratch.faces);
    }
}

/// [`decide`] for the lists of a point (six faces) or spot light (one).
fn decide_faces(
    item: &mut CasterItem<'_, '_>,
    shape: &Shape<'_>,
    layers: &ViewLayers,
    (lod_origin, ranges): (Option<Entity>, Option<&VisibleEntityRanges>),
    faces: &mut [Vec<Entity>; 6],
) {
    let (entity, inherited, view_visibility, entity_mask, aabb, transform, has_range, nfc) = item;
    if !may_cast(
        *entity,
        inherited,
        *entity_mask,
        *has_range,
        layers,
        lod_origin,
        ranges,
    ) {
        return;
    }
    let (Some(aabb), Some(transform)) = (aabb, transform) else {
        // No bounds: seen by every face.
        mark(view_visibility);
        let count = if matches!(shape, Shape::Point(..)) {
            6
        } else {
            1
        };
        faces[..count].iter_mut().for_each(|f| f.push(*entity));
        return;
    };
    let model = transform.affine();
    match shape {
        Shape::Point(sphere, frusta) => {
            if !*nfc && !sphere.intersects_obb(aabb, &model) {
                return;
            }
            for (frustum, face) in frusta.iter().zip(faces.iter_mut()) {
                if *nfc || frustum.intersects_obb(aabb, &model, true, true) {
                    mark(view_visibility);
                    face.push(*entity);
                }
            }
        }
        Shape::Spot(sphere, frustum) => {
            if !*nfc && !sphere.intersects_obb(aabb, &model) {
                return;
            }
            if *nfc || frustum.intersects_obb(aabb, &model, true, true) {
                mark(view_visibility);
                faces[0].push(*entity);
            }
        }
    }
}

/// Bevy's checks before any shape test: visible in the hierarchy, on a
/// layer the light renders, within its visibility range of `origin` (the
/// cascade's view, or the shadow level-of-detail origin; with none, an
/// entity with a range casts no point or spot shadow).
pub(super) fn may_cast(
    entity: Entity,
    inherited: &InheritedVisibility,
    entity_mask: Option<&RenderLayers>,
    has_range: bool,
    layers: &ViewLayers,
    origin: Option<Entity>,
    ranges: Option<&VisibleEntityRanges>,
) -> bool {
    inherited.get()
        && layers.renders(entity, entity_mask)
        && !(has_range
            && ranges.is_some_and(|r| {
                origin.is_none_or(|origin| !r.entity_is_in_range_of_view(entity, origin))
            }))
}

fn mark(view_visibility: &mut Option<Mut<ViewVisibility>>) {
    if let Some(view_visibility) = view_visibility {
        view_visibility.set_visible();
    }
}

/// Where the largest coordinate of a light's centre and that of the
/// entries sum to at most this many metres, no square or product of Bevy's
/// sphere test overflows `f32` for an indexed entry: the vector from the
/// light to a box is then under `sqrt(3) * 5e18` m long, its square under `f32::MAX`,
/// and its product with a column of at most
/// [`COLUMN_BEYOND_BEVY_S_TEST`](super::sync::COLUMN_BEYOND_BEVY_S_TEST)
/// far under it too. (A light's radius times that length may still
/// overflow; then Bevy's test accepts every caster, and so does the
/// tree's, the radius being longer than any gap.)
pub(super) const FAR_FOR_BEVY_S_SPHERE_TEST: f64 = 5e18;

/// The tree's candidates for a light's range sphere: every entry whose
/// box `B` lies within `radius + |half extents of B|` of the centre (plus a
/// slack for rounding). Bevy's sphere test accepts an oriented box only if
/// its centre lies within the radius plus the box's reach along the line
/// between the centres, which is no more than the half diagonal of the
/// world box around it: so no box it accepts is missed, and the test is
/// monotone (a larger box passes too), which lets it prune nodes.
fn sphere_candidates(
    index: &SpatialIndex<Renderable>,
    sphere: &Sphere,
    scratch: &mut LightScratch,
) {
    scratch.candidates.clear();
    let tree = index.tree();
    let Some(bounds) = tree.bounds() else { return };
    let centre = Vec3::from(sphere.center).as_dvec3();
    let radius = f64::from(sphere.radius);
    let out = &mut scratch.candidates;
    let farthest = centre.abs().max_element()
        + f64::from(bounds.min.abs().max(bounds.max.abs()).max_element());
    if !centre.is_finite() || !radius.is_finite() || farthest > FAR_FOR_BEVY_S_SPHERE_TEST {
        // A sphere Bevy's test cannot decide either, or one so far from
        // the entries that Bevy's `f32` squares and products may overflow
        // to infinity (which accepts the caster): every entry is a
        // candidate, and Bevy's test says what it says.
        out.extend(tree.iter().map(|(_, entity, _)| (entity, false)));
        return;
    }
    // Bevy's test runs in `f32` at world coordinates: 2^-16 of the
    // magnitudes involved is far more than its rounding error.
    let reach = f64::from(bounds.min.abs().max(bounds.max.abs()).max_element()) * 3.0
        + centre.abs().max_element()
        + radius.abs();
    // A negative radius still accepts a box centred on the light.
    let limit = radius.max(0.0) + reach / 65_536.0;
    tree.visit_boxes_where(
        &mut scratch.workspace,
        |b| {
            let (min, max) = (b.min.as_dvec3(), b.max.as_dvec3());
            let gap: DVec3 = centre - centre.clamp(min, max);
            let half_diagonal = ((max - min) * 0.5).length();
            gap.length() <= limit + half_diagonal
        },
        |entity, _| out.push((entity, false)),
    );
}
