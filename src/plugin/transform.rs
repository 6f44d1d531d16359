//! World boxes from `GlobalTransform` (feature `bevy`): an entity with a
//! [`LocalBounds`] gets its [`SpatialBounds`] computed after transform
//! propagation, only when its transform or local box changed.

use std::panic::Location;

use bevy_ecs::change_detection::ContiguousMut;
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_ecs::schedule::{InternedScheduleLabel, ScheduleLabel};
use bevy_transform::TransformSystems;
use bevy_transform::prelude::GlobalTransform;

use super::SpatialIndexSystems;
use super::bounds::SpatialBounds;
use super::change_scan::ChangeTest;
use crate::geometry::Aabb;

/// The entity's box in its local space; its world box follows its
/// `GlobalTransform` ([contract S1](crate::contract): outward rounding unless the transform is
/// a pure translation).
///
/// A transform that is not finite or that collapses an axis (a zero
/// column: a zero scale on the entity, or on an ancestor not turned
/// against it) gives no world box: the entity leaves the index, is
/// reported once and counted, until its transform is usable again. A zero
/// scale on a turned ancestor of a turned entity leaves, once `f32` has
/// rounded the product, columns only nearly in one plane, which no test
/// can tell from a steep but real stretch: such an entity keeps the flat
/// box around its image, a true box for it.
///
/// `LocalBounds` requires the [`SpatialBounds`] it writes. Removing it (or
/// the `GlobalTransform`) leaves that component, as Bevy leaves required
/// components: the entity stays indexed at its last world box, which no
/// longer follows the transform. Remove `SpatialBounds` too to take the
/// entity out of the index; inserting it again brings the entity back at
/// its world box. A `SpatialBounds` written by hand on an entity with
/// `LocalBounds` is replaced by the world box in the same frame.
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

/// What the world boxes are computed from, and written to, table by table.
type TransformRow<'a> = (
    Ref<'a, LocalBounds>,
    Ref<'a, GlobalTransform>,
    &'a mut SpatialBounds,
);

/// Writes the world box of every entity whose transform, local box or
/// `SpatialBounds` changed since the last run, marking it changed only
/// where it differs (Bevy's `set_if_neq`), so that the index's sync sees
/// only real moves.
///
/// `SpatialBounds` counts because it is this system's to write: one
/// inserted again after it was removed (which took the entity out of the
/// index, while its transform may have moved), or written by hand, is
/// replaced by the world box at once. Its own writes carry the tick of
/// its run, which the next run does not count as newer.
fn bounds_from_transforms(mut entities: Query<TransformRow<'_>>, mut written: Local<Vec<usize>>) {
    // Table by table where the query can be read so (an app's disabling
    // component stored in a sparse set makes it row by row).
    let tables = match entities.contiguous_iter_mut() {
        Ok(tables) => tables,
        Err(_) => {
            for (local, global, mut bounds) in &mut entities {
                if local.is_changed() || global.is_changed() || bounds.is_changed() {
                    bounds.set_if_neq(SpatialBounds(world_box(&local, &global)));
                }
            }
            return;
        }
    };
    for (locals, globals, bounds) in tables {
        let test = ChangeTest::new(globals.last_run_tick(), globals.this_run_tick());
        let this_run = globals.this_run_tick();
        let (values, mut ticks) = ContiguousMut::bypass_change_detection_split(bounds);
        written.clear();
        let columns = [
            globals.changed_ticks_slice(),
            locals.changed_ticks_slice(),
            ticks.changed(),
        ];
        test.for_each_changed(columns, |row| {
            let world = SpatialBounds(world_box(&locals[row], &globals[row]));
            if values[row] != world {
                values[row] = world;
                written.push(row);
            }
        });
        // What `set_if_neq` writes, once the scan no longer reads these
        // ticks. `SpatialBounds` keeps no summary tick for it to update (a
        // test checks).
        let caller = Location::caller();
        for &row in written.iter() {
            ticks.changed_mut()[row] = this_run;
            ticks.changed_by_mut().map(|by| by[row] = caller);
        }
    }
}

/// The world box of `local` under `global`, or the unusable box (refused
/// by the index, and reported) where the transform collapses an axis or is
/// not finite.
fn world_box(local: &LocalBounds, global: &GlobalTransform) -> Aabb {
    let affine = global.affine();
    if collapses_an_axis(&affine.matrix3) {
        return Aabb::UNUSABLE;
    }
    local.0.transformed(&affine).unwrap_or(Aabb::UNUSABLE)
}

/// Whether a transform collapses an axis: its determinant is zero in
/// `f32` and again in `f64` (a scale of 1e-16 on each axis, a valid tiny
/// box, underflows `f32` alone). See [`LocalBounds`] for what this misses.
pub(crate) fn collapses_an_axis(matrix: &glam::Mat3A) -> bool {
    matrix.determinant() == 0.0 && matrix.as_dmat3().determinant() == 0.0
}
