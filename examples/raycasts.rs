//! Ray casters over a moving crowd: 300 guards check line of sight to the
//! player (any hit), 300 lasers find what they hit first, and 100 scanners
//! list everything along their beam (at most 8). All casters of a mode share
//! one batched traversal per frame.
//!
//! Run with `cargo run --release --example raycasts` (`-- --frames N`).

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, Ray, RayMode};
use glam::Vec3;

/// A crowd member's step per frame.
#[derive(Component)]
pub struct Walk(pub Vec3);

/// The random source of the scene, for deterministic frames.
#[derive(Resource)]
pub struct Rng(pub SceneRng);

const PLAYER: Vec3 = Vec3::new(100.0, 1.0, 100.0);

pub fn build() -> App {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_systems(Update, (walk, aim));
    let mut rng = SceneRng::new(11);
    let world = app.world_mut();
    for _ in 0..5_000 {
        let center = Vec3::new(rng.range(0.0, 200.0), 1.0, rng.range(0.0, 200.0));
        let bounds =
            Aabb::from_center_half_extents(center, Vec3::new(0.3, 1.0, 0.3)).expect("valid box");
        let step = Vec3::new(rng.range(-0.2, 0.2), 0.0, rng.range(-0.2, 0.2));
        world.spawn((SpatialBounds(bounds), Walk(step)));
    }
    let modes = [
        (300, RayMode::Any),
        (300, RayMode::First),
        (100, RayMode::All { limit: Some(8) }),
    ];
    for (count, mode) in modes {
        for _ in 0..count {
            let ray = Ray::new(Vec3::ZERO, Vec3::X, 1.0).expect("a valid placeholder");
            world.spawn(RayCaster::new(ray, mode));
        }
    }
    app.insert_resource(Rng(rng));
    app
}

fn walk(mut crowd: Query<(&mut SpatialBounds, &mut Walk)>) {
    for (mut bounds, mut step) in &mut crowd {
        let moved = Aabb::new(bounds.0.min + step.0, bounds.0.max + step.0).expect("small step");
        if moved.min.x < 0.0 || moved.max.x > 200.0 || moved.min.z < 0.0 || moved.max.z > 200.0 {
            step.0 = -step.0;
        } else {
            bounds.0 = moved;
        }
    }
}

/// Guards look at the player; lasers and scanners point anywhere.
fn aim(mut rng: ResMut<Rng>, mut casters: Query<&mut RayCaster>) {
    for mut caster in &mut casters {
        let from = Vec3::new(rng.0.range(0.0, 200.0), 1.5, rng.0.range(0.0, 200.0));
        caster.ray = match caster.mode {
            RayMode::Any => Ray::segment(from, PLAYER).unwrap_or(caster.ray),
            _ => Ray::new(from, rng.0.direction() * Vec3::new(1.0, 0.1, 1.0), 80.0)
                .unwrap_or(caster.ray),
        };
    }
}

/// Guards that see the player, lasers that hit, entities scanned, and
/// whether every caster's answer equals brute force.
pub fn check(app: &mut App) -> (usize, usize, usize, bool) {
    let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
    let world = app.world_mut();
    let mut casters = world.query::<(&RayCaster, &RayCasterHits)>();
    let (mut seeing, mut hitting, mut scanned, mut agrees) = (0, 0, 0, true);
    for (caster, answer) in casters.iter(world) {
        let Ok(hits) = oracle.ray_hits(&caster.ray) else {
            agrees &= answer.error().is_some();
            continue;
        };
        match caster.mode {
            RayMode::Any => {
                seeing += usize::from(!answer.any());
                agrees &= answer.any() != hits.is_empty();
            }
            RayMode::First => {
                hitting += usize::from(answer.first().is_some());
                agrees &= answer.first() == hits.first().copied();
            }
            RayMode::All { limit } => {
                scanned += answer.hits().len();
                agrees &= answer.hits() == &hits[..hits.len().min(limit.unwrap_or(usize::MAX))];
            }
        }
    }
    (seeing, hitting, scanned, agrees)
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
    let mut app = build();
    let mut all_agree = true;
    for frame in 1..=frames {
        app.update();
        if frame % 10 == 0 || frame == frames {
            let (seeing, hitting, scanned, agrees) = check(&mut app);
            all_agree &= agrees;
            let d = app.world().resource::<SpatialDiagnostics>().rays;
            println!(
                "frame {frame:3}: {seeing} of 300 guards see the player, {hitting} of 300 lasers hit, \
                 {scanned} entities scanned; {} rays in {} traversals, {} nodes visited",
                d.queries, d.runs, d.nodes_visited,
            );
        }
    }
    println!("oracle agrees: {all_agree}");
    assert!(all_agree, "raycasts disagree with brute force");
}
