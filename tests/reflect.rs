//! The plugin's components through Bevy's reflection (feature `reflect`):
//! registered by the plugin, read and written as an inspector or a scene
//! would.
#![cfg(feature = "reflect")]

use bevy_app::prelude::*;
use bevy_ecs::reflect::{AppTypeRegistry, ReflectComponent};
use bevy_reflect::{FromReflect, GetPath, PartialReflect, Reflect, TypePath};
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

/// The type registry of an App with the plugin (what it registers).
fn plugin_registry() -> AppTypeRegistry {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default());
    app.world().resource::<AppTypeRegistry>().clone()
}

/// A component written as a Bevy scene writes it (through the type
/// registry, in RON) and read back into its concrete type.
fn through_a_scene<T: FromReflect + TypePath>(
    value: &T,
    registry: &bevy_reflect::TypeRegistry,
) -> T {
    use bevy_reflect::serde::{ReflectDeserializer, ReflectSerializer};
    use serde::de::DeserializeSeed;
    let text = ron::to_string(&ReflectSerializer::new(value, registry))
        .unwrap_or_else(|e| panic!("{} saves: {e}", T::type_path()));
    let mut reader = ron::Deserializer::from_str(&text).unwrap();
    let loaded = ReflectDeserializer::new(registry)
        .deserialize(&mut reader)
        .unwrap_or_else(|e| panic!("{} loads from {text}: {e}", T::type_path()));
    T::from_reflect(loaded.as_ref()).expect("the loaded value is the type")
}

/// A frustum through a scene and back, as the bytes of its eye and planes.
fn frustum_bits(frustum: &Frustum) -> Vec<u32> {
    let planes = frustum.planes().iter();
    let numbers = planes.flat_map(|p| [p.normal.x, p.normal.y, p.normal.z, p.offset]);
    frustum
        .eye()
        .to_array()
        .into_iter()
        .chain(numbers)
        .map(f32::to_bits)
        .collect()
}

#[test]
fn a_scene_saves_and_loads_every_component_and_its_frustum_exactly() {
    let registry = plugin_registry();
    let registry = registry.read();

    let bounds =
        SpatialBounds(Aabb::new(Vec3::new(-1.5, 0.25, 3.0), Vec3::new(2.0, 1.0, 7.5)).unwrap());
    assert_eq!(through_a_scene(&bounds, &registry), bounds);
    assert_eq!(through_a_scene(&NoSpatialIndex, &registry), NoSpatialIndex);

    // A perspective camera away from the origin (its planes relative to its
    // eye), the same with an inactive far plane, whose infinite offset is
    // written as `None`, and planes the frustum scaled by powers of two.
    let rotation = Quat::from_euler(bevy_rtree::glam::EulerRot::YXZ, 0.7, -0.3, 0.1);
    let perspective =
        Frustum::perspective(Vec3::new(1e5, 20.0, -3e4), rotation, 1.1, 1.7, 0.05, 900.0).unwrap();
    let mut planes = *perspective.planes();
    planes[5] = HalfSpace::INACTIVE;
    let infinite_far = Frustum::new(perspective.eye(), planes).unwrap();
    let tiny = HalfSpace {
        normal: Vec3::new(1e-30, 3e-31, -4e-30),
        offset: 2e-29,
    };
    let huge = HalfSpace {
        normal: Vec3::new(0.0, 5e30, 1e29),
        offset: -1e30,
    };
    let i = HalfSpace::INACTIVE;
    let scaled = Frustum::new(Vec3::new(3.0, -2.0, 1.0), [tiny, huge, i, i, i, i]).unwrap();
    for frustum in [perspective, infinite_far, scaled] {
        let camera = CullingCamera::new(frustum).with_mode(CullMode::Exact);
        let loaded = through_a_scene(&camera, &registry);
        assert_eq!(frustum_bits(&loaded.frustum), frustum_bits(&frustum));
        assert_eq!(loaded.mode, CullMode::Exact);
    }
    assert!(through_a_scene(&infinite_far, &registry).planes()[5].is_inactive());

    let mut caster = RayCaster::new(
        Ray::new(Vec3::ONE, Vec3::NEG_Y, 40.0).unwrap(),
        RayMode::Any,
    );
    caster.ignore_self = false;
    let loaded = through_a_scene(&caster, &registry);
    assert_eq!(
        (loaded.ray, loaded.mode, loaded.ignore_self),
        (caster.ray, caster.mode, false)
    );

    #[cfg(feature = "bevy")]
    {
        let local = LocalBounds(Aabb::new(Vec3::splat(-0.5), Vec3::new(0.5, 2.0, 0.5)).unwrap());
        assert_eq!(through_a_scene(&local, &registry), local);
    }
    #[cfg(feature = "bevy_camera")]
    {
        let follow = FollowBevyFrustum::default().with_mode(CullMode::Exact);
        assert_eq!(through_a_scene(&follow, &registry), follow);
    }
}

#[test]
fn a_scene_edited_into_an_invalid_frustum_is_refused_not_loaded() {
    use serde::de::DeserializeSeed;
    let registry = plugin_registry();
    let registry = registry.read();
    let frustum = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0).unwrap();
    let saved = ron::to_string(&bevy_reflect::serde::ReflectSerializer::new(
        &frustum, &registry,
    ))
    .unwrap();
    let load = |text: &str| {
        let mut reader = ron::Deserializer::from_str(text).unwrap();
        bevy_reflect::serde::ReflectDeserializer::new(&registry)
            .deserialize(&mut reader)
            .map(|loaded| Frustum::from_reflect(loaded.as_ref()))
    };
    assert!(
        matches!(load(&saved), Ok(Some(f)) if f == frustum),
        "{saved}"
    );
    // The first plane's normal edited to zero, then to NaN (finite offsets):
    // neither is a plane a frustum may have.
    let first_plane = saved.find("Some((").expect("an active plane") + "Some((".len();
    let normal_end = first_plane + saved[first_plane..].find(')').unwrap();
    for normal in ["(0.0, 0.0, 0.0", "(NaN, 0.0, 1.0"] {
        let edited = format!("{}{normal}{}", &saved[..first_plane], &saved[normal_end..]);
        let error = load(&edited).expect_err(&edited).to_string();
        assert!(
            error.contains(&SpatialError::InvalidFrustum.to_string()),
            "{error}"
        );
    }
}

#[test]
fn an_inspector_clones_and_creates_the_components() {
    use bevy_reflect::std_traits::ReflectDefault;
    let registry = plugin_registry();
    let registry = registry.read();

    // Cloned through reflection, the fields reflection ignores included.
    let frustum = Frustum::perspective(Vec3::ZERO, Quat::IDENTITY, 1.0, 1.5, 0.1, 100.0).unwrap();
    let camera = CullingCamera::new(frustum);
    let clone = camera.reflect_clone().expect("CullingCamera clones");
    assert_eq!(clone.reflect_partial_eq(&camera), Some(true));
    let caster = RayCaster::new(Ray::new(Vec3::ZERO, Vec3::X, 5.0).unwrap(), RayMode::First);
    let clone = caster.reflect_clone().expect("RayCaster clones");
    assert_eq!(clone.reflect_partial_eq(&caster), Some(true));
    for value in [
        &VisibleEntityList::<SpatialBounds>::default() as &dyn Reflect,
        &RayCasterHits::<SpatialBounds>::default(),
    ] {
        assert!(
            value.reflect_clone().is_ok(),
            "{}",
            value.reflect_type_path()
        );
    }

    // Created from nothing, as an inspector's "add component" does.
    for (name, id, expected) in [
        (
            "SpatialBounds",
            TypeId::of::<SpatialBounds>(),
            Box::new(SpatialBounds::default()) as Box<dyn PartialReflect>,
        ),
        (
            "NoSpatialIndex",
            TypeId::of::<NoSpatialIndex>(),
            Box::new(NoSpatialIndex),
        ),
        (
            "SpatialDiagnostics",
            TypeId::of::<SpatialDiagnostics>(),
            Box::new(SpatialDiagnostics::default()),
        ),
    ] {
        let default = registry
            .get_type_data::<ReflectDefault>(id)
            .unwrap_or_else(|| panic!("{name} has a reflected Default"));
        assert_eq!(
            default.default().reflect_partial_eq(expected.as_ref()),
            Some(true),
            "{name}"
        );
    }
    #[cfg(feature = "bevy_camera")]
    {
        let default = registry
            .get_type_data::<ReflectDefault>(TypeId::of::<FollowBevyFrustum>())
            .expect("FollowBevyFrustum has a reflected Default");
        assert_eq!(
            default
                .default()
                .reflect_partial_eq(&FollowBevyFrustum::default()),
            Some(true)
        );
    }
    for (name, id) in [
        ("VisibleEntityList", TypeId::of::<VisibleEntityList>()),
        ("RayCasterHits", TypeId::of::<RayCasterHits>()),
    ] {
        assert!(
            registry.get_type_data::<ReflectDefault>(id).is_some(),
            "{name} has a reflected Default"
        );
    }

    // The geometry types no component field reaches are registered too.
    for (name, id) in [
        ("HalfSpace", TypeId::of::<HalfSpace>()),
        ("JoinMode", TypeId::of::<JoinMode>()),
        ("Frustum", TypeId::of::<Frustum>()),
    ] {
        assert!(registry.get(id).is_some(), "{name} is registered");
    }
}
