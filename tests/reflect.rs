//! The plugin's components through Bevy's reflection (feature `reflect`):
//! registered by the plugin, read and written as an inspector or a scene
//! would.
#![cfg(feature = "reflect")]

use bevy_app::prelude::*;
use bevy_ecs::reflect::{AppTypeRegistry, ReflectComponent};
use bevy_reflect::{GetPath, PartialReflect};
use bevy_rtree::prelude::*;
use std::any::TypeId;

#[test]
fn an_inspector_reads_and_edits_a_box_and_the_index_follows() {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    let crate_box = Aabb::new(Vec3::ZERO, Vec3::ONE).unwrap();
    let entity = app.world_mut().spawn(SpatialBounds(crate_box)).id();
    app.update();

    let registry = app.world().resource::<AppTypeRegistry>().clone();
    let registry = registry.read();
    let registration = registry
        .get(TypeId::of::<SpatialBounds>())
        .expect("the plugin registers SpatialBounds");
    let component = registration.data::<ReflectComponent>().unwrap();

    // Read the box's max through reflection, by path.
    let reflected = component.reflect(app.world().entity(entity)).unwrap();
    let max = *reflected.path::<Vec3>(".0.max").unwrap();
    assert_eq!(max, Vec3::ONE);

    // Edit it as an inspector would: the index follows the change.
    let mut moved = SpatialBounds(crate_box);
    moved.0.max = Vec3::splat(3.0);
    let mut world_entity = app.world_mut().entity_mut(entity);
    component.apply(&mut world_entity, moved.as_partial_reflect());
    app.update();
    let index = app.world().resource::<SpatialIndex>();
    assert!(index.get(entity).unwrap().contains_point(Vec3::splat(2.5)));

    // The other components an inspector shows are registered too.
    for (name, id) in [
        ("CullingCamera", TypeId::of::<CullingCamera>()),
        ("RayCaster", TypeId::of::<RayCaster>()),
        ("RayCasterHits", TypeId::of::<RayCasterHits>()),
        ("VisibleEntityList", TypeId::of::<VisibleEntityList>()),
        ("NoSpatialIndex", TypeId::of::<NoSpatialIndex>()),
        ("SpatialDiagnostics", TypeId::of::<SpatialDiagnostics>()),
    ] {
        assert!(registry.get(id).is_some(), "{name} is registered");
    }
}
