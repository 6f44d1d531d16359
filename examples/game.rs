//! A small headless game written as a Bevy app is: a convoy of trucks
//! whose cargo (children) follows them, enemies that check their line of
//! sight to the player every frame, turrets on the trucks with casters
//! that turn with them, barrels that warn the enemies near them, and a
//! Bevy camera over it all. The boxes come from `LocalBounds` and Bevy's
//! transforms; no system writes a world box by hand.
//!
//! Run with `cargo run --example game --features bevy_camera`.

use bevy_app::prelude::*;
use bevy_camera::{CameraProjection, PerspectiveProjection};
use bevy_ecs::prelude::*;
use bevy_rtree::prelude::*;
use bevy_transform::prelude::*;

#[derive(Component)]
pub struct Truck;

#[derive(Component)]
pub struct Player;

#[derive(Component)]
pub struct Enemy;

#[derive(Component)]
pub struct Barrel;

/// What the game saw this frame.
#[derive(Resource, Default, Debug)]
pub struct Seen {
    /// Enemies with a clear line of sight to the player.
    pub enemies_seeing_player: usize,
    /// Enemies whose line of sight is blocked.
    pub blocked: Vec<Entity>,
    /// Each enemy warned by a barrel within 5 m since the start, as
    /// `(enemy, barrel)`.
    pub warned: Vec<(Entity, Entity)>,
    /// Lines of sight the index refused (none, with valid rays).
    pub refused: usize,
}

/// Units the handful of systems below move or read.
pub fn build() -> App {
    let mut app = App::new();
    // DefaultPlugins in a game; headless, Bevy's transforms.
    app.add_plugins(TransformPlugin)
        .add_plugins(SpatialIndexPlugin::default())
        .add_spatial_layer::<Enemy>()
        .add_spatial_join::<Enemy, Barrel>(5.0, JoinMode::Euclidean)
        .init_resource::<Seen>()
        .add_systems(Update, drive_trucks)
        // Queries in PostUpdate, once the index holds this frame's boxes;
        // the join's messages are read after the set that writes them, so
        // that a pair is heard in the frame it starts.
        .add_systems(
            PostUpdate,
            (
                look_for_the_player.in_set(SpatialIndexSystems::Queries),
                warn_enemies.after(SpatialIndexSystems::Queries),
            ),
        );
    let world = app.world_mut();
    let unit = Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5)).unwrap();
    let truck_body = Aabb::new(Vec3::new(-2.0, 0.0, -1.0), Vec3::new(2.0, 2.0, 1.0)).unwrap();
    world.spawn((
        Player,
        Transform::from_xyz(0.0, 0.5, 0.0),
        LocalBounds(unit),
    ));
    for i in 0..4 {
        let z = -20.0 + i as f32 * 10.0;
        world
            .spawn((
                Truck,
                Transform::from_xyz(-30.0, 0.0, z),
                LocalBounds(truck_body),
            ))
            .with_children(|truck| {
                // Cargo rides on the truck; its box follows it.
                truck.spawn((Transform::from_xyz(0.0, 2.5, 0.0), LocalBounds(unit)));
                // A turret in the cab, looking ahead down the truck's +X,
                // blind to its own truck.
                let ahead = Ray::new(Vec3::ZERO, Vec3::X, 40.0).unwrap();
                let own_truck = SpatialQueryFilter::excluding([truck.target_entity()]);
                truck.spawn((
                    Transform::from_xyz(1.0, 0.5, 0.0),
                    RayCaster::new(ahead, RayMode::First).with_filter(own_truck),
                ));
            });
    }
    // A ring of enemies around the player, every other one behind a wall.
    for i in 0..16 {
        let angle = i as f32 * std::f32::consts::TAU / 16.0;
        let at = Vec3::new(angle.cos(), 0.0, angle.sin()) * 15.0 + Vec3::Y * 0.5;
        world.spawn((Enemy, Transform::from_translation(at), LocalBounds(unit)));
        if i % 2 == 0 {
            // Half-way to the player, 3 m wide across the line of sight
            // (local x) and 0.4 m thick along it (local z, which
            // `looking_to` turns towards the enemy).
            let wall = Aabb::new(Vec3::new(-1.5, -1.0, -0.2), Vec3::new(1.5, 2.0, 0.2)).unwrap();
            world.spawn((
                Transform::from_translation(at * 0.5).looking_to(at, Vec3::Y),
                LocalBounds(wall),
            ));
        }
        if i % 4 == 0 {
            // Beside the enemy along the ring, out of its line of sight.
            let along_ring = Vec3::new(-angle.sin(), 0.0, angle.cos());
            let beside = at + along_ring * 2.0;
            world.spawn((
                Barrel,
                Transform::from_translation(beside),
                LocalBounds(unit),
            ));
        }
    }
    // A Bevy camera: its Frustum (kept by Bevy's camera systems in a game)
    // drives a culling camera of ours.
    let eye = Transform::from_xyz(0.0, 20.0, 30.0).looking_at(Vec3::ZERO, Vec3::Y);
    let frustum = PerspectiveProjection::default().compute_frustum(&GlobalTransform::from(eye));
    world.spawn((eye, frustum, FollowBevyFrustum::default()));
    app
}

/// The trucks drive along +X, turning slowly.
fn drive_trucks(mut trucks: Query<&mut Transform, With<Truck>>) {
    for mut truck in &mut trucks {
        let forward = truck.rotation * Vec3::X;
        truck.translation += forward * 0.5;
        truck.rotate_y(0.01);
    }
}

/// Each enemy casts a ray to the player; its own box (which the ray starts
/// in) and the other enemies are left out by the filter.
fn look_for_the_player(
    mut spatial: SpatialQuery,
    enemies: Query<(Entity, &GlobalTransform), With<Enemy>>,
    player: Single<(Entity, &GlobalTransform), With<Player>>,
    mut seen: ResMut<Seen>,
) {
    let (player, target) = *player;
    let others: Vec<Entity> = enemies.iter().map(|(e, _)| e).collect();
    let filter = SpatialQueryFilter::excluding(others);
    seen.enemies_seeing_player = 0;
    seen.blocked.clear();
    for (entity, enemy) in &enemies {
        let Ok(ray) = Ray::segment(enemy.translation(), target.translation()) else {
            continue;
        };
        match spatial.cast_ray(&ray, &filter) {
            Ok(Some(hit)) if hit.key == player => seen.enemies_seeing_player += 1,
            Ok(Some(_)) => seen.blocked.push(entity),
            Ok(None) => {}
            Err(_) => seen.refused += 1,
        }
    }
}

/// A barrel within 5 m warns the enemy, once per pair.
fn warn_enemies(mut started: MessageReader<PairStarted<Enemy, Barrel>>, mut seen: ResMut<Seen>) {
    seen.warned
        .extend(started.read().map(|pair| (pair.a, pair.b)));
}

fn main() {
    let mut app = build();
    for frame in 0..10 {
        app.update();
        let seen = app.world().resource::<Seen>();
        let (seeing, blocked, warned) = (
            seen.enemies_seeing_player,
            seen.blocked.len(),
            seen.warned.len(),
        );
        let visible: usize = {
            let world = app.world_mut();
            let mut lists = world.query::<&VisibleEntityList>();
            lists.iter(world).map(|l| l.entities().len()).sum()
        };
        let world = app.world_mut();
        let mut casters = world.query::<&RayCasterHits>();
        let turrets_on_target = casters.iter(world).filter(|h| h.any()).count();
        println!(
            "frame {frame}: {seeing} enemies see the player, {blocked} are blocked, {warned} warned; \
             the camera sees {visible} entities, {turrets_on_target} turrets have a target"
        );
    }
}
