//! Bevy's own visibility served by the index, against Bevy itself: twin
//! Apps from one seed, one running Bevy's `check_visibility_cpu_culling`,
//! the other with `BevyVisibilityPlugin`; after every frame every entity's
//! `ViewVisibility` and every camera's `VisibleEntities` must be the same.
#![cfg(feature = "bevy_camera")]

#[path = "common/bevy_random.rs"]
mod bevy_random;

use std::any::TypeId;

use bevy_app::prelude::*;
use bevy_asset::Assets;
use bevy_camera::primitives::{Aabb, Sphere};
use bevy_camera::visibility::{
    InheritedVisibility, NoCpuCulling, NoFrustumCulling, RenderLayers, ViewVisibility, Visibility,
    VisibilityClass, VisibilityRange, VisibleEntities,
};
use bevy_camera::{Camera, Camera3d, CameraPlugin, OrthographicProjection, Projection};
use bevy_ecs::change_detection::Tick;
use bevy_ecs::entity_disabling::Disabled;
use bevy_ecs::prelude::*;
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_random::{random_aabb, random_transform, random_visibility};
use bevy_rtree::plugin::{
    BevyVisibilityPlugin, BevyVisibilitySettings, Renderable, RenderableHandle, SpatialDiagnostics,
    SpatialIndex, SpatialIndexPlugin,
};
use bevy_rtree::scene::SceneRng;
use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use bevy_transform::prelude::*;
use glam::{Quat, Vec3, Vec3A};

/// A visibility class of the app's own, beside Bevy's `Mesh3d`.
struct AppClass;

/// Bevy's compute pool with three threads (where bevy_tasks has threads:
/// features `parallel` or `multi_threaded`), so that the plugin's parallel
/// paths run even on a machine of two cores.
fn three_threads() {
    let pool = ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(3).build());
    if cfg!(any(feature = "parallel", feature = "multi_threaded")) {
        assert_eq!(pool.thread_num(), 3);
    }
}

/// A headless App with Bevy's transforms and cameras, and with the index
/// serving visibility if `ours`.
fn app(ours: bool) -> App {
    three_threads();
    let mut app = App::new();
    app.add_plugins((TransformPlugin, CameraPlugin))
        .insert_resource(Assets::<Mesh>::default())
        .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default());
    if ours {
        app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    }
    app
}

/// The twin Apps and the entities of the scene, in spawn order, in each.
struct Twins {
    bevy: App,
    ours: App,
    entities: Vec<[Entity; 2]>,
    cameras: Vec<[Entity; 2]>,
    rng: SceneRng,
    /// Half the width of the square the entities are spread over, in metres.
    spread: f32,
    /// Each world's change tick before its last update.
    before: [Tick; 2],
    /// The visibility classes either world's cameras had a list for in an
    /// earlier frame.
    classes_seen: Vec<TypeId>,
}

impl Twins {
    fn new(seed: u64) -> Twins {
        Twins {
            bevy: app(false),
            ours: app(true),
            entities: Vec::new(),
            cameras: Vec::new(),
            rng: SceneRng::new(seed),
            spread: 100.0,
            before: [Tick::new(0); 2],
            classes_seen: Vec::new(),
        }
    }

    /// Runs `f` on both worlds with the same random draws.
    fn both<R>(&mut self, mut f: impl FnMut(&mut World, &mut SceneRng, usize) -> R) -> [R; 2] {
        let state = self.rng.clone();
        let a = f(self.bevy.world_mut(), &mut self.rng, 0);
        self.rng = state;
        let b = f(self.ours.world_mut(), &mut self.rng, 1);
        [a, b]
    }

    fn spawn_entity(&mut self) {
        let parent = (self.rng.below(8) == 0 && !self.entities.is_empty())
            .then(|| self.entities[self.rng.below(self.entities.len())]);
        let spread = self.spread;
        let pair = self.both(|world, rng, side| {
            let mut entity = world.spawn((
                random_transform(rng, spread, (-5.0, 30.0)),
                random_visibility(rng),
            ));
            match rng.below(10) {
                0 => {
                    // No box: Bevy does not cull it.
                    entity.insert(VisibilityClass([TypeId::of::<Mesh3d>()].into()));
                }
                1 => {
                    // A bounding sphere, and a class of the app's own: each
                    // camera's lists must have the keys Bevy gives them.
                    entity.insert((
                        Sphere {
                            center: Vec3A::ZERO,
                            radius: rng.range(0.1, 3.0),
                        },
                        VisibilityClass([TypeId::of::<AppClass>()].into()),
                    ));
                }
                _ => {
                    entity.insert((Mesh3d::default(), random_aabb(rng)));
                }
            }
            match rng.below(12) {
                0 => {
                    entity.insert(NoFrustumCulling);
                }
                1 => {
                    entity.insert(NoCpuCulling);
                }
                2 => {
                    entity.insert(RenderLayers::layer(1));
                }
                3 => {
                    entity.insert(RenderLayers::from_layers(&[0, 1]));
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
        self.entities.push(pair);
    }

    fn spawn_camera(&mut self, kind: usize) {
        let pair = self.both(|world, rng, _| {
            let eye = Vec3::new(
                rng.range(-60.0, 60.0),
                rng.range(0.0, 20.0),
                rng.range(-60.0, 60.0),
            );
            let look = Quat::from_rotation_y(rng.range(0.0, 6.3)) * Quat::from_rotation_x(-0.2);
            let mut camera = world.spawn((
                Camera3d::default(),
                Transform::from_translation(eye).with_rotation(look),
            ));
            match kind {
                1 => {
                    camera.insert(Camera {
                        is_active: false,
                        ..Camera::default()
                    });
                }
                2 => {
                    camera.insert(RenderLayers::layer(1));
                }
                3 => {
                    camera.insert(NoCpuCulling);
                }
                4 => {
                    camera.insert(Projection::Orthographic(OrthographicProjection {
                        scale: 0.05,
                        ..OrthographicProjection::default_3d()
                    }));
                }
                _ => {}
            }
            camera.id()
        });
        self.cameras.push(pair);
    }

    /// One frame of random changes, the same in both worlds.
    fn mutate(&mut self) {
        let n = self.entities.len();
        let spread = self.spread;
        for _ in 0..n / 10 {
            let i = self.rng.below(n);
            let pair = self.entities[i];
            let action = self.rng.below(20);
            self.both(|world, rng, side| {
                let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                    return;
                };
                match action {
                    0..=9 => {
                        if let Some(mut t) = entity.get_mut::<Transform>() {
                            t.translation +=
                                Vec3::new(rng.range(-1.0, 1.0), 0.0, rng.range(-1.0, 1.0));
                            t.rotate_y(rng.range(-0.3, 0.3));
                        }
                    }
                    10..=11 => {
                        entity.insert(random_transform(rng, spread, (-5.0, 30.0)));
                    }
                    12 => {
                        entity.insert(random_visibility(rng));
                    }
                    13 => {
                        if entity.contains::<NoFrustumCulling>() {
                            entity.remove::<NoFrustumCulling>();
                        } else {
                            entity.insert(NoFrustumCulling);
                        }
                    }
                    14 => {
                        if entity.contains::<NoCpuCulling>() {
                            entity.remove::<NoCpuCulling>();
                        } else {
                            entity.insert(NoCpuCulling);
                        }
                    }
                    15 => {
                        entity.insert(random_aabb(rng));
                    }
                    16 => {
                        entity.remove::<Aabb>();
                    }
                    17 => {
                        // Bad input as Bevy sees it.
                        let bad = [
                            Transform::from_scale(Vec3::ZERO),
                            Transform::from_xyz(f32::NAN, 0.0, 0.0),
                        ][rng.below(2)];
                        entity.insert(bad);
                    }
                    18 => {
                        entity.insert(Aabb {
                            center: Vec3A::ZERO,
                            half_extents: Vec3A::new(
                                -1.0,
                                1.0,
                                f32::NAN * rng.range(0.0, 1.0).signum(),
                            ),
                        });
                    }
                    _ => {
                        entity.despawn();
                    }
                }
            });
        }
        for _ in 0..n / 50 {
            self.spawn_entity();
        }
        // The cameras move and turn.
        for pair in self.cameras.clone() {
            self.both(|world, rng, side| {
                let mut t = world.get_mut::<Transform>(pair[side]).unwrap();
                t.translation += Vec3::new(rng.range(-3.0, 3.0), 0.0, rng.range(-3.0, 3.0));
                t.rotate_y(rng.range(-0.4, 0.4));
            });
        }
    }

    /// Every entity's `ViewVisibility` (and whether the last update marked
    /// it changed) and every camera's visible lists, mapped to spawn order,
    /// are the same in both worlds.
    fn check(&mut self, frame: usize) -> usize {
        let mut visible = 0;
        let seen = |app: &App, entity: Entity, before: Tick| {
            let world = app.world();
            let entity = world.get_entity(entity).ok()?;
            let value = entity.get::<ViewVisibility>()?.get();
            let ticks = entity.get_change_ticks::<ViewVisibility>()?;
            let marked = ticks.is_changed(before, world.read_change_tick());
            Some((value, marked))
        };
        for (i, pair) in self.entities.iter().enumerate() {
            let bevy = seen(&self.bevy, pair[0], self.before[0]);
            let ours = seen(&self.ours, pair[1], self.before[1]);
            assert_eq!(
                bevy, ours,
                "frame {frame}: ViewVisibility of entity {i} (value, marked changed)"
            );
            visible += usize::from(bevy.is_some_and(|(value, _)| value));
        }
        let order = |app: &App, side: usize| {
            let index: std::collections::HashMap<Entity, usize> = self
                .entities
                .iter()
                .enumerate()
                .map(|(i, p)| (p[side], i))
                .collect();
            self.cameras
                .iter()
                .map(|cam| {
                    let lists = app.world().get::<VisibleEntities>(cam[side]).unwrap();
                    // Which classes have a list (extraction sees only
                    // those), then each class's entities.
                    let mut classes: Vec<TypeId> = lists.entities.keys().copied().collect();
                    classes.sort_unstable();
                    let listed = [TypeId::of::<Mesh3d>(), TypeId::of::<AppClass>()].map(|class| {
                        let list = lists.get(class);
                        assert!(
                            list.is_sorted(),
                            "sorted by Entity, as Bevy's diffing needs"
                        );
                        let mut spawned: Vec<usize> = list.iter().map(|e| index[e]).collect();
                        spawned.sort_unstable();
                        spawned
                    });
                    (classes, listed)
                })
                .collect::<Vec<_>>()
        };
        let (bevy_lists, our_lists) = (order(&self.bevy, 0), order(&self.ours, 1));
        // In the frame a class is first seen, Bevy gives a list for it only
        // to the cameras its query visits after the first that saw one, an
        // order the twin worlds need not share (their cameras' archetypes
        // can differ); from the next frame on every active camera has one.
        let mut classes: Vec<TypeId> = bevy_lists
            .iter()
            .chain(&our_lists)
            .flat_map(|(classes, _)| classes.iter().copied())
            .collect();
        classes.sort_unstable();
        classes.dedup();
        let settled = classes.iter().all(|c| self.classes_seen.contains(c));
        for (c, (b, o)) in bevy_lists.iter().zip(&our_lists).enumerate() {
            assert_eq!(b.1, o.1, "frame {frame}: camera {c}'s visible entities");
            if settled {
                assert_eq!(b.0, o.0, "frame {frame}: camera {c}'s classes");
            }
        }
        self.classes_seen.extend(classes);
        self.classes_seen.sort_unstable();
        self.classes_seen.dedup();
        visible
    }

    fn update(&mut self) {
        self.before = [
            self.bevy.world().read_change_tick(),
            self.ours.world().read_change_tick(),
        ];
        self.bevy.update();
        self.ours.update();
    }
}

/// Random scenes of a few thousand entities, five kinds of camera and
/// hundreds of frames of moves, teleports, toggles and respawns; the
/// second scene with the work kept on one thread.
#[test]
fn cameras_see_what_bevy_sees_every_frame() {
    for seed in 0..3 {
        let mut twins = Twins::new(seed);
        twins.ours.insert_resource(BevyVisibilitySettings {
            parallel: seed != 1,
            ..Default::default()
        });
        for _ in 0..2_000 {
            twins.spawn_entity();
        }
        for kind in [0, 0, 1, 2, 3, 4] {
            twins.spawn_camera(kind);
        }
        let mut seen = 0;
        for frame in 0..60 {
            twins.update();
            seen += twins.check(frame);
            twins.mutate();
        }
        assert!(seen > 10_000, "the cameras see enough to compare: {seen}");
        let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
        assert!(
            index.len() > 1_000,
            "the renderables are indexed: {}",
            index.len()
        );
        let diagnostics = twins.ours.world().resource::<SpatialDiagnostics>();
        assert!(diagnostics.culling.runs > 0);
        // The last frame's work: most candidates proven, the rest and the
        // entities outside the tree left to Bevy's tests.
        let work = diagnostics.bevy_visibility;
        assert!(
            work.proven > 0 && work.proven <= work.candidates,
            "{work:?}"
        );
        assert!(work.tested >= work.candidates - work.proven, "{work:?}");
    }
}

/// With the inside proof off (`BevyVisibilitySettings`), every candidate
/// takes Bevy's tests: the same answers.
#[test]
fn cameras_without_the_inside_proof_see_what_bevy_sees() {
    let mut twins = Twins::new(5);
    twins.ours.insert_resource(BevyVisibilitySettings {
        prove_inside: false,
        ..Default::default()
    });
    for _ in 0..2_000 {
        twins.spawn_entity();
    }
    for kind in [0, 2, 4] {
        twins.spawn_camera(kind);
    }
    let mut seen = 0;
    for frame in 0..20 {
        twins.update();
        seen += twins.check(frame);
        twins.mutate();
    }
    assert!(seen > 2_000, "the cameras see enough to compare: {seen}");
    let work = twins
        .ours
        .world()
        .resource::<SpatialDiagnostics>()
        .bevy_visibility;
    assert_eq!(work.proven, 0, "nothing proven with the proof off");
    assert!(
        work.candidates > 0 && work.tested >= work.candidates,
        "{work:?}"
    );
}

/// Entities spread over 4 km, cameras that each see a small part of them:
/// candidates are looked up one by one (the path for large worlds), not
/// decided in a pass over all entities.
#[test]
fn cameras_that_see_a_small_part_see_what_bevy_sees() {
    let mut twins = Twins::new(11);
    twins.spread = 2_000.0;
    for _ in 0..6_000 {
        twins.spawn_entity();
    }
    for kind in [0, 1, 2] {
        twins.spawn_camera(kind);
    }
    let mut seen = 0;
    for frame in 0..30 {
        twins.update();
        seen += twins.check(frame);
        twins.mutate();
    }
    // The counts include the entities no frustum culls (no box,
    // `NoFrustumCulling`): the tree's candidates are far fewer than an
    // eighth of the entities, which sends them to the look-up path.
    assert!(seen > 200, "{seen} seen in 30 frames");
}

/// Boxes placed across, on and just outside a camera's planes, closer than
/// the rounding of either test can tell: the tree must keep every box
/// Bevy's test accepts, and prove inside only boxes Bevy's test accepts.
#[test]
fn boxes_at_a_camera_plane_are_decided_as_bevy_decides() {
    let mut twins = Twins::new(7);
    twins.spawn_camera(0);
    twins.update();
    let camera = twins.cameras[0][0];
    let frustum = *twins
        .bevy
        .world()
        .get::<bevy_camera::primitives::Frustum>(camera)
        .unwrap();
    let eye = twins
        .bevy
        .world()
        .get::<GlobalTransform>(camera)
        .unwrap()
        .translation();
    let forward = twins
        .bevy
        .world()
        .get::<GlobalTransform>(camera)
        .unwrap()
        .forward();
    for _ in 0..4_000 {
        let pair = twins.both(|world, rng, _| {
            let plane = frustum.half_spaces[rng.below(5)];
            let n = Vec3::from(plane.normal());
            let q = eye
                + forward * rng.range(2.0, 60.0)
                + Vec3::new(
                    rng.range(-20.0, 20.0),
                    rng.range(-10.0, 10.0),
                    rng.range(-20.0, 20.0),
                );
            let on_plane = q - n * (n.dot(q) + plane.d());
            // Points and slivers too, which lie wholly within rounding of a plane.
            let half = Vec3::new(
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
                rng.range(0.0, 2.0),
            ) * [0.0, 1e-3, 1.0, 1.0][rng.below(4)];
            let reach = n.abs().dot(half);
            let delta =
                [1e-6, 1e-5, 3e-5, 1e-4, 1e-3, 5e-3, 2e-2][rng.below(7)] * rng.range(-1.0, 1.0);
            let center = on_plane - n * (reach + delta);
            world
                .spawn((
                    Mesh3d::default(),
                    Aabb {
                        center: Vec3A::ZERO,
                        half_extents: half.into(),
                    },
                    Transform::from_translation(center),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    twins.update();
    let seen = twins.check(0);
    assert!(
        seen > 1_000 && seen < 3_500,
        "both sides of the planes: {seen} seen"
    );
}

/// Entities spawned before the plugin is added (so without the component
/// that keeps their index handle) are indexed and decided as Bevy decides.
#[test]
fn entities_spawned_before_the_plugin_are_served_too() {
    let mut apps = [app(false), app(false)];
    let mut entities = [Vec::new(), Vec::new()];
    for (app, spawned) in apps.iter_mut().zip(&mut entities) {
        let mut rng = SceneRng::new(3);
        for _ in 0..500 {
            let entity = app
                .world_mut()
                .spawn((
                    Mesh3d::default(),
                    random_aabb(&mut rng),
                    random_transform(&mut rng, 50.0, (-5.0, 30.0)),
                ))
                .id();
            spawned.push(entity);
        }
        app.world_mut()
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 5.0, 60.0)));
    }
    apps[1].add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    for frame in 0..3 {
        for app in &mut apps {
            app.update();
        }
        let seen = |app: &App, list: &[Entity]| -> Vec<bool> {
            list.iter()
                .map(|&e| app.world().get::<ViewVisibility>(e).unwrap().get())
                .collect()
        };
        let (bevy, ours) = (seen(&apps[0], &entities[0]), seen(&apps[1], &entities[1]));
        assert_eq!(bevy, ours, "frame {frame}");
        assert!(bevy.iter().any(|&v| v) && !bevy.iter().all(|&v| v));
    }
    let index = apps[1].world().resource::<SpatialIndex<Renderable>>();
    assert_eq!(index.len(), 500);
}

/// A disabling component stored in a sparse set, registered in both Apps
/// after their plugins (as a plugin added later would; taking Bevy's
/// culling out when the plugin was built used to initialize `PostUpdate`
/// first, so that none of its queries left such entities out), makes
/// every query sparse, so no query of the plugin can be read table by
/// table: it goes row by row through Bevy's iteration, with the same
/// answers. Entities fall asleep (that component) and wake, and are
/// disabled (Bevy's `Disabled`) and enabled, every frame; neither side sees
/// them meanwhile. The scenes take both ways of deciding candidates (a
/// pass over every entity, and look-ups), on one thread and on several.
#[test]
fn a_sparse_disabling_component_changes_no_answer() {
    #[derive(Component)]
    #[component(storage = "SparseSet")]
    struct Asleep;
    for (seed, spread, parallel) in [(21, 100.0, true), (22, 100.0, false), (23, 2_000.0, true)] {
        let mut twins = Twins::new(seed);
        twins.spread = spread;
        twins.both(|world, _, _| world.register_disabling_component::<Asleep>());
        twins.ours.insert_resource(BevyVisibilitySettings {
            parallel,
            ..Default::default()
        });
        for _ in 0..3_000 {
            twins.spawn_entity();
        }
        for kind in [0, 1, 2] {
            twins.spawn_camera(kind);
        }
        let mut seen = 0;
        for frame in 0..20 {
            for _ in 0..30 {
                let pair = twins.entities[twins.rng.below(twins.entities.len())];
                let action = twins.rng.below(4);
                twins.both(|world, _, side| {
                    let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                        return;
                    };
                    match action {
                        0 => entity.insert(Asleep),
                        1 => entity.remove::<Asleep>(),
                        2 => entity.insert(Disabled),
                        _ => entity.remove::<Disabled>(),
                    };
                });
            }
            twins.update();
            seen += twins.check(frame);
            // Nothing asleep or disabled is left in the index.
            let world = twins.ours.world();
            let index = world.resource::<SpatialIndex<Renderable>>();
            index.validate().unwrap();
            for (_, entity, _) in index.tree().iter() {
                let held = world.entity(entity);
                assert!(
                    !held.contains::<Asleep>() && !held.contains::<Disabled>(),
                    "frame {frame}: {entity} is indexed while disabled"
                );
            }
            twins.mutate();
        }
        assert!(seen > 200, "seed {seed}: {seen} seen in 20 frames");
    }
}

/// An entity whose `Mesh3d` was removed and inserted again names its
/// visibility class twice (Bevy's hook pushes it again), and Bevy lists it
/// twice in the camera's list: so does the index, on both ways of deciding.
#[test]
fn a_class_named_twice_is_listed_twice_as_bevy_lists_it() {
    for spread in [100.0, 2_000.0] {
        let mut twins = Twins::new(31);
        twins.spread = spread;
        for _ in 0..3_000 {
            twins.spawn_entity();
        }
        twins.spawn_camera(0);
        for pair in twins.entities.clone().iter().step_by(3) {
            twins.both(|world, _, side| {
                let mut entity = world.entity_mut(pair[side]);
                if entity.take::<Mesh3d>().is_some() {
                    entity.insert(Mesh3d::default());
                }
            });
        }
        for frame in 0..5 {
            twins.update();
            twins.check(frame);
            twins.mutate();
        }
        let camera = twins.cameras[0][0];
        let list = twins
            .bevy
            .world()
            .get::<VisibleEntities>(camera)
            .unwrap()
            .get(TypeId::of::<Mesh3d>());
        let twice = list.windows(2).filter(|w| w[0] == w[1]).count();
        assert!(twice > 0, "spread {spread}: Bevy lists some entity twice");
    }
}

/// `CulledColumns::set_visible` writes `ViewVisibility`'s change ticks as Bevy's
/// `set_visible` does, which also updates a column's summary tick where the
/// component keeps one: `ViewVisibility` keeps none.
#[test]
fn view_visibility_keeps_no_summary_tick() {
    let mut world = World::new();
    let id = world.register_component::<ViewVisibility>();
    let info = world.components().get_info(id).unwrap();
    assert!(!info.summary_tick());
}

/// An entity that gets its visibility components after its box is culled
/// from then on, as Bevy culls it: gaining `InheritedVisibility` and
/// `ViewVisibility` puts an entity into the set Bevy's culling tests as
/// much as gaining a box does. Entities spawned with a box and no
/// visibility get it a few frames later, some lose it and get it back.
#[test]
fn entities_that_get_their_visibility_late_are_culled_as_bevy_culls_them() {
    let mut twins = Twins::new(11);
    for kind in [0, 0, 4] {
        twins.spawn_camera(kind);
    }
    let spread = 60.0;
    for _ in 0..600 {
        let pair = twins.both(|world, rng, _| {
            world
                .spawn((
                    random_transform(rng, spread, (-5.0, 30.0)),
                    random_aabb(rng),
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    let mut visible = 0;
    for frame in 0..12 {
        let entities = twins.entities.clone();
        for (i, pair) in entities.iter().enumerate() {
            twins.both(|world, _, side| {
                let mut entity = world.entity_mut(pair[side]);
                match frame {
                    2 if i % 2 == 0 => {
                        entity.insert(Visibility::Visible);
                    }
                    5 => {
                        entity.insert(Visibility::Inherited);
                    }
                    8 if i % 3 == 0 => {
                        entity.remove::<(Visibility, InheritedVisibility, ViewVisibility)>();
                    }
                    10 if i % 3 == 0 => {
                        entity.insert(Visibility::Visible);
                    }
                    _ => {}
                }
            });
        }
        twins.update();
        visible = twins.check(frame);
    }
    assert!(visible > 0, "the cameras see some of the entities");
}

/// Where entities with a box existed before the plugin, Bevy refuses the
/// handle as a required component of `Aabb`, and no entity gets one: an
/// entity given its visibility after its box is still culled as Bevy culls
/// it (observers stand in for the handle's hook).
#[test]
fn late_visibility_is_seen_where_no_entity_gets_the_handle() {
    let mut apps = [app(false), app(false)];
    let mut late = Vec::new();
    for app in &mut apps {
        app.world_mut().spawn((
            Mesh3d::default(),
            Aabb::from_min_max(Vec3::splat(-40.0), Vec3::splat(-39.0)),
            Transform::default(),
        ));
        app.world_mut()
            .spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 20.0)));
    }
    apps[1].add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
    for app in &mut apps {
        app.update();
        let entity = app
            .world_mut()
            .spawn((
                Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                Transform::default(),
                VisibilityClass([TypeId::of::<Mesh3d>()].into()),
            ))
            .id();
        app.update();
        app.world_mut()
            .entity_mut(entity)
            .insert(Visibility::Visible);
        app.update();
        app.update();
        late.push(entity);
    }
    assert!(apps[1].world().get::<RenderableHandle>(late[1]).is_none());
    let seen: Vec<Option<bool>> = apps
        .iter()
        .zip(&late)
        .map(|(app, &e)| app.world().get::<ViewVisibility>(e).map(|v| v.get()))
        .collect();
    assert_eq!(seen, vec![Some(true), Some(true)]);
}

/// A transform with a column near `f32::MAX` over a box flat along it:
/// Bevy's box test then computes NaN for a plane, which culls nothing, so
/// Bevy keeps an entity whose (small, valid) world box lies outside that
/// plane. Such entities are decided by Bevy's test alone, as Bevy decides.
#[test]
fn entities_on_huge_columns_are_decided_as_bevy_decides() {
    use glam::Affine3A;
    let mut twins = Twins::new(17);
    // At the origin, looking down -Z: the left plane's normal is about
    // (0.92, 0, -0.38).
    let camera =
        twins.both(|world, _, _| world.spawn((Camera3d::default(), Transform::IDENTITY)).id());
    twins.cameras.push(camera);
    for i in 0..40 {
        let pair = twins.both(|world, rng, _| {
            // Left of the view, from just outside its plane (within the
            // box's bounding sphere) to well outside; the first column is
            // huge and meets a half extent of 0.
            let at = Vec3::new(-5.2 - rng.range(0.0, 0.5), 0.0, -10.0);
            let huge = f32::MAX * if i % 2 == 0 { 1.0 } else { 0.6 };
            let columns =
                Affine3A::from_cols(Vec3A::new(huge, 0.0, -huge), Vec3A::Y, Vec3A::Z, at.into());
            world
                .spawn((
                    GlobalTransform::from(columns),
                    Aabb {
                        center: Vec3A::ZERO,
                        half_extents: Vec3A::new(0.0, 1.0, 1.0),
                    },
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    for frame in 0..3 {
        twins.update();
        // Half of them overflow Bevy's test: it keeps most of those.
        let kept = twins.check(frame);
        assert!((1..=20).contains(&kept), "frame {frame}: {kept}");
    }
    let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
}

/// A tiny scale (1e-16 on every axis, whose determinant underflows `f32`)
/// collapses no axis: such entities are indexed like any other, and seen
/// as Bevy sees them.
#[test]
fn entities_of_a_tiny_scale_are_indexed_and_seen_as_bevy_sees_them() {
    let mut twins = Twins::new(13);
    twins.spawn_camera(0);
    for i in 0..200 {
        let pair = twins.both(|world, rng, _| {
            let mut transform = random_transform(rng, 40.0, (-5.0, 30.0));
            if i % 2 == 0 {
                transform.scale = Vec3::splat(1e-16);
            }
            world
                .spawn((
                    transform,
                    random_aabb(rng),
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        });
        twins.entities.push(pair);
    }
    for frame in 0..3 {
        twins.update();
        twins.check(frame);
    }
    let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
    assert_eq!(index.unindexed().count(), 0);
    assert_eq!(index.len(), 200);
}

/// The renderables' layer belongs to `BevyVisibilityPlugin`: a join over
/// it, registered after the plugin, shares its one index, and a mesh the
/// app takes out of its own index (`NoSpatialIndex`) stays in the
/// renderables' and is seen as Bevy sees it.
#[test]
fn a_join_over_the_renderables_shares_their_index() {
    use bevy_rtree::JoinMode;
    use bevy_rtree::plugin::{NoSpatialIndex, SpatialAppExt, SpatialJoin};
    let mut bevy = app(false);
    let mut ours = app(true);
    ours.add_spatial_join::<Renderable, Renderable>(1.0, JoinMode::Euclidean);
    let meshes = [&mut bevy, &mut ours].map(|app| {
        let world = app.world_mut();
        world.spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 10.0)));
        let spawn = |world: &mut World, x: f32| {
            world
                .spawn((
                    Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                    Transform::from_xyz(x, 0.0, 0.0),
                    Visibility::Visible,
                    VisibilityClass([TypeId::of::<Mesh3d>()].into()),
                ))
                .id()
        };
        [spawn(world, 0.0), spawn(world, 1.5)]
    });
    for frame in 0..3 {
        if frame == 1 {
            for (app, pair) in [&mut bevy, &mut ours].into_iter().zip(&meshes) {
                app.world_mut().entity_mut(pair[0]).insert(NoSpatialIndex);
            }
        }
        bevy.update();
        ours.update();
        let apps = [&bevy, &ours];
        let [seen_by_bevy, seen_by_ours] = [0, 1].map(|side| {
            meshes[side].map(|e| apps[side].world().get::<ViewVisibility>(e).unwrap().get())
        });
        assert_eq!(seen_by_bevy, [true, true], "frame {frame}");
        assert_eq!(seen_by_ours, seen_by_bevy, "frame {frame}");
        let index = ours.world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
        assert_eq!(index.len(), 2, "frame {frame}");
        let join = ours
            .world()
            .resource::<SpatialJoin<Renderable, Renderable>>();
        let (a, b) = (meshes[1][0], meshes[1][1]);
        assert_eq!(
            join.pairs(),
            [(a.min(b), a.max(b))],
            "frame {frame}: the two meshes 0.5 m apart"
        );
    }
}

/// The other order, a join over the renderables before the plugin that
/// fills them, is refused with a message that names the fix.
#[test]
#[should_panic(expected = "add BevyVisibilityPlugin before")]
fn a_renderables_layer_before_the_plugin_is_refused() {
    use bevy_rtree::JoinMode;
    use bevy_rtree::plugin::SpatialAppExt;
    let mut app = App::new();
    app.add_plugins((TransformPlugin, CameraPlugin, SpatialIndexPlugin::default()))
        .add_spatial_join::<Renderable, Renderable>(1.0, JoinMode::Euclidean)
        .add_plugins(BevyVisibilityPlugin);
}

/// Every active camera has a list for every visibility class seen so far,
/// as Bevy's queues give one, empty or not: a camera that sees only
/// layer 1, beside two that see entities of the app's own class on
/// layer 0, has an empty list for that class from the next frame on
/// (extraction sees only the classes a camera has a list for).
#[test]
fn a_camera_has_a_list_for_every_class_seen_so_far() {
    let mut twins = Twins::new(41);
    for (i, layer) in [0, 1, 0].into_iter().enumerate() {
        let pair = twins.both(|world, _, _| {
            let mut camera = world.spawn((
                Camera3d::default(),
                Transform::from_xyz(i as f32 * 5.0, 0.0, 10.0),
            ));
            if layer == 1 {
                camera.insert(RenderLayers::layer(1));
            }
            camera.id()
        });
        twins.cameras.push(pair);
    }
    let pair = twins.both(|world, _, _| {
        world
            .spawn((
                Transform::from_xyz(5.0, 0.0, 0.0),
                Visibility::default(),
                Sphere {
                    center: Vec3A::ZERO,
                    radius: 1.0,
                },
                VisibilityClass([TypeId::of::<AppClass>()].into()),
            ))
            .id()
    });
    twins.entities.push(pair);
    for frame in 0..3 {
        twins.update();
        twins.check(frame);
    }
    let classes = |app: &App, camera: Entity| {
        let lists = app.world().get::<VisibleEntities>(camera).unwrap();
        lists.entities.contains_key(&TypeId::of::<AppClass>())
    };
    let [_, layer_1, _] = twins.cameras.clone().try_into().unwrap();
    assert!(
        classes(&twins.bevy, layer_1[0]),
        "Bevy's lists have the key"
    );
    assert!(classes(&twins.ours, layer_1[1]));
    let ours = twins
        .ours
        .world()
        .get::<VisibleEntities>(layer_1[1])
        .unwrap();
    assert!(ours.get(TypeId::of::<AppClass>()).is_empty());
}

/// A disabling component registered by a `Startup` system (Bevy asks for
/// them before the app starts; its own culling, whose queries are set up
/// at their first run, still leaves such entities out): the index's side
/// leaves them out too, on both ways of deciding candidates.
#[test]
fn a_disabling_component_registered_at_startup_is_respected() {
    #[derive(Component)]
    struct Hidden;
    for (seed, spread) in [(51, 100.0), (52, 2_000.0)] {
        let mut twins = Twins::new(seed);
        twins.spread = spread;
        for app in [&mut twins.bevy, &mut twins.ours] {
            app.add_systems(Startup, |world: &mut World| {
                world.register_disabling_component::<Hidden>();
            });
        }
        for _ in 0..2_000 {
            twins.spawn_entity();
        }
        for kind in [0, 2] {
            twins.spawn_camera(kind);
        }
        for pair in twins.entities.clone().iter().step_by(3) {
            twins.both(|world, _, side| {
                world.entity_mut(pair[side]).insert(Hidden);
            });
        }
        let mut seen = 0;
        for frame in 0..5 {
            twins.update();
            seen += twins.check(frame);
            twins.mutate();
        }
        assert!(seen > 100, "seed {seed}: {seen} seen");
    }
}
