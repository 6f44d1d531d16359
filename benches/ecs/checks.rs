//! Correctness before timing: the core path's answers equal the plugin's,
//! frame by frame.

use super::core_town::CoreTown;
use super::town::{Barrel, Enemy, Town};
use super::{CHECK_FRAMES, town};
use bevy_app::prelude::App;
use bevy_ecs::prelude::Entity;
use bevy_rtree::plugin::{RayCasterHits, SpatialJoin, VisibleEntityList};
use bevy_rtree::{QueryWorkspace, RayHit};

// Correctness: the core path's answers equal the plugin's.

/// Panics unless this frame's visible list, first hits and pairs of the App
/// and of the core path are equal.
pub(crate) fn assert_same_frame(app: &App, core: &CoreTown, frame: usize) {
    let world = app.world();
    let town = world.resource::<Town>();
    assert!(
        town.scene.boxes() == core.scene.boxes(),
        "frame {frame}: the two scenes are out of step"
    );
    let entity = |i: u32| town.entities[i as usize];

    let visible = world
        .get::<VisibleEntityList>(town.camera)
        .expect("the camera has its list")
        .entities();
    // Sorted again after mapping: the check must not rely on the entity ids
    // growing with the scene index.
    let mut core_visible: Vec<Entity> = core.visible[0].iter().map(|&i| entity(i)).collect();
    core_visible.sort_unstable();
    assert!(!visible.is_empty(), "frame {frame}: nothing visible");
    assert!(
        visible == core_visible.as_slice(),
        "frame {frame}: visible lists differ ({} vs {} entities)",
        visible.len(),
        core_visible.len()
    );

    // First hit is the smallest `(t, key)`, and `Entity` order is not scene
    // order (bevy_ecs stores the index inverted, so later spawns sort
    // first): on a tie in `t` the two paths rightly pick different boxes.
    // So the core's first hit is re-derived under `Entity` order from all of
    // the ray's hits at the core's best `t`.
    let mut ws = QueryWorkspace::default();
    let mut all_hits = Vec::new();
    let mut hits = 0;
    for (k, &caster) in town.casters.iter().enumerate() {
        let plugin = world
            .get::<RayCasterHits>(caster)
            .expect("every caster has hits")
            .first();
        let core_first = core.hits.first(k).expect("the scene's rays are valid");
        let core = core_first.map(|best| {
            core.all
                .cast_ray_all(&core.rays[k], None, &mut ws, &mut all_hits)
                .expect("the scene's rays are valid");
            let key = all_hits
                .iter()
                .filter(|h| h.t == best.t)
                .map(|h| entity(h.key))
                .min()
                .expect("the best hit is among all hits");
            RayHit { key, t: best.t }
        });
        assert_eq!(plugin, core, "frame {frame}: ray {k} differs");
        hits += usize::from(plugin.is_some());
    }
    assert!(hits > 0, "frame {frame}: no ray hit anything");

    let pairs = world.resource::<SpatialJoin<Enemy, Barrel>>().pairs();
    let mut core_pairs: Vec<(Entity, Entity)> = core
        .pairs
        .iter()
        .map(|&(a, b)| (entity(a), entity(b)))
        .collect();
    core_pairs.sort_unstable();
    assert!(!pairs.is_empty(), "frame {frame}: no pairs");
    assert!(
        pairs == core_pairs.as_slice(),
        "frame {frame}: pairs differ ({} vs {})",
        pairs.len(),
        core_pairs.len()
    );
}

/// Runs `CHECK_FRAMES` frames of both paths, comparing each, then checks the
/// plugin against brute force.
pub(crate) fn check_paths(app: &mut App, core: &mut CoreTown) {
    for frame in 0..CHECK_FRAMES {
        app.update();
        core.frame();
        assert_same_frame(app, core, frame);
    }
    assert!(
        town::agrees_with_oracle(app),
        "the plugin disagrees with brute force"
    );
    let (visible, hits, pairs) = town::counts(app);
    eprintln!(
        "ecs check ok over {CHECK_FRAMES} frames: {visible} visible, {hits} of {} rays hit, \
         {pairs} pairs; executor: {}",
        app.world().resource::<Town>().casters.len(),
        if cfg!(feature = "multi_threaded") {
            "bevy_ecs multi_threaded"
        } else {
            "single-threaded"
        }
    );
}
