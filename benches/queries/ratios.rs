//! The ratios that decide the targets: bevy_rtree against parry3d in
//! alternating short blocks, warm and with the caches evicted before each
//! call.

use super::peers::{
    Planes, parry_build_and_cross_join, parry_cross_join, parry_first_hit, parry_leaves,
    parry_self_join, parry_visible_into,
};
use super::{Contenders, SELF_JOIN_DISTANCE};
use bevy_rtree::scene::TownScene;
use bevy_rtree::{CullMode, JoinMode, QueryWorkspace, RayMode, RayResults};
use parry3d::partitioning::BvhWorkspace;

/// Where the machine drifts during a run, criterion's medians of two
/// contenders, timed seconds apart, drift with it. For each target, this
/// times bevy_rtree and parry3d in alternating short blocks
/// (`common::paired`) and prints the ratio of neighbouring blocks: its
/// median and its range over the rounds. Written to
/// `target/criterion/queries_paired_ratios.md` as well.
pub(crate) fn paired_ratios(c: &Contenders) {
    const ROUNDS: usize = 41;
    // (query, target if one is set, inputs per iteration, ratio)
    let mut rows: Vec<(&str, Option<f64>, usize, super::common::paired::PairedRatio)> = Vec::new();

    // One iteration runs every input of the group's cycle (the 60 camera
    // yaws, the 4 ray batches), so that both blocks of a round time the same
    // inputs; the table gives the time per view or per batch.
    let views = c.frustums.len();
    let mut ws = QueryWorkspace::default();
    let (mut out, mut list) = (vec![Vec::new()], Vec::new());
    let ratio = super::common::paired::paired_ratio(
        ROUNDS,
        3,
        || {
            let mut visible = 0;
            for frustum in &c.frustums {
                out[0].clear();
                let mode = CullMode::Conservative;
                let frustum = std::slice::from_ref(frustum);
                c.bevy.tree.visible_into(frustum, mode, &mut ws, &mut out);
                visible += out[0].len();
            }
            visible
        },
        || {
            let mut visible = 0;
            for frustum in &c.frustums {
                list.clear();
                parry_visible_into(&c.parry.bvh, &Planes::new(frustum), &mut list);
                visible += list.len();
            }
            visible
        },
    );
    rows.push(("frustum cull", Some(0.25), views, ratio));

    for (name, target, batches) in [
        ("1,000 incoherent rays", 0.40, &c.incoherent),
        ("1,000 coherent rays, standard eye", 1.0 / 3.0, &c.coherent),
        (
            "1,000 coherent rays, clear eye",
            1.0 / 3.0,
            &c.coherent_clear_eye,
        ),
    ] {
        let mut ws = QueryWorkspace::default();
        let (mut out, mut hits) = (RayResults::default(), Vec::new());
        let ratio = super::common::paired::paired_ratio(
            ROUNDS,
            3,
            || {
                let mut answered = 0;
                for rays in batches {
                    c.bevy
                        .tree
                        .cast_rays(rays, RayMode::First, &mut ws, &mut out);
                    answered += out.len();
                }
                answered
            },
            || {
                for rays in batches {
                    hits.clear();
                    let first_hits = rays
                        .iter()
                        .map(|ray| parry_first_hit(&c.parry.bvh, &c.boxes, ray));
                    hits.extend(first_hits);
                }
                hits.len()
            },
        );
        rows.push((name, Some(target), batches.len(), ratio));
    }

    let d = TownScene::JOIN_DISTANCE;
    let enemy_leaves = parry_leaves(&c.boxes, TownScene::ENEMIES);
    let barrel_leaves = parry_leaves(&c.boxes, TownScene::BARRELS);
    let (mut ws, mut out, mut peer_out) = (QueryWorkspace::default(), Vec::new(), Vec::new());
    let our_cross_join = |ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>| {
        out.clear();
        let (enemies, barrels) = (&c.bevy_enemies.tree, &c.bevy_barrels.tree);
        let result = enemies.cross_join_into(barrels, d, JoinMode::Euclidean, ws, out);
        result.expect("valid distance");
        out.len()
    };
    let ratio = super::common::paired::paired_ratio(
        ROUNDS,
        4,
        || our_cross_join(&mut ws, &mut out),
        || {
            peer_out.clear();
            let (enemies, barrels) = (&enemy_leaves, &barrel_leaves);
            parry_build_and_cross_join(enemies, barrels, &c.boxes, d, &mut peer_out);
            peer_out.len()
        },
    );
    rows.push((
        "cross join (parry3d builds its trees)",
        Some(0.125),
        1,
        ratio,
    ));
    // The same join against parry3d's trees kept from frame to frame, as
    // ours are: no target is set against it, and it is the fairer figure.
    let ratio = super::common::paired::paired_ratio(
        ROUNDS,
        4,
        || our_cross_join(&mut ws, &mut out),
        || {
            peer_out.clear();
            let (enemies, barrels) = (&c.parry_enemies.bvh, &c.parry_barrels.bvh);
            parry_cross_join(enemies, barrels, &c.boxes, d, &mut peer_out);
            peer_out.len()
        },
    );
    rows.push(("cross join (parry3d's trees kept)", None, 1, ratio));

    let d = SELF_JOIN_DISTANCE;
    let (mut ws, mut peer_ws) = (QueryWorkspace::default(), BvhWorkspace::default());
    let ratio = super::common::paired::paired_ratio(
        ROUNDS,
        3,
        || {
            out.clear();
            let result = c
                .bevy
                .tree
                .self_join_into(d, JoinMode::Euclidean, &mut ws, &mut out);
            result.expect("valid distance");
            out.len()
        },
        || {
            peer_out.clear();
            parry_self_join(&c.parry.bvh, &mut peer_ws, d, &mut peer_out);
            peer_out.len()
        },
    );
    rows.push(("self join", Some(0.40), 1, ratio));

    let mut table = format!(
        "bevy_rtree time ÷ parry3d time, alternating blocks, {ROUNDS} rounds\n\n\
         | query | bevy_rtree (µs) | parry3d (µs) | ratio, median | ratio, range | target |\n\
         |---|---:|---:|---:|---:|---:|\n"
    );
    for (name, target, inputs, r) in &rows {
        let per_input = |us: f64| us / *inputs as f64;
        let target = match target {
            Some(target) => format!("≤ {target:.3}"),
            None => "none".to_string(),
        };
        table += &format!(
            "| {name} | {:.1} | {:.1} | {:.3} | {:.3}–{:.3} | {target} |\n",
            per_input(r.a_us),
            per_input(r.b_us),
            r.median,
            r.low,
            r.high
        );
    }
    eprintln!("\n{table}");
    let path = std::path::Path::new("target/criterion/queries_paired_ratios.md");
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}
/// The paired ratios again with cold caches, as a game frame meets the
/// tree: before each timed call (one view, one batch of rays, one join) a
/// buffer several times the last-level cache is streamed through
/// (`super::common::paired::paired_ratio_cold`). Printed and written to
/// `target/criterion/queries_cold_ratios.md`; the warm ratios of the same
/// queries are the paired table's.
pub(crate) fn cold_ratios(c: &Contenders) {
    use super::common::paired::paired_ratio_cold;
    const ROUNDS: usize = 31;
    let mut rows: Vec<(&str, super::common::paired::PairedRatio)> = Vec::new();
    let mut ws = QueryWorkspace::default();
    let (mut out, mut list) = (vec![Vec::new()], Vec::new());
    let views = &c.frustums;
    let ratio = paired_ratio_cold(
        ROUNDS,
        |i| {
            out[0].clear();
            let frustum = std::slice::from_ref(&views[i % views.len()]);
            c.bevy
                .tree
                .visible_into(frustum, CullMode::Conservative, &mut ws, &mut out);
            out[0].len()
        },
        |i| {
            list.clear();
            let planes = Planes::new(&views[i % views.len()]);
            parry_visible_into(&c.parry.bvh, &planes, &mut list);
            list.len()
        },
    );
    rows.push(("frustum cull", ratio));
    for (name, batches) in [
        ("1,000 incoherent rays", &c.incoherent),
        ("1,000 coherent rays, clear eye", &c.coherent_clear_eye),
    ] {
        let (mut out, mut hits) = (RayResults::default(), Vec::new());
        let ratio = paired_ratio_cold(
            ROUNDS,
            |i| {
                let rays = &batches[i % batches.len()];
                c.bevy
                    .tree
                    .cast_rays(rays, RayMode::First, &mut ws, &mut out);
                out.len()
            },
            |i| {
                hits.clear();
                let rays = &batches[i % batches.len()];
                let first = rays
                    .iter()
                    .map(|ray| parry_first_hit(&c.parry.bvh, &c.boxes, ray));
                hits.extend(first);
                hits.len()
            },
        );
        rows.push((name, ratio));
    }
    let d = SELF_JOIN_DISTANCE;
    let (mut pairs, mut peer_pairs) = (Vec::new(), Vec::new());
    let mut peer_ws = BvhWorkspace::default();
    let ratio = paired_ratio_cold(
        ROUNDS,
        |_| {
            pairs.clear();
            let tree = &c.bevy.tree;
            let result = tree.self_join_into(d, JoinMode::Euclidean, &mut ws, &mut pairs);
            result.expect("valid distance");
            pairs.len()
        },
        |_| {
            peer_pairs.clear();
            parry_self_join(&c.parry.bvh, &mut peer_ws, d, &mut peer_pairs);
            peer_pairs.len()
        },
    );
    rows.push(("self join", ratio));

    let mut table = format!(
        "cold caches (a 128 MB buffer streamed through before each call): bevy_rtree time \
         ÷ parry3d time, {ROUNDS} alternating rounds of one call each\n\n\
         | query | bevy_rtree cold (µs) | parry3d cold (µs) | ratio, median | ratio, range |\n\
         |---|---:|---:|---:|---:|\n"
    );
    for (name, r) in &rows {
        table += &format!(
            "| {name} | {:.1} | {:.1} | {:.3} | {:.3}–{:.3} |\n",
            r.a_us, r.b_us, r.median, r.low, r.high
        );
    }
    let n = c.bevy.tree.len().max(1);
    let ours = c.bevy.tree.memory();
    table += &format!(
        "\nmemory per entry: bevy_rtree {} B (nodes {}, entry records {}, keys {}, handles {}); \
         parry3d {} B (`Bvh::total_memory_size`); rstar not reported\n",
        ours.total() / n,
        ours.nodes / n,
        ours.entries / n,
        ours.keys / n,
        ours.handles / n,
        c.parry.bvh.total_memory_size() / n,
    );
    eprintln!("\n{table}");
    let path = std::path::Path::new("target/criterion/queries_cold_ratios.md");
    if let Err(e) = std::fs::write(path, &table) {
        eprintln!("could not write {}: {e}", path.display());
    }
}
