//! The bevy_ecs / bevy_app integration: [`SpatialIndexPlugin`].
//!
//! Add the plugin, give entities a [`SpatialBounds`], and every frame read:
//! - the visible entities of each [`CullingCamera`] in its
//!   [`VisibleEntityList`];
//! - the hits of each [`RayCaster`] in its [`RayCasterHits`];
//! - the pairs of each join registered with
//!   [`add_spatial_join`](SpatialAppExt::add_spatial_join) in its
//!   [`SpatialJoin`] resource, with [`PairStarted`] / [`PairEnded`] messages;
//! - anything else through the [`SpatialQuery`] system parameter.
//!
//! Layers are marker components registered with
//! [`add_spatial_layer`](SpatialAppExt::add_spatial_layer): each layer keeps
//! its own tree, so a query or join limited to a layer visits nothing else.
//!
//! The plugin runs only what the scene calls for: culling only while a
//! culling camera exists, rays only while a caster exists, a join only while
//! both its layers have entities and one of them changed, leaf repair only
//! where churn left work. [`SpatialDiagnostics`] shows what ran each frame.
//!
//! ```
//! use bevy_app::prelude::*;
//! use bevy_ecs::prelude::*;
//! use bevy_rtree::{Aabb, Ray, RayMode};
//! use bevy_rtree::plugin::*;
//! use bevy_rtree::glam::Vec3;
//!
//! let mut app = App::new();
//! app.add_plugins(SpatialIndexPlugin::default());
//! let crate_box = SpatialBounds(Aabb::new(Vec3::new(4.0, -1.0, -1.0), Vec3::new(5.0, 1.0, 1.0))?);
//! let target = app.world_mut().spawn(crate_box).id();
//! let eye = app.world_mut().spawn(RayCaster::new(Ray::new(Vec3::ZERO, Vec3::X, 10.0)?, RayMode::First)).id();
//! app.update();
//! assert_eq!(app.world().get::<RayCasterHits>(eye).unwrap().first().map(|h| h.key), Some(target));
//! # Ok::<(), bevy_rtree::SpatialError>(())
//! ```

/// `Clone`, `Copy` and `Debug` for types generic over layer markers, which
/// derives would only give when the markers themselves implement them.
macro_rules! impl_layer_generic_traits {
    ($ty:ident<$($layer:ident),+> { $($field:ident),* }) => {
        impl<$($layer: Component),+> Clone for $ty<$($layer),+> {
            fn clone(&self) -> Self {
                *self
            }
        }
        impl<$($layer: Component),+> Copy for $ty<$($layer),+> {}
        impl<$($layer: Component),+> std::fmt::Debug for $ty<$($layer),+> {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.debug_struct(stringify!($ty))
                    $(.field(stringify!($field), &self.$field))*
                    .finish()
            }
        }
    };
}

#[cfg(feature = "bevy_camera")]
mod bevy_camera;
#[cfg(feature = "bevy_camera")]
mod bevy_visibility;
mod bounds;
mod change_scan;
mod culling;
mod diagnostics;
mod disabling;
mod filter;
mod frame_queries;
mod index;
mod join;
mod maintenance;
mod move_order;
mod oracle;
mod query_param;
mod raycast;
#[cfg(feature = "bevy")]
mod transform;

use bevy_app::prelude::*;
use bevy_ecs::change_detection::CheckChangeTicks;
use bevy_ecs::entity_disabling::{DefaultQueryFilters, Disabled};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{InternedScheduleLabel, ScheduleLabel};

#[cfg(feature = "bevy_camera")]
pub use bevy_camera::FollowBevyFrustum;
#[cfg(feature = "bevy_camera")]
pub use bevy_visibility::{
    BevyVisibilityPlugin, BevyVisibilitySettings, Renderable, RenderableHandle,
    RenderableSyncSystems,
};
pub use bounds::{NoSpatialIndex, SpatialBounds, SpatialHandle};
pub use culling::{CullingCamera, VisibleEntityList};
pub use diagnostics::{
    BevyVisibilityWork, MaintenanceWork, QueryWork, SpatialDiagnostics, SyncWork,
};
pub use filter::SpatialQueryFilter;
pub use index::SpatialIndex;
pub use join::{PairEnded, PairStarted, SpatialJoin};
pub use maintenance::RebuildMode;
pub use oracle::layer_oracle;
pub use query_param::SpatialQuery;
pub use raycast::{RayCaster, RayCasterHits};
#[cfg(feature = "bevy")]
pub use transform::LocalBounds;

use crate::query::JoinMode;
use crate::tree::TreeSettings;
use diagnostics::DiagnosticsSink;

/// Maintains one spatial index per layer and answers the frame's culling,
/// raycasts and joins.
///
/// Every index is an [`RTree`](crate::RTree) of the default width keyed by
/// [`Entity`].
///
/// The plugin's resources ([`SpatialIndex<L>`](SpatialIndex),
/// [`SpatialJoin<A, B>`](SpatialJoin), [`SpatialDiagnostics`]) live as long
/// as the App, as those of Bevy's own plugins do: its systems and observers
/// expect them and fail, as Bevy's do, if one is removed.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::TreeSettings;
/// use bevy_rtree::plugin::SpatialIndexPlugin;
///
/// App::new().add_plugins(SpatialIndexPlugin {
///     tree: TreeSettings { margin: 0.25, ..TreeSettings::default() },
///     ..SpatialIndexPlugin::default()
/// });
/// ```
#[derive(Clone, Debug)]
pub struct SpatialIndexPlugin {
    /// The enlarging policy and the other tree settings, for every layer. If
    /// they are invalid, a warning is logged and the defaults are used.
    pub tree: TreeSettings,
    /// The schedule the plugin's systems run in: `PostUpdate` by default, so
    /// that this frame's moves (and, with the `bevy` feature, transform
    /// propagation) come first. A system in `Update` then queries the boxes
    /// as the last frame ended, as it reads `GlobalTransform`; with
    /// `PostUpdate`, the entities spawned at startup are also indexed in
    /// `PostStartup`, so the first frame's queries see them. In a schedule
    /// before transform propagation (`Update`), world boxes from
    /// `LocalBounds` and casters on a transform read the `GlobalTransform`
    /// the last propagation wrote: an entity spawned earlier in the same
    /// frame still has the default one, so for that frame it is indexed
    /// (or casts) at the origin.
    pub schedule: InternedScheduleLabel,
    /// Most churned nodes re-tiled per layer per frame; bounds the cost of
    /// repair in any one frame (0 turns repair off).
    pub optimize_budget: usize,
    /// Whether and how each layer's tree is rebuilt when the changes since
    /// its last rebuild reach a quarter of its entries, so that it stays
    /// near the speed of a fresh one in long sessions: on Bevy's async
    /// task pool by default where the app has one and the feature
    /// `parallel` is on, off otherwise; see [`RebuildMode`].
    pub rebuild: RebuildMode,
}

impl Default for SpatialIndexPlugin {
    fn default() -> Self {
        SpatialIndexPlugin {
            tree: TreeSettings::default(),
            schedule: PostUpdate.intern(),
            optimize_budget: 64,
            rebuild: RebuildMode::default(),
        }
    }
}

/// The plugin's settings as the layers registered later read them.
#[derive(Resource, Clone, Debug)]
pub(crate) struct SpatialIndexConfig {
    tree: TreeSettings,
    schedule: InternedScheduleLabel,
    optimize_budget: usize,
    rebuild: RebuildMode,
}

/// The plugin's system sets, run in this order in the plugin's schedule.
/// Order your systems against them: e.g. move entities before `Bounds`, read
/// visible lists, hits and pairs after `Queries`.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// #[derive(Component)]
/// struct Mover;
///
/// fn step(mut movers: Query<&mut SpatialBounds, With<Mover>>) {
///     for mut bounds in &mut movers {
///         let b = bounds.0;
///         bounds.0 = Aabb { min: b.min + Vec3::X, max: b.max + Vec3::X };
///     }
/// }
/// fn read(cameras: Query<&VisibleEntityList>) {
///     for list in &cameras {
///         println!("{} visible", list.entities().len());
///     }
/// }
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default()).add_systems(
///     PostUpdate,
///     (
///         step.before(SpatialIndexSystems::Bounds),
///         read.after(SpatialIndexSystems::Queries),
///     ),
/// );
/// app.world_mut().spawn((SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?), Mover));
/// app.update();
/// # Ok::<(), SpatialError>(())
/// ```
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SpatialIndexSystems {
    /// World boxes from transforms (feature `bevy`).
    Bounds,
    /// Changed boxes into the indexes.
    Sync,
    /// Repair of leaves degraded by churn.
    Maintain,
    /// Culling, raycasts and joins.
    Queries,
}

impl Plugin for SpatialIndexPlugin {
    fn build(&self, app: &mut App) {
        let tree = match self.tree.validate() {
            Ok(()) => self.tree,
            Err(error) => {
                log::warn!(
                    "SpatialIndexPlugin: invalid tree settings ({error}); using the defaults"
                );
                TreeSettings::default()
            }
        };
        app.insert_resource(SpatialIndexConfig {
            tree,
            schedule: self.schedule,
            optimize_budget: self.optimize_budget,
            rebuild: self.rebuild,
        })
        .init_resource::<SpatialDiagnostics>()
        .init_resource::<DiagnosticsSink>()
        .configure_sets(
            self.schedule,
            (
                SpatialIndexSystems::Bounds,
                SpatialIndexSystems::Sync,
                SpatialIndexSystems::Maintain,
                SpatialIndexSystems::Queries,
            )
                .chain(),
        )
        // After the queries, should the plugin's schedule be `Last` too.
        .add_systems(
            Last,
            diagnostics::publish_diagnostics.after(SpatialIndexSystems::Queries),
        )
        .add_observer(opt_back_in)
        .add_observer(enabled_again)
        .add_observer(index::put_handle_back);
        if self.schedule == PostUpdate.intern() {
            // The boxes of entities spawned at startup are indexed before
            // the first frame, so that the first frame's queries see them.
            app.configure_sets(
                PostStartup,
                (SpatialIndexSystems::Bounds, SpatialIndexSystems::Sync).chain(),
            );
        }
        #[cfg(feature = "reflect")]
        app.register_type::<SpatialBounds>()
            .register_type::<NoSpatialIndex>()
            .register_type::<CullingCamera>()
            .register_type::<VisibleEntityList>()
            .register_type::<RayCaster>()
            .register_type::<RayCasterHits>()
            .register_type::<SpatialDiagnostics>()
            // Reached by no registered field (`Frustum` is opaque; joins
            // are not components): registered for scripts and inspectors.
            .register_type::<crate::geometry::HalfSpace>()
            .register_type::<crate::query::JoinMode>();
        #[cfg(feature = "bevy")]
        transform::build(app, self.schedule);
        #[cfg(feature = "bevy_camera")]
        bevy_camera::build(app, self.schedule);
        app.add_spatial_layer::<SpatialBounds>();
    }
}

/// Registration of layers and joins on an [`App`].
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::prelude::*;
///
/// #[derive(Component)]
/// struct Wall;
/// #[derive(Component)]
/// struct Enemy;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default())
///     .add_spatial_layer::<Wall>()
///     .add_spatial_join::<Enemy, Enemy>(2.0, JoinMode::Euclidean);
/// let wall = app
///     .world_mut()
///     .spawn((SpatialBounds(Aabb::new(Vec3::new(-5.0, 0.0, -3.0), Vec3::new(5.0, 3.0, -2.0))?), Wall))
///     .id();
/// let ray = Ray::new(Vec3::new(0.0, 1.0, 0.0), Vec3::NEG_Z, 50.0)?;
/// let eye = app.world_mut().spawn(RayCaster::<Wall>::for_layer(ray, RayMode::First)).id();
/// app.update();
/// let hits = app.world().get::<RayCasterHits<Wall>>(eye).unwrap();
/// assert_eq!(hits.first().map(|h| h.key), Some(wall));
/// # Ok::<(), SpatialError>(())
/// ```
pub trait SpatialAppExt {
    /// Keeps a separate index of the entities marked `L` (with
    /// [`SpatialBounds`]), readable as `Res<SpatialIndex<L>>` and usable by
    /// `CullingCamera<L>`, `RayCaster<L>`, `SpatialQuery<L>` and joins.
    /// Registering a layer twice does nothing.
    ///
    /// # Panics
    ///
    /// If [`SpatialIndexPlugin`] has not been added yet: the layer would
    /// otherwise be built with settings the plugin added later could not
    /// change. With feature `bevy_camera`, also for the renderables' layer
    /// (`Renderable`) before `BevyVisibilityPlugin`, which registers it.
    fn add_spatial_layer<L: Component>(&mut self) -> &mut Self;

    /// Computes, every frame, the pairs of layer `A` × layer `B` within
    /// `distance` (a self join when `A == B`), into the resource
    /// [`SpatialJoin<A, B>`], with [`PairStarted<A, B>`] and
    /// [`PairEnded<A, B>`] messages. Registers both layers. Registering the
    /// same join again replaces its distance and mode.
    fn add_spatial_join<A: Component, B: Component>(
        &mut self,
        distance: f32,
        mode: JoinMode,
    ) -> &mut Self;
}

impl SpatialAppExt for App {
    fn add_spatial_layer<L: Component>(&mut self) -> &mut Self {
        if self.world().contains_resource::<index::SpatialIndex<L>>() {
            return self;
        }
        let Some(config) = self.world().get_resource::<SpatialIndexConfig>().cloned() else {
            panic!(
                "add_spatial_layer::<{}> (or add_spatial_join) before SpatialIndexPlugin: \
                 add the plugin first, as in \
                 app.add_plugins(SpatialIndexPlugin::default()).add_spatial_layer::<L>()",
                std::any::type_name::<L>()
            );
        };
        // The renderables' layer is filled from Bevy's own components by
        // `BevyVisibilityPlugin`, which registers it; a generic layer of
        // that name would add a second set of systems and observers over
        // the same index (entries taken out by `NoSpatialIndex`, two
        // maintenance systems cancelling each other's rebuilds).
        #[cfg(feature = "bevy_camera")]
        if std::any::TypeId::of::<L>() == std::any::TypeId::of::<bevy_visibility::Renderable>() {
            panic!(
                "the Renderable layer is BevyVisibilityPlugin's: add BevyVisibilityPlugin \
                 before add_spatial_layer::<Renderable> or add_spatial_join over it"
            );
        }
        self.insert_resource(index::SpatialIndex::<L>::new(config.tree));
        register_layer_queries::<L>(self, &config);
        let mut schedules = vec![config.schedule];
        if config.schedule == PostUpdate.intern() {
            schedules.push(PostStartup.intern());
        }
        for schedule in schedules {
            if index::is_main_layer::<L>() {
                self.add_systems(
                    schedule,
                    (
                        disabling::watch_disabling::<L>(Some(disabling::read_again_when_enabled))
                            .run_if(resource_changed::<DefaultQueryFilters>),
                        index::sync_main.run_if(any_with_component::<SpatialBounds>),
                    )
                        // The observers may come at the schedule's next sync
                        // point: no extra one every frame for a rare change.
                        .chain_ignore_deferred()
                        .in_set(SpatialIndexSystems::Sync),
                );
            } else {
                self.add_systems(
                    schedule,
                    (
                        disabling::watch_disabling::<L>(None)
                            .run_if(resource_changed::<DefaultQueryFilters>),
                        index::sync_layer::<L>.run_if(any_with_component::<L>),
                    )
                        .chain_ignore_deferred()
                        .in_set(SpatialIndexSystems::Sync),
                );
            }
        }
        self.add_observer(
            // The main layer's marker is its box.
            |event: On<Remove<L>>,
             mut index: ResMut<SpatialIndex<L>>,
             sink: Res<DiagnosticsSink>| {
                if index::is_main_layer::<L>() {
                    index::remove_box(event.entity, &mut index, &sink);
                } else {
                    index::remove_from_layer(event.entity, &mut index, &sink);
                }
            },
        )
        .add_observer(
            |event: On<Add<NoSpatialIndex>>,
             mut index: ResMut<SpatialIndex<L>>,
             sink: Res<DiagnosticsSink>| {
                index::remove_from_layer(event.entity, &mut index, &sink);
            },
        )
        .add_observer(
            // Bevy's queries leave a disabled entity out (unless the app
            // took `Disabled` out of their filters); so do the indexes.
            |event: On<Add<Disabled>>,
             mut index: ResMut<SpatialIndex<L>>,
             filters: Res<DefaultQueryFilters>,
             components: &bevy_ecs::component::Components,
             sink: Res<DiagnosticsSink>| {
                if disabling::disabled_is_left_out(&filters, components) {
                    index::remove_from_layer(event.entity, &mut index, &sink);
                }
            },
        )
        .add_observer(
            |check: On<CheckChangeTicks>, mut index: ResMut<SpatialIndex<L>>| {
                index.check_ticks(*check);
            },
        );
        if !index::is_main_layer::<L>() {
            self.add_observer(
                |event: On<Remove<SpatialBounds>>,
                 mut index: ResMut<SpatialIndex<L>>,
                 sink: Res<DiagnosticsSink>| {
                    index::remove_box(event.entity, &mut index, &sink);
                },
            );
        }
        self
    }

    fn add_spatial_join<A: Component, B: Component>(
        &mut self,
        distance: f32,
        mode: JoinMode,
    ) -> &mut Self {
        self.add_spatial_layer::<A>().add_spatial_layer::<B>();
        if let Some(mut join) = self.world_mut().get_resource_mut::<SpatialJoin<A, B>>() {
            join.distance = distance;
            join.mode = mode;
            return self;
        }
        let schedule = self.world().resource::<SpatialIndexConfig>().schedule;
        self.insert_resource(SpatialJoin::<A, B>::new(distance, mode))
            .add_message::<PairStarted<A, B>>()
            .add_message::<PairEnded<A, B>>()
            .add_systems(
                schedule,
                join::run_join::<A, B>
                    .in_set(SpatialIndexSystems::Queries)
                    .run_if(join::join_has_work::<A, B>),
            )
    }
}

/// The systems that serve a layer's index, whatever fills it: repair,
/// culling cameras and ray casters of the layer.
fn register_layer_queries<L: Component>(app: &mut App, config: &SpatialIndexConfig) {
    app.add_systems(
        config.schedule,
        (
            maintenance::maintain_layer::<L>
                .in_set(SpatialIndexSystems::Maintain)
                .run_if(maintenance::needs_maintenance::<L>),
            culling::cull_cameras::<L>
                .in_set(SpatialIndexSystems::Queries)
                .run_if(any_with_component::<CullingCamera<L>>),
            raycast::cast_rays::<L>
                .in_set(SpatialIndexSystems::Queries)
                .run_if(any_with_component::<RayCaster<L>>),
        ),
    )
    .add_observer(drop_answer::<CullingCamera<L>, VisibleEntityList<L>>)
    .add_observer(drop_answer::<RayCaster<L>, RayCasterHits<L>>);
    #[cfg(feature = "bevy_camera")]
    bevy_camera::add_follow_system::<L>(app, config.schedule);
}

/// Observer: an entity that loses its camera or caster `Q` loses its
/// answer `A`, so that no answer names entities long despawned.
fn drop_answer<Q: Component, A: Component>(event: On<Remove<Q>>, mut commands: Commands) {
    if let Ok(mut entity) = commands.get_entity(event.entity) {
        entity.try_remove::<A>();
    }
}

/// Component hook of the layer-generic components (cameras and casters of
/// layer `L`): the layer must be registered, or the component would
/// silently answer nothing forever.
pub(crate) fn layer_must_be_registered<L: Component>(
    world: bevy_ecs::world::DeferredWorld,
    context: bevy_ecs::lifecycle::HookContext,
) {
    if !world.contains_resource::<index::SpatialIndex<L>>() {
        let layer = std::any::type_name::<L>();
        #[cfg(feature = "bevy_camera")]
        let renderables =
            std::any::TypeId::of::<L>() == std::any::TypeId::of::<bevy_visibility::Renderable>();
        #[cfg(not(feature = "bevy_camera"))]
        let renderables = false;
        let fix = if renderables {
            "add BevyVisibilityPlugin, which registers it".to_string()
        } else {
            format!("call app.add_spatial_layer::<{layer}>() after adding SpatialIndexPlugin")
        };
        panic!(
            "{} on {} uses the spatial layer {layer}, which is not registered: {fix}",
            world
                .components()
                .get_name(context.component_id)
                .map_or_else(|| "a component".to_string(), |n| n.to_string()),
            context.entity
        );
    }
}

/// Observer: an entity that drops its opt-out marker is put back on the next
/// sync, by marking its box as changed.
fn opt_back_in(event: On<Remove<NoSpatialIndex>>, mut bounds: Query<&mut SpatialBounds>) {
    if let Ok(mut bounds) = bounds.get_mut(event.entity) {
        bounds.set_changed();
    }
}

/// Observer: an entity enabled again (Bevy's `Disabled` removed) is put
/// back on the next sync, by marking what the syncs read of it as changed.
fn enabled_again(event: On<Remove<Disabled>>, mut world: bevy_ecs::world::DeferredWorld) {
    disabling::read_again(&mut world, event.entity);
}
