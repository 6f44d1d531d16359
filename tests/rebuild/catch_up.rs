//! How a rebuild catches up with the changes made while it was built,
//! what it counts, and what ends it.

use super::*;

/// How a rebuild catches up with the changes made while it was built:
/// `away`, the tiling runs at once as work taken elsewhere, with four
/// frames of changes meanwhile (and a step asked for in each of them if
/// `steps_while_away`); otherwise it is built in slices of four units a
/// frame, with changes every frame. Every frame after, changes
/// again, one step given no time, `validate()` and the oracle's answers;
/// returns the frames from the end of the work (or from the start of the
/// slices) to the swap, and the slices' frames with nothing changing.
fn churn_across_a_rebuild(away: bool, steps_while_away: bool) -> (usize, usize) {
    let scene = TownScene::new(if away { 20_000 } else { 2_000 }, 12);
    let (mut tree, ids) = scene.bulk_loaded_tree();
    let mut oracle = BruteForce::default();
    let mut handles: BTreeMap<u32, ProxyId> = BTreeMap::new();
    for (key, aabb) in scene.boxes().iter().enumerate() {
        handles.insert(key as u32, ids[key]);
        oracle.insert(key as u32, *aabb);
    }
    let mut rng = SceneRng::new(21);
    let mut next_key = scene.len() as u32;
    // A frame's changes: respawns (a removal and an insert elsewhere) and
    // teleports.
    let mut churn = |tree: &mut RTree<u32>, oracle: &mut BruteForce<u32>, count: usize| {
        for _ in 0..count {
            let keys: Vec<u32> = handles.keys().copied().collect();
            let key = keys[rng.below(keys.len())];
            let id = handles.remove(&key).unwrap();
            assert_eq!(tree.remove(id), Ok(key));
            oracle.remove(key);
            let aabb = cube(rng.point_in_world(), rng.range(0.25, 3.0));
            handles.insert(next_key, tree.insert(next_key, aabb).unwrap());
            oracle.insert(next_key, aabb);
            next_key += 1;
            let key = keys[rng.below(keys.len())];
            if let Some(&id) = handles.get(&key) {
                let aabb = cube(rng.point_in_world(), rng.range(0.25, 3.0));
                tree.update(id, aabb).unwrap();
                oracle.update(key, aabb);
            }
        }
    };
    let mut quiet = 0;
    if away {
        tree.start_rebuild();
        let mut work = tree.take_rebuild_work().unwrap();
        for _ in 0..4 {
            churn(&mut tree, &mut oracle, 500);
            if steps_while_away {
                assert!(!tree.step_rebuild(Duration::ZERO));
            }
        }
        work.run();
        assert!(tree.finish_rebuild_work(work));
    } else {
        let mut still = tree.clone();
        still.start_rebuild();
        quiet = 1;
        while !still.step_rebuild_units(4) {
            quiet += 1;
        }
        tree.start_rebuild();
    }
    let mut probe = SceneRng::new(22);
    let mut frames = 0;
    let mut ws = QueryWorkspace::default();
    loop {
        churn(&mut tree, &mut oracle, if away { 100 } else { 10 });
        frames += 1;
        let swapped = if away {
            tree.step_rebuild(Duration::ZERO)
        } else {
            tree.step_rebuild_units(4)
        };
        tree.validate().unwrap();
        assert_eq!(tree.len(), oracle.len());
        let query = cube(probe.point_in_world(), 60.0);
        assert_eq!(tree.overlapping(&query), oracle.overlapping(&query));
        let ray = Ray::new(probe.point_in_world(), probe.direction(), 800.0).unwrap();
        assert_eq!(tree.cast_ray(&ray, &mut ws), oracle.ray_first(&ray));
        if swapped {
            break;
        }
        assert!(frames < quiet + 20, "not swapped in after {frames} frames");
    }
    assert!(!tree.rebuild_pending());
    let frustum = scene.frustum();
    assert_eq!(
        tree.visible(&frustum, CullMode::Conservative),
        oracle.visible(&frustum, CullMode::Conservative)
    );
    for (&key, &id) in &handles {
        let want = oracle.entries().iter().find(|e| e.0 == key).unwrap().1;
        assert_eq!(tree.get(id), Ok((key, want)));
    }
    (frames, quiet)
}

/// After a build in slices, which spans many frames, the changes made
/// meanwhile are applied over several steps, not in one frame: a step
/// given no more units still applies its share, and the swap comes within
/// nine steps of the build's end.
#[test]
fn changes_waiting_after_a_build_in_slices_are_spread_over_steps() {
    let (frames, quiet) = churn_across_a_rebuild(false, false);
    assert!(
        frames > quiet + 2,
        "swapped {frames} frames in, the build alone takes {quiet}"
    );
    assert!(
        frames <= quiet + 9,
        "swapped {frames} frames in, the build alone takes {quiet}"
    );
}

/// After work on another thread that came back before the next step was
/// asked for (a frame, at 60 Hz), the changes made meanwhile are applied
/// at the first step, and the tree swapped in.
#[test]
fn changes_waiting_after_work_away_are_applied_at_the_first_step() {
    let (frames, _) = churn_across_a_rebuild(true, false);
    assert_eq!(frames, 1);
}

/// After work on another thread that spanned four steps, the changes that
/// piled up meanwhile are spread again: over as many steps, about.
#[test]
fn changes_waiting_after_long_work_away_are_spread_over_steps() {
    let (frames, _) = churn_across_a_rebuild(true, true);
    assert!(
        (2..=5).contains(&frames),
        "swapped {frames} frames after the work"
    );
}

/// A move made while the rebuild's work was away reaches the new tiling
/// with the enlarged box the tree gave it then, not one stretched over
/// every frame the work took: a walker three steps on would otherwise get
/// three steps' stretch ahead of it, a box that grows the leaves of a
/// crowd that all walk (the decay bench's crowd).
#[test]
fn moves_made_while_the_work_was_away_keep_the_enlarged_box_they_were_given() {
    let mut tree = RTree::new();
    let mut rng = SceneRng::new(7);
    let mut centres = Vec::new();
    let mut ids = Vec::new();
    for i in 0..3_000u32 {
        let centre = Vec3::new(
            rng.range(0.0, 400.0),
            rng.range(0.0, 10.0),
            rng.range(0.0, 400.0),
        );
        ids.push(tree.insert(i, cube(centre, 0.5)).unwrap());
        centres.push(centre);
    }
    tree.rebuild();
    tree.start_rebuild();
    let mut work = tree.take_rebuild_work().unwrap();
    // Three frames of walking while the work is away: the first step
    // leaves the walker's enlarged box and stretches a new one two metres
    // ahead, which the next two steps stay inside.
    let step = Vec3::new(0.5, 0.0, 0.0);
    for _ in 0..3 {
        for (id, centre) in ids.iter().zip(&mut centres) {
            *centre += step;
            tree.update(*id, cube(*centre, 0.5)).unwrap();
        }
    }
    let given: Vec<Aabb> = ids
        .iter()
        .map(|&id| tree.enlarged_box(id).unwrap())
        .collect();
    work.run();
    assert!(tree.finish_rebuild_work(work));
    while !tree.step_rebuild(Duration::from_secs(1)) {}
    tree.validate().unwrap();
    for (i, &id) in ids.iter().enumerate() {
        assert_eq!(tree.enlarged_box(id).unwrap(), given[i], "entry {i}");
        assert_eq!(tree.get(id).unwrap(), (i as u32, cube(centres[i], 0.5)));
    }
}

/// A teleport wears the tiling as a respawn does (a hole in one place, an
/// entry far away): teleporting a seventh of the entries makes the tree
/// worn (a quarter, counted twice, less the few that land in a leaf
/// already grown to hold them), as removing and inserting them again does,
/// where a seventh of them stepping aside does not.
#[test]
fn a_teleport_wears_the_tiling_as_a_respawn_does() {
    let build = || {
        let mut tree = RTree::new();
        let mut rng = SceneRng::new(11);
        let boxes: Vec<Aabb> = (0..4_000)
            .map(|_| {
                cube(
                    Vec3::new(rng.range(0.0, 1_000.0), 0.0, rng.range(0.0, 1_000.0)),
                    0.5,
                )
            })
            .collect();
        let ids: Vec<ProxyId> = boxes
            .iter()
            .enumerate()
            .map(|(i, b)| tree.insert(i as u32, *b).unwrap())
            .collect();
        tree.rebuild();
        assert!(!tree.is_worn());
        (tree, boxes, ids)
    };
    let far = |b: &Aabb| {
        cube(
            b.min + Vec3::new(0.5, 0.0, 0.5) + Vec3::new(0.0, 0.0, 5_000.0),
            0.5,
        )
    };
    let (mut teleported, boxes, ids) = build();
    for (id, b) in ids.iter().zip(&boxes).step_by(7) {
        teleported.update(*id, far(b)).unwrap();
    }
    teleported.validate().unwrap();
    assert!(teleported.is_worn());

    let (mut respawned, boxes, ids) = build();
    for (i, (id, b)) in ids.iter().zip(&boxes).enumerate().step_by(7) {
        respawned.remove(*id).unwrap();
        respawned.insert(i as u32, far(b)).unwrap();
    }
    assert!(respawned.is_worn());

    let (mut stepped, boxes, ids) = build();
    for (id, b) in ids.iter().zip(&boxes).step_by(7) {
        stepped
            .update(*id, cube(b.min + Vec3::splat(0.5) + Vec3::X * 0.2, 0.5))
            .unwrap();
    }
    assert!(!stepped.is_worn());
}

/// A respawn (a removal and an insert that takes the freed slot, as a
/// frame's despawn and spawn do) wears the tiling twice, whether it is
/// made to the tree or replayed onto a rebuild that was away meanwhile:
/// respawning a seventh of the entries far away makes both worn.
#[test]
fn a_respawn_replayed_by_the_catch_up_wears_the_tiling_twice() {
    let far = |i: usize| cube(Vec3::new(i as f32 * 3.0, 0.0, 9_000.0), 0.5);
    let scene = TownScene::new(4_000, 41);
    let respawn = |tree: &mut RTree<u32>, ids: &[ProxyId]| {
        for (i, &id) in ids.iter().enumerate().step_by(7) {
            tree.remove(id).unwrap();
            let again = tree.insert(i as u32, far(i)).unwrap();
            // The freed slot is taken again, under a new generation.
            assert_eq!(again.index(), id.index());
            assert_ne!(again, id);
        }
    };
    let (mut direct, ids) = scene.bulk_loaded_tree();
    assert!(!direct.is_worn());
    respawn(&mut direct, &ids);
    assert!(direct.is_worn());

    let (mut replayed, ids) = scene.bulk_loaded_tree();
    replayed.start_rebuild();
    let mut work = replayed.take_rebuild_work().unwrap();
    respawn(&mut replayed, &ids);
    work.run();
    assert!(replayed.finish_rebuild_work(work));
    let mut steps = 0;
    while !replayed.step_rebuild_units(200) {
        steps += 1;
        assert!(steps < 20, "not swapped in");
    }
    assert!(!replayed.rebuild_pending());
    replayed.validate().unwrap();
    assert!(replayed.is_worn());
}

/// The maintenance counters count each change the caller made once: the
/// rebuild's catch-up, which applies the changes made while the work was
/// away to the new structure through the same moves, inserts and removals,
/// counts only as the rebuild. The memory it holds meanwhile is counted
/// until the swap.
#[test]
fn a_rebuild_counts_replayed_changes_once_and_its_memory_until_the_swap() {
    let scene = TownScene::new(5_000, 31);
    let (mut tree, ids) = scene.bulk_loaded_tree();
    tree.start_rebuild();
    let mut work = tree.take_rebuild_work().unwrap();
    tree.take_maintenance_stats();
    let mut rng = SceneRng::new(32);
    let (mut moves, mut inserts, mut removals) = (0u64, 0u64, 0u64);
    for (i, &id) in ids.iter().enumerate().take(1_500) {
        match i % 3 {
            0 | 1 => {
                // Steps and jumps: every kind of move.
                let (_, old) = tree.get(id).unwrap();
                let step = if i % 3 == 0 { 0.3 } else { 400.0 };
                let moved = Aabb::new(old.min + Vec3::splat(step), old.max + Vec3::splat(step));
                tree.update(id, moved.unwrap()).unwrap();
                moves += 1;
            }
            _ => {
                tree.remove(id).unwrap();
                removals += 1;
                tree.insert(u32::MAX - i as u32, cube(rng.point_in_world(), 1.0))
                    .unwrap();
                inserts += 1;
            }
        }
    }
    work.run();
    assert!(tree.finish_rebuild_work(work));
    // The new structure, about the size of the tree's own, is held beside
    // it until the swap, and counted.
    let memory = tree.memory();
    assert!(memory.rebuild >= memory.nodes / 2, "{memory:?}");
    let mut steps = 0;
    while !tree.step_rebuild_units(200) {
        steps += 1;
        assert!(steps < 20, "not swapped in");
    }
    tree.validate().unwrap();
    let stats = tree.take_maintenance_stats();
    let counted_moves = stats.moves_in_place
        + stats.moves_in_leaf
        + stats.moves_leaf_grown
        + stats.moves_reinserted;
    assert_eq!(counted_moves, moves, "{stats:?}");
    assert_eq!(stats.inserts, inserts, "{stats:?}");
    assert_eq!(stats.removals, removals, "{stats:?}");
    assert_eq!(stats.rebuilds, 1, "{stats:?}");
    assert_eq!(tree.memory().rebuild, 0);
}

/// `Duration::MAX` reads as "no limit": one call finishes the rebuild and
/// swaps it in, where adding it to the clock overflowed.
#[test]
fn a_budget_without_limit_finishes_the_rebuild() {
    let scene = TownScene::new(3_000, 33);
    let (mut tree, ids) = scene.bulk_loaded_tree();
    for &id in &ids[..1_000] {
        tree.remove(id).unwrap();
    }
    assert!(tree.is_worn());
    tree.start_rebuild();
    assert!(tree.step_rebuild(Duration::MAX), "swapped in at once");
    tree.validate().unwrap();
    assert!(!tree.rebuild_pending());
    assert!(!tree.is_worn());
    // And a tree worn again rebuilds through the frame-by-frame call too.
    for &id in &ids[1_000..2_000] {
        tree.remove(id).unwrap();
    }
    assert!(tree.rebuild_when_worn(Duration::MAX), "swapped in at once");
    tree.validate().unwrap();
    assert_eq!(tree.len(), 1_000);
}

/// A bulk insert into a tree with a rebuild under way retiles every entry
/// itself (an empty one does nothing), so the rebuild is dropped: swapping
/// its older tiling in would insert every new entry into it one by one and
/// leave the tree worn.
#[test]
fn a_bulk_insert_during_a_rebuild_drops_the_rebuild() {
    let scene = TownScene::new(2_000, 34);
    let (mut tree, _) = scene.bulk_loaded_tree();
    tree.start_rebuild();
    tree.step_rebuild_units(3);
    assert!(tree.rebuild_pending());
    // Nothing to insert: nothing retiled, the rebuild goes on.
    assert_eq!(tree.insert_bulk(std::iter::empty()).unwrap(), Vec::new());
    assert!(tree.rebuild_pending());
    // So too in a tree that never held an entry.
    let mut new_tree = RTree::<u32>::new();
    new_tree.start_rebuild();
    assert_eq!(
        new_tree.insert_bulk(std::iter::empty()).unwrap(),
        Vec::new()
    );
    assert!(new_tree.rebuild_pending());
    let mut rng = SceneRng::new(35);
    let added: Vec<(u32, Aabb)> = (0..3_000u32)
        .map(|i| (10_000 + i, cube(rng.point_in_world(), 1.0)))
        .collect();
    let ids = tree.insert_bulk(added.iter().copied()).unwrap();
    tree.validate().unwrap();
    assert!(!tree.rebuild_pending());
    assert!(!tree.is_worn());
    // Nothing is left to swap in, and every new handle names its entry.
    assert!(!tree.step_rebuild_units(1_000));
    for (id, (key, aabb)) in ids.iter().zip(&added) {
        assert_eq!(tree.get(*id).unwrap(), (*key, *aabb));
    }
    assert_eq!(tree.len(), 5_000);
}

/// While the tiling runs elsewhere, the tree counts only what it keeps to
/// note the changes made meanwhile: far less than the structure itself,
/// which the work owns.
#[test]
fn a_rebuild_away_counts_only_its_notes() {
    let scene = TownScene::new(5_000, 36);
    let (mut tree, _) = scene.bulk_loaded_tree();
    tree.start_rebuild();
    let work = tree.take_rebuild_work().unwrap();
    let memory = tree.memory();
    assert!(memory.rebuild > 0, "{memory:?}");
    assert!(memory.rebuild < memory.nodes / 8, "{memory:?}");
    drop(work);
}
