//! Four cameras over a field of 20,000 static boxes: two turning players
//! with conservative culling (Bevy's convention) and the same two views in
//! exact mode, all culled in one traversal per mode. Prints what each camera
//! sees and how many conservative answers are false positives.
//!
//! Run with `cargo run --release --example culling` (`-- --frames N`).

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, CullMode, Frustum};
use glam::{Quat, Vec3};

/// The cameras, in order: player 1 and 2 conservative, then exact.
#[derive(Resource)]
pub struct Cameras(pub Vec<Entity>);

pub fn build(count: usize) -> App {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_systems(Update, turn_cameras);
    let world = app.world_mut();
    let mut rng = SceneRng::new(7);
    for _ in 0..count {
        let center = Vec3::new(
            rng.range(0.0, 500.0),
            rng.range(0.0, 20.0),
            rng.range(0.0, 500.0),
        );
        let half = Vec3::splat(rng.range(0.2, 3.0));
        world.spawn(SpatialBounds(
            Aabb::from_center_half_extents(center, half).expect("valid box"),
        ));
    }
    let cameras = (0..4)
        .map(|i| {
            let mode = if i < 2 {
                CullMode::Conservative
            } else {
                CullMode::Exact
            };
            world
                .spawn(CullingCamera::new(view(i % 2, 0)).with_mode(mode))
                .id()
        })
        .collect();
    app.insert_resource(Cameras(cameras));
    app
}

/// Player `player`'s view at `frame`: standing in the field, turning.
fn view(player: usize, frame: u64) -> Frustum {
    let eye = [Vec3::new(150.0, 2.0, 150.0), Vec3::new(350.0, 2.0, 300.0)][player];
    let yaw = frame as f32 * 0.05 + player as f32 * 2.0;
    Frustum::perspective(eye, Quat::from_rotation_y(yaw), 1.0, 16.0 / 9.0, 0.1, 200.0)
        .expect("a valid view")
}

fn turn_cameras(
    cameras: Res<Cameras>,
    mut views: Query<&mut CullingCamera>,
    mut frame: Local<u64>,
) {
    *frame += 1;
    for (i, &camera) in cameras.0.iter().enumerate() {
        if let Ok(mut c) = views.get_mut(camera) {
            c.frustum = view(i % 2, *frame);
        }
    }
}

/// Each camera's visible count and whether it equals brute force.
pub fn check(app: &mut App) -> Vec<(usize, bool)> {
    let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
    let world = app.world();
    world
        .resource::<Cameras>()
        .0
        .iter()
        .map(|&camera| {
            let c = world.get::<CullingCamera>(camera).expect("camera");
            let visible = world
                .get::<VisibleEntityList>(camera)
                .expect("list")
                .entities();
            (visible.len(), visible == oracle.visible(&c.frustum, c.mode))
        })
        .collect()
}

#[allow(dead_code)]
fn main() {
    let frames = std::env::args()
        .skip_while(|a| a != "--frames")
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap_or(60)
        // At least one frame, so that the oracle is asked at least once.
        .max(1);
    let mut app = build(20_000);
    let mut all_agree = true;
    for frame in 1..=frames {
        app.update();
        if frame % 10 == 0 || frame == frames {
            let seen = check(&mut app);
            all_agree &= seen.iter().all(|(_, ok)| *ok);
            let d = app.world().resource::<SpatialDiagnostics>().culling;
            println!(
                "frame {frame:3}: player 1 sees {} (exact {}, {} false positives), player 2 sees {} (exact {}, {} false positives); \
                 {} traversals, {} nodes visited",
                seen[0].0,
                seen[2].0,
                seen[0].0 - seen[2].0,
                seen[1].0,
                seen[3].0,
                seen[1].0 - seen[3].0,
                d.runs,
                d.nodes_visited,
            );
        }
    }
    println!("oracle agrees: {all_agree}");
    assert!(all_agree, "culling disagrees with brute force");
}
