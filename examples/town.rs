//! The standard scene "town" through the plugin: 100,000 entities, 10 % of
//! them moving every frame, a spinning camera, 2,000 rays (1,000 scattered,
//! 1,000 from the eye through a pixel grid) and the enemy-barrel join at
//! 5 m. Prints counts and timings every 20 frames, each time checking that
//! frame's answers against brute force (and the last frame's).
//!
//! Run with `cargo run --release --example town` (`-- --frames N`,
//! `-- --count N` for a smaller scene, `-- --rebuild-us N` to rebuild worn
//! trees in slices of N µs a frame where there is no task pool (by default
//! only on the task pool, which the feature `parallel` brings), 0 never;
//! `-- --frame-us N` to give each frame N µs, the rest after the update
//! spent waiting as a game's other work would; with the features
//! `parallel,multi_threaded`, `-- --threads N` sets the task pool's size).

use std::time::{Duration, Instant};

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::oracle::BruteForce;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{JoinMode, RayMode};

/// The first 10,000 entities of the scene.
#[derive(Component)]
pub struct Enemy;

/// Entities 10,000..15,000 of the scene.
#[derive(Component)]
pub struct Barrel;

/// The scene's data and the entity of each of its boxes.
#[derive(Resource)]
pub struct Town {
    pub scene: TownScene,
    pub entities: Vec<Entity>,
    pub camera: Entity,
    pub casters: Vec<Entity>,
    /// Per scene index: whether it moves this frame.
    moving: Vec<bool>,
}

/// An entity's index in the scene, which says where it moves.
#[derive(Component, Clone, Copy)]
pub struct SceneIndex(pub u32);

/// When the plugin's work started this frame, and how long it took.
#[derive(Resource, Default)]
pub struct IndexTimer {
    started: Option<Instant>,
    pub last: Duration,
}

/// Builds the town app: entities spawned, systems added, no frame run yet.
pub fn build(count: usize, seed: u64) -> App {
    build_with(count, seed, SpatialIndexPlugin::default())
}

/// [`build`] with the plugin's settings given.
pub fn build_with(count: usize, seed: u64, plugin: SpatialIndexPlugin) -> App {
    let mut app = App::new();
    // Bevy's task pools, as DefaultPlugins and MinimalPlugins add them.
    app.add_plugins((TaskPoolPlugin::default(), plugin))
        .add_spatial_join::<Enemy, Barrel>(TownScene::JOIN_DISTANCE, JoinMode::Euclidean)
        .init_resource::<IndexTimer>()
        // Chained: both systems draw from the scene's random stream and the
        // camera follows the frame counter, so an unspecified order would
        // make frames differ between runs and executors.
        .add_systems(Update, (move_entities, aim_camera_and_rays).chain())
        .add_systems(
            PostUpdate,
            (
                start_timer.before(SpatialIndexSystems::Bounds),
                stop_timer.after(SpatialIndexSystems::Queries),
            ),
        );
    let scene = TownScene::new(count, seed);
    let world = app.world_mut();
    let entities: Vec<Entity> = scene
        .boxes()
        .iter()
        .enumerate()
        .map(|(i, aabb)| {
            let mut entity = world.spawn((SpatialBounds(*aabb), SceneIndex(i as u32)));
            if TownScene::ENEMIES.contains(&i) {
                entity.insert(Enemy);
            } else if TownScene::BARRELS.contains(&i) {
                entity.insert(Barrel);
            }
            entity.id()
        })
        .collect();
    let camera = world.spawn(CullingCamera::new(scene.frustum())).id();
    let casters = (0..2_000)
        .map(|_| {
            let placeholder = bevy_rtree::Ray::new(glam::Vec3::ZERO, glam::Vec3::X, 1.0)
                .expect("a valid placeholder ray");
            world
                .spawn(RayCaster::new(placeholder, RayMode::First))
                .id()
        })
        .collect();
    app.insert_resource(Town {
        moving: vec![false; scene.len()],
        scene,
        entities,
        camera,
        casters,
    });
    app
}

/// A fresh 10 % of the entities take their step: as a game moves its
/// entities, through a query over them (a box is written, and so marked
/// changed, only where it moves).
fn move_entities(mut town: ResMut<Town>, mut bounds: Query<(&SceneIndex, &mut SpatialBounds)>) {
    let town = &mut *town;
    town.scene.advance_frame();
    for &i in town.scene.moved() {
        town.moving[i as usize] = true;
    }
    for (index, mut b) in &mut bounds {
        let i = index.0 as usize;
        if town.moving[i] {
            b.0 = town.scene.boxes()[i];
        }
    }
    for &i in town.scene.moved() {
        town.moving[i as usize] = false;
    }
}

/// The camera turns; the rays are re-aimed every frame.
fn aim_camera_and_rays(
    mut town: ResMut<Town>,
    mut cameras: Query<&mut CullingCamera>,
    mut casters: Query<&mut RayCaster>,
) {
    let town = &mut *town;
    if let Ok(mut camera) = cameras.get_mut(town.camera) {
        camera.frustum = town.scene.frustum();
    }
    let mut rays = town.scene.incoherent_rays(1_000);
    rays.extend(town.scene.coherent_rays());
    for (&caster, ray) in town.casters.iter().zip(rays) {
        if let Ok(mut caster) = casters.get_mut(caster) {
            caster.ray = ray;
        }
    }
}

fn start_timer(mut timer: ResMut<IndexTimer>) {
    timer.started = Some(Instant::now());
}

fn stop_timer(mut timer: ResMut<IndexTimer>) {
    if let Some(started) = timer.started.take() {
        timer.last = started.elapsed();
    }
}

/// This frame's visible count, rays that hit, and pairs.
pub fn counts(app: &App) -> (usize, usize, usize) {
    let world = app.world();
    let town = world.resource::<Town>();
    let visible = world
        .get::<VisibleEntityList>(town.camera)
        .map_or(0, |v| v.entities().len());
    let hits = town
        .casters
        .iter()
        .filter(|&&c| world.get::<RayCasterHits>(c).is_some_and(|h| h.any()))
        .count();
    let pairs = world.resource::<SpatialJoin<Enemy, Barrel>>().pairs().len();
    (visible, hits, pairs)
}

/// Whether this frame's visible list, ray hits and pairs equal brute force
/// over the entities' current boxes, and the indexes are valid.
pub fn agrees_with_oracle(app: &App) -> bool {
    let world = app.world();
    let town = world.resource::<Town>();
    let mut all = BruteForce::default();
    let mut enemies = BruteForce::default();
    let mut barrels = BruteForce::default();
    for (i, (&entity, aabb)) in town.entities.iter().zip(town.scene.boxes()).enumerate() {
        all.insert(entity, *aabb);
        if TownScene::ENEMIES.contains(&i) {
            enemies.insert(entity, *aabb);
        } else if TownScene::BARRELS.contains(&i) {
            barrels.insert(entity, *aabb);
        }
    }
    let valid = world.resource::<SpatialIndex>().validate().is_ok()
        && world.resource::<SpatialIndex<Enemy>>().validate().is_ok()
        && world.resource::<SpatialIndex<Barrel>>().validate().is_ok();
    let camera = world.get::<CullingCamera>(town.camera).expect("camera");
    let visible = world.get::<VisibleEntityList>(town.camera).expect("list");
    let culling = visible.entities() == all.visible(&camera.frustum, camera.mode);
    let rays = town.casters.iter().all(|&c| {
        let ray = world.get::<RayCaster>(c).expect("caster").ray;
        let hits = world.get::<RayCasterHits>(c).expect("hits");
        all.ray_first(&ray).is_ok_and(|first| first == hits.first())
    });
    let pairs = enemies
        .cross_join(&barrels, TownScene::JOIN_DISTANCE, JoinMode::Euclidean)
        .is_ok_and(|expected| world.resource::<SpatialJoin<Enemy, Barrel>>().pairs() == expected);
    valid && culling && rays && pairs
}

fn arg(name: &str, default: usize) -> usize {
    args_value(name).unwrap_or(default)
}

fn args_value(name: &str) -> Option<usize> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
}

/// `--threads N` (feature `parallel`): the task pool the parallel queries
/// and the multi-threaded executor share gets exactly `N` threads, so that
/// a scaling run means the same on any machine.
fn set_threads() {
    let threads = arg("--threads", 0);
    if threads == 0 {
        return;
    }
    #[cfg(feature = "parallel")]
    {
        let pool = bevy_tasks::ComputeTaskPool::get_or_init(|| {
            bevy_tasks::TaskPoolBuilder::new()
                .num_threads(threads)
                .build()
        });
        println!("town: a task pool of {} threads", pool.thread_num());
    }
    #[cfg(not(feature = "parallel"))]
    println!("town: --threads {threads} needs the feature `parallel`; one thread");
}

#[allow(dead_code)]
fn main() {
    set_threads();
    let frames = arg("--frames", 120).max(1);
    let count = arg("--count", TownScene::STANDARD_COUNT);
    let mut plugin = SpatialIndexPlugin::default();
    if let Some(us) = args_value("--rebuild-us") {
        plugin.rebuild = match us {
            0 => RebuildMode::Off,
            us => RebuildMode::OnTaskPoolOrInSlices(Duration::from_micros(us as u64)),
        };
    }
    let start = Instant::now();
    let mut app = build_with(count, 2024, plugin);
    app.update();
    println!(
        "town: {count} entities spawned and indexed in {:.1} ms (first frame)",
        start.elapsed().as_secs_f64() * 1e3
    );
    let frame_length = Duration::from_micros(arg("--frame-us", 0) as u64);
    let mut index_total = Duration::ZERO;
    let mut frame_total = Duration::ZERO;
    let mut checked = 0;
    for frame in 1..=frames {
        let t = Instant::now();
        app.update();
        let whole = t.elapsed();
        // The rest of a game's frame: a rebuild on the task pool runs
        // meanwhile, as it would beside a game's other systems.
        while t.elapsed() < frame_length {
            std::hint::spin_loop();
        }
        let index = app.world().resource::<IndexTimer>().last;
        index_total += index;
        frame_total += whole;
        if frame % 20 == 0 || frame == frames {
            let (visible, hits, pairs) = counts(&app);
            let d = *app.world().resource::<SpatialDiagnostics>();
            println!(
                "frame {frame:4}: {} box updates over the three indexes, \
                 {visible} visible, {hits} of 2000 rays hit, \
                 {pairs} enemy-barrel pairs; index and queries {:.2} ms, whole frame {:.2} ms",
                d.sync.updated,
                index.as_secs_f64() * 1e3,
                whole.as_secs_f64() * 1e3,
            );
            checked += 1;
            assert!(
                agrees_with_oracle(&app),
                "frame {frame}: the plugin's answers disagree with brute force"
            );
        }
    }
    println!(
        "summary: {frames} frames, mean index and queries {:.2} ms, mean whole frame {:.2} ms, \
         oracle agrees in all {checked} frames checked",
        index_total.as_secs_f64() * 1e3 / frames as f64,
        frame_total.as_secs_f64() * 1e3 / frames as f64,
    );
}
