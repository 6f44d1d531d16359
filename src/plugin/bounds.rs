//! The components that put an entity into the index.

use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
#[cfg(feature = "reflect")]
use bevy_reflect::std_traits::ReflectDefault;

use crate::geometry::Aabb;

/// The entity's world box; adding it puts the entity into the index.
///
/// Set it yourself (or, with the `bevy` feature, let `LocalBounds` derive it
/// from the `GlobalTransform`). Only entities whose `SpatialBounds` changed since the
/// last frame touch the index, as Bevy's change detection tells: a write
/// through `bypass_change_detection` is not seen until the next detected
/// one. Removing the component, or despawning the
/// entity, takes it out of every index at once, before any later query.
///
/// A box that is not valid (NaN, infinite, inverted, beyond
/// [`MAX_COORD`](crate::MAX_COORD)) takes the entity *out* of the index until
/// it gets a valid box again: an entity whose position is unknown is found by
/// no query. A warning names the entity once per `SpatialBounds`
/// component: not again when the box is set invalid again, nor when the
/// entity is disabled or opted out and comes back with it, but again after
/// the component was removed and inserted anew (a `LocalBounds` removed
/// and inserted again keeps its `SpatialBounds`, and its warning).
/// [`SpatialDiagnostics`](crate::plugin::SpatialDiagnostics) counts every
/// time the sync skips an invalid box (each time one is set, and when an
/// entity comes back with one). The default box
/// (`SpatialBounds::default()`, [`Aabb::INVERTED`]) is a placeholder: the
/// entity is left out until a valid box is set, with no warning and no
/// count.
///
/// ```
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::{Aabb, plugin::SpatialBounds};
/// use bevy_rtree::glam::Vec3;
///
/// let mut world = World::new();
/// let bounds = SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?);
/// let entity = world.spawn(bounds).id();
/// assert_eq!(world.get::<SpatialBounds>(entity), Some(&bounds));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(
    feature = "reflect",
    reflect(Component, Default, Debug, PartialEq, Clone)
)]
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[require(SpatialHandle)]
pub struct SpatialBounds(pub Aabb);

/// The entity's handle in the main index ([`SpatialIndex`](super::SpatialIndex)),
/// kept on the entity by the plugin (every entity with [`SpatialBounds`]
/// has one, as a required component): a changed box then finds its entry
/// without looking the entity up. A stale handle (the entity left and came
/// back) is refused by the index and costs only that look-up.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
/// use bevy_rtree::plugin::SpatialHandle;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// let crate_box = app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?)).id();
/// app.update();
/// let id = app.world().get::<SpatialHandle>(crate_box).unwrap().id().unwrap();
/// let index = app.world().resource::<SpatialIndex>();
/// assert_eq!(index.tree().get(id)?.0, crate_box);
/// # Ok::<(), SpatialError>(())
/// ```
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpatialHandle(pub(crate) Option<crate::tree::ProxyId>);

impl SpatialHandle {
    /// The entity's handle in the main index's tree, once indexed.
    pub fn id(self) -> Option<crate::tree::ProxyId> {
        self.0
    }
}

impl Default for SpatialBounds {
    /// An inverted box, the placeholder for "no box yet": not indexed until
    /// a valid box is set, and neither warned about nor counted.
    fn default() -> Self {
        SpatialBounds(Aabb::INVERTED)
    }
}

/// Opt-out: an entity with this marker is in no index, whatever its
/// [`SpatialBounds`]. Removing the marker puts it back on the next frame.
///
/// ```
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::plugin::{NoSpatialIndex, SpatialBounds};
///
/// let mut world = World::new();
/// let hidden = world.spawn((SpatialBounds::default(), NoSpatialIndex)).id();
/// assert!(world.get::<NoSpatialIndex>(hidden).is_some());
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(
    feature = "reflect",
    reflect(Component, Default, Debug, PartialEq, Clone)
)]
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NoSpatialIndex;
