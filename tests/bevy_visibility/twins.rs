//! The twin Apps: one with Bevy's own culling, one with the index
//! serving it, the same scene and changes in both, compared every frame.

use super::*;

/// The twin Apps and the entities of the scene, in spawn order, in each.
pub(crate) struct Twins {
    pub(crate) bevy: App,
    pub(crate) ours: App,
    pub(crate) entities: Vec<[Entity; 2]>,
    pub(crate) cameras: Vec<[Entity; 2]>,
    pub(crate) rng: SceneRng,
    /// Half the width of the square the entities are spread over, in metres.
    pub(crate) spread: f32,
    /// Each world's change tick before its last update.
    pub(crate) before: [Tick; 2],
    /// The visibility classes either world's cameras had a list for in an
    /// earlier frame.
    pub(crate) classes_seen: Vec<TypeId>,
}

impl Twins {
    pub(crate) fn new(seed: u64) -> Twins {
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
    pub(crate) fn both<R>(
        &mut self,
        mut f: impl FnMut(&mut World, &mut SceneRng, usize) -> R,
    ) -> [R; 2] {
        let state = self.rng.clone();
        let a = f(self.bevy.world_mut(), &mut self.rng, 0);
        self.rng = state;
        let b = f(self.ours.world_mut(), &mut self.rng, 1);
        [a, b]
    }

    pub(crate) fn spawn_entity(&mut self) {
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

    pub(crate) fn spawn_camera(&mut self, kind: usize) {
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
    pub(crate) fn mutate(&mut self) {
        let n = self.entities.len();
        let spread = self.spread;
        for _ in 0..n / 10 {
            let i = self.rng.below(n);
            let pair = self.entities[i];
            let action = self.rng.below(22);
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
                    19 => {
                        if entity.contains::<Disabled>() {
                            entity.remove::<Disabled>();
                        } else {
                            entity.insert(Disabled);
                        }
                    }
                    20 => {
                        let layers = [RenderLayers::none(), RenderLayers::from_layers(&[0, 1])];
                        entity.insert(layers[rng.below(2)].clone());
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
        // The cameras move and turn, and now and then one but the first is
        // turned off or on.
        for (c, pair) in self.cameras.clone().into_iter().enumerate() {
            let switch = self.rng.below(15) == 0 && c > 0;
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

    /// Every entity's `ViewVisibility` (and whether the last update marked
    /// it changed) and every camera's visible lists, mapped to spawn order,
    /// are the same in both worlds.
    pub(crate) fn check(&mut self, frame: usize) -> usize {
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
            // An inactive camera keeps the lists of the last frame it was
            // active in, which may be the first frame of a class.
            let active = self
                .bevy
                .world()
                .get::<Camera>(self.cameras[c][0])
                .unwrap()
                .is_active;
            if settled && active {
                assert_eq!(b.0, o.0, "frame {frame}: camera {c}'s classes");
            }
        }
        self.classes_seen.extend(classes);
        self.classes_seen.sort_unstable();
        self.classes_seen.dedup();
        visible
    }

    pub(crate) fn update(&mut self) {
        self.before = [
            self.bevy.world().read_change_tick(),
            self.ours.world().read_change_tick(),
        ];
        self.bevy.update();
        self.ours.update();
    }
}
