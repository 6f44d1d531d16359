//! Light probes boxed by command, a view without cascades, and casters
//! where Bevy's `f32` sphere test overflows.

use super::*;

/// Light probes and clustered decals get their `Aabb` from bevy_light's
/// own system, through commands, in the frame they are spawned; Bevy's
/// culling sees that box in the same frame, and so must the index. Probes
/// spawned in view (and one out of view) frame after frame are visible
/// exactly when Bevy says they are.
#[test]
fn light_probes_are_seen_in_the_frame_they_get_their_box() {
    use bevy_light::LightProbe;
    let mut apps = [app(false), app(true)];
    let mut probes: [Vec<Entity>; 2] = [Vec::new(), Vec::new()];
    for app in &mut apps {
        app.world_mut()
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)));
    }
    for frame in 0..5 {
        for (app, spawned) in apps.iter_mut().zip(&mut probes) {
            let ahead = app
                .world_mut()
                .spawn((
                    LightProbe::default(),
                    Transform::from_xyz(frame as f32, 0.0, 0.0),
                ))
                .id();
            let behind = app
                .world_mut()
                .spawn((LightProbe::default(), Transform::from_xyz(0.0, 0.0, 40.0)))
                .id();
            spawned.extend([ahead, behind]);
            app.update();
        }
        let [bevy, ours] = [0, 1].map(|side| {
            probes[side]
                .iter()
                .map(|&e| apps[side].world().get::<ViewVisibility>(e).map(|v| v.get()))
                .collect::<Vec<_>>()
        });
        assert_eq!(bevy, ours, "frame {frame}");
        let expected: Vec<_> = (0..bevy.len()).map(|i| Some(i % 2 == 0)).collect();
        assert_eq!(
            bevy, expected,
            "frame {frame}: probes ahead seen, behind culled"
        );
    }
}

/// A directional light whose view has no cascades (a `CascadeShadowConfig`
/// with no bounds) lists nothing, but Bevy still marks the casters it
/// cannot bound (no `Aabb`) visible: so must the index. The caster is on a
/// layer the camera does not render, so only the light can mark it.
#[test]
fn a_view_without_cascades_still_marks_unbounded_casters() {
    use bevy_light::CascadeShadowConfig;
    let mut apps = [app(false), app(true)];
    let casters = apps.each_mut().map(|app| {
        let world = app.world_mut();
        world.spawn((Camera3d::default(), Transform::from_xyz(0.0, 2.0, 10.0)));
        world.spawn((
            DirectionalLight {
                shadow_maps_enabled: true,
                ..DirectionalLight::default()
            },
            CascadeShadowConfig {
                bounds: Vec::new(),
                ..CascadeShadowConfig::default()
            },
            RenderLayers::from_layers(&[0, 1]),
            Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
        ));
        let unbounded = world
            .spawn((
                Mesh3d::default(),
                Transform::default(),
                RenderLayers::layer(1),
            ))
            .id();
        let bounded = world
            .spawn((
                Mesh3d::default(),
                Transform::default(),
                RenderLayers::layer(1),
                bevy_camera::primitives::Aabb::from_min_max(Vec3::splat(-1.0), Vec3::ONE),
            ))
            .id();
        [unbounded, bounded]
    });
    for frame in 0..3 {
        apps.iter_mut().for_each(App::update);
        let [bevy, ours] = [0, 1].map(|side| {
            casters[side].map(|e| apps[side].world().get::<ViewVisibility>(e).map(|v| v.get()))
        });
        assert_eq!(bevy, ours, "frame {frame}");
        assert_eq!(
            bevy,
            [Some(true), Some(false)],
            "frame {frame}: Bevy marks the unbounded caster only"
        );
    }
}

/// Bevy's sphere test of point and spot lights runs in `f32`, and where its
/// products or squares overflow to infinity it accepts the caster, leaving
/// the light's frusta to decide: a caster whose transform has a column of
/// 1e37 (its box small, a metre wide), and lights so far away (2e19 m)
/// that the distance squared overflows, seen from a camera inside their
/// range. Each caster is listed, and marked visible, as Bevy lists and
/// marks it; Bevy does list the point lights' overflowing casters, so the
/// case is met.
#[test]
fn casters_where_bevy_s_sphere_test_overflows_are_listed_as_bevy_lists_them() {
    use bevy_camera::primitives::Aabb;
    let mut twins = Twins::new(3);
    let thin = |scale: f32| Aabb {
        center: Vec3::ZERO.into(),
        half_extents: Vec3::new(0.5 / scale, 0.5, 0.5).into(),
    };
    // Near a light at the origin (range 100): a caster stretched 1e37 times
    // along x (a column Bevy's test overflows on), one stretched 1e17 times
    // (one it does not), and one at the origin for the far lights.
    let corner = Vec3::splat(86.6);
    let casters = [
        (corner, 1e37, thin(1e37)),
        (corner, 1e17, thin(1e17)),
        (corner + Vec3::Y, 1.0, thin(1.0)),
        (Vec3::ZERO, 1.0, thin(1.0)),
    ];
    for (at, scale, aabb) in casters {
        let pair = twins.both(|world, _, _| {
            world
                .spawn((
                    Mesh3d::default(),
                    Transform::from_translation(at).with_scale(Vec3::new(scale, 1.0, 1.0)),
                    aabb,
                ))
                .id()
        });
        twins.casters.push(pair);
    }
    let far = Vec3::new(1.6e19, 1.4e19, 0.0);
    let lights = [
        (LightKind::Point, Vec3::ZERO, 100.0),
        (LightKind::Point, far, 2.1e19),
        (LightKind::Spot, far, 2.1e19),
    ];
    for (kind, at, range) in lights {
        let pair = twins.both(|world, _, _| {
            // The spot looks 20 degrees aside from the caster at the origin:
            // the caster is then beyond the range but not beyond the far
            // plane, where only the overflow of the sphere test accepts it.
            let aim = if at == far {
                Vec3::new(0.0, 0.0, 8e18)
            } else {
                Vec3::ZERO
            };
            let place = Transform::from_translation(at).looking_at(aim, Vec3::Y);
            let light = match kind {
                LightKind::Spot => world.spawn((
                    SpotLight {
                        range,
                        shadow_maps_enabled: true,
                        ..SpotLight::default()
                    },
                    place,
                )),
                _ => world.spawn((
                    PointLight {
                        range,
                        shadow_maps_enabled: true,
                        ..PointLight::default()
                    },
                    place,
                )),
            };
            light.id()
        });
        twins.lights.push((kind, pair));
    }
    let camera = twins.both(|world, _, _| {
        world
            .spawn((
                Camera3d::default(),
                Transform::from_xyz(1e18, 1e18, 0.0).looking_at(Vec3::ZERO, Vec3::Y),
            ))
            .id()
    });
    twins.cameras.push(camera);
    for frame in 0..3 {
        twins.update();
        twins.check(frame);
    }
    // Bevy lists the 1e37 caster for the near light, and the caster at the
    // origin for the far point light (beyond its range, inside its face's
    // far plane), where its sphere test overflows.
    let lists = twins.light_lists(0);
    let listed = |light: usize, caster: usize| lists[light].iter().flatten().any(|&c| c == caster);
    assert!(listed(0, 0) && listed(1, 3), "{lists:?}");
    let index = twins.apps[1].world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
}

/// Bevy's layer test answers yes for the same `RenderLayers` component
/// before it compares layers: a point light that also casts shadows (a
/// `Mesh3d` on its own entity) casts into its own shadow maps even with
/// no layers. An inactive camera keeps the list that names the light
/// (Bevy keeps an inactive camera's lists), so the light is still looked
/// at after its layers are emptied.
#[test]
fn a_light_that_casts_with_no_layers_sees_itself_as_bevy_does() {
    let mut apps = [app(false), app(true)];
    let ids = apps.each_mut().map(|app| {
        let world = app.world_mut();
        let camera = world
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)))
            .id();
        // A bulb: the light and its mesh on one entity (no `Aabb`: the
        // mesh handle names no asset), shadows on.
        let light = world
            .spawn((
                PointLight {
                    range: 20.0,
                    shadow_maps_enabled: true,
                    ..PointLight::default()
                },
                Mesh3d::default(),
                Transform::default(),
            ))
            .id();
        [camera, light]
    });
    // The active camera sees the light and lists it.
    apps.iter_mut().for_each(App::update);
    for (app, [camera, light]) in apps.iter_mut().zip(ids) {
        let world = app.world_mut();
        world.get_mut::<Camera>(camera).unwrap().is_active = false;
        world.entity_mut(light).insert(RenderLayers::none());
    }
    for frame in 0..3 {
        apps.iter_mut().for_each(App::update);
        let [bevy, ours] = [0, 1].map(|side| {
            let light = apps[side].world().entity(ids[side][1]);
            let faces: Vec<usize> = light
                .get::<CubemapVisibleEntities>()
                .unwrap()
                .iter()
                .map(|face| face.entities.len())
                .collect();
            (light.get::<ViewVisibility>().unwrap().get(), faces)
        });
        assert_eq!(bevy, (true, vec![1; 6]), "frame {frame}: Bevy's own answer");
        assert_eq!(bevy, ours, "frame {frame}");
    }
}
