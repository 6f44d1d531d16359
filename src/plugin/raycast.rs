//! Raycasts for caster entities: every frame, all casters of a layer are
//! batched into one traversal per ray mode, and each gets its hits.

use super::frame_queries::{self, FrameWorkspace};
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
#[cfg(feature = "reflect")]
use bevy_reflect::std_traits::ReflectDefault;
use std::marker::PhantomData;

use bevy_ecs::prelude::*;

use super::bounds::SpatialBounds;
use super::diagnostics::DiagnosticsSink;
use super::filter::SpatialQueryFilter;
use super::index::SpatialIndex;
use crate::geometry::{Ray, SpatialError};
use crate::query::{QueryWorkspace, RayHit, RayMode, RayResults};

/// A ray cast every frame against layer `L` (all indexed entities by
/// default); the answer lands in the entity's [`RayCasterHits`].
///
/// With feature `bevy`, the ray is in the entity's own space when the
/// entity has a `GlobalTransform`, and follows it: each frame, after
/// transform propagation, the origin is carried by the whole transform and
/// the direction turned by its rotation (its scale stretches nothing, but a
/// mirroring scale mirrors it, as it does the origin), and the direction is
/// normalised, so hits' `t` are distances in metres along the world ray
/// (`max_t` is read in units of the given direction's length). A transform
/// that collapses an axis (a zero column, as `LocalBounds` says) has no
/// rotation: the answer is then `SpatialError::InvalidRay` until the scale
/// is back. Without a `GlobalTransform` the ray is in world space as
/// given.
/// [`RayCasterHits::ray`] is the ray that was cast.
///
/// The caster ignores its own entity (its ray usually starts inside its own
/// box; set [`ignore_self`](Self::ignore_self) to `false` to hit it), and
/// hits only what its [`filter`](Self::filter) allows. Ray work runs only
/// while at least one `RayCaster<L>` exists; all casters of a layer are
/// cast in one batch per mode.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::{Aabb, Ray, RayMode};
/// use bevy_rtree::plugin::{RayCaster, RayCasterHits, SpatialBounds, SpatialIndexPlugin};
/// use bevy_rtree::glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let wall = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::new(5.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0))?)).id();
/// let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0)?;
/// // The caster has a box of its own around the ray's start: ignored.
/// let own_box = SpatialBounds(Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5))?);
/// let caster = app.world_mut().spawn((RayCaster::new(ray, RayMode::First), own_box)).id();
/// app.update();
/// let hits = app.world().get::<RayCasterHits>(caster).unwrap();
/// assert_eq!(hits.first().map(|h| (h.key, h.t)), Some((wall, 5.0)));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
#[derive(Component)]
#[require(RayCasterHits<L>)]
#[component(on_add = super::layer_must_be_registered::<L>)]
pub struct RayCaster<L: Component = SpatialBounds> {
    /// The ray ([contract S3](crate::contract)): in the entity's space if it
    /// has a `GlobalTransform` (feature `bevy`), else in world space.
    pub ray: Ray,
    /// First hit, all hits (optionally limited) or any hit.
    pub mode: RayMode,
    /// Which entities the ray may hit (not reflected: it may hold a
    /// closure).
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    pub filter: SpatialQueryFilter,
    /// Whether the caster's own entity is left out (the default).
    pub ignore_self: bool,
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    _layer: PhantomData<fn() -> L>,
}

impl<L: Component> Clone for RayCaster<L> {
    fn clone(&self) -> Self {
        RayCaster {
            ray: self.ray,
            mode: self.mode,
            filter: self.filter.clone(),
            ignore_self: self.ignore_self,
            _layer: PhantomData,
        }
    }
}

impl<L: Component> std::fmt::Debug for RayCaster<L> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RayCaster")
            .field("ray", &self.ray)
            .field("mode", &self.mode)
            .field("filter", &self.filter)
            .field("ignore_self", &self.ignore_self)
            .finish()
    }
}

impl RayCaster {
    /// A caster against all indexed entities.
    pub fn new(ray: Ray, mode: RayMode) -> Self {
        RayCaster::for_layer(ray, mode)
    }
}

impl<L: Component> RayCaster<L> {
    /// A caster that only hits entities of layer `L` (register the layer
    /// with [`add_spatial_layer`](super::SpatialAppExt::add_spatial_layer)).
    ///
    /// # Panics
    ///
    /// Inserting the caster on an entity panics if the app has not
    /// registered layer `L`: a setup mistake, which would otherwise answer
    /// nothing forever, not bad data.
    pub fn for_layer(ray: Ray, mode: RayMode) -> Self {
        RayCaster {
            ray,
            mode,
            filter: SpatialQueryFilter::default(),
            ignore_self: true,
            _layer: PhantomData,
        }
    }

    /// The same caster with another filter.
    pub fn with_filter(mut self, filter: SpatialQueryFilter) -> Self {
        self.filter = filter;
        self
    }

    /// The same caster, hitting its own entity too if `hit_self`.
    pub fn hitting_self(mut self, hit_self: bool) -> Self {
        self.ignore_self = !hit_self;
        self
    }

    /// Whether the caster on `caster` may hit `entity`.
    #[inline]
    fn allows(&self, caster: Entity, entity: Entity) -> bool {
        !(self.ignore_self && entity == caster) && self.filter.allows(entity)
    }

    /// Whether every entity is allowed (nothing to check after a batch).
    fn allows_all(&self) -> bool {
        !self.ignore_self && self.filter.allows_all()
    }
}

/// This frame's answer for a [`RayCaster<L>`] ([contract S5](crate::contract)).
///
/// One answer per layer: an entity with casters of two layers has a
/// `RayCasterHits<A>` and a `RayCasterHits<B>`. When the entity loses its
/// `RayCaster<L>`, the answer goes too. The answer is the stored result of
/// the frame's cast ([contract S9](crate::contract)): an entity despawned
/// after it is still named until the next cast. A disabled caster (where
/// Bevy's queries leave disabled entities out, as by default) is not
/// cast: its answer is the one from before it was disabled until it is
/// enabled again, as Bevy leaves a disabled camera's `VisibleEntities`,
/// and may name entities despawned since.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let target = app
///     .world_mut()
///     .spawn(SpatialBounds(Aabb::new(Vec3::new(4.0, -1.0, -1.0), Vec3::new(6.0, 1.0, 1.0))?))
///     .id();
/// let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0)?;
/// let eye = app.world_mut().spawn(RayCaster::new(ray, RayMode::First)).id();
/// app.update();
/// let hits = app.world().get::<RayCasterHits>(eye).unwrap();
/// let first = hits.first().unwrap();
/// assert_eq!((first.key, first.t), (target, 4.0));
/// assert_eq!(hits.point(&first), Some(Vec3::new(4.0, 0.0, 0.0)));
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component, Default))]
#[derive(Component)]
pub struct RayCasterHits<L: Component = SpatialBounds> {
    hits: Vec<RayHit<Entity>>,
    any: bool,
    error: Option<SpatialError>,
    /// The ray that was cast, in world space.
    ray: Option<Ray>,
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    _layer: PhantomData<fn() -> L>,
}

impl<L: Component> Default for RayCasterHits<L> {
    fn default() -> Self {
        RayCasterHits {
            hits: Vec::new(),
            any: false,
            error: None,
            ray: None,
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
            ray: self.ray,
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

    /// The ray that was cast this frame, in world space (the caster's ray
    /// carried by its entity's transform, if it has one). A ray invalid as
    /// the caster gave it ([`RayCasterHits::error`] set) is not carried:
    /// it is reported as given, in the caster's own space.
    pub fn ray(&self) -> Option<Ray> {
        self.ray
    }

    /// Where `hit` lies in world space: the cast ray's point at `hit.t`.
    pub fn point(&self, hit: &RayHit<Entity>) -> Option<glam::Vec3> {
        self.ray.map(|ray| ray.point_at(hit.t))
    }
}

/// Scratch reused by the ray system from frame to frame.
#[derive(Default)]
pub(crate) struct RayScratch {
    workspace: FrameWorkspace,
    /// For the casters whose filter turned down a batched answer.
    single: QueryWorkspace,
    modes: Vec<RayMode>,
    rays: Vec<Ray>,
    results: RayResults<Entity>,
}

/// Where a caster is: its `GlobalTransform`, if it has one (feature `bevy`).
#[cfg(feature = "bevy")]
type Placement<'a> = Option<&'a bevy_transform::prelude::GlobalTransform>;
/// Where a caster is: nothing to read without feature `bevy`.
#[cfg(not(feature = "bevy"))]
type Placement<'a> = ();

/// The caster's ray in world space: carried by the entity's transform, with
/// its direction turned (not stretched) and normalised, so that `t` is in
/// metres and `max_t` keeps its length.
///
/// The length is taken in `f64`: in `f32` the squared length of a valid
/// direction overflows beyond about 1.8e19 and vanishes below about 3.7e-23,
/// and either turned the caster's valid ray into an invalid one.
#[cfg(feature = "bevy")]
pub(crate) fn world_ray(ray: &Ray, placement: Placement<'_>) -> Ray {
    let Some(transform) = placement else {
        return *ray;
    };
    // An invalid ray stays as it is, to be reported as such; a valid one
    // loses its subnormal components first, as the index would drop them.
    let Ok(ray) = ray.canonicalized() else {
        return *ray;
    };
    let dir = ray.dir.as_dvec3();
    let length = dir.length();
    let unit = dir / length;
    // Each local axis goes where the transform takes it, at unit length:
    // turned, and mirrored where the transform mirrors (as the origin is),
    // but not stretched. In `f64`, so that a tiny scale (1e-16) neither
    // underflows nor loses its reflection, as a split into scale and
    // rotation in `f32` would; a collapsed axis gives NaN, an invalid ray.
    let m = transform.affine().matrix3.as_dmat3();
    // (Not glam's `normalize`, which panics on such an axis where glam's
    // assertions are on.)
    let unit_of = crate::geometry::unit_or_nan_f64;
    let turned =
        unit_of(m.x_axis) * unit.x + unit_of(m.y_axis) * unit.y + unit_of(m.z_axis) * unit.z;
    Ray {
        origin: transform.transform_point(ray.origin),
        dir: unit_of(turned).as_vec3(),
        max_t: (f64::from(ray.max_t) * length) as f32,
    }
}

/// The caster's ray in world space: as given, without feature `bevy`.
#[cfg(not(feature = "bevy"))]
fn world_ray(ray: &Ray, _: Placement<'_>) -> Ray {
    *ray
}

/// Casts every ray of layer `L`: one batched traversal per distinct mode;
/// then a caster whose filter (or its own entity) turned down what the
/// batch found casts again alone, through the filter.
pub(crate) fn cast_rays<L: Component>(
    index: Res<SpatialIndex<L>>,
    casters: Query<(Entity, &RayCaster<L>, Placement<'_>)>,
    mut answers: Query<&mut RayCasterHits<L>, With<RayCaster<L>>>,
    mut scratch: Local<RayScratch>,
    sink: Res<DiagnosticsSink>,
) {
    let scratch = &mut *scratch;
    let tree = index.tree();
    let (mut cast, mut refused) = (0, 0);
    scratch.modes.clear();
    for (_, caster, _) in &casters {
        if !scratch.modes.contains(&caster.mode) {
            scratch.modes.push(caster.mode);
        }
    }
    for m in 0..scratch.modes.len() {
        let mode = scratch.modes[m];
        scratch.rays.clear();
        for (_, caster, placement) in &casters {
            if caster.mode == mode {
                scratch.rays.push(world_ray(&caster.ray, placement));
            }
        }
        frame_queries::cast_rays(
            tree,
            &scratch.rays,
            mode,
            &mut scratch.workspace,
            &mut scratch.results,
        );
        cast += scratch.rays.len();
        // The casters of this mode again, in the order their rays were
        // gathered (a query walks its rows in the same order within a run).
        let of_mode = casters.iter().filter(|(_, caster, _)| caster.mode == mode);
        for (i, ((entity, caster, _), ray)) in of_mode.zip(&scratch.rays).enumerate() {
            let Ok(mut answer) = answers.get_mut(entity) else {
                continue;
            };
            let answer = &mut *answer;
            answer.ray = Some(*ray);
            answer.hits.clear();
            answer.any = false;
            // Refused last frame too: already logged (once each time a
            // caster's ray becomes refused, kept on the caster itself).
            let refused_before = answer.error.take().is_some();
            let hits = match scratch.results.hits(i) {
                Ok(hits) => hits,
                Err(error) => {
                    answer.error = Some(error);
                    refused += 1;
                    if !refused_before {
                        log::warn!(
                            "{entity}: its RayCaster's ray is refused in world space ({error}): \
                             a zero scale or a NaN transform? Its RayCasterHits holds the error"
                        );
                    }
                    continue;
                }
            };
            let any = scratch.results.any(i).unwrap_or(false);
            // A mode that reports no hit (any-hit, or all hits with a limit
            // of none) cannot show which entity `any` came from.
            let hides_hits = matches!(mode, RayMode::Any | RayMode::All { limit: Some(0) });
            let turned_down = !caster.allows_all()
                && if hides_hits {
                    any
                } else {
                    hits.iter().any(|h| !caster.allows(entity, h.key))
                };
            if !turned_down {
                answer.hits.extend_from_slice(hits);
                answer.any = any;
                continue;
            }
            let allow = |e| caster.allows(entity, e);
            let ws = &mut scratch.single;
            // The ray was accepted by the batch, so it is valid here too.
            match mode {
                RayMode::First => {
                    answer
                        .hits
                        .extend(tree.cast_ray_where(ray, ws, allow).ok().flatten());
                    answer.any = !answer.hits.is_empty();
                }
                // No hit listed: only whether an allowed one exists, in one
                // walk.
                RayMode::Any | RayMode::All { limit: Some(0) } => {
                    answer.any = tree.ray_hits_any_where(ray, ws, allow).unwrap_or(false);
                }
                RayMode::All { limit } => {
                    let _ = tree.cast_ray_all_where(ray, limit, ws, &mut answer.hits, allow);
                    answer.any = !answer.hits.is_empty();
                }
            }
        }
    }
    // One run, whatever modes its casters use; the walks of the casters
    // cast again through their filters are part of its work.
    sink.add(|d| {
        d.rays.record(cast, &mut scratch.workspace);
        d.rays.add_walks(&mut scratch.single);
        d.rays.refused += refused;
    });
}
