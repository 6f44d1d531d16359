//! Bevy's shadow visibility of directional lights from the index (feature
//! `bevy_light`): each cascade of each view takes from the tree the
//! casters its planes may see, and Bevy's own test decides each one. As
//! in Bevy, the casters' `ViewVisibility` is not touched by the system
//! itself but marked by a command after it, so that the system reads no
//! caster's `ViewVisibility` and runs beside the point lights' one.

use bevy_camera::Camera;
use bevy_camera::primitives::{Aabb as BevyAabb, CascadesFrusta, Frustum as BevyFrustum};
use bevy_camera::visibility::{
    CascadesVisibleEntities, InheritedVisibility, NoFrustumCulling, RenderLayers,
    SetViewVisibility, ViewVisibility, VisibilityRange, VisibleEntityRanges, VisibleMeshEntities,
};
use bevy_ecs::prelude::*;
use bevy_ecs::query::QueryData;
use bevy_light::{DirectionalLight, SpotLight};
use bevy_transform::prelude::GlobalTransform;
use glam::Vec3;

use super::frustum_candidates::{UNTESTED_BY_CASCADES, candidates};
use super::layers::ViewLayers;
use super::lights::{CasterFilter, LightScratch, OutsideTheTree, may_cast};
use super::{BevyVisibilitySettings, Renderable};
use crate::plugin::index::SpatialIndex;

/// What Bevy's directional light visibility reads of a caster: its query,
/// which has no `ViewVisibility`.
type CascadeCaster<'a> = (
    Entity,
    &'a InheritedVisibility,
    Option<&'a RenderLayers>,
    Option<&'a BevyAabb>,
    Option<&'a GlobalTransform>,
    Has<VisibilityRange>,
    Has<NoFrustumCulling>,
);

type CascadeCasterItem<'w, 's> = <CascadeCaster<'static> as QueryData>::Item<'w, 's>;

/// The casters a frame's cascades saw, each once, for the command that
/// marks them visible.
#[derive(Default)]
pub(super) struct Marks {
    /// Per entity index, whether it is already in `entities`.
    seen: Vec<u64>,
    entities: Vec<Entity>,
}

impl Marks {
    fn push(&mut self, entity: Entity) {
        let index = entity.index_u32() as usize;
        let (word, bit) = (index / 64, 1u64 << (index % 64));
        if self.seen.len() <= word {
            self.seen.resize(word + 1, 0);
        }
        if self.seen[word] & bit == 0 {
            self.seen[word] |= bit;
            self.entities.push(entity);
        }
    }

    /// The entities to mark, leaving the set empty for the next frame.
    fn take(&mut self) -> Vec<Entity> {
        for entity in &self.entities {
            let index = entity.index_u32() as usize;
            self.seen[index / 64] = 0;
        }
        std::mem::take(&mut self.entities)
    }
}

/// Replaces bevy_light's `check_dir_light_mesh_visibility`, in
/// `SimulationLightSystems::CheckLightVisibility`: the same lists of every
/// cascade of every directional light, in the same order (sorted), and the
/// same `ViewVisibility` for every caster, marked by a command as Bevy's.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub(super) fn check_dir_light_visibility_from_index(
    mut directional_lights: Query<
        (
            Entity,
            &DirectionalLight,
            &CascadesFrusta,
            &mut CascadesVisibleEntities,
            Option<&RenderLayers>,
            &ViewVisibility,
        ),
        Without<SpotLight>,
    >,
    casters: Query<CascadeCaster<'_>, CasterFilter>,
    outside_the_tree: Query<Entity, OutsideTheTree>,
    view_transforms: Query<&GlobalTransform, With<Camera>>,
    index: Res<SpatialIndex<Renderable>>,
    ranges: Option<Res<VisibleEntityRanges>>,
    settings: Res<BevyVisibilitySettings>,
    mut scratch: Local<(LightScratch, Marks)>,
    mut commands: Commands,
) {
    let ranges = ranges.as_deref();
    let (scratch, marks) = &mut *scratch;
    scratch.gather_one_by_one(&outside_the_tree, &index);
    for (light_entity, light, frusta, mut visible, mask, light_visibility) in
        &mut directional_lights
    {
        // One list per cascade of every view that has cascades, as Bevy
        // keeps them.
        visible
            .entities
            .retain(|view, _| frusta.frusta.contains_key(view));
        for (view, view_frusta) in &frusta.frusta {
            visible
                .entities
                .entry(*view)
                .or_default()
                .resize(view_frusta.len(), VisibleMeshEntities::default());
        }
        if !light.shadow_maps_enabled || !light_visibility.get() {
            visible.entities.clear();
            continue;
        }
        let layers = ViewLayers::new(light_entity, mask);
        for (view, view_frusta) in &frusta.frusta {
            let eye = view_transforms
                .get(*view)
                .map_or(Vec3::ZERO, GlobalTransform::translation);
            let Some(lists) = visible.entities.get_mut(view) else {
                continue;
            };
            let decide = (&layers, *view, ranges);
            for (frustum, list) in view_frusta.iter().zip(lists.iter_mut()) {
                scratch.candidates.clear();
                candidates(
                    &index,
                    frustum,
                    UNTESTED_BY_CASCADES,
                    eye,
                    &mut scratch.workspace,
                    &mut scratch.candidates,
                );
                let cascade = &mut scratch.faces[0];
                cascade.clear();
                for &(entity, proven) in &scratch.candidates {
                    if let Ok(item) = casters.get(entity) {
                        let proven = proven && settings.prove_inside;
                        decide_cascade(&item, (frustum, proven), decide, cascade);
                    }
                }
                for &entity in &scratch.one_by_one {
                    if let Ok(item) = casters.get(entity) {
                        decide_cascade(&item, (frustum, false), decide, cascade);
                    }
                }
                cascade.iter().for_each(|&entity| marks.push(entity));
                cascade.sort_unstable();
                list.entities.clear();
                list.entities.append(cascade);
            }
            if view_frusta.is_empty() {
                mark_unbounded_casters(&casters, &scratch.one_by_one, decide, marks);
            }
        }
    }
    let marked = marks.take();
    if !marked.is_empty() {
        commands.queue(move |world: &mut World| {
            let mut view_visibility = world.query::<&mut ViewVisibility>();
            for entity in marked {
                if let Ok(mut visibility) = view_visibility.get_mut(world, entity) {
                    visibility.set_visible();
                }
            }
        });
    }
}

/// Bevy's decision for one caster and one cascade of a directional light
/// (its frustum, and whether the tree proved the caster inside every
/// plane Bevy tests): listed in `out` if it casts into the cascade.
fn decide_cascade(
    item: &CascadeCasterItem<'_, '_>,
    (frustum, proven): (&BevyFrustum, bool),
    (layers, view, ranges): (&ViewLayers, Entity, Option<&VisibleEntityRanges>),
    out: &mut Vec<Entity>,
) {
    let &(entity, inherited, entity_mask, aabb, transform, has_range, nfc) = item;
    if !may_cast(
        entity,
        inherited,
        entity_mask,
        has_range,
        layers,
        Some(view),
        ranges,
    ) {
        return;
    }
    if let (Some(aabb), Some(transform), false, false) = (aabb, transform, nfc, proven) {
        // Shadow casters before the near plane still cast: no near plane.
        if !frustum.intersects_obb(aabb, &transform.affine(), false, true) {
            return;
        }
    }
    out.push(entity);
}

/// A view with no cascades still sees the casters Bevy cannot bound (no
/// `Aabb` or no transform): Bevy marks them visible before it looks at the
/// cascades, and lists them in none.
fn mark_unbounded_casters(
    casters: &Query<CascadeCaster<'_>, CasterFilter>,
    one_by_one: &[Entity],
    (layers, view, ranges): (&ViewLayers, Entity, Option<&VisibleEntityRanges>),
    marks: &mut Marks,
) {
    for &entity in one_by_one {
        let Ok((entity, inherited, entity_mask, aabb, transform, has_range, _)) =
            casters.get(entity)
        else {
            continue;
        };
        let unbounded = aabb.is_none() || transform.is_none();
        let origin = Some(view);
        if unbounded
            && may_cast(
                entity,
                inherited,
                entity_mask,
                has_range,
                layers,
                origin,
                ranges,
            )
        {
            marks.push(entity);
        }
    }
}
