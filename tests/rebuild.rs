//! A rebuild spread over frames (`start_rebuild` / `step_rebuild`):
//! answers equal to the oracle before, during and after every swap, with
//! `validate()` after every frame; handles valid across swaps; and the
//! swapped tree as good as a fresh bulk load.

use std::collections::BTreeMap;
use std::time::Duration;

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_rtree::{Aabb, CullMode, ProxyId, QueryWorkspace, RTree, Ray, RebuildWork, SpatialError};
use glam::Vec3;

fn cube(centre: Vec3, half: f32) -> Aabb {
    Aabb::new(centre - half, centre + half).unwrap()
}

/// Frames of steps, teleports, removals and inserts over a town of 20,000
/// boxes while rebuilds run a few units a frame: every frame the tree is
/// valid and answers as the oracle does, and every live handle names its
/// entry; several rebuilds are swapped in.
#[test]
fn answers_and_handles_hold_before_during_and_after_swaps() {
    churn_through_rebuilds(false, 150);
}

/// The same frames with each rebuild's work run on another thread, given
/// back two frames later: the tree changes meanwhile as it would anyway.
#[test]
fn answers_and_handles_hold_while_the_work_runs_on_another_thread() {
    churn_through_rebuilds(true, 150);
}

/// The work away again, and one unit a frame after it: the changes made
/// while it ran (two frames) are applied within two steps after it is
/// back, however few units each step is given, while entries already
/// written into the new structure move again.
#[test]
fn answers_and_handles_hold_with_one_unit_a_frame_after_the_work() {
    churn_through_rebuilds(true, 1);
}

fn churn_through_rebuilds(work_away: bool, units_per_frame: usize) {
    let scene = TownScene::new(20_000, 3);
    let mut tree = RTree::new();
    // Each live entry's handle and box; the oracle is built from the boxes
    // once a frame (its updates search every entry, and 440 a frame of them
    // over 20,000 entries were most of this test's time).
    let mut live: BTreeMap<u32, (ProxyId, Aabb)> = BTreeMap::new();
    let mut retired: Vec<ProxyId> = Vec::new();
    for (key, aabb) in scene.boxes().iter().enumerate() {
        live.insert(key as u32, (tree.insert(key as u32, *aabb).unwrap(), *aabb));
    }
    let mut rng = SceneRng::new(11);
    let mut next_key = scene.len() as u32;
    let mut swaps = 0;
    let mut works_back = 0;
    let mut away: Option<(usize, std::thread::JoinHandle<RebuildWork<u32>>)> = None;
    let mut ws = QueryWorkspace::default();
    for frame in 0..150 {
        let keys: Vec<u32> = live.keys().copied().collect();
        for _ in 0..400 {
            let key = keys[rng.below(keys.len())];
            let Some(&(id, _)) = live.get(&key) else {
                continue;
            };
            let (_, now) = tree.get(id).unwrap();
            let moved = match rng.below(10) {
                // A teleport.
                0 => cube(rng.point_in_world(), rng.range(0.25, 3.0)),
                // A step.
                _ => {
                    let step = Vec3::new(rng.range(-0.3, 0.3), 0.0, rng.range(-0.3, 0.3));
                    Aabb::new(now.min + step, now.max + step).unwrap()
                }
            };
            tree.update(id, moved).unwrap();
            live.insert(key, (id, moved));
        }
        for _ in 0..40 {
            let key = keys[rng.below(keys.len())];
            if let Some((id, _)) = live.remove(&key) {
                assert_eq!(tree.remove(id), Ok(key));
                retired.push(id);
            }
            let aabb = cube(rng.point_in_world(), rng.range(0.25, 3.0));
            live.insert(next_key, (tree.insert(next_key, aabb).unwrap(), aabb));
            next_key += 1;
        }
        if !tree.rebuild_pending() {
            tree.start_rebuild();
            if work_away {
                let mut work = tree.take_rebuild_work().unwrap();
                assert!(!work.is_done());
                let worker = std::thread::spawn(move || {
                    work.run();
                    work
                });
                away = Some((frame, worker));
            }
        }
        if let Some((since, _)) = &away
            && frame >= since + 2
        {
            let (_, worker) = away.take().unwrap();
            let work = worker.join().unwrap();
            assert!(work.is_done());
            assert!(tree.finish_rebuild_work(work));
            works_back += 1;
        }
        let away_now = away.is_some();
        let swapped = tree.step_rebuild_units(units_per_frame);
        assert!(!(away_now && swapped), "no swap while the work is away");
        if swapped {
            swaps += 1;
            // The swapped-in structure, before any repair touches it.
            tree.validate().unwrap();
        }
        tree.optimize(64);

        tree.validate().unwrap();
        let mut oracle = BruteForce::default();
        for (&key, &(_, aabb)) in &live {
            oracle.insert(key, aabb);
        }
        assert_eq!(tree.len(), oracle.len());
        for _ in 0..20 {
            let key = keys[rng.below(keys.len())];
            if let Some(&(id, want)) = live.get(&key) {
                assert_eq!(tree.get(id), Ok((key, want)), "frame {frame}: handle {key}");
            }
        }
        for &id in retired.iter().rev().take(20) {
            assert_eq!(tree.get(id), Err(SpatialError::UnknownProxy));
        }
        let query = cube(rng.point_in_world(), 40.0);
        assert_eq!(tree.overlapping(&query), oracle.overlapping(&query));
        let ray = Ray::new(rng.point_in_world(), rng.direction(), 500.0).unwrap();
        assert_eq!(tree.cast_ray(&ray, &mut ws), oracle.ray_first(&ray));
        let frustum = scene.frustum();
        assert_eq!(
            tree.visible(&frustum, CullMode::Conservative),
            oracle.visible(&frustum, CullMode::Conservative)
        );
    }
    assert!(swaps >= 3, "{swaps} rebuilds swapped in");
    assert!(
        !work_away || works_back >= swaps,
        "{works_back} pieces of work came back"
    );
}

/// Work run on another thread gives the structure `rebuild()` gives.
#[test]
fn work_run_elsewhere_builds_what_rebuild_builds() {
    let scene = TownScene::new(30_000, 6);
    let (mut tree, _) = scene.bulk_loaded_tree();
    let mut at_once = tree.clone();
    at_once.rebuild();
    tree.start_rebuild();
    let mut work = tree.take_rebuild_work().unwrap();
    assert!(
        tree.take_rebuild_work().is_none(),
        "one piece of work per rebuild"
    );
    // While it is away, steps do nothing.
    assert!(!tree.step_rebuild(Duration::from_millis(5)));
    assert!(tree.rebuild_pending());
    std::thread::scope(|s| {
        s.spawn(|| work.run());
    });
    assert!(tree.finish_rebuild_work(work));
    while !tree.step_rebuild(Duration::from_micros(200)) {}
    tree.validate().unwrap();
    for level in 0..tree.height() {
        assert_eq!(tree.nodes_at_level(level), at_once.nodes_at_level(level));
    }
    let query = cube(Vec3::new(1_000.0, 10.0, 1_000.0), 60.0);
    assert!(same_box_query(&tree, &at_once, &query) > 0);
}

/// Asserts that two trees answer a box query alike with the same work;
/// returns how many entries they found.
fn same_box_query(tree: &RTree<u32>, other: &RTree<u32>, query: &Aabb) -> usize {
    let (mut a, mut b) = (QueryWorkspace::default(), QueryWorkspace::default());
    let (mut x, mut y) = (Vec::new(), Vec::new());
    tree.overlapping_into(query, &mut a, &mut x);
    other.overlapping_into(query, &mut b, &mut y);
    x.sort_unstable();
    y.sort_unstable();
    assert_eq!(x, y);
    assert_eq!(a.stats(), b.stats());
    x.len()
}

/// Work that is not the rebuild under way's (cancelled meanwhile, or
/// another tree's) is refused and changes nothing; work given back unrun
/// is finished by the steps.
#[test]
fn work_lands_only_in_its_own_rebuild() {
    let scene = TownScene::new(3_000, 8);
    let (mut tree, _) = scene.bulk_loaded_tree();
    let (mut other, _) = scene.bulk_loaded_tree();
    tree.start_rebuild();
    other.start_rebuild();
    let mine = tree.take_rebuild_work().unwrap();
    let theirs = other.take_rebuild_work().unwrap();
    assert!(!tree.finish_rebuild_work(theirs), "another tree's work");
    tree.cancel_rebuild();
    let before = tree.clone();
    assert!(
        !tree.finish_rebuild_work(mine),
        "a cancelled rebuild's work"
    );
    assert!(!tree.rebuild_pending());
    tree.validate().unwrap();
    assert_eq!(tree.height(), before.height());
    assert_eq!(tree.nodes_at_level(0), before.nodes_at_level(0));
    // Unrun, given back: the steps do it.
    tree.start_rebuild();
    let unrun = tree.take_rebuild_work().unwrap();
    assert!(tree.finish_rebuild_work(unrun));
    while !tree.step_rebuild_units(10) {}
    tree.validate().unwrap();
    assert_eq!(tree.len(), 3_000);
}

/// With nothing changing meanwhile, a rebuild in steps swaps in the same
/// structure `rebuild()` makes at once: the same nodes per level and the
/// same work for every query. (The tree is churned by teleports, after
/// which every enlarged box is fresh, as `rebuild()` makes them.)
#[test]
fn a_rebuild_in_steps_builds_what_rebuild_builds() {
    let scene = TownScene::new(30_000, 5);
    let (mut tree, ids) = scene.bulk_loaded_tree();
    let mut boxes = scene.boxes().to_vec();
    let mut rng = SceneRng::new(4);
    for _ in 0..3_000 {
        let i = rng.below(boxes.len());
        boxes[i] = cube(rng.point_in_world(), rng.range(0.25, 3.0));
        tree.update(ids[i], boxes[i]).unwrap();
    }
    let mut at_once = tree.clone();
    at_once.rebuild();
    tree.start_rebuild();
    let mut steps = 0;
    // A budget no machine meets: each step does its one unit of work.
    while !tree.step_rebuild(Duration::from_nanos(1)) {
        steps += 1;
        assert!(tree.rebuild_pending());
    }
    assert!(steps > 1, "spread over {steps} steps");
    assert!(!tree.rebuild_pending());
    tree.validate().unwrap();
    assert_eq!(tree.height(), at_once.height());
    for level in 0..tree.height() {
        assert_eq!(tree.nodes_at_level(level), at_once.nodes_at_level(level));
    }
    for _ in 0..50 {
        let query = cube(rng.point_in_world(), 25.0);
        same_box_query(&tree, &at_once, &query);
    }
    // Every handle still names its entry.
    for (i, &id) in ids.iter().enumerate() {
        assert_eq!(tree.get(id), Ok((i as u32, boxes[i])));
    }
}

/// A slot freed and reused while the rebuild runs: the old handle is
/// refused after the swap, the new one names the new entry, and an entry
/// removed before its leaf was filled is not brought back.
#[test]
fn slots_reused_during_a_rebuild_keep_their_handles_apart() {
    let mut tree = RTree::new();
    let ids: Vec<ProxyId> = (0..500u32)
        .map(|i| tree.insert(i, cube(Vec3::splat(i as f32), 0.5)).unwrap())
        .collect();
    tree.start_rebuild();
    tree.step_rebuild_units(2);
    tree.remove(ids[10]).unwrap();
    let reused = tree.insert(1_000, cube(Vec3::splat(-50.0), 0.5)).unwrap();
    assert_eq!(reused.index(), ids[10].index(), "the slot is reused");
    tree.remove(ids[20]).unwrap();
    while !tree.step_rebuild_units(5) {}
    tree.validate().unwrap();
    assert_eq!(tree.get(ids[10]), Err(SpatialError::UnknownProxy));
    assert_eq!(tree.get(reused), Ok((1_000, cube(Vec3::splat(-50.0), 0.5))));
    assert_eq!(tree.get(ids[20]), Err(SpatialError::UnknownProxy));
    assert!(tree.containing_point(Vec3::splat(20.0)).is_empty());
    assert_eq!(tree.containing_point(Vec3::splat(-50.0)), vec![1_000]);
    assert_eq!(tree.len(), 499);
}

#[path = "rebuild/catch_up.rs"]
mod catch_up;
