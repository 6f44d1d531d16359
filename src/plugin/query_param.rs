//! `SpatialQuery`: immediate queries on a layer's index from any system.

use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;

use super::bounds::SpatialBounds;
use super::index::SpatialIndex;
use glam::Vec3;

use std::ops::ControlFlow;

use super::filter::SpatialQueryFilter;
use crate::geometry::{Aabb, Ray, SpatialError};
use crate::query::{Neighbor, QueryWorkspace, RayHit};

/// A system parameter for queries on the index of layer `L` (all indexed
/// entities by default), answered at once, with a workspace kept by the
/// system so repeated queries do not allocate. Every query takes a
/// [`SpatialQueryFilter`]: the entities it excludes (the asking entity's
/// own, say) and a predicate; `&SpatialQueryFilter::default()` allows all.
///
/// The index is current after
/// [`SpatialIndexSystems::Sync`](super::SpatialIndexSystems::Sync); order
/// systems that need this frame's boxes after it. For everything else, see
/// [`index`](Self::index) and the core [`RTree`](crate::RTree) API.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::{Aabb, Ray};
/// use bevy_rtree::plugin::{
///     SpatialBounds, SpatialIndexPlugin, SpatialIndexSystems, SpatialQuery, SpatialQueryFilter,
/// };
/// use bevy_rtree::glam::Vec3;
///
/// #[derive(Resource, Default)]
/// struct Seen(Option<Entity>);
///
/// fn look(mut spatial: SpatialQuery, mut seen: ResMut<Seen>) {
///     let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0).unwrap();
///     let everything = SpatialQueryFilter::default();
///     seen.0 = spatial.cast_ray(&ray, &everything).ok().flatten().map(|hit| hit.key);
/// }
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default())
///     .init_resource::<Seen>()
///     .add_systems(PostUpdate, look.after(SpatialIndexSystems::Sync));
/// let wall = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::new(3.0, -1.0, -1.0), Vec3::new(4.0, 1.0, 1.0))?)).id();
/// app.update();
/// assert_eq!(app.world().resource::<Seen>().0, Some(wall));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[derive(SystemParam)]
pub struct SpatialQuery<'w, 's, L: Component = SpatialBounds> {
    index: Res<'w, SpatialIndex<L>>,
    workspace: Local<'s, QueryWorkspace>,
}

impl<L: Component> SpatialQuery<'_, '_, L> {
    /// The layer's index (and through it the whole core API).
    pub fn index(&self) -> &SpatialIndex<L> {
        &self.index
    }

    /// The nearest hit of `ray` among the entities `filter` allows
    /// ([contract S5](crate::contract)).
    pub fn cast_ray(
        &mut self,
        ray: &Ray,
        filter: &SpatialQueryFilter,
    ) -> Result<Option<RayHit<Entity>>, SpatialError> {
        let tree = self.index.tree();
        tree.cast_ray_where(ray, &mut self.workspace, |e| filter.allows(e))
    }

    /// Every hit of `ray` among the entities `filter` allows, sorted by
    /// `(t, entity)`, at most `limit` if given.
    pub fn cast_ray_all(
        &mut self,
        ray: &Ray,
        limit: Option<usize>,
        filter: &SpatialQueryFilter,
        out: &mut Vec<RayHit<Entity>>,
    ) -> Result<(), SpatialError> {
        let tree = self.index.tree();
        tree.cast_ray_all_where(ray, limit, &mut self.workspace, out, |e| filter.allows(e))
    }

    /// Whether `ray` hits an entity `filter` allows (line of sight,
    /// occlusion).
    pub fn ray_hits_any(
        &mut self,
        ray: &Ray,
        filter: &SpatialQueryFilter,
    ) -> Result<bool, SpatialError> {
        let tree = self.index.tree();
        tree.ray_hits_any_where(ray, &mut self.workspace, |e| filter.allows(e))
    }

    /// The entities `filter` allows whose box overlaps `query` (closed
    /// boxes), unordered, into `out` (cleared first). An invalid query box
    /// (one built without [`Aabb::new`]'s check) matches nothing.
    pub fn overlapping(
        &mut self,
        query: &Aabb,
        filter: &SpatialQueryFilter,
        out: &mut Vec<Entity>,
    ) {
        out.clear();
        self.index
            .tree()
            .visit_overlapping(query, &mut self.workspace, |entity, _| {
                if filter.allows(entity) {
                    out.push(entity);
                }
                ControlFlow::Continue(())
            });
    }

    /// The entities `filter` allows whose box meets the closed sphere,
    /// unordered, into `out` (cleared first; a refused sphere leaves it as
    /// it was, as every query of the crate does).
    pub fn overlapping_sphere(
        &mut self,
        center: Vec3,
        radius: f32,
        filter: &SpatialQueryFilter,
        out: &mut Vec<Entity>,
    ) -> Result<(), SpatialError> {
        // Refused before `out` is touched.
        crate::geometry::predicates::check_point(center)?;
        crate::geometry::predicates::check_distance(radius)?;
        out.clear();
        self.index
            .tree()
            .visit_sphere(center, radius, &mut self.workspace, |entity, _, _| {
                if filter.allows(entity) {
                    out.push(entity);
                }
                ControlFlow::Continue(())
            })
    }

    /// The `k` entities `filter` allows nearest to `point` (box distance, 0
    /// inside), at most `max_distance` away if given, sorted by
    /// `(distance_sq, entity)`, into `out` (cleared first).
    pub fn nearest(
        &mut self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
        filter: &SpatialQueryFilter,
        out: &mut Vec<Neighbor<Entity>>,
    ) -> Result<(), SpatialError> {
        let tree = self.index.tree();
        let ws = &mut self.workspace;
        tree.nearest_where_into(point, k, max_distance, ws, out, |e| filter.allows(e))
    }

    /// Every entity `filter` allows within `radius` of `point`, sorted by
    /// `(distance_sq, entity)`, into `out` (cleared first).
    pub fn within_radius(
        &mut self,
        point: Vec3,
        radius: f32,
        filter: &SpatialQueryFilter,
        out: &mut Vec<Neighbor<Entity>>,
    ) -> Result<(), SpatialError> {
        self.index
            .tree()
            .within_radius_into(point, radius, &mut self.workspace, out)?;
        out.retain(|n| filter.allows(n.key));
        Ok(())
    }
}
