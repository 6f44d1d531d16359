//! Bevy's own visibility step against the index serving it, on twin Apps:
//! the same scene, the same moves, one App running Bevy's
//! `check_visibility_cpu_culling`, the other `BevyVisibilityPlugin`. Each
//! App times its whole visibility step (for the index: its sync of this
//! frame's moves, its repair and the culling) with marker systems around
//! it; the two run in alternating blocks of frames, and each case reports
//! the median ratio of neighbouring blocks (Bevy's time ÷ ours).
//!
//! With feature `bevy_light`, the light cases time bevy_light's shadow
//! visibility (`SimulationLightSystems::CheckLightVisibility`) the same way,
//! in a second row.
//!
//! `cargo bench --bench bevy_visibility --features bevy_light`
//! (add `multi_threaded` for Bevy's parallel executor; `-- --quick` for a
//! short run; words after `--` pick cases by name; `--no-proof` sends every
//! candidate to Bevy's tests; `--world-box` also prints what the tree's
//! candidates alone would list, and the time of that cull;
//! `BEVY_RTREE_THREADS=n` gives Bevy's compute pool n threads).

#[path = "common/bevy_town.rs"]
mod bevy_town;
#[path = "common/threads.rs"]
mod threads;

use std::any::TypeId;

use bevy_app::prelude::*;
use bevy_camera::primitives::Aabb;
use bevy_camera::visibility::{ViewVisibility, VisibleEntities};
use bevy_camera::{Camera3d, CameraProjection, OrthographicProjection, Projection, ScalingMode};
use bevy_ecs::prelude::*;
use bevy_mesh::Mesh3d;
use bevy_rtree::scene::SceneRng;
#[cfg(feature = "bevy_light")]
use bevy_rtree::scene::TownScene;
use bevy_town::{Motion, Mover, app, block, camera_lists, town, world_boxes_alone};
use bevy_transform::prelude::*;
#[cfg(feature = "bevy_light")]
use glam::Quat;
use glam::{Vec3, Vec3A};

/// One case: what to spawn and how it moves.
struct Case {
    name: &'static str,
    spawn: fn(&mut World, u64),
    /// Whether the case has Bevy's lights (and times their step).
    lights: bool,
    /// One entity in `period` moves each frame.
    period: u32,
    turn: f32,
}

/// The town with 16 shadow-casting point lights of 15 m range in front of
/// its one camera.
#[cfg(feature = "bevy_light")]
fn town_point_lights(world: &mut World, seed: u64) {
    town(world, seed, 1);
    let mut rng = SceneRng::new(seed ^ 0x119);
    let ahead = Quat::from_rotation_y(0.0) * Vec3::NEG_Z;
    for _ in 0..16 {
        let along = ahead * rng.range(20.0, 120.0);
        let side = Vec3::new(rng.range(-30.0, 30.0), 0.0, 0.0);
        let at = TownScene::eye() + along + side - Vec3::Y * TownScene::eye().y * 0.5;
        world.spawn((
            bevy_light::PointLight {
                range: 15.0,
                shadow_maps_enabled: true,
                ..bevy_light::PointLight::default()
            },
            Transform::from_translation(at),
        ));
    }
}

/// The town with a shadow-casting directional light of 4 cascades.
#[cfg(feature = "bevy_light")]
fn town_sun(world: &mut World, seed: u64) {
    town(world, seed, 1);
    world.spawn((
        bevy_light::DirectionalLight {
            shadow_maps_enabled: true,
            ..bevy_light::DirectionalLight::default()
        },
        bevy_light::CascadeShadowConfigBuilder {
            num_cascades: 4,
            ..bevy_light::CascadeShadowConfigBuilder::default()
        }
        .build(),
        Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
}

/// A large 2D-like map: `count` flat tiles over a square 20 km wide, and
/// an orthographic camera looking down on about 2 % of it.
fn large_map(world: &mut World, seed: u64) {
    const COUNT: usize = 1_000_000;
    const SIDE: f32 = 20_000.0;
    let mut rng = SceneRng::new(seed);
    let tiles: Vec<_> = (0..COUNT)
        .map(|i| {
            let at = Vec3::new(rng.range(0.0, SIDE), 0.0, rng.range(0.0, SIDE));
            let half = Vec3::new(rng.range(0.5, 5.0), 0.5, rng.range(0.5, 5.0));
            let step = Vec3::new(rng.range(-0.5, 0.5), 0.0, rng.range(-0.5, 0.5));
            (
                Mesh3d::default(),
                Aabb {
                    center: Vec3A::ZERO,
                    half_extents: half.into(),
                },
                Transform::from_translation(at),
                Mover {
                    step,
                    slot: i as u32,
                },
            )
        })
        .collect();
    world.spawn_batch(tiles);
    // Looking straight down on a 2,800 m square: 2 % of the map. Headless,
    // no window sizes the projection, so it is sized here.
    let mut projection = OrthographicProjection {
        scaling_mode: ScalingMode::Fixed {
            width: 2_800.0,
            height: 2_800.0,
        },
        near: 0.0,
        far: 1_000.0,
        ..OrthographicProjection::default_3d()
    };
    projection.update(1.0, 1.0);
    world.spawn((
        Camera3d::default(),
        Projection::Orthographic(projection),
        Transform::from_xyz(SIDE / 2.0, 500.0, SIDE / 2.0)
            .looking_at(Vec3::new(SIDE / 2.0, 0.0, SIDE / 2.0), Vec3::NEG_Z),
    ));
}

/// What both Apps made of the last frame: the visible count and whether
/// every `ViewVisibility` and camera list is the same.
fn same_answers(bevy: &mut App, ours: &mut App) -> (usize, bool) {
    // Per mover (by its slot, as storage orders may differ), then the
    // others (cameras, lights) in storage order.
    let visible = |app: &mut App| -> Vec<bool> {
        let mut query = app.world_mut().query::<(&ViewVisibility, Option<&Mover>)>();
        let mut movers: Vec<(u32, bool)> = Vec::new();
        let mut others = Vec::new();
        for (v, mover) in query.iter(app.world()) {
            match mover {
                Some(m) => movers.push((m.slot, v.get())),
                None => others.push(v.get()),
            }
        }
        movers.sort_unstable_by_key(|m| m.0);
        movers.into_iter().map(|m| m.1).chain(others).collect()
    };
    let (a, b) = (visible(bevy), visible(ours));
    let count = a.iter().filter(|&&v| v).count();
    (
        count,
        a == b
            && camera_lists(bevy) == camera_lists(ours)
            && light_lists(bevy) == light_lists(ours),
    )
}

/// Every light's lists (cube faces, cascades), by slot.
#[cfg(feature = "bevy_light")]
fn light_lists(app: &mut App) -> Vec<Vec<u32>> {
    use bevy_camera::visibility::{CascadesVisibleEntities, CubemapVisibleEntities};
    let slots = bevy_town::slots(app);
    let world = app.world_mut();
    let mut cubes = world.query::<&CubemapVisibleEntities>();
    let mut out: Vec<Vec<u32>> = cubes
        .iter(world)
        .flat_map(|c| c.iter().map(|f| bevy_town::by_slot(&slots, &f.entities)))
        .collect();
    let mut cascades = world.query::<&CascadesVisibleEntities>();
    for lists in cascades.iter(world) {
        out.extend(
            lists
                .entities
                .values()
                .flatten()
                .map(|l| bevy_town::by_slot(&slots, &l.entities)),
        );
    }
    out
}

#[cfg(not(feature = "bevy_light"))]
fn light_lists(_: &mut App) -> Vec<Vec<u32>> {
    Vec::new()
}

/// What to measure beside the default run.
#[derive(Clone, Copy)]
struct Options {
    /// `--no-proof`: every candidate takes Bevy's tests.
    no_proof: bool,
    /// `--world-box`: also the tree's candidates alone, without Bevy's
    /// tests (what the world box costs in accuracy, and its time).
    world_box: bool,
}

fn run(case: &Case, rounds: usize, frames: usize, options: Options) {
    let mut bevy = app(false, case.lights);
    let mut ours = app(true, case.lights);
    if options.no_proof {
        ours.insert_resource(bevy_rtree::plugin::BevyVisibilitySettings {
            prove_inside: false,
            ..Default::default()
        });
    }
    for app in [&mut bevy, &mut ours] {
        (case.spawn)(app.world_mut(), 0x5EED);
        app.insert_resource(Motion {
            frame: 0,
            period: case.period,
            turn: case.turn,
        });
        // The first frames build everything (and load the tree).
        for _ in 0..3 {
            app.update();
        }
    }
    let (visible, same) = same_answers(&mut bevy, &mut ours);
    assert!(same, "{}: the twin Apps disagree", case.name);
    // Per round: (Bevy, ours) for the visibility step and the lights' step.
    let mut rows: Vec<[(f64, f64); 2]> = Vec::new();
    for round in 0..rounds {
        let (b, o) = if round % 2 == 0 {
            let b = block(&mut bevy, frames);
            (b, block(&mut ours, frames))
        } else {
            let o = block(&mut ours, frames);
            (block(&mut bevy, frames), o)
        };
        rows.push([(b.0, o.0), (b.1, o.1)]);
    }
    let (_, same) = same_answers(&mut bevy, &mut ours);
    assert!(same, "{}: the twin Apps disagree", case.name);
    if options.world_box {
        world_box_alone(case.name, &mut ours);
    }
    report(case.name, rows.iter().map(|r| r[0]), visible);
    if case.lights {
        let name = format!("{}: light visibility", case.name);
        report(&name, rows.iter().map(|r| r[1]), visible);
    }
}

/// The tree's candidates for each camera without Bevy's tests: how many
/// more than Bevy lists, and the median time of the cull.
fn world_box_alone(name: &str, ours: &mut App) {
    let world = ours.world_mut();
    let mut cameras = world.query::<&VisibleEntities>();
    let listed: usize = cameras
        .iter(world)
        .map(|listed| listed.get(TypeId::of::<Mesh3d>()).len())
        .sum();
    let (ms, candidates) = world_boxes_alone(ours);
    println!(
        "{name}: world boxes alone list {candidates} for Bevy's {listed} ({:+.1} %), \
         the tree's cull {ms:.3} ms",
        (candidates as f64 / listed.max(1) as f64 - 1.0) * 100.0,
    );
}

/// One table row: median times and the median ratio of paired blocks.
fn report(name: &str, pairs: impl Iterator<Item = (f64, f64)>, visible: usize) {
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (mut bevy_us, mut our_us): (Vec<f64>, Vec<f64>) = pairs.unzip();
    let mut ratios: Vec<f64> = bevy_us.iter().zip(&our_us).map(|(b, o)| b / o).collect();
    let (lo, hi) = (
        ratios.iter().copied().fold(f64::INFINITY, f64::min),
        ratios.iter().copied().fold(0.0, f64::max),
    );
    println!(
        "| {} | {:.2} | {:.2} | {:.2} ({:.2}–{:.2}) | {} |",
        name,
        median(&mut bevy_us) / 1e3,
        median(&mut our_us) / 1e3,
        median(&mut ratios),
        lo,
        hi,
        visible
    );
}

/// Bevy's compute pool of `BEVY_RTREE_THREADS` threads if set (so that a
/// run means the same on any machine); else whichever of Bevy's users
/// makes it first sizes it (the multi-threaded executor: one thread per
/// core; the light cases' `TaskPoolPlugin`: its share of the cores).
fn set_pool_threads() {
    if let Some(n) = threads::threads_wanted() {
        let pool = bevy_tasks::ComputeTaskPool::get_or_init(|| {
            bevy_tasks::TaskPoolBuilder::new().num_threads(n).build()
        });
        println!("Bevy's compute pool: {} threads", pool.thread_num());
    }
}

fn main() {
    set_pool_threads();
    let quick = std::env::args().any(|a| a == "--quick");
    let (rounds, frames) = if quick { (3, 5) } else { (9, 15) };
    #[cfg_attr(not(feature = "bevy_light"), allow(unused_mut))]
    let mut cases = vec![
        Case {
            name: "town 100,000, 10 % moving, 1 camera",
            spawn: |w, s| town(w, s, 1),
            lights: false,
            period: 10,
            turn: std::f32::consts::TAU / 60.0,
        },
        Case {
            name: "town 100,000, 10 % moving, 4 cameras",
            spawn: |w, s| town(w, s, 4),
            lights: false,
            period: 10,
            turn: std::f32::consts::TAU / 60.0,
        },
        Case {
            name: "map 1,000,000, 1 % moving, 2 % in view",
            spawn: large_map,
            lights: false,
            period: 100,
            turn: 0.0,
        },
    ];
    #[cfg(feature = "bevy_light")]
    cases.extend([
        Case {
            name: "town 100,000, 10 % moving, 16 point lights",
            spawn: town_point_lights,
            lights: true,
            period: 10,
            // The lights stay in view (a light no camera sees casts no
            // shadow in Bevy either).
            turn: 0.0,
        },
        Case {
            name: "town 100,000, 10 % moving, sun with 4 cascades",
            spawn: town_sun,
            lights: true,
            period: 10,
            turn: std::f32::consts::TAU / 60.0,
        },
    ]);
    println!("| case | Bevy (ms) | bevy_rtree (ms) | speed-up, median (range) | visible |");
    println!("|---|---:|---:|---:|---:|");
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let options = Options {
        no_proof: std::env::args().any(|a| a == "--no-proof"),
        world_box: std::env::args().any(|a| a == "--world-box"),
    };
    for case in &cases {
        if filter.iter().all(|f| case.name.contains(f.as_str())) {
            run(case, rounds, frames, options);
        }
    }
}
