//! Does the tree decay? Eight ways games move things, each for 2,000
//! frames over the standard scene's 100,000 entities, maintained as the
//! plugin maintains its trees (a batch of moves, inserts and removals per
//! frame, then `optimize` with the plugin's default budget of 64). After
//! the last frame, every query family is timed on the maintained tree and
//! on a fresh bulk load of the same entries, alternating, and reported as
//! the ratio maintained ÷ fresh (1.00 = as good as fresh); beside it, the
//! maintenance time per frame (the trees' own work: the motion is worked
//! out before the timer starts; mean over the frames before the last 200),
//! the worst frame's, and the rebuilds swapped in. Every kept frame's
//! answers must equal the fresh load's, and the last frame's the
//! brute-force oracle's.
//!
//! `cargo bench --bench decay` (`-- --frames 500` for a shorter run;
//! `-- --rebuild-us 100` keeps every tree rebuilt when worn
//! (`RTree::rebuild_when_worn`) in slices of 100 µs a frame, and
//! `-- --work-away` with it runs each rebuild's work on another thread
//! as the plugin does on Bevy's async pool (`RTree::take_rebuild_work`);
//! `-- --frame-ms 16.7` gives each frame that length, the rest after the
//! maintenance spent waiting on this thread as a game's other systems
//! would, so that a rebuild on another thread spans as many frames as in a
//! game at that rate instead of the many short frames of a bare loop; `-- --retiled` adds a row for the maintained trees
//! retiled at the end, each entry keeping its enlarged box; words after
//! `--` pick patterns by name). The times and nodes are taken over each of
//! the last 200 frames, each against a fresh load of that frame's entries
//! (a rebuilt tree wears until its next swap, and one look at the end may
//! land anywhere on that saw-tooth): each family's time summed over those
//! frames, maintained ÷ fresh; the nodes all families visited, the same
//! ratio without the timer's noise, summed and in the worst frame.
//! Deterministic from the seed, apart from where the time-budgeted slices
//! end.

#[path = "common/decay_queries.rs"]
mod decay_queries;
#[path = "common/rebuild_thread.rs"]
mod rebuild_thread;

use std::time::Instant;

use bevy_rtree::scene::{SceneRng, TownScene, WORLD_MAX};
use bevy_rtree::{Aabb, ProxyId, QueryWorkspace, RTree, RebuildWork};
use decay_queries::{FAMILIES, Queries, Scratch, nodes_visited};
use glam::Vec3;
use rebuild_thread::keep_fresh_on_a_thread;

const SEED: u64 = 0x5EED_2024;
/// The plugin's default repair budget per layer and frame.
const OPTIMIZE_BUDGET: usize = 64;

/// How the entities move.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pattern {
    /// The standard scene: a fresh random 10 % step 0.1 m each frame.
    Steps,
    /// The steps, and 1 % teleport anywhere in the world each frame.
    Teleports,
    /// 1 % removed and inserted at new places each frame.
    Respawn,
    /// Everyone walks 0.5 m a frame towards one of four points for 300
    /// frames, then away for 300 frames, and again.
    Crowd,
    /// 10 % swing back and forth 4 m along an axis, a period of 60 frames.
    Oscillation,
    /// 5 % drive straight at 0.5 m a frame (30 m/s at 60 Hz), wrapping
    /// around the world.
    Vehicles,
    /// The steps, and 2,000 bullets inserted and 2,000 removed each frame
    /// (each lives 8 frames, moving 1 m a frame).
    Bullets,
    /// The same 10 % move every frame; 90 % never do.
    Asleep,
}

const PATTERNS: [Pattern; 8] = [
    Pattern::Steps,
    Pattern::Teleports,
    Pattern::Respawn,
    Pattern::Crowd,
    Pattern::Oscillation,
    Pattern::Vehicles,
    Pattern::Bullets,
    Pattern::Asleep,
];

/// The scene's entities, their motion and their trees: all of them, and
/// the join's enemies and barrels in trees of their own.
struct World {
    centres: Vec<Vec3>,
    halves: Vec<Vec3>,
    velocity: Vec<Vec3>,
    all: RTree<u32>,
    ids: Vec<ProxyId>,
    enemies: RTree<u32>,
    barrels: RTree<u32>,
    /// Handle in the enemies or barrels tree, for entities in the join.
    join_ids: Vec<Option<ProxyId>>,
    /// Live bullets: their handle, centre and velocity, and the frame they
    /// expire.
    bullets: Vec<(ProxyId, Vec3, Vec3, u32)>,
    rng: SceneRng,
    frame: u32,
    /// With `--rebuild-us N`: each tree rebuilt continuously in slices of
    /// `N` µs a frame.
    rebuild_budget: Option<std::time::Duration>,
    /// With `--work-away`: each rebuild's work runs on another thread
    /// (as the plugin runs it on Bevy's async pool), one slot per tree.
    work_away: bool,
    away: [Option<std::thread::JoinHandle<RebuildWork<u32>>>; 3],
}

impl World {
    fn new(
        scene: &TownScene,
        rebuild_budget: Option<std::time::Duration>,
        work_away: bool,
    ) -> World {
        let boxes = scene.boxes();
        let centres: Vec<Vec3> = boxes.iter().map(|b| (b.min + b.max) * 0.5).collect();
        let halves: Vec<Vec3> = boxes.iter().map(|b| (b.max - b.min) * 0.5).collect();
        let (all, ids) = scene.bulk_loaded_tree();
        // Loaded as the plugin's first sync loads a layer, and as the fresh
        // trees they are measured against are: maintained ÷ fresh is then
        // the wear alone.
        let mut join_ids = vec![None; boxes.len()];
        let mut load = |range: std::ops::Range<usize>| {
            let mut tree = RTree::new();
            let entries = range.clone().map(|i| (i as u32, boxes[i]));
            for (i, id) in range.zip(tree.insert_bulk(entries).unwrap()) {
                join_ids[i] = Some(id);
            }
            tree
        };
        let enemies = load(TownScene::ENEMIES);
        let barrels = load(TownScene::BARRELS);
        let mut rng = SceneRng::new(SEED ^ 0xDECA7);
        let velocity = (0..boxes.len())
            .map(|_| Vec3::new(rng.range(-0.1, 0.1), 0.0, rng.range(-0.1, 0.1)))
            .collect();
        World {
            centres,
            halves,
            velocity,
            all,
            ids,
            enemies,
            barrels,
            join_ids,
            bullets: Vec::new(),
            rng,
            frame: 0,
            rebuild_budget,
            work_away,
            away: [None, None, None],
        }
    }

    fn aabb(&self, i: usize) -> Aabb {
        Aabb {
            min: self.centres[i] - self.halves[i],
            max: self.centres[i] + self.halves[i],
        }
    }

    /// Moves entity `i` to `centre`, to be applied to every tree it is in.
    fn place(&mut self, i: usize, centre: Vec3, changes: &mut Changes) {
        self.centres[i] = clamp_to_world(centre);
        let aabb = self.aabb(i);
        changes.moves.push((self.ids[i], aabb));
        if self.join_ids[i].is_some() {
            changes.join_moves.push((i, aabb));
        }
    }

    /// The tree of the join that entity `i` is in.
    fn join_tree(&mut self, i: usize) -> &mut RTree<u32> {
        if TownScene::ENEMIES.contains(&i) {
            &mut self.enemies
        } else {
            &mut self.barrels
        }
    }

    /// One frame of `pattern`; returns the time the trees' maintenance took
    /// (updates, inserts, removals, repair and rebuild steps), in ms. The
    /// motion itself is worked out first, outside the timer.
    fn advance(&mut self, pattern: Pattern) -> f64 {
        let n = self.centres.len();
        let mut changes = Changes::default();
        match pattern {
            Pattern::Steps | Pattern::Teleports | Pattern::Bullets => {
                for _ in 0..n / 10 {
                    let i = self.rng.below(n);
                    let to = self.centres[i] + self.velocity[i];
                    self.place(i, to, &mut changes);
                }
                if pattern == Pattern::Teleports {
                    for _ in 0..n / 100 {
                        let i = self.rng.below(n);
                        let to = self.rng.point_in_world();
                        self.place(i, to, &mut changes);
                    }
                }
            }
            Pattern::Respawn => {
                for _ in 0..n / 100 {
                    let i = self.rng.below(n);
                    self.centres[i] = self.rng.point_in_world();
                    changes.respawns.push((i, self.aabb(i)));
                }
            }
            Pattern::Crowd => {
                let gathering = (self.frame / 300).is_multiple_of(2);
                let points = [
                    Vec3::new(500.0, 50.0, 500.0),
                    Vec3::new(1500.0, 50.0, 500.0),
                    Vec3::new(500.0, 50.0, 1500.0),
                    Vec3::new(1500.0, 50.0, 1500.0),
                ];
                for i in 0..n {
                    let towards = points[i % 4] - self.centres[i];
                    let dir = towards.normalize_or_zero() * if gathering { 0.5 } else { -0.5 };
                    let step = if towards.length() < 1.0 && gathering {
                        Vec3::ZERO
                    } else {
                        dir
                    };
                    let to = self.centres[i] + step;
                    self.place(i, to, &mut changes);
                }
            }
            Pattern::Oscillation => {
                let phase = (self.frame % 60) as f32 / 60.0 * std::f32::consts::TAU;
                // Velocity of a 4 m swing: d/dt of 2 sin(phase).
                let speed = 2.0 * std::f32::consts::TAU / 60.0 * phase.cos();
                for i in (0..n).step_by(10) {
                    let axis = self.velocity[i].normalize_or_zero();
                    let to = self.centres[i] + axis * speed;
                    self.place(i, to, &mut changes);
                }
            }
            Pattern::Vehicles => {
                for i in (0..n).step_by(20) {
                    let dir = self.velocity[i].normalize_or_zero();
                    let mut to = self.centres[i] + dir * 0.5;
                    // Wrap around instead of piling up at the edge.
                    to.x = to.x.rem_euclid(WORLD_MAX.x);
                    to.z = to.z.rem_euclid(WORLD_MAX.z);
                    self.place(i, to, &mut changes);
                }
            }
            Pattern::Asleep => {
                for i in (0..n).step_by(10) {
                    let to = self.centres[i] + self.velocity[i] * 2.0;
                    self.place(i, to, &mut changes);
                }
            }
        }
        if pattern == Pattern::Bullets {
            self.aim_bullets(&mut changes);
        }
        let start = Instant::now();
        self.apply(changes);
        let trees = [&mut self.all, &mut self.enemies, &mut self.barrels];
        for (tree, away) in trees.into_iter().zip(&mut self.away) {
            tree.optimize(OPTIMIZE_BUDGET);
            match self.rebuild_budget {
                Some(budget) if self.work_away => {
                    keep_fresh_on_a_thread(tree, budget, away);
                }
                Some(budget) => {
                    tree.rebuild_when_worn(budget);
                }
                None => {}
            }
        }
        self.frame += 1;
        start.elapsed().as_secs_f64() * 1e3
    }

    /// A frame's changes, to every tree they concern, as the plugin applies
    /// a frame's: despawned and spawned again, moved (the same entity may
    /// move twice: the later box wins), bullets.
    fn apply(&mut self, changes: Changes) {
        for &(i, aabb) in &changes.respawns {
            self.all.remove(self.ids[i]).unwrap();
            self.ids[i] = self.all.insert(i as u32, aabb).unwrap();
            if let Some(id) = self.join_ids[i] {
                let tree = self.join_tree(i);
                tree.remove(id).unwrap();
                self.join_ids[i] = Some(tree.insert(i as u32, aabb).unwrap());
            }
        }
        self.all.update_batch(&changes.moves).unwrap();
        for &(i, aabb) in &changes.join_moves {
            let id = self.join_ids[i].unwrap();
            self.join_tree(i).update(id, aabb).unwrap();
        }
        for id in changes.expired_bullets {
            self.all.remove(id).unwrap();
        }
        self.all.update_batch(&changes.bullet_moves).unwrap();
        let frame = self.frame;
        for (key, centre, velocity) in changes.new_bullets {
            let id = self.all.insert(key, bullet_box(centre)).unwrap();
            self.bullets.push((id, centre, velocity, frame + 8));
        }
    }

    /// 2,000 new bullets, the expired ones removed, the rest moved on: the
    /// changes to make (the live bullets kept here are those that stay).
    fn aim_bullets(&mut self, changes: &mut Changes) {
        let frame = self.frame;
        let mut kept = Vec::with_capacity(self.bullets.len() + 2_000);
        for (id, centre, velocity, expires) in self.bullets.drain(..) {
            if expires <= frame {
                changes.expired_bullets.push(id);
                continue;
            }
            let to = clamp_to_world(centre + velocity);
            changes.bullet_moves.push((id, bullet_box(to)));
            kept.push((id, to, velocity, expires));
        }
        self.bullets = kept;
        for b in 0..2_000u32 {
            let from = Vec3::new(
                self.rng.range(0.0, WORLD_MAX.x),
                self.rng.range(0.0, 10.0),
                self.rng.range(0.0, WORLD_MAX.z),
            );
            let velocity = self.rng.direction();
            let key = u32::MAX - (frame % 8) * 2_000 - b;
            changes.new_bullets.push((key, from, velocity));
        }
    }
}

/// One frame's changes, worked out before the trees are touched.
#[derive(Default)]
struct Changes {
    /// Entities despawned and spawned again elsewhere, with their new box.
    respawns: Vec<(usize, Aabb)>,
    /// Moves in the tree of all entities.
    moves: Vec<(ProxyId, Aabb)>,
    /// Moves of the join's entities (index, new box), in their own trees.
    join_moves: Vec<(usize, Aabb)>,
    expired_bullets: Vec<ProxyId>,
    bullet_moves: Vec<(ProxyId, Aabb)>,
    /// Key, centre and velocity of each bullet fired.
    new_bullets: Vec<(u32, Vec3, Vec3)>,
}

/// Fresh bulk loads of the entries of `trees`.
fn fresh_loads(trees: &[RTree<u32>; 3]) -> [RTree<u32>; 3] {
    trees.each_ref().map(|tree| {
        let mut fresh = RTree::new();
        fresh
            .insert_bulk(tree.iter().map(|(_, key, aabb)| (key, aabb)))
            .unwrap();
        fresh
    })
}

fn bullet_box(centre: Vec3) -> Aabb {
    Aabb {
        min: centre - Vec3::splat(0.05),
        max: centre + Vec3::splat(0.05),
    }
}

fn clamp_to_world(p: Vec3) -> Vec3 {
    p.clamp(Vec3::ZERO, WORLD_MAX)
}

/// How many of the last frames the nodes are counted over (every one of
/// them).
const SAMPLED_FRAMES: u32 = 200;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run(
    pattern: Pattern,
    frames: u32,
    rebuild_budget: Option<std::time::Duration>,
    work_away: bool,
    retiled: bool,
    frame_length: Option<std::time::Duration>,
) {
    let mut scene = TownScene::new(TownScene::STANDARD_COUNT, SEED);
    let mut world = World::new(&scene, rebuild_budget, work_away);
    let queries = Queries::new(&mut scene, SEED ^ 0xB0C5);
    let mut maintenance = Vec::new();
    let mut kept: Vec<[RTree<u32>; 3]> = Vec::new();
    for frame in 0..frames {
        let start = Instant::now();
        maintenance.push(world.advance(pattern));
        // A rebuilt tree wears until the next swap, so one look at the end
        // lands anywhere on that saw-tooth: the trees of each of the last
        // 200 frames are kept (a copy takes a millisecond or two of the
        // frame's waiting time) and measured after the run against fresh
        // loads of their entries. Measuring within the frame took tens of
        // milliseconds, which stretched the measured frames, gave the
        // rebuild's worker more time in them, and with a look every tenth
        // frame locked onto one phase of the saw-tooth.
        if frames - frame <= SAMPLED_FRAMES {
            kept.push([
                world.all.clone(),
                world.enemies.clone(),
                world.barrels.clone(),
            ]);
        }
        // The rest of a game's frame, on this thread: the rebuild's worker
        // runs meanwhile, as it would beside the game's own systems.
        while frame_length.is_some_and(|length| start.elapsed() < length) {
            std::hint::spin_loop();
        }
    }
    // The maintenance of the frames before the measured ones: copying the
    // trees leaves the next frame's moves colder caches (over the last
    // 200 frames the steps' maintenance read 1.4–1.9 ms instead of
    // 1.2–1.3). Over all of those frames, since a pattern with phases (the
    // crowd gathers for 300 frames, then scatters) costs differently in
    // each.
    let untouched = &maintenance[..maintenance.len().saturating_sub(SAMPLED_FRAMES as usize)];
    let untouched = if untouched.is_empty() {
        &maintenance[..]
    } else {
        untouched
    };
    let per_frame = untouched.iter().sum::<f64>() / untouched.len().max(1) as f64;
    // The first frame after the load is the slowest of all anyway.
    let worst = untouched.iter().skip(1).copied().fold(0.0, f64::max);
    world.all.validate().unwrap();
    // The maintained trees' answers, held to the oracle once; those of
    // every kept frame are held to a fresh load's below.
    queries.check_against_the_oracle([&world.all, &world.enemies, &world.barrels]);
    let rebuilds = world.all.take_maintenance_stats().rebuilds;
    let mut rows = Vec::new();
    if retiled {
        // The same entries retiled in place, each keeping the enlarged box
        // the tree gave it: what a rebuild can restore.
        let again: Vec<[RTree<u32>; 3]> = kept
            .iter()
            .map(|trees| {
                trees.clone().map(|mut tree| {
                    tree.start_rebuild();
                    while !tree.step_rebuild_units(usize::MAX) {}
                    tree
                })
            })
            .collect();
        rows.push(("retiled", compare(pattern, &again, &queries)));
    }
    rows.insert(0, ("maintained", compare(pattern, &kept, &queries)));
    for (label, (times, work, worst_work)) in rows {
        let cells: Vec<String> = times.iter().map(|r| format!("{r:.2}")).collect();
        println!(
            "| {pattern:?}, {label} | {} | {work:.2} | {worst_work:.2} | {per_frame:.3} | {worst:.2} | {rebuilds} |",
            cells.join(" | ")
        );
    }
}

/// Over the trees kept from the last frames, each against a fresh load of
/// its own entries (whose answers must be the same): each family's time
/// summed over the frames (per frame and side the median of three runs) ÷
/// the fresh loads' sum; the nodes all families visited ÷ the fresh loads'
/// nodes, over all the frames and in the worst one.
fn compare(pattern: Pattern, kept: &[[RTree<u32>; 3]], queries: &Queries) -> (Vec<f64>, f64, f64) {
    let mut ws = [QueryWorkspace::default(), QueryWorkspace::default()];
    let mut scratch = Scratch::default();
    let mut sums = vec![[0.0f64; 2]; FAMILIES.len()];
    let mut visited = [0u64; 2];
    let mut worst = 0.0f64;
    for (i, kept) in kept.iter().enumerate() {
        // Both sides freshly allocated, in turn first, so that neither
        // keeps the better place in memory.
        let (trees, fresh) = if i % 2 == 0 {
            let trees = kept.clone();
            (trees, fresh_loads(kept))
        } else {
            let fresh = fresh_loads(kept);
            (kept.clone(), fresh)
        };
        let sets = [trees.each_ref(), fresh.each_ref()];
        for (f, family) in FAMILIES.iter().enumerate() {
            // Each side in a block of its own: one run that warms the
            // caches with that tree (and gives the answer to compare), then
            // three timed runs. Alternated runs of the two trees measured
            // whichever ran first after the other a tenth slower or faster
            // (two bulk loads of the same entries: 1,000 incoherent rays
            // 1.09–1.16 one way round, 0.89–0.93 the other).
            let order = if i % 2 == 0 { [0, 1] } else { [1, 0] };
            let mut answers = [Vec::new(), Vec::new()];
            let mut times = [Vec::new(), Vec::new()];
            for which in order {
                answers[which] = queries.run(f, sets[which], &mut ws[which], &mut scratch).1;
                for _ in 0..3 {
                    times[which].push(queries.run(f, sets[which], &mut ws[which], &mut scratch).0);
                }
            }
            assert!(
                answers[0] == answers[1],
                "{pattern:?}: {family} answers differ"
            );
            for which in 0..2 {
                sums[f][which] += median(&mut times[which]);
            }
        }
        let counts = nodes_visited(queries, sets);
        visited[0] += counts[0];
        visited[1] += counts[1];
        worst = worst.max(counts[0] as f64 / counts[1].max(1) as f64);
    }
    let cells = sums.iter().map(|[m, n]| m / n).collect();
    (cells, visited[0] as f64 / visited[1].max(1) as f64, worst)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let frames = args
        .iter()
        .position(|a| a == "--frames")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(2_000u32);
    let rebuild_budget = args
        .iter()
        .position(|a| a == "--rebuild-us")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .map(std::time::Duration::from_micros);
    let retiled = args.iter().any(|a| a == "--retiled");
    let work_away = args.iter().any(|a| a == "--work-away");
    let frame_length = args
        .iter()
        .position(|a| a == "--frame-ms")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse::<f64>().ok())
        .map(|ms| std::time::Duration::from_secs_f64(ms / 1e3));
    // Pattern names: the words that are neither options nor their values.
    let takes_value =
        |option: &String| ["--frames", "--rebuild-us", "--frame-ms"].contains(&&**option);
    let picked: Vec<&String> = args
        .iter()
        .enumerate()
        .filter(|&(i, a)| !a.starts_with("--") && (i == 0 || !takes_value(&args[i - 1])))
        .map(|(_, a)| a)
        .collect();
    println!(
        "{frames} frames, 100,000 entities; maintained ÷ fresh bulk loads of the same \
         entries, over each of the last {SAMPLED_FRAMES} frames (times: per frame the median of 3 \
         runs in a block of each); maintenance over the frames before those; rebuild in \
         slices: {rebuild_budget:?} per tree and frame{}{}",
        if work_away {
            ", the work on another thread"
        } else {
            ""
        },
        match frame_length {
            Some(length) => format!("; each frame {length:?} long, the rest spent waiting"),
            None => String::new(),
        }
    );
    println!();
    println!(
        "| pattern | {} | nodes visited | nodes, worst frame | maintenance ms/frame | worst frame ms | rebuilds |",
        FAMILIES.join(" | ")
    );
    println!(
        "|---|{}---:|---:|---:|---:|---:|",
        "---:|".repeat(FAMILIES.len())
    );
    for pattern in PATTERNS {
        let name = format!("{pattern:?}").to_lowercase();
        if picked.is_empty() || picked.iter().any(|p| name.contains(&p.to_lowercase())) {
            run(
                pattern,
                frames,
                rebuild_budget,
                work_away,
                retiled,
                frame_length,
            );
        }
    }
}
