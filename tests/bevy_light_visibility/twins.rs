//! The twin Apps with Bevy's lights: one with Bevy's own shadow
//! visibility, one with the index serving it, the same scene and changes
//! in both, compared every frame.

use super::*;

/// Which kind of light a twin pair is.
#[derive(Clone, Copy)]
pub(crate) enum LightKind {
    Point,
    Spot,
    Directional,
}

pub(crate) struct Twins {
    pub(crate) apps: [App; 2],
    pub(crate) casters: Vec<[Entity; 2]>,
    pub(crate) lights: Vec<(LightKind, [Entity; 2])>,
    pub(crate) cameras: Vec<[Entity; 2]>,
    pub(crate) rng: SceneRng,
}

impl Twins {
    pub(crate) fn new(seed: u64) -> Twins {
        Twins {
            apps: [app(false), app(true)],
            casters: Vec::new(),
            lights: Vec::new(),
            cameras: Vec::new(),
            rng: SceneRng::new(seed),
        }
    }

    /// Runs `f` on both worlds with the same random draws.
    pub(crate) fn both<R>(
        &mut self,
        mut f: impl FnMut(&mut World, &mut SceneRng, usize) -> R,
    ) -> [R; 2] {
        let state = self.rng.clone();
        let a = f(self.apps[0].world_mut(), &mut self.rng, 0);
        self.rng = state;
        let b = f(self.apps[1].world_mut(), &mut self.rng, 1);
        [a, b]
    }

    pub(crate) fn spawn_caster(&mut self) {
        let parent = (self.rng.below(10) == 0 && !self.casters.is_empty())
            .then(|| self.casters[self.rng.below(self.casters.len())]);
        let pair = self.both(|world, rng, side| {
            let mut entity = world.spawn((
                Mesh3d::default(),
                random_transform(rng, 60.0, (-2.0, 12.0)),
                random_visibility(rng),
            ));
            // One in twelve has no box (Bevy's lights see it everywhere).
            if rng.below(12) != 0 {
                entity.insert(random_aabb(rng));
            }
            match rng.below(14) {
                0 => {
                    entity.insert(NoFrustumCulling);
                }
                1 => {
                    entity.insert(NoCpuCulling);
                }
                2 => {
                    entity.insert(NotShadowCaster);
                }
                3 => {
                    entity.insert(RenderLayers::layer(1));
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
        self.casters.push(pair);
    }

    pub(crate) fn spawn_camera(&mut self, active: bool) {
        let pair = self.both(|world, rng, _| {
            let eye = Vec3::new(rng.range(-40.0, 40.0), 5.0, rng.range(-40.0, 40.0));
            let look = Quat::from_rotation_y(rng.range(0.0, 6.3)) * Quat::from_rotation_x(-0.2);
            world
                .spawn((
                    Camera3d::default(),
                    Camera {
                        is_active: active,
                        ..Camera::default()
                    },
                    Transform::from_translation(eye).with_rotation(look),
                ))
                .id()
        });
        self.cameras.push(pair);
    }

    pub(crate) fn spawn_light(&mut self, kind: LightKind) {
        let pair = self.both(|world, rng, _| {
            let at = Vec3::new(
                rng.range(-50.0, 50.0),
                rng.range(1.0, 15.0),
                rng.range(-50.0, 50.0),
            );
            let shadows = rng.below(5) != 0;
            let mut light = match kind {
                LightKind::Point => world.spawn((
                    PointLight {
                        range: rng.range(3.0, 30.0),
                        shadow_maps_enabled: shadows,
                        ..PointLight::default()
                    },
                    Transform::from_translation(at),
                )),
                LightKind::Spot => world.spawn((
                    SpotLight {
                        range: rng.range(5.0, 40.0),
                        outer_angle: rng.range(0.2, 1.2),
                        shadow_maps_enabled: shadows,
                        ..SpotLight::default()
                    },
                    Transform::from_translation(at).looking_at(Vec3::ZERO, Vec3::Y),
                )),
                LightKind::Directional => world.spawn((
                    DirectionalLight {
                        shadow_maps_enabled: shadows,
                        ..DirectionalLight::default()
                    },
                    Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
                )),
            };
            if rng.below(6) == 0 {
                light.insert(RenderLayers::layer(1));
            }
            light.id()
        });
        self.lights.push((kind, pair));
    }

    /// One frame of random changes, the same in both worlds: the casters
    /// move, jump, change their markers and boxes, are disabled and
    /// despawned; the lights move and change; the cameras move, and now and
    /// then one is turned off or on.
    pub(crate) fn mutate(&mut self) {
        let n = self.casters.len();
        for _ in 0..n / 10 {
            let pair = self.casters[self.rng.below(n)];
            let action = self.rng.below(22);
            self.both(|world, rng, side| {
                let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                    return;
                };
                match action {
                    0..=8 => {
                        if let Some(mut t) = entity.get_mut::<Transform>() {
                            t.translation +=
                                Vec3::new(rng.range(-1.0, 1.0), 0.0, rng.range(-1.0, 1.0));
                            t.rotate_y(rng.range(-0.3, 0.3));
                        }
                    }
                    9..=10 => {
                        entity.insert(random_transform(rng, 60.0, (-2.0, 12.0)));
                    }
                    11 => {
                        entity.insert(random_visibility(rng));
                    }
                    12 => {
                        if entity.contains::<NotShadowCaster>() {
                            entity.remove::<NotShadowCaster>();
                        } else {
                            entity.insert(NotShadowCaster);
                        }
                    }
                    13 => {
                        // Bad input as Bevy sees it.
                        let bad = [
                            Transform::from_scale(Vec3::ZERO),
                            Transform::from_xyz(f32::NAN, 0.0, 0.0),
                        ][rng.below(2)];
                        entity.insert(bad);
                    }
                    14 => {
                        entity.insert(random_aabb(rng));
                    }
                    15 => {
                        toggle::<NoFrustumCulling>(&mut entity);
                    }
                    16 => {
                        toggle::<NoCpuCulling>(&mut entity);
                    }
                    17 => {
                        toggle::<bevy_ecs::entity_disabling::Disabled>(&mut entity);
                    }
                    18 => {
                        // No box, or one Bevy's tests see as bad.
                        if rng.below(2) == 0 {
                            entity.remove::<bevy_camera::primitives::Aabb>();
                        } else {
                            entity.insert(bevy_camera::primitives::Aabb {
                                center: Vec3::ZERO.into(),
                                half_extents: Vec3::new(-1.0, 1.0, f32::NAN).into(),
                            });
                        }
                    }
                    19 => {
                        // A second marker beside the one it may have.
                        if rng.below(2) == 0 {
                            entity.insert(VisibilityRange::abrupt(0.0, rng.range(10.0, 80.0)));
                        } else {
                            entity.insert(RenderLayers::from_layers(&[0, 1]));
                        }
                    }
                    20 => {
                        entity.insert(RenderLayers::none());
                    }
                    _ => {
                        entity.despawn();
                    }
                }
            });
        }
        for _ in 0..n / 50 {
            self.spawn_caster();
        }
        for (kind, pair) in self.lights.clone() {
            let change = self.rng.below(12);
            self.both(|world, rng, side| {
                let mut light = world.entity_mut(pair[side]);
                let mut t = light.get_mut::<Transform>().unwrap();
                t.translation += Vec3::new(rng.range(-2.0, 2.0), 0.0, rng.range(-2.0, 2.0));
                // Now and then the light itself changes: its shadows, its
                // layers, its range (none at all, too) or its cone.
                match (change, kind) {
                    (0, LightKind::Point) => {
                        let mut point = light.get_mut::<PointLight>().unwrap();
                        point.shadow_maps_enabled = !point.shadow_maps_enabled;
                    }
                    (0, LightKind::Spot) => {
                        let mut spot = light.get_mut::<SpotLight>().unwrap();
                        spot.shadow_maps_enabled = !spot.shadow_maps_enabled;
                    }
                    (0, LightKind::Directional) => {
                        let mut sun = light.get_mut::<DirectionalLight>().unwrap();
                        sun.shadow_maps_enabled = !sun.shadow_maps_enabled;
                    }
                    (1, _) => {
                        let layers = [RenderLayers::layer(0), RenderLayers::layer(1)];
                        light.insert(layers[rng.below(2)].clone());
                    }
                    (2, LightKind::Point) => {
                        let range = [0.0, rng.range(3.0, 30.0)][rng.below(2)];
                        light.get_mut::<PointLight>().unwrap().range = range;
                    }
                    (2, LightKind::Spot) => {
                        let mut spot = light.get_mut::<SpotLight>().unwrap();
                        spot.range = [0.0, rng.range(5.0, 40.0)][rng.below(2)];
                        spot.outer_angle = rng.range(0.05, 1.5);
                        spot.inner_angle = spot.inner_angle.min(spot.outer_angle);
                    }
                    _ => {}
                }
            });
        }
        for pair in self.cameras.clone() {
            let switch = self.rng.below(15) == 0;
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

    /// Every caster's `ViewVisibility` and every light's lists, mapped to
    /// spawn order, are the same in both worlds; returns how many entries
    /// the lists of point, spot and directional lights hold.
    pub(crate) fn check(&self, frame: usize) -> [usize; 3] {
        for (i, pair) in self.casters.iter().enumerate() {
            let [bevy, ours] = [0, 1].map(|side| {
                let world = self.apps[side].world();
                world
                    .get_entity(pair[side])
                    .ok()
                    .and_then(|e| e.get::<ViewVisibility>().map(|v| v.get()))
            });
            assert_eq!(bevy, ours, "frame {frame}: ViewVisibility of caster {i}");
        }
        let [bevy, ours] = [0, 1].map(|side| self.light_lists(side));
        for (l, (b, o)) in bevy.iter().zip(&ours).enumerate() {
            assert_eq!(b, o, "frame {frame}: the lists of light {l}");
        }
        let mut listed = [0; 3];
        for ((kind, _), lists) in self.lights.iter().zip(&bevy) {
            let entries: usize = lists.iter().map(Vec::len).sum();
            listed[*kind as usize] += entries;
        }
        listed
    }

    /// Each light's lists (six faces, one spot list, or one list per
    /// cascade of each camera), as spawn indices, sorted.
    pub(crate) fn light_lists(&self, side: usize) -> Vec<Vec<Vec<usize>>> {
        let world = self.apps[side].world();
        let spawned: HashMap<Entity, usize> = self
            .casters
            .iter()
            .enumerate()
            .map(|(i, p)| (p[side], i))
            .collect();
        let map = |list: &VisibleMeshEntities| {
            assert!(list.entities.is_sorted(), "sorted, as Bevy sorts them");
            let mut out: Vec<usize> = list.entities.iter().map(|e| spawned[e]).collect();
            out.sort_unstable();
            out
        };
        self.lights
            .iter()
            .map(|(kind, pair)| {
                let light = world.entity(pair[side]);
                match kind {
                    LightKind::Point => light
                        .get::<CubemapVisibleEntities>()
                        .unwrap()
                        .iter()
                        .map(map)
                        .collect(),
                    LightKind::Spot => vec![map(light.get::<VisibleMeshEntities>().unwrap())],
                    LightKind::Directional => {
                        let cascades = light.get::<CascadesVisibleEntities>().unwrap();
                        let mut lists = Vec::new();
                        for camera in &self.cameras {
                            let per_view = cascades.entities.get(&camera[side]);
                            lists.push(vec![per_view.map_or(usize::MAX, Vec::len)]);
                            lists.extend(per_view.into_iter().flatten().map(map));
                        }
                        lists
                    }
                }
            })
            .collect()
    }

    pub(crate) fn update(&mut self) {
        self.apps.iter_mut().for_each(App::update);
    }
}
