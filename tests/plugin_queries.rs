//! Named scenes through the plugin: what its queries answer (culling
//! cameras, `SpatialQuery`, filters, ray casters) against the oracle.
#![cfg(feature = "plugin")]

use bevy_app::prelude::*;
use bevy_ecs::prelude::*;
use bevy_rtree::plugin::*;
use bevy_rtree::{Aabb, CullMode, Ray, RayMode};
use glam::Vec3;

mod common;
use common::plugin_scene::*;

#[test]
fn culling_modes_and_camera_lists_match_the_oracle() {
    let mut app = app();
    let mut oracle = bevy_rtree::oracle::BruteForce::default();
    for i in 0..50 {
        let b = unit_at(i as f32 * 1.5 - 30.0);
        let e = app.world_mut().spawn(b).id();
        oracle.insert(e, b.0);
    }
    let conservative = app.world_mut().spawn(camera()).id();
    let exact = app
        .world_mut()
        .spawn(camera().with_mode(CullMode::Exact))
        .id();
    app.update();
    let frustum = app
        .world()
        .get::<CullingCamera>(conservative)
        .unwrap()
        .frustum;
    for (cam, mode) in [
        (conservative, CullMode::Conservative),
        (exact, CullMode::Exact),
    ] {
        let list = app.world().get::<VisibleEntityList>(cam).unwrap();
        let expected = oracle.visible(&frustum, mode);
        assert!(!expected.is_empty());
        assert_eq!(list.entities(), expected);
    }
    // Two modes, two traversals, in one run of the layer's culling.
    let culling = diagnostics(&app).culling;
    assert_eq!((culling.runs, culling.queries), (1, 2));
}

#[test]
fn spatial_query_answers_like_the_oracle_from_any_system() {
    #[derive(Resource, Default)]
    struct Answers {
        first: Option<Entity>,
        nearest: Vec<Entity>,
        within: Vec<Entity>,
        sphere: Vec<Entity>,
        overlap: Vec<Entity>,
        enemies_near: Vec<Entity>,
    }

    fn ask(mut all: SpatialQuery, mut enemies: SpatialQuery<Enemy>, mut answers: ResMut<Answers>) {
        let origin = Vec3::new(-5.0, 0.5, 0.5);
        let ray = Ray::new(origin, Vec3::X, 100.0).unwrap();
        let any = &SpatialQueryFilter::default();
        answers.first = all.cast_ray(&ray, any).unwrap().map(|h| h.key);
        let mut neighbours = Vec::new();
        all.nearest(Vec3::new(10.2, 0.5, 0.5), 3, None, any, &mut neighbours)
            .unwrap();
        answers.nearest = neighbours.iter().map(|n| n.key).collect();
        all.within_radius(Vec3::new(10.2, 0.5, 0.5), 2.0, any, &mut neighbours)
            .unwrap();
        answers.within = neighbours.iter().map(|n| n.key).collect();
        let mut found = Vec::new();
        all.overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 1.0, any, &mut found)
            .unwrap();
        found.sort_unstable();
        answers.sphere = std::mem::take(&mut found);
        all.overlapping(
            &Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap(),
            any,
            &mut found,
        );
        found.sort_unstable();
        answers.overlap = std::mem::take(&mut found);
        enemies
            .nearest(Vec3::new(10.2, 0.5, 0.5), 2, None, any, &mut neighbours)
            .unwrap();
        answers.enemies_near = neighbours.iter().map(|n| n.key).collect();
    }

    let mut app = app();
    app.add_spatial_layer::<Enemy>()
        .init_resource::<Answers>()
        .add_systems(PostUpdate, ask.after(SpatialIndexSystems::Sync));
    let mut all = bevy_rtree::oracle::BruteForce::default();
    let mut enemies = bevy_rtree::oracle::BruteForce::default();
    for i in 0..40 {
        let b = unit_at(i as f32 * 1.25);
        let mut entity = app.world_mut().spawn(b);
        if i % 3 == 0 {
            entity.insert(Enemy);
        }
        let e = entity.id();
        all.insert(e, b.0);
        if i % 3 == 0 {
            enemies.insert(e, b.0);
        }
    }
    app.update();
    let answers = app.world().resource::<Answers>();
    let origin = Vec3::new(-5.0, 0.5, 0.5);
    let ray = Ray::new(origin, Vec3::X, 100.0).unwrap();
    assert_eq!(answers.first, all.ray_first(&ray).unwrap().map(|h| h.key));
    let p = Vec3::new(10.2, 0.5, 0.5);
    let keys =
        |v: Vec<bevy_rtree::Neighbor<Entity>>| v.into_iter().map(|n| n.key).collect::<Vec<_>>();
    assert_eq!(answers.nearest, keys(all.nearest(p, 3, None).unwrap()));
    assert_eq!(answers.within, keys(all.within_radius(p, 2.0).unwrap()));
    assert_eq!(
        answers.enemies_near,
        keys(enemies.nearest(p, 2, None).unwrap())
    );
    assert_eq!(
        answers.sphere,
        all.overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 1.0)
            .unwrap()
    );
    let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
    assert_eq!(answers.overlap, all.overlapping(&query));
    assert_eq!(answers.nearest.len(), 3);
    assert!(!answers.within.is_empty() && !answers.sphere.is_empty());
}

/// Every query of `SpatialQuery` with a filter answers as the oracle does
/// with the filtered-out entities left out: the first allowed hit, the k
/// nearest allowed entities, and so on; and a line of sight from inside
/// the asking entity's own box finds the target, not itself.
#[test]
fn filtered_queries_answer_as_if_the_excluded_entities_were_not_there() {
    #[derive(Resource, Default)]
    struct Asked {
        filter: SpatialQueryFilter,
        first: Option<Entity>,
        all: Vec<Entity>,
        any: bool,
        nearest: Vec<Entity>,
        within: Vec<Entity>,
        sphere: Vec<Entity>,
        overlap: Vec<Entity>,
    }

    fn ask(mut spatial: SpatialQuery, mut asked: ResMut<Asked>) {
        let asked = &mut *asked;
        let filter = &asked.filter;
        let ray = Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::X, 100.0).unwrap();
        asked.first = spatial.cast_ray(&ray, filter).unwrap().map(|h| h.key);
        let mut hits = Vec::new();
        spatial
            .cast_ray_all(&ray, Some(5), filter, &mut hits)
            .unwrap();
        asked.all = hits.iter().map(|h| h.key).collect();
        asked.any = spatial.ray_hits_any(&ray, filter).unwrap();
        let mut near = Vec::new();
        spatial
            .nearest(Vec3::new(10.2, 0.5, 0.5), 4, None, filter, &mut near)
            .unwrap();
        asked.nearest = near.iter().map(|n| n.key).collect();
        spatial
            .within_radius(Vec3::new(10.2, 0.5, 0.5), 3.0, filter, &mut near)
            .unwrap();
        asked.within = near.iter().map(|n| n.key).collect();
        let mut found = Vec::new();
        spatial
            .overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 2.0, filter, &mut found)
            .unwrap();
        found.sort_unstable();
        asked.sphere = std::mem::take(&mut found);
        let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
        spatial.overlapping(&query, filter, &mut found);
        found.sort_unstable();
        asked.overlap = found;
    }

    let mut app = app();
    app.init_resource::<Asked>()
        .add_systems(PostUpdate, ask.after(SpatialIndexSystems::Sync));
    let entities: Vec<Entity> = (0..40)
        .map(|i| app.world_mut().spawn(unit_at(i as f32 * 0.75)).id())
        .collect();
    // The ray starts inside entity 0 (its own box, as a line of sight from
    // an enemy does); exclude it, every third one, and by predicate those
    // from 20 on.
    let shooter = entities[0];
    let excluded: Vec<Entity> = entities.iter().copied().step_by(3).collect();
    let late: Vec<Entity> = entities[20..].to_vec();
    let filter =
        SpatialQueryFilter::excluding(excluded.clone()).with_predicate(move |e| !late.contains(&e));
    app.world_mut().resource_mut::<Asked>().filter = filter.clone();
    app.update();
    let oracle = layer_oracle::<SpatialBounds>(app.world_mut());
    let allowed = |list: Vec<Entity>| -> Vec<Entity> {
        list.into_iter().filter(|e| filter.allows(*e)).collect()
    };
    let ray = Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::X, 100.0).unwrap();
    let hits: Vec<Entity> = allowed(
        oracle
            .ray_hits(&ray)
            .unwrap()
            .iter()
            .map(|h| h.key)
            .collect(),
    );
    let asked = app.world().resource::<Asked>();
    assert_eq!(asked.first, hits.first().copied());
    assert_ne!(
        asked.first,
        Some(shooter),
        "the shooter does not see itself"
    );
    assert_eq!(asked.all, hits[..5.min(hits.len())]);
    assert_eq!(asked.any, !hits.is_empty());
    assert!(!hits.is_empty(), "the ray has allowed hits to find");
    let all = entities.len();
    let near = oracle
        .nearest(Vec3::new(10.2, 0.5, 0.5), all, None)
        .unwrap();
    let near: Vec<Entity> = allowed(near.iter().map(|n| n.key).collect());
    assert_eq!(asked.nearest, near[..4]);
    let within = oracle
        .within_radius(Vec3::new(10.2, 0.5, 0.5), 3.0)
        .unwrap();
    assert_eq!(
        asked.within,
        allowed(within.iter().map(|n| n.key).collect())
    );
    let sphere = oracle
        .overlapping_sphere(Vec3::new(20.0, 0.5, 0.5), 2.0)
        .unwrap();
    assert_eq!(asked.sphere, allowed(sphere));
    let query = Aabb::new(Vec3::new(4.0, 0.0, 0.0), Vec3::new(9.0, 1.0, 1.0)).unwrap();
    assert_eq!(asked.overlap, allowed(oracle.overlapping(&query)));
    assert!(!asked.overlap.is_empty() && asked.overlap.len() < oracle.overlapping(&query).len());
}

/// A caster ignores its own entity by default (its ray starts inside its
/// own box, as a line of sight from an enemy does), hits it when told to,
/// and hits only what its filter allows, in every mode.
#[test]
fn casters_ignore_themselves_and_obey_their_filter() {
    let mut app = app();
    // Five walls 20 m tall along +X; each shooter stands at its own height,
    // in its own unit box, looking down +X.
    let walls: Vec<Entity> = (1..6)
        .map(|i| {
            let x = i as f32 * 3.0;
            let wall = Aabb::new(Vec3::new(x, 0.0, 0.0), Vec3::new(x + 1.0, 20.0, 1.0)).unwrap();
            app.world_mut().spawn(SpatialBounds(wall)).id()
        })
        .collect();
    let mut height = 0.0;
    let mut shooter = |app: &mut App, mode: RayMode, setup: fn(RayCaster) -> RayCaster| {
        let body = Aabb::new(
            Vec3::new(0.0, height, 0.0),
            Vec3::new(1.0, height + 1.0, 1.0),
        )
        .unwrap();
        let ray = Ray::new(Vec3::new(0.5, height + 0.5, 0.5), Vec3::X, 100.0).unwrap();
        height += 1.5;
        app.world_mut()
            .spawn((SpatialBounds(body), setup(RayCaster::new(ray, mode))))
            .id()
    };
    let plain = shooter(&mut app, RayMode::First, |c| c);
    let selfish = shooter(&mut app, RayMode::First, |c| c.hitting_self(true));
    let all = shooter(&mut app, RayMode::All { limit: Some(2) }, |c| c);
    let any = shooter(&mut app, RayMode::Any, |c| c);
    let filtered: Vec<Entity> = [
        RayMode::First,
        RayMode::All { limit: Some(2) },
        RayMode::Any,
    ]
    .into_iter()
    .map(|mode| shooter(&mut app, mode, |c| c))
    .collect();
    let filter = SpatialQueryFilter::excluding([walls[0]]).with_predicate({
        let skip = walls[1];
        move |e| e != skip
    });
    for &e in &filtered {
        app.world_mut().get_mut::<RayCaster>(e).unwrap().filter = filter.clone();
    }
    let blind = shooter(&mut app, RayMode::Any, |c| c);
    // All hits with a limit of none report only whether there was one.
    let counter = shooter(&mut app, RayMode::All { limit: Some(0) }, |c| c);
    let blind_counter = shooter(&mut app, RayMode::All { limit: Some(0) }, |c| c);
    for e in [blind, blind_counter] {
        app.world_mut().get_mut::<RayCaster>(e).unwrap().filter =
            SpatialQueryFilter::excluding(walls.clone());
    }
    app.update();
    let hits = |app: &App, e: Entity| app.world().get::<RayCasterHits>(e).unwrap().clone();
    let keys = |app: &App, e: Entity| -> Vec<Entity> {
        hits(app, e).hits().iter().map(|h| h.key).collect()
    };
    assert_eq!(keys(&app, plain), [walls[0]]);
    assert_eq!(
        hits(&app, selfish).first().map(|h| (h.key, h.t)),
        Some((selfish, 0.0))
    );
    assert_eq!(keys(&app, all), walls[..2]);
    assert!(hits(&app, any).any());
    assert_eq!(keys(&app, filtered[0]), [walls[2]]);
    assert_eq!(keys(&app, filtered[1]), walls[2..4]);
    assert!(hits(&app, filtered[2]).any());
    assert!(!hits(&app, blind).any(), "only walls and itself on its ray");
    assert!(hits(&app, counter).any() && keys(&app, counter).is_empty());
    assert!(!hits(&app, blind_counter).any(), "only walls and itself");
}

/// `SpatialQuery`'s box and sphere overlaps clear their output before they
/// answer (as its other queries do), and a refused query leaves it as it
/// was (the error is found before the output is touched, as everywhere in
/// the crate).
#[test]
fn spatial_query_outputs_hold_this_answer_only() {
    #[derive(Resource, Default)]
    struct Outputs {
        overlap: Vec<Entity>,
        sphere: Vec<Entity>,
        refused_nearest: Vec<usize>,
        refused_sphere: usize,
    }
    let mut app = app();
    for i in 0..5 {
        app.world_mut().spawn(unit_at(2.0 * i as f32));
    }
    app.init_resource::<Outputs>().add_systems(
        PostUpdate,
        (|mut spatial: SpatialQuery, mut outputs: ResMut<Outputs>| {
            let all = SpatialQueryFilter::default();
            let around = Aabb::new(Vec3::splat(-1.0), Vec3::splat(2.5)).unwrap();
            let mut found = vec![Entity::PLACEHOLDER];
            spatial.overlapping(&around, &all, &mut found);
            outputs.overlap = found.clone();
            spatial
                .overlapping_sphere(Vec3::ZERO, 0.5, &all, &mut found)
                .unwrap();
            outputs.sphere = found.clone();
            let refused = spatial.overlapping_sphere(Vec3::ZERO, f32::NAN, &all, &mut found);
            assert!(refused.is_err());
            outputs.refused_sphere = found.len();
            let mut near = Vec::new();
            spatial
                .nearest(Vec3::ZERO, 3, None, &all, &mut near)
                .unwrap();
            outputs.refused_nearest.push(near.len());
            assert!(
                spatial
                    .nearest(Vec3::ZERO, 0, None, &all, &mut near)
                    .is_err()
            );
            outputs.refused_nearest.push(near.len());
        })
        .after(SpatialIndexSystems::Sync),
    );
    app.update();
    let outputs = app.world().resource::<Outputs>();
    assert_eq!(outputs.overlap.len(), 2, "{:?}", outputs.overlap);
    assert!(!outputs.overlap.contains(&Entity::PLACEHOLDER));
    assert_eq!(outputs.sphere.len(), 1);
    assert_eq!(outputs.refused_sphere, 1);
    assert_eq!(outputs.refused_nearest, [3, 3]);
}
