//! Culling cameras that follow a real Bevy camera (feature `bevy_camera`):
//! the camera's `Frustum`, which Bevy keeps current from its projection and
//! transform, becomes the [`CullingCamera`]'s frustum every frame it changes.

use bevy_camera::primitives::Frustum as BevyFrustum;
use bevy_camera::visibility::VisibilitySystems;
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_ecs::schedule::InternedScheduleLabel;
use bevy_transform::prelude::GlobalTransform;
use glam::{Vec3, Vec4};

use std::marker::PhantomData;

use super::{CullingCamera, SpatialBounds, SpatialIndexSystems};
use crate::geometry::Frustum;
use crate::query::CullMode;

/// Put this on a Bevy camera (next to its `Frustum` and `GlobalTransform`)
/// and the plugin keeps a [`CullingCamera`] on the same entity equal to it,
/// so its [`VisibleEntityList`](super::VisibleEntityList) lists what the
/// camera sees. The eye is the camera's world position.
///
/// A frustum that cannot be converted (a NaN or infinite plane other than
/// Bevy's infinite far plane, see [`Frustum::from_bevy`]) keeps the
/// previous one, logs a warning each time it becomes refused, and is
/// counted in [`QueryWork::refused`](super::QueryWork) every frame it
/// stays refused. Removing
/// `FollowBevyFrustum` (or the camera's `Frustum`) removes the
/// `CullingCamera` and its list; a Bevy camera with `is_active: false` is
/// not culled and keeps its last list, as Bevy skips it.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_asset::Assets;
/// use bevy_camera::{Camera3d, CameraPlugin};
/// use bevy_mesh::{Mesh, skinning::SkinnedMeshInverseBindposes};
/// use bevy_rtree::prelude::*;
/// use bevy_transform::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins((TransformPlugin, CameraPlugin, SpatialIndexPlugin::default()))
///     // The asset stores Bevy's camera systems read, headless.
///     .insert_resource(Assets::<Mesh>::default())
///     .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default());
/// let ahead = Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, -10.0), Vec3::splat(0.5))?;
/// let behind = Aabb::from_center_half_extents(Vec3::new(0.0, 0.0, 10.0), Vec3::splat(0.5))?;
/// let seen = app.world_mut().spawn(SpatialBounds(ahead)).id();
/// app.world_mut().spawn(SpatialBounds(behind));
/// // A Bevy camera at the origin, looking down -Z.
/// let camera = app.world_mut().spawn((Camera3d::default(), FollowBevyFrustum::default())).id();
/// app.update();
/// let list = app.world().get::<VisibleEntityList>(camera).unwrap();
/// assert_eq!(list.entities(), &[seen]);
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
#[derive(Component)]
#[component(on_add = super::layer_must_be_registered::<L>)]
pub struct FollowBevyFrustum<L: Component = SpatialBounds> {
    /// The cull mode of the [`CullingCamera<L>`].
    pub mode: CullMode,
    #[cfg_attr(feature = "reflect", reflect(ignore, clone))]
    _layer: PhantomData<fn() -> L>,
}

impl_layer_generic_traits!(FollowBevyFrustum<L> { mode });

/// The main layer's (the only `Default`, so that `FollowBevyFrustum::default()`
/// needs no annotation; a layer's is [`FollowBevyFrustum::for_layer`]).
impl Default for FollowBevyFrustum {
    fn default() -> Self {
        FollowBevyFrustum::for_layer()
    }
}

impl<L: Component> PartialEq for FollowBevyFrustum<L> {
    fn eq(&self, other: &Self) -> bool {
        self.mode == other.mode
    }
}

impl<L: Component> FollowBevyFrustum<L> {
    /// Follows the Bevy camera with a [`CullingCamera<L>`] over layer `L`
    /// (registered with `add_spatial_layer::<L>()`), conservative.
    ///
    /// ```
    /// use bevy_app::prelude::*;
    /// use bevy_camera::Camera3d;
    /// use bevy_ecs::prelude::*;
    /// use bevy_rtree::prelude::*;
    ///
    /// #[derive(Component)]
    /// struct Enemy;
    ///
    /// let mut app = App::new();
    /// app.add_plugins(SpatialIndexPlugin::default()).add_spatial_layer::<Enemy>();
    /// // This camera's `VisibleEntityList<Enemy>` lists the enemies it sees.
    /// app.world_mut().spawn((Camera3d::default(), FollowBevyFrustum::<Enemy>::for_layer()));
    /// ```
    pub fn for_layer() -> Self {
        FollowBevyFrustum {
            mode: CullMode::Conservative,
            _layer: PhantomData,
        }
    }

    /// The same camera with cull mode `mode`.
    pub fn with_mode(mut self, mode: CullMode) -> Self {
        self.mode = mode;
        self
    }
}

pub(crate) fn build(app: &mut bevy_app::App, schedule: InternedScheduleLabel) {
    // The main layer's `Default` (the only one: see its impl) for an
    // inspector's "add component"; the derive cannot name it for every layer.
    app.register_type::<FollowBevyFrustum>()
        .register_type_data::<FollowBevyFrustum, bevy_reflect::std_traits::ReflectDefault>();
    app.configure_sets(
        schedule,
        SpatialIndexSystems::Bounds.after(VisibilitySystems::UpdateFrusta),
    );
}

/// The system that keeps layer `L`'s cameras on their Bevy frustums.
pub(crate) fn add_follow_system<L: Component>(
    app: &mut bevy_app::App,
    schedule: InternedScheduleLabel,
) {
    app.add_systems(
        schedule,
        follow_bevy_frustums::<L>
            .in_set(SpatialIndexSystems::Bounds)
            .run_if(any_with_component::<FollowBevyFrustum<L>>),
    )
    .add_observer(stop_following::<L>)
    .add_observer(lose_frustum::<L>);
}

/// Marks a camera of layer `L` whose Bevy frustum is refused, from the
/// frame it becomes so (logged then) until it converts again or the camera
/// stops following: counted in the diagnostics every frame it stays, as a
/// refused caster is.
#[derive(Component)]
struct RefusedFrustum<L: Component>(PhantomData<fn() -> L>);

/// Observer: an entity that stops following its Bevy camera loses the
/// culling camera the plugin kept for it (and with it its list), so that
/// no frozen view keeps being culled, and is no longer counted as refused.
fn stop_following<L: Component>(event: On<Remove<FollowBevyFrustum<L>>>, mut commands: Commands) {
    if let Ok(mut entity) = commands.get_entity(event.entity) {
        entity.try_remove::<(CullingCamera<L>, RefusedFrustum<L>)>();
    }
}

/// Observer: a follower whose Bevy `Frustum` goes has nothing to follow;
/// its culling camera goes too, and comes back with a new `Frustum`.
fn lose_frustum<L: Component>(
    event: On<Remove<BevyFrustum>>,
    followers: Query<(), With<FollowBevyFrustum<L>>>,
    mut commands: Commands,
) {
    if followers.contains(event.entity)
        && let Ok(mut entity) = commands.get_entity(event.entity)
    {
        entity.try_remove::<CullingCamera<L>>();
    }
}

pub(crate) fn convert(frustum: &BevyFrustum, eye: Vec3) -> Option<Frustum> {
    Frustum::from_bevy(frustum, eye).ok()
}

#[allow(clippy::type_complexity)]
fn follow_bevy_frustums<L: Component>(
    mut commands: Commands,
    mut cameras: Query<
        (
            Entity,
            &BevyFrustum,
            &GlobalTransform,
            &FollowBevyFrustum<L>,
            Option<&mut CullingCamera<L>>,
        ),
        Or<(
            Changed<BevyFrustum>,
            Changed<FollowBevyFrustum<L>>,
            Without<CullingCamera<L>>,
        )>,
    >,
    refused: Query<(), (With<RefusedFrustum<L>>, With<BevyFrustum>)>,
    sink: Res<super::diagnostics::DiagnosticsSink>,
) {
    // The cameras whose frustum stays refused count every frame, changed
    // or not (a camera is read below only when its frustum changes); those
    // that become refused or valid in this frame are counted as they are
    // now (their marks land after the system).
    let mut still_refused = refused.iter().count() as u64;
    for (entity, frustum, global, follow, culling) in &mut cameras {
        // Bevy's frustum as its required component makes it, before Bevy's
        // first `UpdateFrusta` (the index's schedule may run before it, as
        // `Update` does): nothing to follow yet, and nothing to warn of.
        if frustum
            .half_spaces
            .iter()
            .all(|h| h.normal_d() == Vec4::ZERO)
        {
            continue;
        }
        let was_refused = refused.contains(entity);
        let Some(converted) = convert(frustum, global.translation()) else {
            if !was_refused {
                still_refused += 1;
                log::warn!(
                    "{entity}: its Bevy frustum is refused (a NaN plane, or an eye beyond \
                     MAX_COORD); keeping the last culling frustum"
                );
                // `try_`: an earlier command may despawn the camera.
                commands
                    .entity(entity)
                    .try_insert(RefusedFrustum::<L>(PhantomData));
            }
            continue;
        };
        if was_refused {
            still_refused -= 1;
            commands.entity(entity).try_remove::<RefusedFrustum<L>>();
        }
        match culling {
            Some(mut culling) => {
                culling.frustum = converted;
                culling.mode = follow.mode;
            }
            None => {
                // Only onto an entity that still follows when the command
                // runs: it may be despawned, or stop following, meanwhile.
                let camera = CullingCamera::<L>::for_layer(converted).with_mode(follow.mode);
                commands.queue(move |world: &mut World| {
                    if let Ok(mut entity) = world.get_entity_mut(entity)
                        && entity.contains::<FollowBevyFrustum<L>>()
                    {
                        entity.insert(camera);
                    }
                });
            }
        }
    }
    if still_refused > 0 {
        sink.add(|d| d.culling.refused += still_refused);
    }
}
