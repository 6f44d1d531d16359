//! Twin headless Bevy Apps for timing Bevy's visibility against the
//! index serving it (benches/bevy_visibility.rs, and the accuracy report's
//! section on Bevy's visibility): the town as Bevy meshes, movers and
//! cameras moved through queries, and timers around the visibility step.
#![allow(dead_code)]

use std::time::Instant;

use bevy_app::prelude::*;
use bevy_asset::Assets;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::VisibilitySystems;
use bevy_camera::{Camera3d, CameraPlugin, PerspectiveProjection, Projection};
use bevy_ecs::prelude::*;
use bevy_mesh::skinning::SkinnedMeshInverseBindposes;
use bevy_mesh::{Mesh, Mesh3d};
use bevy_rtree::plugin::{
    BevyVisibilityPlugin, RenderableSyncSystems, SpatialIndexPlugin, SpatialIndexSystems,
};
use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_transform::TransformSystems;
use bevy_transform::prelude::*;
use glam::{EulerRot, Quat, Vec3, Vec3A};

/// When this frame's visibility step started, and how long the last took;
/// likewise for the lights' step.
#[derive(Resource, Default)]
pub struct StepTimer {
    pub start: Option<Instant>,
    pub last_us: f64,
    #[cfg_attr(not(feature = "bevy_light"), allow(dead_code))]
    pub light_start: Option<Instant>,
    pub light_us: f64,
}

#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct StepStart;

/// Where the camera step's timer stops: after both sides' culling, before
/// what follows it in `PostUpdate`, so that neither side's window takes in
/// a system the other's leaves out (the executor may otherwise order them
/// differently in the two Apps).
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct StepStop;

pub fn start_step(mut timer: ResMut<StepTimer>) {
    timer.start = Some(Instant::now());
}

pub fn stop_step(mut timer: ResMut<StepTimer>) {
    if let Some(start) = timer.start.take() {
        timer.last_us = start.elapsed().as_secs_f64() * 1e6;
    }
}

#[cfg(feature = "bevy_light")]
pub fn start_light_step(mut timer: ResMut<StepTimer>) {
    timer.light_start = Some(Instant::now());
}

#[cfg(feature = "bevy_light")]
pub fn stop_light_step(mut timer: ResMut<StepTimer>) {
    if let Some(start) = timer.light_start.take() {
        timer.light_us = start.elapsed().as_secs_f64() * 1e6;
    }
}

/// Bevy's `LightPlugin` (which needs assets and images), with timers
/// around its shadow visibility step.
#[cfg(feature = "bevy_light")]
pub fn add_lights(app: &mut App) {
    use bevy_asset::AssetApp;
    use bevy_light::SimulationLightSystems;
    app.add_plugins((bevy_asset::AssetPlugin::default(), bevy_light::LightPlugin))
        .init_asset::<bevy_image::Image>()
        .add_systems(
            PostUpdate,
            (
                start_light_step
                    .after(VisibilitySystems::CheckVisibility)
                    .after(SimulationLightSystems::UpdateLightFrusta)
                    .before(SimulationLightSystems::CheckLightVisibility),
                stop_light_step
                    .after(SimulationLightSystems::CheckLightVisibility)
                    .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
            ),
        );
}

/// A mover: a fresh tenth (or hundredth) of them moves each frame.
#[derive(Component)]
pub struct Mover {
    pub step: Vec3,
    pub slot: u32,
}

/// Each mover's slot by its entity: the twin Apps' entity ids and storage
/// orders may differ, their slots do not.
pub fn slots(app: &mut App) -> std::collections::HashMap<Entity, u32> {
    let world = app.world_mut();
    let mut movers = world.query::<(Entity, &Mover)>();
    movers.iter(world).map(|(e, m)| (e, m.slot)).collect()
}

/// `entities` by their movers' slots (`u32::MAX` for any other), sorted.
pub fn by_slot(slots: &std::collections::HashMap<Entity, u32>, entities: &[Entity]) -> Vec<u32> {
    let mut named: Vec<u32> = entities
        .iter()
        .map(|e| slots.get(e).copied().unwrap_or(u32::MAX))
        .collect();
    named.sort_unstable();
    named
}

/// Every camera's list of meshes, by slot (in the cameras' storage order).
pub fn camera_lists(app: &mut App) -> Vec<Vec<u32>> {
    use bevy_camera::visibility::VisibleEntities;
    let slots = slots(app);
    let world = app.world_mut();
    let mut cameras = world.query::<&VisibleEntities>();
    cameras
        .iter(world)
        .map(|v| by_slot(&slots, v.get(std::any::TypeId::of::<Mesh3d>())))
        .collect()
}

/// The scene's movers and cameras, as a game would move them: through
/// queries.
#[derive(Resource)]
pub struct Motion {
    pub frame: u32,
    /// One entity in `period` moves each frame.
    pub period: u32,
    /// Camera yaw per frame, in radians.
    pub turn: f32,
}

pub fn move_entities(mut motion: ResMut<Motion>, mut movers: Query<(&Mover, &mut Transform)>) {
    motion.frame += 1;
    let (frame, period) = (motion.frame, motion.period);
    for (mover, mut transform) in &mut movers {
        if mover.slot % period == frame % period {
            transform.translation += mover.step;
        }
    }
}

pub fn turn_cameras(motion: Res<Motion>, mut cameras: Query<&mut Transform, With<Camera3d>>) {
    for mut transform in &mut cameras {
        transform.rotate_y(motion.turn);
    }
}

/// A headless App with Bevy's cameras and transforms (and lights if
/// `lights`); the index serves visibility if `ours`.
pub fn app(ours: bool, lights: bool) -> App {
    let mut app = App::new();
    app.add_plugins((TransformPlugin, CameraPlugin))
        .insert_resource(Assets::<Mesh>::default())
        .insert_resource(Assets::<SkinnedMeshInverseBindposes>::default())
        .init_resource::<StepTimer>()
        .add_systems(Update, (move_entities, turn_cameras));
    #[cfg(feature = "bevy_light")]
    if lights {
        app.add_plugins(TaskPoolPlugin::default());
        add_lights(&mut app);
    }
    #[cfg(not(feature = "bevy_light"))]
    let _ = lights;
    if ours {
        app.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin))
            .configure_sets(
                PostUpdate,
                StepStart
                    .after(TransformSystems::Propagate)
                    .after(VisibilitySystems::CalculateBounds)
                    .after(VisibilitySystems::VisibilityPropagate)
                    .before(RenderableSyncSystems),
            )
            .add_systems(
                PostUpdate,
                (
                    start_step.in_set(StepStart),
                    stop_step
                        .after(VisibilitySystems::CheckVisibility)
                        .after(SpatialIndexSystems::Maintain)
                        .in_set(StepStop),
                ),
            );
    } else {
        app.configure_sets(
            PostUpdate,
            StepStart
                .after(TransformSystems::Propagate)
                .after(VisibilitySystems::CalculateBounds)
                .after(VisibilitySystems::VisibilityPropagate)
                .before(VisibilitySystems::CheckVisibility),
        )
        .add_systems(
            PostUpdate,
            (
                start_step.in_set(StepStart),
                stop_step
                    .after(VisibilitySystems::CheckVisibility)
                    .in_set(StepStop),
            ),
        );
    }
    app.configure_sets(
        PostUpdate,
        StepStop.before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
    );
    #[cfg(feature = "bevy_light")]
    app.configure_sets(
        PostUpdate,
        StepStop.before(bevy_light::SimulationLightSystems::CheckLightVisibility),
    );
    app.finish();
    app.cleanup();
    app
}

/// The standard town as Bevy meshes: each box a mesh with its half
/// extents as `Aabb`, at a random yaw; plus `cameras` perspective cameras
/// at the standard eye, facing apart.
pub fn town(world: &mut World, seed: u64, cameras: usize) {
    let scene = TownScene::new(TownScene::STANDARD_COUNT, seed);
    let mut rng = SceneRng::new(seed ^ 0x70_57);
    let entities: Vec<_> = scene
        .boxes()
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let half = (b.max - b.min) * 0.5;
            let yaw = Quat::from_rotation_y(rng.range(0.0, std::f32::consts::TAU));
            let step = Vec3::new(rng.range(-0.1, 0.1), 0.0, rng.range(-0.1, 0.1));
            (
                Mesh3d::default(),
                Aabb {
                    center: Vec3A::ZERO,
                    half_extents: half.into(),
                },
                Transform::from_translation((b.min + b.max) * 0.5).with_rotation(yaw),
                Mover {
                    step,
                    slot: i as u32,
                },
            )
        })
        .collect();
    world.spawn_batch(entities);
    for c in 0..cameras {
        let yaw = std::f32::consts::TAU * c as f32 / cameras as f32;
        world.spawn((
            Camera3d::default(),
            Projection::Perspective(PerspectiveProjection {
                fov: 60f32.to_radians(),
                aspect_ratio: 16.0 / 9.0,
                near: 0.1,
                far: 500.0,
                ..PerspectiveProjection::default()
            }),
            Transform::from_translation(TownScene::eye()).with_rotation(Quat::from_euler(
                EulerRot::YXZ,
                yaw,
                -0.17,
                0.0,
            )),
        ));
    }
}

/// Runs `frames` frames and returns the median step times in µs: the
/// visibility step, and the lights' step.
pub fn block(app: &mut App, frames: usize) -> (f64, f64) {
    let (mut steps, mut lights): (Vec<f64>, Vec<f64>) = (0..frames)
        .map(|_| {
            app.update();
            let timer = app.world().resource::<StepTimer>();
            (timer.last_us, timer.light_us)
        })
        .unzip();
    steps.sort_by(f64::total_cmp);
    lights.sort_by(f64::total_cmp);
    (steps[frames / 2], lights[frames / 2])
}

/// The tree's conservative cull through Bevy's planes but the far one (the
/// plane Bevy's camera test skips): its median time in ms and how many
/// entity-camera pairs it lists.
pub fn world_boxes_alone(app: &mut App) -> (f64, usize) {
    use bevy_camera::primitives::Frustum as BevyFrustum;
    use bevy_rtree::plugin::{Renderable, SpatialIndex};
    use bevy_rtree::{CullMode, Frustum, HalfSpace, QueryWorkspace};
    let world = app.world_mut();
    let mut cameras = world.query::<(&BevyFrustum, &GlobalTransform)>();
    let frustums: Vec<Frustum> = cameras
        .iter(world)
        .map(|(frustum, transform)| {
            let whole =
                Frustum::from_bevy(frustum, transform.translation()).expect("a camera's frustum");
            let mut planes = *whole.planes();
            planes[5] = HalfSpace::INACTIVE;
            Frustum::new(whole.eye(), planes).expect("valid planes")
        })
        .collect();
    let tree = world.resource::<SpatialIndex<Renderable>>().tree();
    let (mut ws, mut out) = (QueryWorkspace::default(), Vec::new());
    let mut times = Vec::new();
    for _ in 0..15 {
        out.iter_mut().for_each(Vec::clear);
        let start = Instant::now();
        tree.visible_into(&frustums, CullMode::Conservative, &mut ws, &mut out);
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], out.iter().map(Vec::len).sum())
}
