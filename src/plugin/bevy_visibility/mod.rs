//! Bevy's own visibility served by the index (feature `bevy_camera`).
//!
//! [`BevyVisibilityPlugin`] indexes every entity Bevy's CPU culling tests
//! (from Bevy's `Aabb` and `GlobalTransform`, with nothing of ours on the
//! entity) in the layer [`Renderable`], and takes over Bevy's
//! `check_visibility_cpu_culling`: for every active camera, the tree gives
//! the candidates, and Bevy's own sphere and oriented-box tests decide
//! those the tree cannot prove visible. Every `ViewVisibility` and every
//! camera's `VisibleEntities` come out as Bevy's own system makes them.

mod cameras;
#[cfg(feature = "bevy_light")]
mod cascades;
mod columns;
mod frustum_candidates;
mod layers;
#[cfg(feature = "bevy_light")]
mod lights;
mod orders;
#[cfg(test)]
mod proof_tests;
mod radix;
mod rows;
mod seen;
mod storage_order;
mod sync;

pub use sync::RenderableHandle;

use bevy_app::prelude::*;
use bevy_camera::primitives::Aabb as BevyAabb;
use bevy_camera::visibility::{
    VisibilitySystems, check_visibility_cpu_culling, check_visibility_ranges,
};
use bevy_ecs::entity_disabling::DefaultQueryFilters;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{ScheduleCleanupPolicy, ScheduleLabel};
use bevy_transform::TransformSystems;

use super::disabling;
use super::index::SpatialIndex;
use super::{SpatialIndexConfig, SpatialIndexSystems};

/// The layer of Bevy's renderables: every entity that Bevy's CPU frustum
/// culling tests (it has `GlobalTransform`, `InheritedVisibility` and
/// `ViewVisibility`, and no `NoCpuCulling`) and that has Bevy's `Aabb`,
/// no `NoFrustumCulling` and a usable world box.
///
/// A marker type, never put on entities: with [`BevyVisibilityPlugin`]
/// every such entity is in `SpatialIndex<Renderable>`, kept current from
/// its `Aabb` and `GlobalTransform`, so every query of the crate works on
/// Bevy's renderables with no component of ours:
/// `SpatialQuery<Renderable>`, `RayCaster::<Renderable>::for_layer`,
/// `CullingCamera::<Renderable>::for_layer`.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_camera::primitives::Aabb;
/// use bevy_camera::visibility::{InheritedVisibility, ViewVisibility};
/// use bevy_rtree::plugin::{BevyVisibilityPlugin, Renderable, SpatialIndex, SpatialIndexPlugin};
/// use bevy_transform::prelude::*;
/// use bevy_rtree::glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins((TransformPlugin, SpatialIndexPlugin::default(), BevyVisibilityPlugin));
/// let crate_box = app
///     .world_mut()
///     .spawn((
///         Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
///         Transform::from_xyz(10.0, 0.0, 0.0),
///         InheritedVisibility::VISIBLE,
///         ViewVisibility::default(),
///     ))
///     .id();
/// app.update();
/// let index = app.world().resource::<SpatialIndex<Renderable>>();
/// let found = index.get(crate_box).unwrap();
/// assert!(found.contains_point(Vec3::new(10.5, 0.5, 0.5)));
/// ```
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Renderable;

/// Serves Bevy's camera visibility from the index: add it with (after)
/// [`SpatialIndexPlugin`](super::SpatialIndexPlugin), in an app with Bevy's `CameraPlugin` (part of
/// `DefaultPlugins`, before or after this plugin). Bevy's systems it
/// replaces are taken out as the first frame starts (in `First`, once).
///
/// It indexes Bevy's renderables in the layer [`Renderable`] and replaces
/// Bevy's `check_visibility_cpu_culling` with a system in the same set,
/// `VisibilitySystems::CheckVisibility`, that gives every active camera the
/// same `ViewVisibility` and sorted `VisibleEntities` per visibility class
/// as Bevy's: `InheritedVisibility`, `RenderLayers`, `VisibilityRange`,
/// `NoFrustumCulling`, `NoCpuCulling` (on entities and on cameras) and
/// inactive cameras are honoured exactly as there, and Bevy's sphere test
/// and oriented-box test (without the far plane) decide every candidate
/// that the tree does not prove inside every plane. Entities without an
/// `Aabb` (with or without Bevy's `Sphere`), with `NoFrustumCulling`, or
/// whose world box is unusable (a NaN or zero-scale transform, a NaN or
/// negative half extent) are tested one by one, as Bevy tests them.
///
/// An app's systems ordered before or after Bevy's culling
/// (`.after(check_visibility_cpu_culling)`) or its light systems keep that
/// order against the systems that replace them. What the schedule keeps to
/// itself is not carried over: a set's order against one of Bevy's systems
/// (order a whole set against Bevy's sets instead,
/// `VisibilitySystems::CheckVisibility` or
/// `SimulationLightSystems::CheckLightVisibility`), an `ambiguous_with`
/// exemption, and an `*_ignore_deferred` opt-out (carried as a plain
/// order).
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::plugin::{BevyVisibilityPlugin, SpatialIndexPlugin};
///
/// let mut app = App::new();
/// // With DefaultPlugins (or CameraPlugin) in a real game.
/// app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
/// ```
#[derive(Clone, Copy, Debug, Default)]
pub struct BevyVisibilityPlugin;

/// How [`BevyVisibilityPlugin`] decides the tree's candidates; the plugin
/// inserts the default, and a game may replace it at any time.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::plugin::{BevyVisibilityPlugin, BevyVisibilitySettings, SpatialIndexPlugin};
///
/// let mut app = App::new();
/// app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin))
///     .insert_resource(BevyVisibilitySettings {
///         prove_inside: false,
///         ..Default::default()
///     });
/// ```
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BevyVisibilitySettings {
    /// Candidates whose world box the tree proves inside every plane Bevy
    /// tests (by a margin past both tests' rounding) skip Bevy's frustum
    /// tests. On by default. Off, every candidate takes Bevy's tests: the
    /// same answers, more work (the performance notes price it).
    pub prove_inside: bool,
    /// Where Bevy's `ComputeTaskPool` has more than one thread, the change
    /// scan, the cameras' culls and the pass over the entities are split
    /// over it, as Bevy splits its own culling. On by default; off keeps
    /// the whole step on the thread that runs it. The answers are the same
    /// either way.
    pub parallel: bool,
}

impl Default for BevyVisibilitySettings {
    fn default() -> Self {
        BevyVisibilitySettings {
            prove_inside: true,
            parallel: true,
        }
    }
}

impl BevyVisibilitySettings {
    /// Whether this frame's work is split over the task pool.
    pub(super) fn on_several_threads(&self) -> bool {
        self.parallel
            && bevy_tasks::ComputeTaskPool::try_get().is_some_and(|pool| pool.thread_num() > 1)
    }
}

/// The plugin's system set in `PostUpdate`: the renderables' index follows
/// their transforms and boxes; it runs after transform propagation,
/// Bevy's bounds and `VisibilitySystems::UpdateFrusta` (so after the sets
/// before it, bevy_light's `UpdateBounds` among them), before
/// `VisibilitySystems::CheckVisibility`.
///
/// The index reads a renderable's box again when Bevy's change detection
/// says its `GlobalTransform` or `Aabb` changed: a write through
/// `bypass_change_detection` is not seen until the next detected one,
/// where Bevy's culling, which reads every box each frame, sees it at
/// once (Bevy's transform propagation, too, misses such a write to
/// `Transform`).
///
/// A system of the app that writes `GlobalTransform` or `Aabb` (or spawns
/// or enables renderables, gives them their visibility components, or
/// takes `NoFrustumCulling` or `NoCpuCulling` off them) after transform
/// propagation but before Bevy's culling must run before this set too:
/// Bevy's culling would see its change in the same frame, and the index
/// only from the next one. The
/// same holds for the lights' shadow visibility (feature `bevy_light`),
/// which runs after camera culling from the same index: a shadow caster
/// written between camera culling and
/// `SimulationLightSystems::CheckLightVisibility` is tested by the lights
/// with the box the index read before camera culling, until the next
/// frame.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_ecs::prelude::*;
/// use bevy_rtree::plugin::{Renderable, RenderableSyncSystems, SpatialIndex};
///
/// // A system that reads the renderables' index once it is current.
/// fn count_renderables(index: Res<SpatialIndex<Renderable>>) {
///     println!("{} renderables indexed", index.len());
/// }
/// App::new().add_systems(PostUpdate, count_renderables.after(RenderableSyncSystems));
/// ```
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct RenderableSyncSystems;

impl Plugin for BevyVisibilityPlugin {
    fn build(&self, app: &mut App) {
        let Some(config) = app.world().get_resource::<SpatialIndexConfig>().cloned() else {
            panic!(
                "BevyVisibilityPlugin needs SpatialIndexPlugin: add it first, as in \
                 app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin))"
            );
        };
        // Bevy refuses a new required component once an archetype holds
        // `Aabb` (entities with a box spawned before this plugin): then no
        // entity gets the handle, their entries are looked up instead, and
        // observers stand in for the handle's hook (see `sync::Resync`).
        let handles_kept = app
            .try_register_required_components::<BevyAabb, RenderableHandle>()
            .is_ok();
        app.insert_resource(SpatialIndex::<Renderable>::new(config.tree))
            .init_resource::<sync::Resync>()
            .init_resource::<BevyVisibilitySettings>()
            .configure_sets(
                PostUpdate,
                RenderableSyncSystems
                    .after(TransformSystems::Propagate)
                    .after(VisibilitySystems::CalculateBounds)
                    // After the sets that run before it, bevy_light's
                    // `UpdateBounds` among them (light probes and decals
                    // get their box there, by command), in a build
                    // without the feature `bevy_light` too.
                    .after(VisibilitySystems::UpdateFrusta)
                    .before(VisibilitySystems::CheckVisibility),
            )
            .add_systems(
                PostUpdate,
                (
                    (
                        disabling::watch_disabling::<Renderable>(Some(sync::come_back_on_enable))
                            .run_if(resource_changed::<DefaultQueryFilters>),
                        sync::sync_renderables,
                    )
                        // The observers may come at the schedule's next sync
                        // point: no extra one every frame for a rare change.
                        .chain_ignore_deferred()
                        .in_set(RenderableSyncSystems),
                    cameras::check_visibility_from_index
                        .in_set(VisibilitySystems::CheckVisibility)
                        .in_set(orders::ServesCameraVisibility)
                        // Where Bevy orders its own: after this frame's
                        // visibility ranges.
                        .after(check_visibility_ranges)
                        // Ordered after Bevy's own until that is taken out
                        // in the first frame: taking it out initializes the
                        // schedule, which an app that makes ambiguities
                        // errors would otherwise refuse.
                        .after(check_visibility_cpu_culling),
                ),
            );
        if config.schedule == PostUpdate.intern() {
            // The layer's own queries (SpatialQuery and the plugin's
            // cameras and casters) then see this frame's renderables.
            // And the repair of the renderables' tree comes before the
            // cameras read it (either order answers the same; this one is
            // fixed, and the repaired tree is the faster to cull).
            app.configure_sets(
                PostUpdate,
                (
                    RenderableSyncSystems.before(SpatialIndexSystems::Maintain),
                    SpatialIndexSystems::Maintain.before(VisibilitySystems::CheckVisibility),
                ),
            );
        }
        sync::add_observers(app, handles_kept);
        super::register_layer_queries::<Renderable>(app, &config);
        // Bevy's systems this one replaces are taken out at the start of
        // the first frame, not here nor in `PreStartup`: taking a system out
        // initializes its schedule, and every query of a schedule
        // initialized then would miss a disabling component registered
        // after it (by a later plugin, or by a startup system), which
        // Bevy's own systems, set up at their first run, respect (Bevy asks
        // for them before the app starts). By the first frame, Bevy's
        // plugins are there whether they were added before or after this
        // one, and the startup schedules have run. It touches only
        // `PostUpdate`, so its order among `First`'s systems is free.
        app.add_systems(
            First,
            take_out_bevy_systems
                .run_if(bevy_ecs::schedule::common_conditions::run_once)
                .ambiguous_with_all(),
        );
        #[cfg(feature = "bevy_light")]
        add_light_visibility(app);
    }
}

/// Takes out of `PostUpdate` Bevy's `check_visibility_cpu_culling` and,
/// with feature `bevy_light`, bevy_light's `check_point_light_mesh_visibility`
/// and `check_dir_light_mesh_visibility`: once, in the first frame's
/// `First`. The app's
/// systems ordered against them are ordered against their replacements
/// instead (see `orders`).
fn take_out_bevy_systems(world: &mut World) {
    // The schedule is taken out of `Schedules` while it changes (not the
    // whole `Schedules`: initializing a schedule reads it).
    let taken_out = world.try_schedule_scope(PostUpdate, |world, schedule| {
        let policy = ScheduleCleanupPolicy::RemoveSystemsOnly;
        // The orders are read before anything is taken out: taking out
        // builds the schedule, after which its systems are named through
        // the executable (both work; reading first keeps it one way).
        let cameras = orders::ServesCameraVisibility.intern();
        let culling = check_visibility_cpu_culling.into_system_set().intern();
        let camera_orders = orders::orders_against(schedule, culling, cameras);
        #[cfg(feature = "bevy_light")]
        {
            use bevy_light::{check_dir_light_mesh_visibility, check_point_light_mesh_visibility};
            // One replacement each, so that every order of the app against
            // one of Bevy's two carries over to its replacement alone.
            let point = orders::ServesPointLightVisibility.intern();
            let point_shadows = check_point_light_mesh_visibility.into_system_set().intern();
            let point_orders = orders::orders_against(schedule, point_shadows, point);
            let directional = orders::ServesDirectionalLightVisibility.intern();
            let dir_shadows = check_dir_light_mesh_visibility.into_system_set().intern();
            let dir_orders = orders::orders_against(schedule, dir_shadows, directional);
            let _ =
                schedule.remove_systems_in_set(check_point_light_mesh_visibility, world, policy);
            let _ = schedule.remove_systems_in_set(check_dir_light_mesh_visibility, world, policy);
            orders::order(schedule, point, point_orders);
            orders::order(schedule, directional, dir_orders);
        }
        let removed = schedule.remove_systems_in_set(check_visibility_cpu_culling, world, policy);
        orders::order(schedule, cameras, camera_orders);
        matches!(removed, Ok(n) if n > 0)
    });
    let taken_out = taken_out.unwrap_or(false);
    if !taken_out {
        log::warn!(
            "BevyVisibilityPlugin: Bevy's check_visibility_cpu_culling was not found \
             (is CameraPlugin or DefaultPlugins in the app?); the index serves \
             visibility alone"
        );
    }
}

/// Serves bevy_light's shadow visibility from the index too (feature
/// `bevy_light`): two systems in
/// `SimulationLightSystems::CheckLightVisibility`, ordered as Bevy orders
/// its own, in place of `check_point_light_mesh_visibility` and
/// `check_dir_light_mesh_visibility`.
#[cfg(feature = "bevy_light")]
fn add_light_visibility(app: &mut App) {
    use bevy_light::SimulationLightSystems;
    use cascades::check_dir_light_visibility_from_index;
    use lights::check_point_light_visibility_from_index;
    app.add_systems(
        PostUpdate,
        (
            check_point_light_visibility_from_index.in_set(orders::ServesPointLightVisibility),
            // No order between them, as Bevy's two have none (the
            // directional one marks its casters by command afterwards).
            check_dir_light_visibility_from_index
                .in_set(orders::ServesDirectionalLightVisibility)
                .ambiguous_with(check_point_light_visibility_from_index),
        )
            .in_set(SimulationLightSystems::CheckLightVisibility)
            .after(VisibilitySystems::CalculateBounds)
            .after(TransformSystems::Propagate)
            .after(SimulationLightSystems::UpdateLightFrusta)
            // Lights mark the casters they see visible, after the cameras
            // and before the entities no view sees are hidden.
            .after(VisibilitySystems::CheckVisibility)
            .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
    )
    // bevy_light gives light probes and clustered decals their `Aabb` by
    // command in this set, which Bevy's culling sees in the same frame: so
    // must the index.
    .configure_sets(
        PostUpdate,
        RenderableSyncSystems.after(SimulationLightSystems::UpdateBounds),
    );
}
