//! Bevy's light shadow visibility served by the index, against Bevy
//! itself: twin Apps from one seed with Bevy's `LightPlugin`, one running
//! Bevy's own `check_point_light_mesh_visibility` and
//! `check_dir_light_mesh_visibility`, the other with `BevyVisibilityPlugin`;
//! after every frame every caster's `ViewVisibility` and every light's
//! lists (cube faces, spot, cascades per view) must be the same.
#![cfg(feature = "bevy_light")]

#[path = "common/bevy_random.rs"]
mod bevy_random;

use std::collections::HashMap;

use bevy_app::prelude::*;
use bevy_asset::{AssetApp, AssetPlugin, Assets};
use bevy_camera::visibility::{
    CascadesVisibleEntities, CubemapVisibleEntities, NoCpuCulling, NoFrustumCulling, RenderLayers,
    ViewVisibility, VisibilityRange, VisibilitySystems, VisibleMeshEntities,
};
use bevy_camera::{Camera, Camera3d, CameraPlugin};
use bevy_ecs::prelude::*;
use bevy_light::{DirectionalLight, LightPlugin, NotShadowCaster, PointLight, SpotLight};
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_random::{random_aabb, random_transform, random_visibility};
use bevy_rtree::plugin::{
    BevyVisibilityPlugin, BevyVisibilitySettings, Renderable, SpatialIndex, SpatialIndexPlugin,
};
use bevy_rtree::scene::SceneRng;
use bevy_transform::prelude::*;
use glam::{Quat, Vec3};

/// A headless App with Bevy's transforms, cameras and lights, and with the
/// index serving visibility if `ours`.
fn app(ours: bool) -> App {
    let mut app = App::new();
    app.add_plugins((
        TaskPoolPlugin::default(),
        AssetPlugin::default(),
        TransformPlugin,
        CameraPlugin,
        LightPlugin,
    ))
    .insert_resource(Assets::<Mesh>::default())
    .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
    .init_asset::<bevy_image::Image>();
    if ours {
        app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    }
    app.finish();
    app.cleanup();
    app
}

/// Inserts `C` where the entity lacks it, removes it where it has it.
fn toggle<C: Component + Default>(entity: &mut EntityWorldMut) {
    if entity.contains::<C>() {
        entity.remove::<C>();
    } else {
        entity.insert(C::default());
    }
}

/// Which kind of light a twin pair is.
#[derive(Clone, Copy)]
enum LightKind {
    Point,
    Spot,
    Directional,
}

struct Twins {
    apps: [App; 2],
    casters: Vec<[Entity; 2]>,
    lights: Vec<(LightKind, [Entity; 2])>,
    cameras: Vec<[Entity; 2]>,
    rng: SceneRng,
}

impl Twins {
    fn new(seed: u64) -> Twins {
        Twins {
            apps: [app(false), app(true)],
            casters: Vec::new(),
            lights: Vec::new(),
            cameras: Vec::new(),
            rng: SceneRng::new(seed),
        }
    }

    /// Runs `f` on both worlds with the same random draws.
    fn both<R>(&mut self, mut f: impl FnMut(&mut World, &mut SceneRng, usize) -> R) -> [R; 2] {
        let state = self.rng.clone();
        let a = f(self.apps[0].world_mut(), &mut self.rng, 0);
        self.rng = state;
        let b = f(self.apps[1].world_mut(), &mut self.rng, 1);
        [a, b]
    }

    fn spawn_caster(&mut self) {
        let parent = (self.rng.below(10) == 0 && !self.casters.is_empty())
            .then(|| self.casters[self.rng.below(self.casters.len())]);
        let pair = self.both(|world, rng, side| {
            let mut entity = world.spawn((
                Mesh3d::default(),
                random_transform(rng, 60.0, (-2.0, 12.0)),
                random_visibility(rng),
            ));
            // One in twelve has no box (Bevy's lights see it everywhere).
            if rng.below(12) != 0 {
                entity.insert(random_aabb(rng));
            }
            match rng.below(14) {
                0 => {
                    entity.insert(NoFrustumCulling);
                }
                1 => {
                    entity.insert(NoCpuCulling);
                }
                2 => {
                    entity.insert(NotShadowCaster);
                }
                3 => {
                    entity.insert(RenderLayers::layer(1));
                }
                4 => {
                    entity.insert(VisibilityRange::abrupt(0.0, rng.range(10.0, 80.0)));
                }
                _ => {}
            }
            if let Some(parent) = parent {
                entity.insert(ChildOf(parent[side]));
            }
            entity.id()
        });
        self.casters.push(pair);
    }

    fn spawn_camera(&mut self, active: bool) {
        let pair = self.both(|world, rng, _| {
            let eye = Vec3::new(rng.range(-40.0, 40.0), 5.0, rng.range(-40.0, 40.0));
            let look = Quat::from_rotation_y(rng.range(0.0, 6.3)) * Quat::from_rotation_x(-0.2);
            world
                .spawn((
                    Camera3d::default(),
                    Camera {
                        is_active: active,
                        ..Camera::default()
                    },
                    Transform::from_translation(eye).with_rotation(look),
                ))
                .id()
        });
        self.cameras.push(pair);
    }

    fn spawn_light(&mut self, kind: LightKind) {
        let pair = self.both(|world, rng, _| {
            let at = Vec3::new(
                rng.range(-50.0, 50.0),
                rng.range(1.0, 15.0),
                rng.range(-50.0, 50.0),
            );
            let shadows = rng.below(5) != 0;
            let mut light = match kind {
                LightKind::Point => world.spawn((
                    PointLight {
                        range: rng.range(3.0, 30.0),
                        shadow_maps_enabled: shadows,
                        ..PointLight::default()
                    },
                    Transform::from_translation(at),
                )),
                LightKind::Spot => world.spawn((
                    SpotLight {
                        range: rng.range(5.0, 40.0),
                        outer_angle: rng.range(0.2, 1.2),
                        shadow_maps_enabled: shadows,
                        ..SpotLight::default()
                    },
                    Transform::from_translation(at).looking_at(Vec3::ZERO, Vec3::Y),
                )),
                LightKind::Directional => world.spawn((
                    DirectionalLight {
                        shadow_maps_enabled: shadows,
                        ..DirectionalLight::default()
                    },
                    Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
                )),
            };
            if rng.below(6) == 0 {
                light.insert(RenderLayers::layer(1));
            }
            light.id()
        });
        self.lights.push((kind, pair));
    }

    /// One frame of random changes, the same in both worlds: the casters
    /// move, jump, change their markers and boxes, are disabled and
    /// despawned; the lights move and change; the cameras move, and now and
    /// then one is turned off or on.
    fn mutate(&mut self) {
        let n = self.casters.len();
        for _ in 0..n / 10 {
            let pair = self.casters[self.rng.below(n)];
            let action = self.rng.below(22);
            self.both(|world, rng, side| {
                let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                    return;
                };
                match action {
                    0..=8 => {
                        if let Some(mut t) = entity.get_mut::<Transform>() {
                            t.translation +=
                                Vec3::new(rng.range(-1.0, 1.0), 0.0, rng.range(-1.0, 1.0));
                            t.rotate_y(rng.range(-0.3, 0.3));
                        }
                    }
                    9..=10 => {
                        entity.insert(random_transform(rng, 60.0, (-2.0, 12.0)));
                    }
                    11 => {
                        entity.insert(random_visibility(rng));
                    }
                    12 => {
                        if entity.contains::<NotShadowCaster>() {
                            entity.remove::<NotShadowCaster>();
                        } else {
                            entity.insert(NotShadowCaster);
                        }
                    }
                    13 => {
                        // Bad input as Bevy sees it.
                        let bad = [
                            Transform::from_scale(Vec3::ZERO),
                            Transform::from_xyz(f32::NAN, 0.0, 0.0),
                        ][rng.below(2)];
                        entity.insert(bad);
                    }
                    14 => {
                        entity.insert(random_aabb(rng));
                    }
                    15 => {
                        toggle::<NoFrustumCulling>(&mut entity);
                    }
                    16 => {
                        toggle::<NoCpuCulling>(&mut entity);
                    }
                    17 => {
                        toggle::<bevy_ecs::entity_disabling::Disabled>(&mut entity);
                    }
                    18 => {
                        // No box, or one Bevy's tests see as bad.
                        if rng.below(2) == 0 {
                            entity.remove::<bevy_camera::primitives::Aabb>();
                        } else {
                            entity.insert(bevy_camera::primitives::Aabb {
                                center: Vec3::ZERO.into(),
                                half_extents: Vec3::new(-1.0, 1.0, f32::NAN).into(),
                            });
                        }
                    }
                    19 => {
                        // A second marker beside the one it may have.
                        if rng.below(2) == 0 {
                            entity.insert(VisibilityRange::abrupt(0.0, rng.range(10.0, 80.0)));
                        } else {
                            entity.insert(RenderLayers::from_layers(&[0, 1]));
                        }
                    }
                    20 => {
                        entity.insert(RenderLayers::none());
                    }
                    _ => {
                        entity.despawn();
                    }
                }
            });
        }
        for _ in 0..n / 50 {
            self.spawn_caster();
        }
        for (kind, pair) in self.lights.clone() {
            let change = self.rng.below(12);
            self.both(|world, rng, side| {
                let mut light = world.entity_mut(pair[side]);
                let mut t = light.get_mut::<Transform>().unwrap();
                t.translation += Vec3::new(rng.range(-2.0, 2.0), 0.0, rng.range(-2.0, 2.0));
                // Now and then the light itself changes: its shadows, its
                // layers, its range (none at all, too) or its cone.
                match (change, kind) {
                    (0, LightKind::Point) => {
                        let mut point = light.get_mut::<PointLight>().unwrap();
                        point.shadow_maps_enabled = !point.shadow_maps_enabled;
                    }
                    (0, LightKind::Spot) => {
                        let mut spot = light.get_mut::<SpotLight>().unwrap();
                        spot.shadow_maps_enabled = !spot.shadow_maps_enabled;
                    }
                    (0, LightKind::Directional) => {
                        let mut sun = light.get_mut::<DirectionalLight>().unwrap();
                        sun.shadow_maps_enabled = !sun.shadow_maps_enabled;
                    }
                    (1, _) => {
                        let layers = [RenderLayers::layer(0), RenderLayers::layer(1)];
                        light.insert(layers[rng.below(2)].clone());
                    }
                    (2, LightKind::Point) => {
                        let range = [0.0, rng.range(3.0, 30.0)][rng.below(2)];
                        light.get_mut::<PointLight>().unwrap().range = range;
                    }
                    (2, LightKind::Spot) => {
                        let mut spot = light.get_mut::<SpotLight>().unwrap();
                        spot.range = [0.0, rng.range(5.0, 40.0)][rng.below(2)];
                        spot.outer_angle = rng.range(0.05, 1.5);
                        spot.inner_angle = spot.inner_angle.min(spot.outer_angle);
                    }
                    _ => {}
                }
            });
        }
        for pair in self.cameras.clone() {
            let switch = self.rng.below(15) == 0;
            self.both(|world, rng, side| {
                let mut t = world.get_mut::<Transform>(pair[side]).unwrap();
                t.translation += Vec3::new(rng.range(-3.0, 3.0), 0.0, rng.range(-3.0, 3.0));
                t.rotate_y(rng.range(-0.4, 0.4));
                if switch {
                    let mut camera = world.get_mut::<Camera>(pair[side]).unwrap();
                    camera.is_active = !camera.is_active;
                }
            });
        }
    }

    /// Every caster's `ViewVisibility` and every light's lists, mapped to
    /// spawn order, are the same in both worlds; returns how many entries
    /// the lists of point, spot and directional lights hold.
    fn check(&self, frame: usize) -> [usize; 3] {
        for (i, pair) in self.casters.iter().enumerate() {
            let [bevy, ours] = [0, 1].map(|side| {
                let world = self.apps[side].world();
                world
                    .get_entity(pair[side])
                    .ok()
                    .and_then(|e| e.get::<ViewVisibility>().map(|v| v.get()))
            });
            assert_eq!(bevy, ours, "frame {frame}: ViewVisibility of caster {i}");
        }
        let [bevy, ours] = [0, 1].map(|side| self.light_lists(side));
        for (l, (b, o)) in bevy.iter().zip(&ours).enumerate() {
            assert_eq!(b, o, "frame {frame}: the lists of light {l}");
        }
        let mut listed = [0; 3];
        for ((kind, _), lists) in self.lights.iter().zip(&bevy) {
            let entries: usize = lists.iter().map(Vec::len).sum();
            listed[*kind as usize] += entries;
        }
        listed
    }

    /// Each light's lists (six faces, one spot list, or one list per
    /// cascade of each camera), as spawn indices, sorted.
    fn light_lists(&self, side: usize) -> Vec<Vec<Vec<usize>>> {
        let world = self.apps[side].world();
        let spawned: HashMap<Entity, usize> = self
            .casters
            .iter()
            .enumerate()
            .map(|(i, p)| (p[side], i))
            .collect();
        let map = |list: &VisibleMeshEntities| {
            assert!(list.entities.is_sorted(), "sorted, as Bevy sorts them");
            let mut out: Vec<usize> = list.entities.iter().map(|e| spawned[e]).collect();
            out.sort_unstable();
            out
        };
        self.lights
            .iter()
            .map(|(kind, pair)| {
                let light = world.entity(pair[side]);
                match kind {
                    LightKind::Point => light
                        .get::<CubemapVisibleEntities>()
                        .unwrap()
                        .iter()
                        .map(map)
                        .collect(),
                    LightKind::Spot => vec![map(light.get::<VisibleMeshEntities>().unwrap())],
                    LightKind::Directional => {
                        let cascades = light.get::<CascadesVisibleEntities>().unwrap();
                        let mut lists = Vec::new();
                        for camera in &self.cameras {
                            let per_view = cascades.entities.get(&camera[side]);
                            lists.push(vec![per_view.map_or(usize::MAX, Vec::len)]);
                            lists.extend(per_view.into_iter().flatten().map(map));
                        }
                        lists
                    }
                }
            })
            .collect()
    }

    fn update(&mut self) {
        self.apps.iter_mut().for_each(App::update);
    }
}

/// Random scenes of two thousand casters, point, spot and directional
/// lights with and without shadows, two active cameras and an inactive
/// one, over frames of moves, teleports, toggles, bad transforms,
/// despawns and respawns.
#[test]
fn lights_see_what_bevy_lights_see_every_frame() {
    for seed in 0..2 {
        let mut twins = Twins::new(seed);
        // The second scene runs without the inside proof: every cascade
        // candidate takes Bevy's test.
        twins.apps[1].insert_resource(BevyVisibilitySettings {
            prove_inside: seed == 0,
            ..Default::default()
        });
        for _ in 0..2_000 {
            twins.spawn_caster();
        }
        twins.spawn_camera(true);
        twins.spawn_camera(true);
        twins.spawn_camera(false);
        for _ in 0..6 {
            twins.spawn_light(LightKind::Point);
        }
        for _ in 0..3 {
            twins.spawn_light(LightKind::Spot);
        }
        twins.spawn_light(LightKind::Directional);
        twins.spawn_light(LightKind::Directional);
        let mut listed = [0; 3];
        for frame in 0..40 {
            twins.update();
            let seen = twins.check(frame);
            listed.iter_mut().zip(seen).for_each(|(l, s)| *l += s);
            twins.mutate();
        }
        // Point, spot and directional lights each see enough to compare.
        assert!(listed.iter().all(|&l| l > 2_000), "{listed:?}");
        let index = twins.apps[1].world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
    }
}

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

/// Systems an app orders after or before Bevy's visibility systems stay
/// ordered so against the systems that replace them: a probe that reads
/// the lists `.after(check_point_light_mesh_visibility)`,
/// `.after(check_dir_light_mesh_visibility)` or
/// `.after(check_visibility_cpu_culling)` never reads last frame's lists,
/// and one that writes what a light system reads
/// `.before(check_point_light_mesh_visibility)` or
/// `.before(check_dir_light_mesh_visibility)` is seen in the same frame.
/// Checked on the built schedule: no system that accesses what a probe
/// writes or reads runs unordered with it, in either App.
#[test]
fn systems_ordered_against_bevy_s_are_ordered_against_the_index_s() {
    use bevy_camera::visibility::{VisibleEntities, check_visibility_cpu_culling};
    use bevy_ecs::schedule::{IntoSystemSet, Schedules, SystemSet};
    use bevy_light::{check_dir_light_mesh_visibility, check_point_light_mesh_visibility};

    fn light_probe(lists: Query<&CubemapVisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn cascade_probe(lists: Query<&CascadesVisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn camera_probe(lists: Query<&VisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn visibility_probe(marks: Query<&ViewVisibility>) {
        let _ = marks.iter().filter(|v| v.get()).count();
    }
    fn point_writer(mut lists: Query<&mut CubemapVisibleEntities>) {
        lists.iter_mut().for_each(|mut l| l.set_changed());
    }
    fn cascade_writer(mut lists: Query<&mut CascadesVisibleEntities>) {
        lists.iter_mut().for_each(|mut l| l.set_changed());
    }
    let probes = [
        light_probe.into_system_set().intern(),
        cascade_probe.into_system_set().intern(),
        camera_probe.into_system_set().intern(),
        visibility_probe.into_system_set().intern(),
        point_writer.into_system_set().intern(),
        cascade_writer.into_system_set().intern(),
    ];
    // The readers after and the writers before in Apps of their own: a
    // reader after a system and a writer before it are ordered through
    // the set the system leaves behind, which would hide a writer the
    // replacement does not follow.
    for (writers, ours) in [(false, false), (false, true), (true, false), (true, true)] {
        let mut app = app(ours);
        if writers {
            app.add_systems(
                PostUpdate,
                (
                    point_writer.before(check_point_light_mesh_visibility),
                    cascade_writer.before(check_dir_light_mesh_visibility),
                ),
            );
        } else {
            app.add_systems(
                PostUpdate,
                (
                    light_probe.after(check_point_light_mesh_visibility),
                    cascade_probe.after(check_dir_light_mesh_visibility),
                    camera_probe.after(check_visibility_cpu_culling),
                    // Bevy's directional light marks its casters by
                    // command, reading no caster's `ViewVisibility`: a
                    // reader after the point lights needs no other order.
                    visibility_probe
                        .after(check_point_light_mesh_visibility)
                        .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
                ),
            );
        }
        app.update();
        let schedule = app.world().resource::<Schedules>().get(PostUpdate).unwrap();
        // Between runs the systems are held by the schedule's executable;
        // each is known by its function's set.
        let is_probe: HashMap<_, bool> = schedule
            .systems()
            .unwrap()
            .map(|(key, system)| {
                let sets = system.default_system_sets();
                (key, probes.iter().any(|probe| sets.contains(probe)))
            })
            .collect();
        let unordered: Vec<_> = schedule
            .graph()
            .conflicting_systems()
            .0
            .iter()
            .filter(|(a, b, _)| is_probe[a] != is_probe[b])
            .collect();
        assert!(
            unordered.is_empty(),
            "writers {writers}, ours {ours}: {unordered:?}"
        );
    }
}

/// bevy_light's two systems are not ordered against each other: an app's
/// systems between them (`a` after one, `b` before the other, `a` before
/// `b`) must not close a cycle around their replacements, and the app runs
/// as with Bevy's systems.
#[test]
fn systems_between_bevy_s_two_light_systems_make_no_cycle() {
    use bevy_light::{check_dir_light_mesh_visibility, check_point_light_mesh_visibility};

    fn a() {}
    fn b() {}
    for ours in [false, true] {
        let mut app = app(ours);
        app.add_systems(
            PostUpdate,
            (
                a.after(check_dir_light_mesh_visibility),
                b.before(check_point_light_mesh_visibility),
            )
                .chain(),
        );
        app.update();
        app.update();
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
