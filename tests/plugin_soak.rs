//! Random headless scenes through the plugin: spawn, move, teleport,
//! despawn, respawn, layers, opt-outs, invalid boxes, cameras and casters
//! coming and going; after every frame each answer is compared with the
//! brute-force oracle computed from the entities' current boxes.
//!
//! `soak_short` runs in CI; `soak_long` (thousands of frames) runs with
//! `cargo test --release --test plugin_soak -- --ignored`.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::message::Messages;
use bevy_ecs::prelude::*;
use bevy_rtree::oracle::BruteForce;
use bevy_rtree::plugin::*;
use bevy_rtree::scene::SceneRng;
use bevy_rtree::{Aabb, CullMode, Frustum, JoinMode, Ray, RayMode};
use glam::{Quat, Vec3};

/// Where a soak stops spawning: a frame's spawns (at most five) are
/// skipped once this many entities are live. The short soak stays below
/// it, which it checks.
const MAX_LIVE: usize = 600;

#[derive(Component)]
struct Enemy;

#[derive(Component)]
struct Barrel;

const ENEMY_BARREL_DISTANCE: f32 = 2.0;
const ENEMY_SELF_DISTANCE: f32 = 0.5;

/// A random scene and the pairs it has seen started and not yet ended.
struct Driver {
    app: App,
    rng: SceneRng,
    live: Vec<Entity>,
    despawned: Vec<Entity>,
    opted_out: Vec<Entity>,
    cameras: Vec<Entity>,
    casters: Vec<Entity>,
    open_pairs: Vec<(Entity, Entity)>,
    frames: usize,
    /// The most entities live at the start of any frame.
    most_live: usize,
    /// What the checks compared over the run, summed: entities seen by the
    /// cameras, casters' hits, and enemy-barrel pairs (a soak whose
    /// answers were all empty would check nothing).
    compared: [usize; 3],
}

/// A disabling component stored in a sparse set, never given to an entity:
/// registering it makes every query sparse, so that the plugin's syncs read
/// row by row instead of table by table.
#[derive(Component)]
#[component(storage = "SparseSet")]
struct Asleep;

impl Driver {
    fn new(seed: u64, row_by_row: bool) -> Self {
        let mut app = App::new();
        if row_by_row {
            app.world_mut().register_disabling_component::<Asleep>();
        }
        app.add_plugins(SpatialIndexPlugin::default())
            .add_spatial_join::<Enemy, Barrel>(ENEMY_BARREL_DISTANCE, JoinMode::Euclidean)
            .add_spatial_join::<Enemy, Enemy>(ENEMY_SELF_DISTANCE, JoinMode::Chebyshev);
        Driver {
            app,
            rng: SceneRng::new(seed),
            live: Vec::new(),
            despawned: Vec::new(),
            opted_out: Vec::new(),
            cameras: Vec::new(),
            casters: Vec::new(),
            open_pairs: Vec::new(),
            frames: 0,
            most_live: 0,
            compared: [0; 3],
        }
    }

    fn world(&mut self) -> &mut World {
        self.app.world_mut()
    }

    /// A box on a half-metre grid in a 64 m cube, so that faces coincide and
    /// boxes touch often.
    fn grid_box(&mut self) -> Aabb {
        let mut corner = || (self.rng.below(128) as f32) * 0.5;
        let min = Vec3::new(corner(), corner(), corner());
        let extent = Vec3::new(
            self.rng.below(6) as f32 * 0.5,
            self.rng.below(6) as f32 * 0.5,
            self.rng.below(6) as f32 * 0.5,
        );
        Aabb::new(min, min + extent).expect("grid boxes are valid")
    }

    fn pick_live(&mut self) -> Option<Entity> {
        if self.live.is_empty() {
            None
        } else {
            Some(self.live[self.rng.below(self.live.len())])
        }
    }

    fn spawn(&mut self) {
        let bounds = SpatialBounds(self.grid_box());
        let layer = self.rng.below(4);
        let mut entity = self.world().spawn(bounds);
        match layer {
            0 => {
                entity.insert(Enemy);
            }
            1 => {
                entity.insert(Barrel);
            }
            2 => {
                entity.insert((Enemy, Barrel));
            }
            _ => {}
        }
        let id = entity.id();
        self.live.push(id);
    }

    fn random_frustum(&mut self) -> Frustum {
        let eye = Vec3::new(
            self.rng.range(0.0, 64.0),
            self.rng.range(0.0, 64.0),
            self.rng.range(0.0, 64.0),
        );
        let rotation = Quat::from_euler(
            glam::EulerRot::YXZ,
            self.rng.range(-3.1, 3.1),
            self.rng.range(-1.5, 1.5),
            0.0,
        );
        let fov = self.rng.range(0.3, 1.8);
        let far = self.rng.range(5.0, 80.0);
        Frustum::perspective(eye, rotation, fov, 1.5, 0.1, far).expect("valid frustum")
    }

    fn random_ray(&mut self) -> Ray {
        let origin = Vec3::new(
            self.rng.range(-4.0, 68.0),
            self.rng.range(-4.0, 68.0),
            self.rng.range(-4.0, 68.0),
        );
        if self.rng.below(20) == 0 {
            // Invalid on purpose: its error must land in its own answer.
            return Ray {
                origin,
                dir: Vec3::ZERO,
                max_t: 10.0,
            };
        }
        // Axis-aligned directions graze faces on the grid.
        let dir = if self.rng.below(3) == 0 {
            [Vec3::X, Vec3::NEG_Y, Vec3::Z][self.rng.below(3)]
        } else {
            self.rng.direction()
        };
        Ray {
            origin,
            dir,
            max_t: self.rng.range(1.0, 100.0),
        }
    }

    fn random_ray_mode(&mut self) -> RayMode {
        match self.rng.below(4) {
            0 => RayMode::Any,
            1 => RayMode::All { limit: None },
            2 => RayMode::All { limit: Some(3) },
            _ => RayMode::First,
        }
    }

    /// One frame of random changes, the update, and the checks.
    fn step(&mut self) {
        // Spawns outnumber despawns, so a long soak caps the population
        // (the oracle's pairs grow with its square); the draw is made
        // either way, so that a short soak's scene does not change.
        let spawns = self.rng.below(6);
        self.most_live = self.most_live.max(self.live.len());
        if self.live.len() < MAX_LIVE {
            for _ in 0..spawns {
                self.spawn();
            }
        }
        for _ in 0..self.rng.below(8) {
            let Some(e) = self.pick_live() else { break };
            let step = Vec3::new(
                self.rng.range(-0.3, 0.3),
                self.rng.range(-0.3, 0.3),
                self.rng.range(-0.3, 0.3),
            );
            let mut bounds = self.world().get_mut::<SpatialBounds>(e).expect("live");
            if bounds.0.is_valid() {
                bounds.0 = Aabb::new(bounds.0.min + step, bounds.0.max + step).expect("small move");
            }
        }
        if self.rng.below(3) == 0
            && let Some(e) = self.pick_live()
        {
            let teleport = if self.rng.below(5) == 0 {
                Aabb::new(Vec3::splat(1e6), Vec3::splat(1e6 + 1.0)).expect("valid")
            } else {
                self.grid_box()
            };
            self.world().get_mut::<SpatialBounds>(e).expect("live").0 = teleport;
        }
        if self.rng.below(3) == 0
            && let Some(e) = self.pick_live()
        {
            self.live.retain(|&x| x != e);
            self.world().despawn(e);
            self.despawned.push(e);
        }
        if self.rng.below(4) == 0
            && let Some(e) = self.pick_live()
        {
            let op = self.rng.below(4);
            let mut entity = self.world().entity_mut(e);
            match op {
                0 if entity.contains::<Enemy>() => {
                    entity.remove::<Enemy>();
                }
                0 => {
                    entity.insert(Enemy);
                }
                1 if entity.contains::<Barrel>() => {
                    entity.remove::<Barrel>();
                }
                1 => {
                    entity.insert(Barrel);
                }
                2 => {
                    entity.insert(NoSpatialIndex);
                    self.opted_out.push(e);
                }
                _ => {
                    entity.remove::<SpatialBounds>();
                    entity.insert(SpatialBounds(Aabb::INVERTED));
                }
            }
        }
        // Opt some back in (the entity may have been despawned since).
        if self.rng.below(3) == 0 && !self.opted_out.is_empty() {
            let e = self
                .opted_out
                .swap_remove(self.rng.below(self.opted_out.len()));
            if let Ok(mut entity) = self.world().get_entity_mut(e) {
                entity.remove::<NoSpatialIndex>();
            }
        }
        if self.rng.below(8) == 0
            && let Some(e) = self.pick_live()
        {
            let bad = [
                Aabb {
                    min: Vec3::new(f32::NAN, 0.0, 0.0),
                    max: Vec3::ONE,
                },
                Aabb {
                    min: Vec3::ONE,
                    max: Vec3::ZERO,
                },
                Aabb {
                    min: Vec3::ZERO,
                    max: Vec3::new(f32::INFINITY, 1.0, 1.0),
                },
            ][self.rng.below(3)];
            self.world().get_mut::<SpatialBounds>(e).expect("live").0 = bad;
        }
        // Bring some invalid boxes back so entities re-enter.
        if self.rng.below(3) == 0
            && let Some(e) = self.pick_live()
        {
            let fresh = self.grid_box();
            let mut bounds = self.world().get_mut::<SpatialBounds>(e).expect("live");
            if !bounds.0.is_valid() {
                bounds.0 = fresh;
            }
        }
        if self.rng.below(10) == 0 {
            if self.cameras.len() < 3 && self.rng.below(2) == 0 {
                let mode = [CullMode::Conservative, CullMode::Exact][self.rng.below(2)];
                let camera = CullingCamera::new(self.random_frustum()).with_mode(mode);
                let id = self.world().spawn(camera).id();
                self.cameras.push(id);
            } else if let Some(camera) = self.cameras.pop() {
                self.world().despawn(camera);
            }
        }
        for i in 0..self.cameras.len() {
            if self.rng.below(2) == 0 {
                let frustum = self.random_frustum();
                let camera = self.cameras[i];
                self.world()
                    .get_mut::<CullingCamera>(camera)
                    .expect("camera")
                    .frustum = frustum;
            }
        }
        if self.rng.below(8) == 0 {
            if self.casters.len() < 12 && self.rng.below(3) != 0 {
                let ray = self.random_ray();
                let mode = self.random_ray_mode();
                let id = self.world().spawn(RayCaster::new(ray, mode)).id();
                self.casters.push(id);
            } else if let Some(caster) = self.casters.pop() {
                self.world().despawn(caster);
            }
        }
        for i in 0..self.casters.len() {
            if self.rng.below(3) == 0 {
                let ray = self.random_ray();
                let caster = self.casters[i];
                self.world()
                    .get_mut::<RayCaster>(caster)
                    .expect("caster")
                    .ray = ray;
            }
        }
        self.app.update();
        self.frames += 1;
        self.check();
    }

    /// Every answer of this frame against the oracle of the current boxes.
    fn check(&mut self) {
        let world = self.app.world_mut();
        let mut all = BruteForce::default();
        let mut enemies = BruteForce::default();
        let mut barrels = BruteForce::default();
        let mut entities = world.query::<(
            Entity,
            &SpatialBounds,
            Has<Enemy>,
            Has<Barrel>,
            Has<NoSpatialIndex>,
        )>();
        for (entity, bounds, enemy, barrel, opted_out) in entities.iter(world) {
            if opted_out || !bounds.0.is_valid() {
                continue;
            }
            all.insert(entity, bounds.0);
            if enemy {
                enemies.insert(entity, bounds.0);
            }
            if barrel {
                barrels.insert(entity, bounds.0);
            }
        }
        let frame = self.frames;
        check_index(world.resource::<SpatialIndex>(), &all, frame, "all");
        check_index(
            world.resource::<SpatialIndex<Enemy>>(),
            &enemies,
            frame,
            "enemies",
        );
        check_index(
            world.resource::<SpatialIndex<Barrel>>(),
            &barrels,
            frame,
            "barrels",
        );
        let index = world.resource::<SpatialIndex>();
        for &gone in &self.despawned {
            assert!(
                !index.contains(gone),
                "frame {frame}: despawned {gone} is indexed"
            );
        }

        for &camera in &self.cameras {
            let culling = world.get::<CullingCamera>(camera).expect("camera");
            let expected = all.visible(&culling.frustum, culling.mode);
            let visible = world.get::<VisibleEntityList>(camera).expect("list");
            assert_eq!(
                visible.entities(),
                expected,
                "frame {frame}: camera {camera}"
            );
            self.compared[0] += expected.len();
        }
        for &caster in &self.casters {
            let ray_caster = world.get::<RayCaster>(caster).expect("caster");
            let answer = world.get::<RayCasterHits>(caster).expect("hits");
            match all.ray_hits(&ray_caster.ray) {
                Err(error) => assert_eq!(answer.error(), Some(error), "frame {frame}"),
                Ok(hits) => {
                    assert_eq!(answer.error(), None);
                    assert_eq!(answer.any(), !hits.is_empty(), "frame {frame}: any");
                    let expected: &[_] = match ray_caster.mode {
                        RayMode::First => &hits[..hits.len().min(1)],
                        RayMode::All { limit } => {
                            &hits[..hits.len().min(limit.unwrap_or(usize::MAX))]
                        }
                        RayMode::Any => &[],
                    };
                    assert_eq!(answer.hits(), expected, "frame {frame}: caster {caster}");
                    self.compared[1] += hits.len();
                }
            }
        }

        let expected = enemies
            .cross_join(&barrels, ENEMY_BARREL_DISTANCE, JoinMode::Euclidean)
            .expect("valid distance");
        let join = world.resource::<SpatialJoin<Enemy, Barrel>>();
        assert_eq!(join.pairs(), expected, "frame {frame}: enemy-barrel pairs");
        self.compared[2] += expected.len();
        let expected_self = enemies
            .self_join(ENEMY_SELF_DISTANCE, JoinMode::Chebyshev)
            .expect("valid distance");
        let self_join = world.resource::<SpatialJoin<Enemy, Enemy>>();
        assert_eq!(
            self_join.pairs(),
            expected_self,
            "frame {frame}: enemy self pairs"
        );

        // Started and ended messages carry last frame's pairs to this frame's.
        let started = world.resource::<Messages<PairStarted<Enemy, Barrel>>>();
        let ended = world.resource::<Messages<PairEnded<Enemy, Barrel>>>();
        let ended: EntityPairSet = ended
            .iter_current_update_messages()
            .map(|m| (m.a, m.b))
            .collect();
        self.open_pairs.retain(|pair| !ended.contains(pair));
        self.open_pairs
            .extend(started.iter_current_update_messages().map(|m| (m.a, m.b)));
        self.open_pairs.sort_unstable();
        assert_eq!(
            self.open_pairs, expected,
            "frame {frame}: started minus ended"
        );

        let diagnostics = world.resource::<SpatialDiagnostics>();
        assert_eq!(
            diagnostics.culling.runs > 0,
            !self.cameras.is_empty(),
            "frame {frame}"
        );
        assert_eq!(
            diagnostics.rays.runs > 0,
            !self.casters.is_empty(),
            "frame {frame}"
        );
    }
}

type EntityPairSet = std::collections::BTreeSet<(Entity, Entity)>;

/// The index holds exactly the oracle's entries, and its invariants hold.
fn check_index<L: Component>(
    index: &SpatialIndex<L>,
    oracle: &BruteForce<Entity>,
    frame: usize,
    name: &str,
) {
    index
        .validate()
        .unwrap_or_else(|e| panic!("frame {frame}: {name} index invalid: {e:?}"));
    let mut held: Vec<(Entity, [f32; 6])> = index
        .tree()
        .iter()
        .map(|(_, entity, b)| {
            (
                entity,
                [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z],
            )
        })
        .collect();
    held.sort_by_key(|(entity, _)| *entity);
    let mut expected: Vec<(Entity, [f32; 6])> = oracle
        .entries()
        .iter()
        .map(|(entity, b)| {
            (
                *entity,
                [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z],
            )
        })
        .collect();
    expected.sort_by_key(|(entity, _)| *entity);
    assert_eq!(held, expected, "frame {frame}: {name} index contents");
}

/// Runs a soak; returns the most entities live at the start of a frame.
fn soak(seed: u64, frames: usize, row_by_row: bool) -> usize {
    let mut driver = Driver::new(seed, row_by_row);
    for _ in 0..40 {
        driver.spawn();
    }
    for _ in 0..frames {
        driver.step();
    }
    assert_eq!(driver.frames, frames);
    let [visible, hits, pairs] = driver.compared;
    assert!(
        visible > 0 && hits > 0 && pairs > 0,
        "answers compared: {visible} visible, {hits} hits, {pairs} pairs"
    );
    driver.most_live
}

#[test]
fn soak_short() {
    let mut most_live = 0;
    for seed in 0..3 {
        most_live = most_live.max(soak(seed, 150, false));
    }
    most_live = most_live.max(soak(3, 150, true));
    assert!(most_live < MAX_LIVE, "the cap never bit: {most_live} live");
}

#[test]
#[ignore = "thousands of frames; run with --release -- --ignored"]
fn soak_long() {
    for seed in 100..104 {
        let most_live = soak(seed, 5_000, seed == 103);
        assert!(most_live >= MAX_LIVE, "a long session: {most_live} live");
    }
}
