//! Every example scene, driven for a few frames, answers like brute force.
#![cfg(feature = "plugin")]

#[cfg(feature = "bevy_light")]
#[path = "../examples/bevy_lights.rs"]
#[allow(dead_code)]
mod bevy_lights;
#[cfg(feature = "bevy_camera")]
#[path = "../examples/bevy_visibility.rs"]
#[allow(dead_code)]
mod bevy_visibility;
#[path = "../examples/culling.rs"]
#[allow(dead_code)]
mod culling;
#[path = "../examples/enemies_barrels.rs"]
#[allow(dead_code)]
mod enemies_barrels;
#[cfg(feature = "bevy_camera")]
#[path = "../examples/game.rs"]
#[allow(dead_code)]
mod game;
#[path = "../examples/minimal.rs"]
#[allow(dead_code)]
mod minimal;
#[path = "../examples/raycasts.rs"]
#[allow(dead_code)]
mod raycasts;
#[path = "../examples/town.rs"]
#[allow(dead_code)]
mod town;

use bevy_rtree::plugin::{
    RayCasterHits, RebuildMode, SpatialDiagnostics, SpatialIndexPlugin, VisibleEntityList,
};

#[test]
fn minimal_sees_and_hits_the_crates_in_front() {
    let mut scene = minimal::build();
    scene.app.update();
    let world = scene.app.world();
    let [near, far, behind] = scene.boxes;
    let mut expected = vec![near, far];
    expected.sort_unstable();
    let visible = world.get::<VisibleEntityList>(scene.camera).unwrap();
    assert_eq!(visible.entities(), expected);
    assert!(!visible.contains(behind));
    let hit = world
        .get::<RayCasterHits>(scene.eye)
        .unwrap()
        .first()
        .unwrap();
    assert_eq!((hit.key, hit.t), (near, 4.5));
}

#[test]
fn town_through_the_plugin_matches_the_oracle() {
    // Enough entities for both join layers (barrels start at 10,000), and
    // 30 frames of moves repaired by the maintenance (rebuilds, where a
    // tree wears, in slices, as where there is no task pool); the
    // brute-force check of 2,000 rays dominates, so it runs on the first
    // two frames and the last.
    let plugin = SpatialIndexPlugin {
        rebuild: RebuildMode::InSlices(std::time::Duration::from_micros(200)),
        ..SpatialIndexPlugin::default()
    };
    let mut app = town::build_with(11_000, 9, plugin);
    for frame in 0..30 {
        app.update();
        if frame < 2 || frame == 29 {
            assert!(town::agrees_with_oracle(&app), "frame {frame}");
        }
    }
    let (visible, hits, pairs) = town::counts(&app);
    assert!(
        visible > 0 && hits > 0 && pairs > 0,
        "{visible} {hits} {pairs}"
    );
    let d = *app.world().resource::<SpatialDiagnostics>();
    assert!(d.sync.updated > 0 && d.culling.runs == 1 && d.rays.queries == 2_000);
}

#[test]
fn culling_cameras_match_the_oracle() {
    let mut app = culling::build(3_000);
    for _ in 0..3 {
        app.update();
        let seen = culling::check(&mut app);
        assert!(seen.iter().all(|&(_, agrees)| agrees));
        assert!(seen.iter().any(|&(count, _)| count > 0));
        // Exact never sees more than conservative from the same view.
        assert!(seen[2].0 <= seen[0].0 && seen[3].0 <= seen[1].0);
    }
}

#[test]
fn raycast_casters_match_the_oracle() {
    let mut app = raycasts::build();
    for _ in 0..3 {
        app.update();
        let (_, hitting, scanned, agrees) = raycasts::check(&mut app);
        assert!(agrees);
        assert!(hitting > 0 && scanned > 0);
    }
}

#[test]
fn enemies_and_barrels_pairs_match_the_oracle() {
    let mut app = enemies_barrels::build();
    for _ in 0..3 {
        app.update();
        let (pairs, agrees) = enemies_barrels::check(&mut app);
        assert!(agrees);
        assert!(pairs > 0);
    }
}

/// The street of Bevy meshes: houses ahead drawn, behind not, the hidden
/// house and its chimney never, the sign on another layer never, the sky
/// with `NoFrustumCulling` always; the camera's list holds exactly the
/// drawn meshes.
#[cfg(feature = "bevy_camera")]
#[test]
fn bevy_visibility_draws_what_bevy_would() {
    let mut street = bevy_visibility::build();
    let mut drawn_total = 0;
    for _ in 0..20 {
        street.app.update();
        let drawn: Vec<_> = street
            .houses
            .iter()
            .filter(|&&h| bevy_visibility::drawn(&street, h))
            .collect();
        assert!(!drawn.is_empty() && drawn.len() < street.houses.len());
        drawn_total += drawn.len();
        assert!(!bevy_visibility::drawn(&street, street.hidden_house));
        assert!(!bevy_visibility::drawn(&street, street.chimney));
        assert!(!bevy_visibility::drawn(&street, street.sign_on_layer_one));
        assert!(bevy_visibility::drawn(&street, street.sky));
        // The houses drawn and the sky.
        assert_eq!(bevy_visibility::listed(&street), drawn.len() + 1);
    }
    assert!(drawn_total > 20 * 20, "{drawn_total}");
    // Culled by the tree: the plugin's culling ran and visited its nodes.
    let d = *street.app.world().resource::<SpatialDiagnostics>();
    assert!(d.culling.runs == 1 && d.culling.nodes_visited > 0, "{d:?}");
}

/// The street with lamps and a moon: every lamp the camera sees lists, in
/// its shadow maps, every house within its 15 m range and no house beyond
/// the range plus the house's half diagonal; the hidden house, its
/// chimney, the sign on another layer and the bush that casts no shadow
/// are in no shadow map; the sky dome with `NoFrustumCulling` is in every
/// one; the moon's cascades hold houses.
#[cfg(feature = "bevy_light")]
#[test]
fn bevy_lights_shadow_what_bevy_would() {
    use bevy_camera::primitives::Aabb;
    use bevy_ecs::entity::Entity;
    use bevy_transform::prelude::GlobalTransform;
    use glam::Vec3;
    let mut street = bevy_lights::build();
    let mut lamps_checked = 0;
    for _ in 0..20 {
        street.app.update();
        let world = street.app.world();
        let world_box = |e: Entity| {
            let aabb = world.get::<Aabb>(e).unwrap();
            let at = world.get::<GlobalTransform>(e).unwrap().translation();
            let (c, h) = (at + Vec3::from(aabb.center), Vec3::from(aabb.half_extents));
            (c - h, c + h)
        };
        for &lamp in &street.lamps {
            // Lights no camera sees keep last frame's lists, as in Bevy.
            if !bevy_lights::drawn(&street, lamp) {
                continue;
            }
            lamps_checked += 1;
            let centre = world.get::<GlobalTransform>(lamp).unwrap().translation();
            for &house in &street.houses {
                let (min, max) = world_box(house);
                let gap = (centre - centre.clamp(min, max)).length();
                let half_diagonal = ((max - min) * 0.5).length();
                let listed = bevy_lights::in_lamp_shadow(&street, lamp, house);
                if gap <= 15.0 {
                    assert!(listed, "a house {gap} m from a lamp casts its shadow");
                }
                if gap > 15.0 + half_diagonal {
                    assert!(!listed, "a house {gap} m from a lamp casts none");
                }
            }
            for never in [
                street.hidden_house,
                street.chimney,
                street.sign_on_layer_one,
                street.bush,
            ] {
                assert!(!bevy_lights::in_lamp_shadow(&street, lamp, never));
            }
            assert!(bevy_lights::in_lamp_shadow(&street, lamp, street.sky));
        }
        let moon = bevy_lights::in_moon_shadow(&street);
        assert!(street.houses.iter().any(|h| moon.contains(h)));
        assert!(moon.contains(&street.sky) && !moon.contains(&street.bush));
        assert!(!moon.contains(&street.hidden_house) && !moon.contains(&street.chimney));
    }
    assert!(lamps_checked > 20, "{lamps_checked}");
}

/// The small game: every enemy either sees the player or is blocked by
/// its wall (every other one); the warnings are the oracle's enemy-barrel
/// pairs within 5 m; each turret's hit is the oracle's first hit of the ray
/// it cast, its own truck left out, and that ray is where the turret sits
/// on its truck; the cargo rides with its truck.
#[cfg(feature = "bevy_camera")]
#[test]
fn the_game_sees_hits_and_warns_as_brute_force_does() {
    use bevy_ecs::prelude::*;
    use bevy_rtree::JoinMode;
    use bevy_rtree::plugin::{LocalBounds, RayCaster, SpatialBounds, layer_oracle};
    use bevy_transform::prelude::{GlobalTransform, Transform};
    use glam::Vec3;
    // The warnings of the first frame: every pair within 5 m (nothing
    // that counts moves) is heard in the frame it starts.
    let mut first = game::build();
    // And no two of its systems that touch the same data run in an order
    // left to the executor.
    first.edit_schedule(bevy_app::PostUpdate, |schedule| {
        schedule.set_build_settings(bevy_ecs::schedule::ScheduleBuildSettings {
            ambiguity_detection: bevy_ecs::schedule::LogLevel::Error,
            ..Default::default()
        });
    });
    first.update();
    let mut first_warned = first.world().resource::<game::Seen>().warned.clone();
    first_warned.sort_unstable();
    let mut app = game::build();
    for _ in 0..5 {
        app.update();
    }
    let enemies = layer_oracle::<game::Enemy>(app.world_mut());
    let barrels = layer_oracle::<game::Barrel>(app.world_mut());
    let mut pairs = enemies
        .cross_join(&barrels, 5.0, JoinMode::Euclidean)
        .unwrap();
    pairs.sort_unstable();
    let all = layer_oracle::<SpatialBounds>(app.world_mut());
    let world = app.world_mut();
    // Each enemy's line of sight, from the oracle: the first hit of the
    // segment to the player that is not an enemy.
    let player = world
        .query_filtered::<(Entity, &GlobalTransform), With<game::Player>>()
        .single(world)
        .map(|(e, at)| (e, at.translation()))
        .unwrap();
    let mut expected_blocked: Vec<Entity> = world
        .query_filtered::<(Entity, &GlobalTransform), With<game::Enemy>>()
        .iter(world)
        .filter(|(_, at)| {
            let ray = bevy_rtree::Ray::segment(at.translation(), player.1).unwrap();
            let hits = all.ray_hits(&ray).unwrap();
            let first = hits
                .iter()
                .find(|hit| !enemies.entries().iter().any(|(e, _)| *e == hit.key));
            first.is_some_and(|hit| hit.key != player.0)
        })
        .map(|(e, _)| e)
        .collect();
    expected_blocked.sort_unstable();
    let seen = world.resource::<game::Seen>();
    let mut blocked = seen.blocked.clone();
    blocked.sort_unstable();
    assert_eq!(
        blocked, expected_blocked,
        "the enemies whose sight is blocked"
    );
    assert_eq!((seen.enemies_seeing_player, blocked.len()), (8, 8));
    assert_eq!(seen.refused, 0);
    let mut warned = seen.warned.clone();
    warned.sort_unstable();
    assert_eq!(
        warned, pairs,
        "one warning per enemy-barrel pair within 5 m"
    );
    assert!(!pairs.is_empty());
    assert_eq!(first_warned, pairs, "warned in the first frame");
    // Where each truck is, from its own `Transform` (it has no parent).
    let mut trucks = world.query_filtered::<&Transform, With<game::Truck>>();
    let mut truck_at = |world: &World, truck: Entity| *trucks.get(world, truck).unwrap();
    let mut turrets = world.query::<(Entity, &RayCasterHits, &ChildOf)>();
    let (mut checked, mut on_target) = (0, 0);
    for (turret, hits, child_of) in turrets.iter(world) {
        let ray = hits.ray().unwrap();
        // The turret sits 1 m ahead and 0.5 m up in the cab, looking down
        // the truck's +X.
        let truck = truck_at(world, child_of.parent());
        let origin = truck.transform_point(Vec3::new(1.0, 0.5, 0.0));
        assert!((ray.origin - origin).length() < 1e-4, "{ray:?}");
        assert!(
            (ray.dir - truck.rotation * Vec3::X).length() < 1e-5,
            "{ray:?}"
        );
        let want = all
            .ray_hits(&ray)
            .unwrap()
            .into_iter()
            .find(|h| h.key != turret && h.key != child_of.parent());
        assert_eq!(hits.first().map(|h| h.key), want.map(|h| h.key));
        on_target += usize::from(want.is_some());
        checked += 1;
    }
    assert_eq!(checked, 4);
    assert!(on_target > 0, "no turret has a target to check");
    // The cargo: a unit box 2.5 m above its truck's origin, indexed there.
    let mut cargo = world
        .query_filtered::<(&SpatialBounds, &ChildOf), (With<LocalBounds>, Without<RayCaster>)>();
    let mut carried = 0;
    for (bounds, child_of) in cargo.iter(world) {
        let truck = truck_at(world, child_of.parent());
        let centre = truck.transform_point(Vec3::new(0.0, 2.5, 0.0));
        let middle = (bounds.0.min + bounds.0.max) * 0.5;
        assert!((middle - centre).length() < 1e-4, "{bounds:?}");
        carried += 1;
    }
    assert_eq!(carried, 4);
}
