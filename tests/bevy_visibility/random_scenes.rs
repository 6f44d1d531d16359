//! Random scenes over hundreds of frames, on the pass over every entity
//! and on look-ups, with and without the inside proof.

use super::*;

/// Random scenes of a few thousand entities, five kinds of camera and
/// hundreds of frames of moves, teleports, toggles and respawns; the
/// second scene with the work kept on one thread.
#[test]
fn cameras_see_what_bevy_sees_every_frame() {
    for seed in 0..3 {
        let mut twins = Twins::new(seed);
        twins.ours.insert_resource(BevyVisibilitySettings {
            parallel: seed != 1,
            ..Default::default()
        });
        for _ in 0..2_000 {
            twins.spawn_entity();
        }
        for kind in [0, 0, 1, 2, 3, 4] {
            twins.spawn_camera(kind);
        }
        let mut seen = 0;
        for frame in 0..60 {
            twins.update();
            seen += twins.check(frame);
            twins.mutate();
        }
        assert!(seen > 10_000, "the cameras see enough to compare: {seen}");
        let index = twins.ours.world().resource::<SpatialIndex<Renderable>>();
        index.validate().unwrap();
        assert!(
            index.len() > 1_000,
            "the renderables are indexed: {}",
            index.len()
        );
        let diagnostics = twins.ours.world().resource::<SpatialDiagnostics>();
        assert!(diagnostics.culling.runs > 0);
        // The last frame's work: most candidates proven, the rest and the
        // entities outside the tree left to Bevy's tests.
        let work = diagnostics.bevy_visibility;
        assert!(
            work.proven > 0 && work.proven <= work.candidates,
            "{work:?}"
        );
        assert!(work.tested >= work.candidates - work.proven, "{work:?}");
    }
}

/// With the inside proof off (`BevyVisibilitySettings`), every candidate
/// takes Bevy's tests: the same answers.
#[test]
fn cameras_without_the_inside_proof_see_what_bevy_sees() {
    let mut twins = Twins::new(5);
    twins.ours.insert_resource(BevyVisibilitySettings {
        prove_inside: false,
        ..Default::default()
    });
    for _ in 0..2_000 {
        twins.spawn_entity();
    }
    for kind in [0, 2, 4] {
        twins.spawn_camera(kind);
    }
    let mut seen = 0;
    for frame in 0..20 {
        twins.update();
        seen += twins.check(frame);
        twins.mutate();
    }
    assert!(seen > 2_000, "the cameras see enough to compare: {seen}");
    let work = twins
        .ours
        .world()
        .resource::<SpatialDiagnostics>()
        .bevy_visibility;
    assert_eq!(work.proven, 0, "nothing proven with the proof off");
    assert!(
        work.candidates > 0 && work.tested >= work.candidates,
        "{work:?}"
    );
}

/// Entities spread over 4 km, cameras that each see a small part of them:
/// candidates are looked up one by one (the path for large worlds), not
/// decided in a pass over all entities.
#[test]
fn cameras_that_see_a_small_part_see_what_bevy_sees() {
    let mut twins = Twins::new(11);
    twins.spread = 2_000.0;
    for _ in 0..6_000 {
        twins.spawn_entity();
    }
    for kind in [0, 1, 2] {
        twins.spawn_camera(kind);
    }
    let mut seen = 0;
    for frame in 0..30 {
        twins.update();
        seen += twins.check(frame);
        twins.mutate();
    }
    // The counts include the entities no frustum culls (no box,
    // `NoFrustumCulling`): the tree's candidates are far fewer than an
    // eighth of the entities, which sends them to the look-up path.
    assert!(seen > 200, "{seen} seen in 30 frames");
}

/// Candidates few against all entities (the look-up path) but many for
/// one camera: on the three-thread pool (where bevy_tasks has threads;
/// `app` checks the pool's size) the look-ups are split into shares over
/// the threads, the rows they saw marked visible afterwards; the frames
/// must reach that path (one camera, so the counts are its own).
#[test]
fn look_ups_split_over_the_pool_see_what_bevy_sees() {
    let mut twins = Twins::new(12);
    twins.spread = 700.0;
    for _ in 0..10_000 {
        twins.spawn_entity();
    }
    twins.spawn_camera(0);
    let mut split_frames = 0;
    for frame in 0..30 {
        twins.update();
        twins.check(frame);
        let world = twins.ours.world_mut();
        let work = world.resource::<SpatialDiagnostics>().bevy_visibility;
        let culled = world
            .query_filtered::<(), (
                With<ViewVisibility>,
                With<GlobalTransform>,
                Without<NoCpuCulling>,
            )>()
            .iter(world)
            .count() as u64;
        if work.proven >= 512 && work.candidates * 8 <= culled {
            split_frames += 1;
        }
        twins.mutate();
    }
    assert!(
        split_frames > 20,
        "{split_frames} frames on the split look-ups"
    );
}
