//! Section 6: what keeping the tree fresh costs in a long session. The
//! standard scene's steps plus 1 % of the entities teleporting anywhere
//! each frame (respawns, portals), with the knobs that decide how the tree
//! ages: the jump limit (`TreeSettings::jump_limit`: a teleport gets no
//! stretch) and the rebuild (`RTree::rebuild_when_worn` in slices on the
//! calling thread, or its work on another thread as the plugin runs it on
//! Bevy's task pool). Maintenance time per frame on the calling thread
//! against the work queries then do, counted against a fresh bulk load of
//! the same boxes.

#[path = "../../benches/common/rebuild_thread.rs"]
mod rebuild_thread;

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use bevy_rtree::scene::{SceneRng, TownScene};
use bevy_rtree::{Aabb, JoinMode, ProxyId, QueryWorkspace, RTree, Ray, RayMode, RayResults};
use bevy_rtree::{RebuildWork, TreeSettings};
use rebuild_thread::keep_fresh_on_a_thread;

use crate::{SEED, mean};

/// Frames of the session.
pub const FRAMES: usize = 400;
/// Entities teleported per frame, per thousand.
const TELEPORTS_PER_MILLE: usize = 10;
/// The slice of a rebuild on the calling thread, per frame.
const SLICE: Duration = Duration::from_micros(250);

/// The plugin's repair budget a frame, as a game's session runs it
/// (`SpatialIndexPlugin::optimize_budget`'s default; the plugin's value
/// where the example is built with it).
fn repair_budget() -> usize {
    #[cfg(feature = "plugin")]
    return bevy_rtree::plugin::SpatialIndexPlugin::default().optimize_budget;
    #[cfg(not(feature = "plugin"))]
    64
}

/// How one contender keeps its tree.
#[derive(Clone, Copy)]
enum Upkeep {
    Repair,
    Slices,
    WorkAway,
}

/// One contender's figures after the session.
pub struct SessionRow {
    pub label: String,
    /// Mean maintenance per frame on the calling thread (moves, repair,
    /// the rebuild's slices or its swap), ms.
    pub maintenance_ms: f64,
    /// Nodes visited, maintained ÷ fresh: box queries, incoherent rays,
    /// the self join's node pairs.
    pub boxes: f64,
    pub rays: f64,
    pub join: f64,
    /// Time of the box queries, maintained ÷ fresh.
    pub boxes_time: f64,
    pub rebuilds: u64,
}

struct Kept {
    label: String,
    tree: RTree<u32>,
    ids: Vec<ProxyId>,
    upkeep: Upkeep,
    away: Option<std::thread::JoinHandle<RebuildWork<u32>>>,
    maintenance_ms: Vec<f64>,
    rebuilds: u64,
}

impl Kept {
    fn new(label: String, scene: &TownScene, settings: TreeSettings, upkeep: Upkeep) -> Kept {
        let mut tree = RTree::with_settings(settings).expect("settings in range");
        let ids = tree
            .insert_bulk(
                scene
                    .boxes()
                    .iter()
                    .enumerate()
                    .map(|(i, b)| (i as u32, *b)),
            )
            .expect("scene boxes are valid");
        Kept {
            label,
            tree,
            ids,
            upkeep,
            away: None,
            maintenance_ms: Vec::new(),
            rebuilds: 0,
        }
    }

    fn frame(&mut self, moves: &[(u32, Aabb)]) {
        let start = Instant::now();
        let batch: Vec<(ProxyId, Aabb)> = moves
            .iter()
            .map(|&(i, b)| (self.ids[i as usize], b))
            .collect();
        self.tree.update_batch(&batch).expect("valid moves");
        // The plugin's repair budget (`SpatialIndexPlugin::optimize_budget`),
        // as a game's session runs it; section 1 repairs everything.
        self.tree.optimize(repair_budget());
        let tree = &mut self.tree;
        let swapped = match self.upkeep {
            Upkeep::Repair => false,
            Upkeep::Slices => tree.rebuild_when_worn(SLICE),
            Upkeep::WorkAway => keep_fresh_on_a_thread(tree, Duration::ZERO, &mut self.away),
        };
        self.rebuilds += u64::from(swapped);
        self.maintenance_ms
            .push(start.elapsed().as_secs_f64() * 1e3);
    }
}

/// Runs the session for every contender and measures them against a
/// fresh bulk load of the final boxes.
pub fn measure(count: usize) -> Vec<SessionRow> {
    let mut scene = TownScene::new(count, SEED);
    let limit = TreeSettings::default().jump_limit;
    let loose = TreeSettings {
        jump_limit: 1e4,
        ..TreeSettings::default()
    };
    let mut kept = [
        Kept::new(
            "no jump limit (every jump stretches), repair only".into(),
            &scene,
            loose,
            Upkeep::Repair,
        ),
        Kept::new(
            format!("jump limit {limit} (default), repair only"),
            &scene,
            TreeSettings::default(),
            Upkeep::Repair,
        ),
        Kept::new(
            format!("jump limit {limit}, rebuild in 0.25 ms slices"),
            &scene,
            TreeSettings::default(),
            Upkeep::Slices,
        ),
        Kept::new(
            format!("jump limit {limit}, rebuild on another thread (RebuildMode::OnTaskPool)"),
            &scene,
            TreeSettings::default(),
            Upkeep::WorkAway,
        ),
    ];
    let mut rng = SceneRng::new(SEED ^ 0x7E1E);
    // Where each entity is: the scene's steps, applied from where a
    // teleport left it (the scene itself never learns of the teleports,
    // and its box would take the entity back: a second jump).
    let mut boxes = scene.boxes().to_vec();
    let mut scene_before = scene.boxes().to_vec();
    for frame in 0..FRAMES {
        let stepped: Vec<u32> = scene.advance_frame().to_vec();
        let mut moves: Vec<(u32, Aabb)> = stepped
            .iter()
            .map(|&i| {
                let i = i as usize;
                let step = scene.boxes()[i].min - scene_before[i].min;
                scene_before[i] = scene.boxes()[i];
                let at = boxes[i];
                let aabb = Aabb {
                    min: at.min + step,
                    max: at.max + step,
                };
                (i as u32, aabb)
            })
            .collect();
        for _ in 0..count * TELEPORTS_PER_MILLE / 1_000 {
            let i = rng.below(count);
            let half = (boxes[i].max - boxes[i].min) * 0.5;
            let to = rng.point_in_world();
            moves.push((
                i as u32,
                Aabb {
                    min: to - half,
                    max: to + half,
                },
            ));
        }
        for &(i, b) in &moves {
            boxes[i as usize] = b;
        }
        // The contenders take turns at going first, so that none always
        // meets the caches another left.
        let n = kept.len();
        for k in 0..n {
            kept[(frame + k) % n].frame(&moves);
        }
    }
    // Any work still away is waited for, so every tree ends valid.
    for k in &mut kept {
        if let Some(worker) = k.away.take() {
            k.tree
                .finish_rebuild_work(worker.join().expect("the work ran"));
            k.tree.cancel_rebuild();
        }
        k.tree.validate().expect("a valid tree after the session");
    }
    let mut fresh = RTree::new();
    fresh
        .insert_bulk(boxes.iter().enumerate().map(|(i, b)| (i as u32, *b)))
        .expect("valid boxes");
    let queries: Vec<Aabb> = (0..1_000)
        .map(|_| {
            let c = rng.point_in_world();
            Aabb {
                min: c - 5.0,
                max: c + 5.0,
            }
        })
        .collect();
    let rays = scene.incoherent_rays(1_000);
    let base = work(&fresh, &queries, &rays);
    let truth = oracle_answers(&boxes, &queries, &rays);
    assert!(
        base.answers == truth,
        "the fresh tree's answers differ from the oracle's"
    );
    kept.iter()
        .map(|k| {
            let w = work(&k.tree, &queries, &rays);
            assert!(
                w.answers == truth,
                "{}: answers differ from the oracle's",
                k.label
            );
            SessionRow {
                label: k.label.clone(),
                maintenance_ms: mean(&k.maintenance_ms),
                boxes: w.box_nodes as f64 / base.box_nodes as f64,
                rays: w.ray_nodes as f64 / base.ray_nodes as f64,
                join: w.join_nodes as f64 / base.join_nodes as f64,
                boxes_time: w.box_ms / base.box_ms,
                rebuilds: k.rebuilds,
            }
        })
        .collect()
}

/// The work of the query families on one tree, and their answers.
struct Work {
    box_nodes: u64,
    ray_nodes: u64,
    join_nodes: u64,
    box_ms: f64,
    answers: Answers,
}

/// Each box query's keys (sorted), each ray's first hit, the self join's
/// pairs (sorted).
#[derive(PartialEq)]
struct Answers {
    boxes: Vec<Vec<u32>>,
    first_hits: Vec<Option<(u32, u32)>>,
    pairs: Vec<(u32, u32)>,
}

/// The brute-force oracle's answers over `boxes` (entry `i` has key `i`).
fn oracle_answers(boxes: &[Aabb], queries: &[Aabb], rays: &[Ray]) -> Answers {
    let mut oracle = bevy_rtree::oracle::BruteForce::default();
    for (i, b) in boxes.iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    Answers {
        boxes: queries.iter().map(|q| oracle.overlapping(q)).collect(),
        first_hits: rays
            .iter()
            .map(|r| {
                let hit = oracle.ray_first(r).expect("a valid ray");
                hit.map(|h| (h.key, h.t.to_bits()))
            })
            .collect(),
        pairs: oracle
            .self_join(0.0, JoinMode::Euclidean)
            .expect("a valid distance"),
    }
}

fn work(tree: &RTree<u32>, queries: &[Aabb], rays: &[Ray]) -> Work {
    let mut ws = QueryWorkspace::default();
    let mut out = Vec::new();
    let mut times = Vec::new();
    let mut box_nodes = 0;
    for rep in 0..7 {
        let start = Instant::now();
        for q in queries {
            out.clear();
            tree.overlapping_into(q, &mut ws, &mut out);
        }
        times.push(start.elapsed().as_secs_f64() * 1e3);
        if rep == 0 {
            box_nodes = ws.take_stats().nodes_visited;
        }
    }
    let boxes = queries
        .iter()
        .map(|q| {
            let mut keys = tree.overlapping(q);
            keys.sort_unstable();
            keys
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let _ = ws.take_stats();
    let mut hits = RayResults::default();
    tree.cast_rays(rays, RayMode::First, &mut ws, &mut hits);
    let ray_nodes = ws.take_stats().nodes_visited;
    let first_hits = (0..hits.len())
        .map(|i| {
            let hit = hits.first(i).expect("a valid ray");
            hit.map(|h| (h.key, h.t.to_bits()))
        })
        .collect();
    let mut pairs = Vec::new();
    tree.self_join_into(0.0, JoinMode::Euclidean, &mut ws, &mut pairs)
        .expect("a valid distance");
    let join_nodes = ws.take_stats().nodes_visited;
    pairs.sort_unstable();
    Work {
        box_nodes,
        ray_nodes,
        join_nodes,
        box_ms: times[times.len() / 2],
        answers: Answers {
            boxes,
            first_hits,
            pairs,
        },
    }
}

/// The section's markdown.
pub fn markdown(rows: &[SessionRow], count: usize, s: &mut String) {
    let _ = writeln!(
        s,
        "\n## 6. Long sessions: the jump limit and the rebuild (TreeSettings, RebuildMode)\n\n\
         {} entities, {FRAMES} frames: each frame the standard 10 % step and {} % \
         teleport anywhere in the world. Maintenance is the calling thread's time per \
         frame (moves, repair with the plugin's budget of {} repacks, and the \
         rebuild's slices or its swap), mean over the \
         session; the work is counted after the last frame, maintained ÷ a fresh bulk \
         load of the same boxes (1.00 = as good as fresh): nodes visited by 1,000 box \
         queries, by 1,000 incoherent rays, node pairs of the self join (d = 0), and the \
         box queries' time (median of 7). Every tree's answers equal the brute-force \
         oracle's.\n",
        crate::report::thousands(count),
        TELEPORTS_PER_MILLE as f64 / 10.0,
        repair_budget(),
    );
    let _ = writeln!(
        s,
        "| upkeep | maintenance ms/frame | box query nodes | ray nodes | self join node pairs | box query time | rebuilds |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.2} | {:.2} | {:.2} | {:.2} | {} |",
            r.label, r.maintenance_ms, r.boxes, r.rays, r.join, r.boxes_time, r.rebuilds
        );
    }
    let _ = writeln!(
        s,
        "\nWithout the jump limit every teleport stretches its entry's enlarged box \
         ahead of it by the displacement factor times the jump, and the stretch stays: \
         the queries' work grows frame after frame. The rebuild's slices run on the \
         calling thread while a rebuild runs (each ends after the unit of work under \
         way when its budget is spent, and the swap's catch-up comes on top): the \
         rows' maintenance with and without a rebuild shows what they cost here. On \
         another thread the calling thread pays the snapshot at the start and, once \
         the work is back, the changes made while it ran, applied to the new structure \
         before the swap over about as many steps as frames the work took (here a \
         few: frames follow each other at once; at 60 Hz one); on a machine of two \
         cores the worker also takes time from the calling thread. A rebuilt tree \
         leaves room in its leaves, so that the teleports after it land in the room \
         instead of splitting leaves (docs/performance.md, \"Room in the leaves of a \
         rebuilt tree\", measures what the room costs the queries)."
    );
}
