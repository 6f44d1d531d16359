//! Frustum culling for cameras: every frame, each culling camera gets the
//! sorted list of the entities it sees, all cameras in one traversal.

use super::frame_queries::{self, FrameWorkspace};
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
#[cfg(feature = "reflect")]
use bevy_reflect::std_traits::ReflectDefault;
use std::marker::PhantomData;

use bevy_ecs::prelude::*;
use glam::{Quat, Vec3};

use super::bounds::SpatialBounds;
use super::diagnostics::DiagnosticsSink;
use super::index::SpatialIndex;
use crate::geometry::{Frustum, SpatialError};
use crate::query::CullMode;

/// A view whose visible entities of layer `L` (all indexed entities by
/// default) are listed in its [`VisibleEntityList`] every frame.
///
/// Culling runs only while at least one `CullingCamera<L>` exists; all
/// cameras of a layer share one traversal of the tree (per eight cameras and
/// per [`CullMode`]). A camera on an entity whose Bevy `Camera` is inactive
/// (`is_active: false`, feature `bevy_camera`) is skipped and keeps its
/// last list, as Bevy skips it.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::Aabb;
/// use bevy_rtree::plugin::{CullingCamera, SpatialBounds, SpatialIndexPlugin, VisibleEntityList};
/// use bevy_rtree::glam::{Quat, Vec3};
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// // Bevy's cameras look down -Z.
/// let ahead = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::new(0.0, 0.0, -11.0), Vec3::new(1.0, 1.0, -10.0))?)).id();
/// let behind = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::new(0.0, 0.0, 10.0), Vec3::new(1.0, 1.0, 11.0))?)).id();
/// let camera = CullingCamera::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 16.0 / 9.0, 0.1, 100.0)?;
/// let camera = app.world_mut().spawn(camera).id();
/// app.update();
/// let visible = app.world().get::<VisibleEntityList>(camera).unwrap();
/// assert_eq!(visible.entities(), [ahead]);
/// # let _ = behind;
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
#[derive(Component)]
#[require(VisibleEntityList<L>)]
#[component(on_add = super::layer_must_be_registered::<L>)]
pub struct CullingCamera<L: Component = SpatialBounds> {
    /// The view volume, relative to its eye ([contract S7](crate::contract)).
    pub frustum: Frustum,
    /// Conservative (Bevy's convention, the default) or exact.
    pub mode: CullMode,
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    _layer: PhantomData<fn() -> L>,
}

impl_layer_generic_traits!(CullingCamera<L> { frustum, mode });

impl CullingCamera {
    /// A camera over all indexed entities.
    pub fn new(frustum: Frustum) -> Self {
        CullingCamera::for_layer(frustum)
    }

    /// A perspective camera over all indexed entities, looking down its local
    /// `-Z` (see [`Frustum::perspective`]).
    pub fn perspective(
        eye: Vec3,
        rotation: Quat,
        fov_y: f32,
        aspect: f32,
        near: f32,
        far: f32,
    ) -> Result<Self, SpatialError> {
        Ok(CullingCamera::new(Frustum::perspective(
            eye, rotation, fov_y, aspect, near, far,
        )?))
    }
}

impl<L: Component> CullingCamera<L> {
    /// A camera that sees only the entities of layer `L` (register the layer
    /// with [`add_spatial_layer`](super::SpatialAppExt::add_spatial_layer)).
    ///
    /// # Panics
    ///
    /// Inserting the camera on an entity panics if the app has not
    /// registered layer `L`: a setup mistake, which would otherwise answer
    /// nothing forever, not bad data.
    pub fn for_layer(frustum: Frustum) -> Self {
        CullingCamera {
            frustum,
            mode: CullMode::Conservative,
            _layer: PhantomData,
        }
    }

    /// The same camera with another [`CullMode`].
    pub fn with_mode(mut self, mode: CullMode) -> Self {
        self.mode = mode;
        self
    }
}

/// The entities a [`CullingCamera<L>`] saw this frame, sorted by [`Entity`].
///
/// One list per layer: a camera entity that culls two layers has a
/// `VisibleEntityList<A>` and a `VisibleEntityList<B>`. Refreshed every
/// frame in
/// [`SpatialIndexSystems::Queries`](super::SpatialIndexSystems::Queries); the
/// list's allocation is reused from frame to frame. When the entity loses
/// its `CullingCamera<L>`, the list goes too. The list is the stored answer
/// of the frame's cull ([contract S9](crate::contract)): an entity despawned
/// after it is still named until the next cull. A disabled camera (where
/// Bevy's queries leave disabled entities out, as by default) or an
/// inactive one does not cull: its list is the one from before it was disabled
/// until it is enabled again, as Bevy leaves a disabled camera's
/// `VisibleEntities`, and may name entities despawned since.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let ahead = Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, -5.0), Vec3::splat(0.5))?;
/// let crate_box = app.world_mut().spawn(SpatialBounds(ahead)).id();
/// let frustum = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0)?;
/// let camera = app.world_mut().spawn(CullingCamera::new(frustum)).id();
/// app.update();
/// let list = app.world().get::<VisibleEntityList>(camera).unwrap();
/// assert!(list.contains(crate_box));
/// assert_eq!(list.entities(), &[crate_box]);
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component, Default))]
#[derive(Component)]
pub struct VisibleEntityList<L: Component = SpatialBounds> {
    entities: Vec<Entity>,
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    _layer: PhantomData<fn() -> L>,
}

impl<L: Component> Default for VisibleEntityList<L> {
    fn default() -> Self {
        VisibleEntityList {
            entities: Vec::new(),
            _layer: PhantomData,
        }
    }
}

impl<L: Component> Clone for VisibleEntityList<L> {
    fn clone(&self) -> Self {
        VisibleEntityList {
            entities: self.entities.clone(),
            _layer: PhantomData,
        }
    }
}

impl<L: Component> std::fmt::Debug for VisibleEntityList<L> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VisibleEntityList")
            .field("entities", &self.entities)
            .finish()
    }
}

impl<L: Component> PartialEq for VisibleEntityList<L> {
    fn eq(&self, other: &Self) -> bool {
        self.entities == other.entities
    }
}

impl<L: Component> Eq for VisibleEntityList<L> {}

impl<L: Component> VisibleEntityList<L> {
    /// The visible entities, sorted.
    pub fn entities(&self) -> &[Entity] {
        &self.entities
    }

    /// Whether `entity` is in the list (binary search).
    pub fn contains(&self, entity: Entity) -> bool {
        self.entities.binary_search(&entity).is_ok()
    }
}

/// Scratch reused by the culling system from frame to frame.
#[derive(Default)]
pub(crate) struct CullingScratch {
    workspace: FrameWorkspace,
    frustums: Vec<Frustum>,
    lists: Vec<Vec<Entity>>,
    cameras: Vec<Entity>,
}

/// Culls every camera of layer `L`: one traversal per mode (and per eight
/// cameras), then each camera's list is sorted and swapped into place.
pub(crate) fn cull_cameras<L: Component>(
    index: Res<SpatialIndex<L>>,
    cameras: Query<(Entity, &CullingCamera<L>)>,
    mut lists: Query<&mut VisibleEntityList<L>, With<CullingCamera<L>>>,
    #[cfg(feature = "bevy_camera")] bevy_cameras: Query<
        &bevy_camera::Camera,
        With<CullingCamera<L>>,
    >,
    mut scratch: Local<CullingScratch>,
    sink: Res<DiagnosticsSink>,
) {
    // A camera on an entity whose Bevy camera is inactive is skipped and
    // keeps its list, as Bevy skips an inactive camera.
    let skipped = |entity: Entity| {
        #[cfg(feature = "bevy_camera")]
        return bevy_cameras.get(entity).is_ok_and(|c| !c.is_active);
        #[cfg(not(feature = "bevy_camera"))]
        {
            let _ = entity;
            false
        }
    };
    let scratch = &mut *scratch;
    let mut culled = 0;
    for mode in [CullMode::Conservative, CullMode::Exact] {
        scratch.frustums.clear();
        scratch.cameras.clear();
        for (entity, camera) in &cameras {
            if camera.mode == mode && !skipped(entity) {
                scratch.frustums.push(camera.frustum);
                scratch.cameras.push(entity);
            }
        }
        if scratch.cameras.is_empty() {
            continue;
        }
        let views = scratch.cameras.len();
        let out = &mut scratch.lists;
        out.iter_mut().for_each(Vec::clear);
        let (tree, frustums) = (index.tree(), &scratch.frustums);
        frame_queries::visible_into(tree, frustums, mode, &mut scratch.workspace, out);
        culled += views;
        for (view, &camera) in scratch.cameras.iter().enumerate() {
            out[view].sort_unstable();
            if let Ok(mut list) = lists.get_mut(camera) {
                std::mem::swap(&mut list.entities, &mut out[view]);
            }
        }
    }
    // One run, whatever modes its cameras use (none, if every camera was
    // skipped); the workspace summed both.
    if culled > 0 {
        sink.add(|d| d.culling.record(culled, &mut scratch.workspace));
    }
}
