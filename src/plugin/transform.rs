//! World boxes from `GlobalTransform` (feature `bevy`): an entity with a
//! [`LocalBounds`] gets its [`SpatialBounds`] computed after transform
//! propagation, only when its transform or local box changed.

use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_ecs::schedule::{InternedScheduleLabel, ScheduleLabel};
use bevy_transform::TransformSystems;
use bevy_transform::prelude::GlobalTransform;

use super::SpatialIndexSystems;
use super::bounds::SpatialBounds;
use crate::geometry::Aabb;

/// The entity's box in its local space; its world box follows its
/// `GlobalTransform` ([contract S1](crate::contract): outward rounding unless the transform is
/// a pure translation).
///
/// A transform that is not finite or that collapses an axis (zero scale)
/// gives no world box: the entity leaves the index, is reported once and
/// counted, until its transform is usable again.
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::prelude::*;
/// use bevy_transform::prelude::*;
///
/// let mut app = App::new();
/// app.add_plugins((TransformPlugin, SpatialIndexPlugin::default()));
/// let local = Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5))?;
/// let truck = app
///     .world_mut()
///     .spawn((LocalBounds(local), Transform::from_xyz(10.0, 0.0, 0.0)))
///     .id();
/// app.update();
/// let index = app.world().resource::<SpatialIndex>();
/// assert!(index.get(truck).unwrap().contains_point(Vec3::new(10.4, 0.0, 0.0)));
/// # Ok::<(), SpatialError>(())
/// ```
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component, Debug, PartialEq, Clone))]
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[require(SpatialBounds, GlobalTransform)]
pub struct LocalBounds(pub Aabb);

pub(crate) fn build(app: &mut bevy_app::App, schedule: InternedScheduleLabel) {
    #[cfg(feature = "reflect")]
    app.register_type::<LocalBounds>();
    let mut schedules = vec![schedule];
    // With the plugin in `PostUpdate`, the entities spawned at startup get
    // their world boxes after Bevy's startup propagation too.
    if schedule == bevy_app::PostUpdate.intern() {
        schedules.push(bevy_app::PostStartup.intern());
    }
    for schedule in schedules {
        app.configure_sets(
            schedule,
            SpatialIndexSystems::Bounds.after(TransformSystems::Propagate),
        )
        .add_systems(
            schedule,
            bounds_from_transforms
                .in_set(SpatialIndexSystems::Bounds)
                .run_if(any_with_component::<LocalBounds>),
        );
    }
}

#[allow(clippy::type_complexity)]
fn bounds_from_transforms(
    mut entities: Query<
        (&LocalBounds, &GlobalTransform, &mut SpatialBounds),
        Or<(Changed<GlobalTransform>, Changed<LocalBounds>)>,
    >,
) {
    for (local, global, mut bounds) in &mut entities {
        let affine = global.affine();
        let collapsed = affine.matrix3.determinant() == 0.0;
        let world = if collapsed {
            Aabb::INVERTED
        } else {
            local.0.transformed(&affine).unwrap_or(Aabb::INVERTED)
        };
        bounds.set_if_neq(SpatialBounds(world));
    }
}
