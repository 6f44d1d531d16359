use bevy_rtree::scene::TownScene;
use bevy_rtree::*;
use std::time::Instant;

fn med(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn measure(label: &str, tree: &RTree<u32>, scene: &mut TownScene) {
    let mut ws = QueryWorkspace::default();
    let rays: Vec<Vec<Ray>> = (0..4).map(|_| scene.incoherent_rays(1000)).collect();
    let coh = scene.coherent_rays();
    let fr = scene.frustum();
    let mut out = RayResults::default();
    let mut t = vec![];
    for k in 0..20 {
        let s = Instant::now();
        tree.cast_rays(&rays[k % 4], RayMode::First, &mut ws, &mut out);
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    ws.take_stats();
    tree.cast_rays(&rays[0], RayMode::First, &mut ws, &mut out);
    let rs = ws.take_stats();
    let rt = med(t);
    let mut t = vec![];
    for _ in 0..20 {
        let s = Instant::now();
        tree.cast_rays(&coh, RayMode::First, &mut ws, &mut out);
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    let ct = med(t);
    let mut vis = vec![Vec::new()];
    let mut t = vec![];
    for _ in 0..20 {
        vis[0].clear();
        let s = Instant::now();
        tree.visible_into(
            std::slice::from_ref(&fr),
            CullMode::Conservative,
            &mut ws,
            &mut vis,
        );
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    ws.take_stats();
    vis[0].clear();
    tree.visible_into(
        std::slice::from_ref(&fr),
        CullMode::Conservative,
        &mut ws,
        &mut vis,
    );
    let fs = ws.take_stats();
    let ft = med(t);
    let mut pairs = Vec::new();
    let mut t = vec![];
    for _ in 0..5 {
        pairs.clear();
        let s = Instant::now();
        tree.self_join_into(0.0, JoinMode::Euclidean, &mut ws, &mut pairs)
            .unwrap();
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    ws.take_stats();
    pairs.clear();
    tree.self_join_into(0.0, JoinMode::Euclidean, &mut ws, &mut pairs)
        .unwrap();
    let js = ws.take_stats();
    let jt = med(t);
    println!(
        "{label}: nodes {} height {} | inc {:.3} ms ({:.1} n/ray, {:.1} e/ray) coh {:.3} | frustum {:.3} ms ({} nodes) | self {:.2} ms ({} node pairs, {} tested, {} pairs)",
        tree.node_count(),
        tree.height(),
        rt,
        rs.nodes_visited as f64 / 1000.0,
        rs.entries_tested as f64 / 1000.0,
        ct,
        ft,
        fs.nodes_visited,
        jt,
        js.nodes_visited,
        js.entries_tested,
        pairs.len()
    );
}

fn main() {
    let mut scene = TownScene::new(TownScene::STANDARD_COUNT, 0x5EED_2024);
    let (mut tree, ids) = scene.bulk_loaded_tree();
    let mut s2 = scene.clone();
    measure("fresh", &tree, &mut s2);
    for _ in 0..60 {
        scene.advance_frame();
        let boxes = scene.boxes().to_vec();
        for &i in scene.moved() {
            tree.update(ids[i as usize], boxes[i as usize]).unwrap();
        }
        tree.optimize(usize::MAX);
    }
    let ms = tree.take_maintenance_stats();
    println!("{ms:?}");
    let mut tu = vec![];
    let mut to = vec![];
    for _ in 0..30 {
        scene.advance_frame();
        let boxes = scene.boxes().to_vec();
        let s = Instant::now();
        for &i in scene.moved() {
            tree.update(ids[i as usize], boxes[i as usize]).unwrap();
        }
        tu.push(s.elapsed().as_secs_f64() * 1e3);
        let s = Instant::now();
        tree.optimize(usize::MAX);
        to.push(s.elapsed().as_secs_f64() * 1e3);
    }
    println!(
        "update {:.3} ms optimize {:.3} ms per frame",
        med(tu),
        med(to)
    );
    let ms = tree.take_maintenance_stats();
    println!("{ms:?}");
    let mut s2 = scene.clone();
    measure("churn90", &tree, &mut s2);
    for _ in 0..510 {
        scene.advance_frame();
        let boxes = scene.boxes().to_vec();
        for &i in scene.moved() {
            tree.update(ids[i as usize], boxes[i as usize]).unwrap();
        }
        tree.optimize(usize::MAX);
    }
    let mut s2 = scene.clone();
    measure("churn600", &tree, &mut s2);
    tree.rebuild();
    let mut s2 = scene.clone();
    measure("rebuilt", &tree, &mut s2);
}
