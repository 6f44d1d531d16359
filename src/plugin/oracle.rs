//! The brute-force oracle of a layer, built from the world's current boxes:
//! what every answer of the plugin must equal.

use bevy_ecs::prelude::*;

use super::bounds::{NoSpatialIndex, SpatialBounds};
use crate::query::oracle::BruteForce;

/// Brute force over the entities that layer `L` should hold right now: with
/// a valid [`SpatialBounds`], the marker `L` and no [`NoSpatialIndex`].
///
/// Meant for tests and examples that check the plugin's answers:
///
/// ```
/// use bevy_app::prelude::*;
/// use bevy_rtree::Aabb;
/// use bevy_rtree::plugin::{SpatialBounds, SpatialIndex, SpatialIndexPlugin, layer_oracle};
/// use bevy_rtree::glam::Vec3;
///
/// let mut app = App::new();
/// app.add_plugins(SpatialIndexPlugin::default());
/// app.world_mut().spawn(SpatialBounds(Aabb::new(Vec3::ZERO, Vec3::ONE)?));
/// app.update();
/// let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
/// let query = Aabb::new(Vec3::splat(0.5), Vec3::splat(2.0))?;
/// let index = app.world().resource::<SpatialIndex>();
/// assert_eq!(index.tree().overlapping(&query), oracle.overlapping(&query));
/// # Ok::<(), bevy_rtree::SpatialError>(())
/// ```
pub fn layer_oracle<L: Component>(world: &mut World) -> BruteForce<Entity> {
    let mut oracle = BruteForce::default();
    let mut members =
        world.query_filtered::<(Entity, &SpatialBounds), (With<L>, Without<NoSpatialIndex>)>();
    for (entity, bounds) in members.iter(world) {
        if bounds.0.is_valid() {
            oracle.insert(entity, bounds.0);
        }
    }
    oracle
}
