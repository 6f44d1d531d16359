//! Random scenes under harder changes than the other scenes make: the
//! visibility components and the transform taken away and given back,
//! classes switched, spheres, spilled layers, clones, disabling, and
//! cameras spawned, despawned, disabled and given `NoCpuCulling` or layers
//! mid-session; on the pass over every entity (on one thread and on
//! several), on look-ups, and where no entity gets the handle.

use super::*;

/// Extra random changes on top of `Twins::mutate`: the visibility
/// components and the transform taken away and given back, classes,
/// spheres, spilled layers, ranges, clones, and cameras spawned,
/// despawned, disabled and given `NoCpuCulling` / layers mid-session.
fn hard_changes(twins: &mut Twins) {
    let n = twins.entities.len();
    for _ in 0..n / 10 {
        let i = twins.rng.below(n);
        let pair = twins.entities[i];
        let action = twins.rng.below(14);
        let out = twins.both(|world, rng, side| {
            let Ok(mut entity) = world.get_entity_mut(pair[side]) else {
                return None;
            };
            match action {
                0 => take_or_give(&mut entity, || InheritedVisibility::VISIBLE),
                1 => take_or_give(&mut entity, ViewVisibility::default),
                2 => take_or_give(&mut entity, || {
                    GlobalTransform::from_xyz(rng.range(-50.0, 50.0), 1.0, rng.range(-50.0, 50.0))
                }),
                3 => {
                    entity.remove::<VisibilityClass>();
                }
                4 => {
                    entity.insert(Sphere {
                        center: Vec3A::ZERO,
                        radius: rng.range(0.1, 3.0),
                    });
                }
                5 => {
                    entity.insert(RenderLayers::from_layers(&[0, 100]));
                }
                6 => take_or_give(&mut entity, || {
                    VisibilityRange::abrupt(0.0, rng.range(10.0, 80.0))
                }),
                7 => {
                    entity.remove::<RenderableHandle>();
                }
                8 => {
                    let id = entity.clone_and_spawn();
                    return Some(id);
                }
                9 => take_or_give(&mut entity, || random_aabb(rng)),
                10 => {
                    entity.insert(Disabled);
                }
                11 => {
                    entity.remove::<Disabled>();
                }
                12 => {
                    // Re-insert the same box (a change without a move).
                    if let Some(aabb) = entity.get::<Aabb>().copied() {
                        entity.insert(aabb);
                    }
                }
                _ => {
                    entity.insert(VisibilityClass([TypeId::of::<AppClass>()].into()));
                }
            }
            None
        });
        if let [Some(a), Some(b)] = out {
            twins.entities.push([a, b]);
        }
    }
    // Cameras.
    let c = twins.cameras.len();
    match twins.rng.below(10) {
        0 if c < 14 => {
            let kind = twins.rng.below(5);
            twins.spawn_camera(kind);
        }
        1 if c > 1 => {
            let k = 1 + twins.rng.below(c - 1);
            let pair = twins.cameras.remove(k);
            twins.both(|world, _, side| {
                world.despawn(pair[side]);
            });
        }
        2 if c > 1 => take_or_give_on_a_camera(twins, || NoCpuCulling),
        3 if c > 1 => take_or_give_on_a_camera(twins, || RenderLayers::from_layers(&[1, 100])),
        4 if c > 1 => take_or_give_on_a_camera(twins, || Disabled),
        _ => {}
    }
}

/// Takes `C` away from `entity` where it has one, gives it `give()` where
/// it has none.
fn take_or_give<C: Component>(entity: &mut EntityWorldMut, give: impl FnOnce() -> C) {
    if entity.take::<C>().is_none() {
        entity.insert(give());
    }
}

/// [`take_or_give`] on one camera other than the first, the same in both
/// Apps.
fn take_or_give_on_a_camera<C: Component>(twins: &mut Twins, give: impl Fn() -> C) {
    let k = 1 + twins.rng.below(twins.cameras.len() - 1);
    let pair = twins.cameras[k];
    twins.both(|world, _, side| take_or_give(&mut world.entity_mut(pair[side]), &give));
}

fn run_hard_changes(seed: u64, spread: f32, parallel: bool, frames: usize) {
    let mut twins = Twins::new(seed);
    twins.spread = spread;
    twins.ours.insert_resource(BevyVisibilitySettings {
        parallel,
        ..Default::default()
    });
    for _ in 0..1_500 {
        twins.spawn_entity();
    }
    for kind in [0, 0, 2, 4, 0, 0, 4, 2, 0, 0] {
        twins.spawn_camera(kind);
    }
    for frame in 0..frames {
        twins.update();
        twins.check(frame);
        twins.mutate();
        hard_changes(&mut twins);
    }
    let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
    index.validate().unwrap();
}
#[test]
fn cameras_see_what_bevy_sees_through_hard_changes_on_several_threads() {
    for seed in 100..103 {
        run_hard_changes(seed, 100.0, true, 40);
    }
}

#[test]
fn cameras_see_what_bevy_sees_through_hard_changes_on_one_thread() {
    for seed in 200..203 {
        run_hard_changes(seed, 100.0, false, 40);
    }
}

/// A scene spread wide, so that the candidates are few and decided by
/// look-ups.
#[test]
fn cameras_see_what_bevy_sees_through_hard_changes_by_look_ups() {
    for seed in 300..303 {
        run_hard_changes(seed, 3_000.0, seed % 2 == 0, 40);
    }
}

/// The same scenes where no entity gets the handle (an `Aabb` entity was
/// spawned before the plugin).
#[test]
fn cameras_see_what_bevy_sees_through_hard_changes_without_handles() {
    for (seed, parallel) in [(400u64, true), (401, false)] {
        let mut bevy = app(false);
        let mut ours = app(false);
        let first = [bevy.world_mut(), ours.world_mut()].map(|world| {
            world
                .spawn((
                    Mesh3d::default(),
                    Aabb::from_min_max(Vec3::ZERO, Vec3::ONE),
                    Transform::default(),
                ))
                .id()
        });
        ours.add_plugins((SpatialIndexPlugin::default(), BevyVisibilityPlugin));
        let mut twins = Twins {
            bevy,
            ours,
            entities: vec![first],
            cameras: Vec::new(),
            rng: SceneRng::new(seed),
            spread: 100.0,
            before: [Tick::new(0); 2],
            classes_seen: Vec::new(),
        };
        twins.ours.insert_resource(BevyVisibilitySettings {
            parallel,
            ..Default::default()
        });
        for _ in 0..1_500 {
            twins.spawn_entity();
        }
        for kind in [0, 0, 2, 4, 0] {
            twins.spawn_camera(kind);
        }
        for frame in 0..40 {
            twins.update();
            twins.check(frame);
            twins.mutate();
            hard_changes(&mut twins);
        }
    }
}
