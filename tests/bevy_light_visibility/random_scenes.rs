//! Random scenes of casters, lights and cameras over many frames.

use super::*;

/// Random scenes of two thousand casters, point, spot and directional
/// lights with and without shadows, two active cameras and an inactive
/// one, over frames of moves, teleports, toggles, bad transforms,
/// despawns and respawns.
#[test]
fn lights_see_what_bevy_lights_see_every_frame() {
    for seed in 0..2 {
        let mut twins = Twins::new(seed);
        // The second scene runs without the inside proof: every cascade
        // candidate takes Bevy's test.
        twins.apps[1].insert_resource(BevyVisibilitySettings {
            prove_inside: seed == 0,
            ..Default::default()
        });
        for _ in 0..2_000 {
            twins.spawn_caster();
        }
        twins.spawn_camera(true);
        twins.spawn_camera(true);
        twins.spawn_camera(false);
        for _ in 0..6 {
            twins.spawn_light(LightKind::Point);
        }
        for _ in 0..3 {
            twins.spawn_light(LightKind::Spot);
        }
        twins.spawn_light(LightKind::Directional);
        twins.spawn_light(LightKind::Directional);
        let mut listed = [0; 3];
        for frame in 0..40 {
            twins.update();
            let seen = twins.check(frame);
            listed.iter_mut().zip(seen).for_each(|(l, s)| *l += s);
            twins.mutate();
        }
        // Point, spot and directional lights each see enough to compare.
        assert!(listed.iter().all(|&l| l > 2_000), "{listed:?}");
        let index = twins.apps[1].world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
    }
}
