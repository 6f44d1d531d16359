//! `SpatialQuery`: immediate queries on a layer's index from any system.

use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;

use super::bounds::SpatialBounds;
use super::index::SpatialIndex;
use glam::Vec3;

use crate::geometry::{Aabb, Ray, SpatialError};
use crate::query::{Neighbor, QueryWorkspace, RayHit};

/// A system parameter for queries on the index of layer `L` (all indexed
/// entities by default), answered at once, with a workspace kept by the
/// system so repeated queries do not allocate.
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
/// use bevy_rtree::plugin::{SpatialBounds, SpatialIndexPlugin, SpatialIndexSystems, SpatialQuery};
/// use glam::Vec3;
///
/// #[derive(Resource, Default)]
/// struct Seen(Option<Entity>);
///
/// fn look(mut spatial: SpatialQuery, mut seen: ResMut<Seen>) {
///     let ray = Ray::new(Vec3::ZERO, Vec3::X, 100.0).unwrap();
///     seen.0 = spatial.cast_ray(&ray).ok().flatten().map(|hit| hit.key);
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

    /// The nearest hit of `ray` ([contract S5](crate::contract)).
    pub fn cast_ray(&mut self, ray: &Ray) -> Result<Option<RayHit<Entity>>, SpatialError> {
        self.index.tree().cast_ray(ray, &mut self.workspace)
    }

    /// Every hit of `ray`, sorted by `(t, entity)`, at most `limit` if given.
    pub fn cast_ray_all(
        &mut self,
        ray: &Ray,
        limit: Option<usize>,
        out: &mut Vec<RayHit<Entity>>,
    ) -> Result<(), SpatialError> {
        self.index
            .tree()
            .cast_ray_all(ray, limit, &mut self.workspace, out)
    }

    /// Whether `ray` hits anything (line of sight, occlusion).
    pub fn ray_hits_any(&mut self, ray: &Ray) -> Result<bool, SpatialError> {
        self.index.tree().ray_hits_any(ray, &mut self.workspace)
    }

    /// Appends the entities whose box overlaps `query` (closed boxes) to
    /// `out`, unordered. An invalid query box matches nothing.
    pub fn overlapping(&mut self, query: &Aabb, out: &mut Vec<Entity>) {
        self.index
            .tree()
            .overlapping_into(query, &mut self.workspace, out);
    }

    /// Appends the entities whose box meets the closed sphere to `out`,
    /// unordered.
    pub fn overlapping_sphere(
        &mut self,
        center: Vec3,
        radius: f32,
        out: &mut Vec<Entity>,
    ) -> Result<(), SpatialError> {
        self.index
            .tree()
            .overlapping_sphere_into(center, radius, &mut self.workspace, out)
    }

    /// The `k` entities nearest to `point` (box distance, 0 inside), at most
    /// `max_distance` away if given, sorted by `(distance, entity)`, into
    /// `out` (cleared first).
    pub fn nearest(
        &mut self,
        point: Vec3,
        k: usize,
        max_distance: Option<f32>,
        out: &mut Vec<Neighbor<Entity>>,
    ) -> Result<(), SpatialError> {
        self.index
            .tree()
            .nearest_into(point, k, max_distance, &mut self.workspace, out)
    }

    /// Every entity within `radius` of `point`, sorted by
    /// `(distance, entity)`, into `out` (cleared first).
    pub fn within_radius(
        &mut self,
        point: Vec3,
        radius: f32,
        out: &mut Vec<Neighbor<Entity>>,
    ) -> Result<(), SpatialError> {
        self.index
            .tree()
            .within_radius_into(point, radius, &mut self.workspace, out)
    }
}
