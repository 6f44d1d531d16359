//! Section 7 (feature `bevy_camera`): Bevy's camera visibility from the
//! index, three ways on the same frames of the town as Bevy meshes
//! (100,000 boxes at random yaws, 10 % moving, cameras turning): the
//! tree's world boxes alone (not Bevy's answer: the oriented boxes'
//! corners make it list a little more), Bevy's own tests on every
//! candidate, and the inside proof that skips them (the default). Times
//! of the whole visibility step against Bevy's own system, and the work:
//! candidates, proven, decided by Bevy's tests.

#[path = "../../benches/common/bevy_town.rs"]
mod bevy_town;

use std::fmt::Write as _;

use bevy_app::App;
use bevy_rtree::plugin::{BevyVisibilitySettings, SpatialDiagnostics};
use bevy_town::{Motion, app, block, camera_lists, town, world_boxes_alone};

use crate::{SEED, median};

/// Alternating blocks per App, and frames per block.
const ROUNDS: usize = 7;
const FRAMES: usize = 10;

/// One way of answering, for one camera count.
pub struct VisibilityRow {
    pub cameras: usize,
    pub label: &'static str,
    /// Median of the visibility step's block medians, ms.
    pub ms: f64,
    /// Entity-camera pairs listed.
    pub listed: usize,
    /// The tree's candidates, proven inside, and decided by Bevy's tests
    /// (entity-camera pairs; zero where not applicable).
    pub candidates: u64,
    pub proven: u64,
    pub tested: u64,
}

/// The town with `cameras` cameras in three Apps: Bevy's, ours without and
/// with the proof; the world boxes alone are culled on the proof's tree.
pub fn measure() -> Vec<VisibilityRow> {
    let mut rows = Vec::new();
    for cameras in [1, 4] {
        let mut apps = [app(false, false), app(true, false), app(true, false)];
        apps[1].insert_resource(BevyVisibilitySettings {
            prove_inside: false,
            ..Default::default()
        });
        for app in &mut apps {
            town(app.world_mut(), SEED, cameras);
            app.insert_resource(Motion {
                frame: 0,
                period: 10,
                turn: std::f32::consts::TAU / 60.0,
            });
            for _ in 0..3 {
                app.update();
            }
        }
        let mut times: [Vec<f64>; 3] = Default::default();
        for round in 0..ROUNDS {
            for k in 0..apps.len() {
                let a = (round + k) % apps.len();
                times[a].push(block(&mut apps[a], FRAMES).0 / 1e3);
            }
        }
        let lists = apps.each_mut().map(camera_lists);
        assert!(
            lists[1] == lists[0] && lists[2] == lists[0],
            "the index lists what Bevy lists"
        );
        let listed = lists.map(|lists| lists.iter().map(Vec::len).sum::<usize>());
        let work = |app: &App| app.world().resource::<SpatialDiagnostics>().bevy_visibility;
        let (no_proof, proof) = (work(&apps[1]), work(&apps[2]));
        let (alone_ms, alone_listed) = world_boxes_alone(&mut apps[2]);
        let row = |label, ms, listed, work: Option<bevy_rtree::plugin::BevyVisibilityWork>| {
            let work = work.unwrap_or_default();
            VisibilityRow {
                cameras,
                label,
                ms,
                listed,
                candidates: work.candidates,
                proven: work.proven,
                tested: work.tested,
            }
        };
        rows.push(row(
            "Bevy's `check_visibility_cpu_culling`",
            median(&times[0]),
            listed[0],
            None,
        ));
        rows.push(row(
            "the tree's world boxes alone (cull only, warm, back to back; not Bevy's answer)",
            alone_ms,
            alone_listed,
            None,
        ));
        rows.push(row(
            "index, Bevy's tests on every candidate",
            median(&times[1]),
            listed[1],
            Some(no_proof),
        ));
        rows.push(row(
            "index, inside proof (default)",
            median(&times[2]),
            listed[2],
            Some(proof),
        ));
    }
    rows
}

/// The section's markdown (nothing without rows).
pub fn markdown(rows: &[VisibilityRow], s: &mut String) {
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "\n## 7. Bevy's visibility: world boxes, Bevy's tests, the inside proof (BevyVisibilitySettings)\n\n\
         The town as Bevy meshes (100,000 boxes at random yaws as `Mesh3d` with \
         Bevy's `Aabb`, 10 % moving, the cameras turning), Bevy's system and the \
         index's in separate Apps on the same frames, {ROUNDS} alternating blocks of \
         {FRAMES} frames; times are the whole visibility step (for the index: its sync, \
         repair and culling), medians of the block medians. Work is entity-camera pairs \
         in the last frame: the tree's candidates, those it proved inside every plane \
         Bevy tests (they skip Bevy's sphere and oriented-box tests), and those Bevy's \
         tests decided (the rest of the candidates, and the entities outside the tree). \
         Every way but the world boxes alone lists exactly what Bevy lists.\n"
    );
    let _ = writeln!(
        s,
        "| cameras | answer | ms per frame | pairs listed | candidates | proven | decided by Bevy's tests |"
    );
    let _ = writeln!(s, "|---:|---|---:|---:|---:|---:|---:|");
    for r in rows {
        let work = |v: u64| {
            if r.candidates == 0 {
                String::new()
            } else {
                v.to_string()
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {:.3} | {} | {} | {} | {} |",
            r.cameras,
            r.label,
            r.ms,
            r.listed,
            work(r.candidates),
            work(r.proven),
            work(r.tested)
        );
    }
    let _ = writeln!(
        s,
        "\nThe world boxes alone are the cheapest and list a little more than Bevy \
         (the corners of rotated boxes), which is why the plugin does not answer \
         with them; `SpatialQuery<Renderable>` and `CullingCamera<Renderable>` give \
         them to a game that wants them."
    );
}
