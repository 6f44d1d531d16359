//! Raycasts for caster entities: every frame, all casters of a layer are
//! batched into one traversal per ray mode, and each gets its hits.

use super::frame_queries::{self, FrameWorkspace};
use std::marker::PhantomData;

use bevy_ecs::prelude::*;

use super::bounds::SpatialBounds;
use super::diagnostics::DiagnosticsSink;
use super::index::SpatialIndex;
use crate::geometry::{Ray, SpatialError};
use crate::query::{RayHit, RayMode, RayResults};

/// A ray cast every frame against layer `L` (all indexed entities by
/// default); the answer lands in the entity's [`RayCasterHits`].
///
/// Ray work runs only while at least one `RayCaster<L>` exists. The ray is
/// in world space and taken as is: a caster that is itself indexed in the
/// same layer can hit its own box (start the ray outside it, or keep the
/// caster in another layer). One caster per entity.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::{Aabb, Ray, RayMode};
/// use bevy_rtree::plugin::{RayCaster, RayCasterHits, SpatialBounds, SpatialIndexPlugin};
/// use glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let wall = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::new(5.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0))?)).id();
/// let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0)?;
/// let caster = app.world_mut().spawn(RayCaster::new(ray, RayMode::First)).id();
/// app.update();
/// let hits = app.world().get::<RayCasterHits>(caster).unwrap();
/// assert_eq!(hits.first().map(|h| (h.key, h.t)), Some((wall, 5.0)));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(Component)]
#[require(RayCasterHits<L>)]
#[component(on_add = super::layer_must_be_registered::<L>)]
pub struct RayCaster<L: Component = SpatialBounds> {
    /// The ray, in world space ([contract S3](crate::contract)).
    pub ray: Ray,
    /// First hit, all hits (optionally limited) or any hit.
    pub mode: RayMode,
    _layer: PhantomData<fn() -> L>,
}

impl_layer_generic_traits!(RayCaster<L> { ray, mode });

impl RayCaster {
    /// A caster against all indexed entities.
    pub fn new(ray: Ray, mode: RayMode) -> Self {
        RayCaster::for_layer(ray, mode)
    }
}

impl<L: Component> RayCaster<L> {
    /// A caster that only hits entities of layer `L` (register the layer
    /// with [`add_spatial_layer`](super::SpatialAppExt::add_spatial_layer)).
    pub fn for_layer(ray: Ray, mode: RayMode) -> Self {
        RayCaster {
            ray,
            mode,
            _layer: PhantomData,
        }
    }
}

/// This frame's answer for a [`RayCaster<L>`] ([contract S5](crate::contract)).
///
/// One answer per layer: an entity with casters of two layers has a
/// `RayCasterHits<A>` and a `RayCasterHits<B>`. When the entity loses its
/// `RayCaster<L>`, the answer goes too, so that it never names entities
/// that no longer exist.
#[derive(Component)]
pub struct RayCasterHits<L: Component = SpatialBounds> {
    hits: Vec<RayHit<Entity>>,
    any: bool,
    error: Option<SpatialError>,
    _layer: PhantomData<fn() -> L>,
}

impl<L: Component> Default for RayCasterHits<L> {
    fn default() -> Self {
        RayCasterHits {
            hits: Vec::new(),
            any: false,
            error: None,
            _layer: PhantomData,
        }
    }
}

impl<L: Component> Clone for RayCasterHits<L> {
    fn clone(&self) -> Self {
        RayCasterHits {
            hits: self.hits.clone(),
            any: self.any,
            error: self.error,
            _layer: PhantomData,
        }
    }
}

impl<L: Component> std::fmt::Debug for RayCasterHits<L> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RayCasterHits")
            .field("hits", &self.hits)
            .field("any", &self.any)
            .field("error", &self.error)
            .finish()
    }
}

impl<L: Component> PartialEq for RayCasterHits<L> {
    fn eq(&self, other: &Self) -> bool {
        (&self.hits, self.any, self.error) == (&other.hits, other.any, other.error)
    }
}

impl<L: Component> RayCasterHits<L> {
    /// The hits sorted by `(t, entity)`: at most one for
    /// [`RayMode::First`], none for [`RayMode::Any`].
    pub fn hits(&self) -> &[RayHit<Entity>] {
        &self.hits
    }

    /// The nearest hit, if any (not for [`RayMode::Any`]).
    pub fn first(&self) -> Option<RayHit<Entity>> {
        self.hits.first().copied()
    }

    /// Whether the ray hit anything (every mode).
    pub fn any(&self) -> bool {
        self.any
    }

    /// The ray's error if it was invalid (its hits are then empty).
    pub fn error(&self) -> Option<SpatialError> {
        self.error
    }
}

/// Scratch reused by the ray system from frame to frame.
#[derive(Default)]
pub(crate) struct RayScratch {
    workspace: FrameWorkspace,
    modes: Vec<RayMode>,
    rays: Vec<Ray>,
    casters: Vec<Entity>,
    results: RayResults<Entity>,
}

/// Observer: an entity that loses its `RayCaster<L>` loses its answer.
pub(crate) fn drop_hits<L: Component>(event: On<Remove<RayCaster<L>>>, mut commands: Commands) {
    if let Ok(mut entity) = commands.get_entity(event.entity) {
        entity.try_remove::<RayCasterHits<L>>();
    }
}

/// Casts every ray of layer `L`: one batched traversal per distinct mode.
pub(crate) fn cast_rays<L: Component>(
    index: Res<SpatialIndex<L>>,
    casters: Query<(Entity, &RayCaster<L>)>,
    mut answers: Query<&mut RayCasterHits<L>, With<RayCaster<L>>>,
    mut scratch: Local<RayScratch>,
    sink: Res<DiagnosticsSink>,
) {
    let scratch = &mut *scratch;
    scratch.modes.clear();
    for (_, caster) in &casters {
        if !scratch.modes.contains(&caster.mode) {
            scratch.modes.push(caster.mode);
        }
    }
    for m in 0..scratch.modes.len() {
        let mode = scratch.modes[m];
        scratch.rays.clear();
        scratch.casters.clear();
        for (entity, caster) in &casters {
            if caster.mode == mode {
                scratch.rays.push(caster.ray);
                scratch.casters.push(entity);
            }
        }
        frame_queries::cast_rays(
            index.tree(),
            &scratch.rays,
            mode,
            &mut scratch.workspace,
            &mut scratch.results,
        );
        sink.add(|d| d.rays.record(scratch.rays.len(), &mut scratch.workspace));
        for (i, &caster) in scratch.casters.iter().enumerate() {
            let Ok(mut answer) = answers.get_mut(caster) else {
                continue;
            };
            let answer = &mut *answer;
            answer.hits.clear();
            match scratch.results.hits(i) {
                Ok(hits) => {
                    answer.hits.extend_from_slice(hits);
                    answer.any = scratch.results.any(i).unwrap_or(false);
                    answer.error = None;
                }
                Err(error) => {
                    answer.any = false;
                    answer.error = Some(error);
                }
            }
        }
    }
}
