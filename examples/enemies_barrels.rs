//! 2,000 wandering enemies and 500 barrels: the join reports every enemy
//! within 5 m of a barrel each frame, and `PairStarted` / `PairEnded`
//! messages say who just came near or left.
//!
//! Run with `cargo run --release --example enemies_barrels` (`-- --frames N`).

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, JoinMode};
use glam::Vec3;

#[derive(Component)]
pub struct Enemy;

#[derive(Component)]
pub struct Barrel;

/// An enemy's step per frame.
#[derive(Component)]
pub struct Wander(pub Vec3);

/// Messages seen this frame.
#[derive(Resource, Default)]
pub struct Events {
    pub started: usize,
    pub ended: usize,
}

pub const DISTANCE: f32 = 5.0;

pub fn build() -> App {
    let mut app = App::new();
    app.add_plugins(SpatialIndexPlugin::default())
        .add_spatial_join::<Enemy, Barrel>(DISTANCE, JoinMode::Euclidean)
        .init_resource::<Events>()
        .add_systems(Update, wander)
        .add_systems(PostUpdate, count_events.after(SpatialIndexSystems::Queries));
    let mut rng = SceneRng::new(3);
    let world = app.world_mut();
    let spot = |rng: &mut SceneRng, half: Vec3| {
        let center = Vec3::new(rng.range(0.0, 300.0), half.y, rng.range(0.0, 300.0));
        SpatialBounds(Aabb::from_center_half_extents(center, half).expect("valid box"))
    };
    for _ in 0..2_000 {
        let bounds = spot(&mut rng, Vec3::new(0.4, 0.9, 0.4));
        let step = Vec3::new(rng.range(-0.3, 0.3), 0.0, rng.range(-0.3, 0.3));
        world.spawn((bounds, Enemy, Wander(step)));
    }
    for _ in 0..500 {
        let bounds = spot(&mut rng, Vec3::new(0.5, 0.6, 0.5));
        world.spawn((bounds, Barrel));
    }
    app
}

fn wander(mut enemies: Query<(&mut SpatialBounds, &mut Wander), With<Enemy>>) {
    for (mut bounds, mut step) in &mut enemies {
        let moved = Aabb::new(bounds.0.min + step.0, bounds.0.max + step.0).expect("small step");
        if moved.min.x < 0.0 || moved.max.x > 300.0 || moved.min.z < 0.0 || moved.max.z > 300.0 {
            step.0 = -step.0;
        } else {
            bounds.0 = moved;
        }
    }
}

fn count_events(
    mut started: MessageReader<PairStarted<Enemy, Barrel>>,
    mut ended: MessageReader<PairEnded<Enemy, Barrel>>,
    mut events: ResMut<Events>,
) {
    events.started = started.read().count();
    events.ended = ended.read().count();
}

/// This frame's pairs, and whether they equal brute force.
pub fn check(app: &mut App) -> (usize, bool) {
    let enemies = layer_oracle::<Enemy>(app.world_mut());
    let barrels = layer_oracle::<Barrel>(app.world_mut());
    let expected = enemies
        .cross_join(&barrels, DISTANCE, JoinMode::Euclidean)
        .expect("valid distance");
    let pairs = app.world().resource::<SpatialJoin<Enemy, Barrel>>().pairs();
    (pairs.len(), pairs == expected)
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
        let (pairs, agrees) = check(&mut app);
        all_agree &= agrees;
        if frame % 10 == 0 || frame == frames {
            let events = app.world().resource::<Events>();
            println!(
                "frame {frame:3}: {pairs} enemy-barrel pairs within {DISTANCE} m, {} started, {} ended",
                events.started, events.ended
            );
        }
    }
    println!("oracle agrees: {all_agree}");
    assert!(all_agree, "the join disagrees with brute force");
}
