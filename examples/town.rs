//! The standard scene "town" on the core tree: 100,000 boxes, 10 % moving
//! every frame, a box query around the camera each frame.
//!
//! Run with `cargo run --release --example town` (`-- --frames N` to change
//! the number of frames, `-- --count N` for a smaller scene).

use std::time::{Duration, Instant};

use bevy_rtree::oracle::BruteForce;
use bevy_rtree::scene::TownScene;
use bevy_rtree::{Aabb, QueryWorkspace};
use glam::Vec3;

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    let frames = arg("--frames", 120);
    let count = arg("--count", TownScene::STANDARD_COUNT);
    let mut scene = TownScene::new(count, 2024);

    let start = Instant::now();
    let (mut tree, ids) = scene.bulk_loaded_tree();
    println!(
        "town: {count} entities bulk-loaded in {:.2} ms (height {}, {} nodes)",
        ms(start.elapsed()),
        tree.height(),
        tree.node_count()
    );

    let mut ws = QueryWorkspace::default();
    let mut found = Vec::new();
    let (mut update_total, mut query_total) = (Duration::ZERO, Duration::ZERO);
    for frame in 1..=frames {
        let moved = scene.advance_frame().to_vec();
        let t = Instant::now();
        for &i in &moved {
            tree.update(ids[i as usize], scene.boxes()[i as usize])
                .expect("scene boxes are valid");
        }
        tree.optimize(usize::MAX);
        let update = t.elapsed();

        // What is within 100 m of the camera, on the ground floor.
        let eye = TownScene::eye();
        let near = Aabb::new(
            eye - Vec3::new(100.0, 50.0, 100.0),
            eye + Vec3::new(100.0, 0.0, 100.0),
        )
        .expect("valid query");
        let t = Instant::now();
        found.clear();
        tree.overlapping_into(&near, &mut ws, &mut found);
        let query = t.elapsed();
        update_total += update;
        query_total += query;

        if frame % 20 == 0 || frame == frames {
            let stats = tree.take_maintenance_stats();
            println!(
                "frame {frame:4}: moved {} (in place {}, in leaf {}, leaf grown {}, reinserted {}, repacked {}) in {:.3} ms; \
                 {} near the camera in {:.3} ms",
                moved.len(),
                stats.moves_in_place,
                stats.moves_in_leaf,
                stats.moves_leaf_grown,
                stats.moves_reinserted,
                stats.repacks,
                ms(update),
                found.len(),
                ms(query)
            );
        }
    }

    // The last frame's answer, checked against brute force.
    let mut oracle = BruteForce::default();
    for (i, b) in scene.boxes().iter().enumerate() {
        oracle.insert(i as u32, *b);
    }
    let eye = TownScene::eye();
    let near = Aabb::new(
        eye - Vec3::new(100.0, 50.0, 100.0),
        eye + Vec3::new(100.0, 0.0, 100.0),
    )
    .expect("valid query");
    let agrees = tree.overlapping(&near) == oracle.overlapping(&near);
    tree.validate().expect("tree invariants hold");
    let stats = ws.take_stats();
    println!(
        "summary: {frames} frames, mean update {:.3} ms, mean query {:.3} ms, \
         {:.0} nodes and {:.0} entries tested per query, oracle agrees: {agrees}",
        ms(update_total) / frames.max(1) as f64,
        ms(query_total) / frames.max(1) as f64,
        stats.nodes_visited as f64 / frames.max(1) as f64,
        stats.entries_tested as f64 / frames.max(1) as f64,
    );
    assert!(agrees, "the tree disagrees with brute force");
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
