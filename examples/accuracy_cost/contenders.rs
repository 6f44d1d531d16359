//! The trees the report compares: one per bounds policy and node width,
//! each kept through the same frames behind one trait so that the frame
//! loop treats every contender alike.

use std::ops::Range;
use std::time::Instant;

use bevy_rtree::scene::TownScene;
use bevy_rtree::{
    Aabb, CullMode, Frustum, JoinMode, MaintenanceStats, ProxyId, QueryWorkspace, RTree, Ray,
    RayHit, RayMode, RayResults, TreeSettings,
};

use crate::measure::{ms_between, ms_since};
use crate::{DEFAULT_WIDTH, OPTIMIZE_BUDGET, WIDTHS};

/// One kept tree of any node width, so the frame loop can treat every
/// contender alike.
pub(crate) trait Kept {
    /// Moves the scene's moved entities, then repairs churn; returns the
    /// milliseconds of each half.
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) -> (f64, f64);
    fn take_maintenance(&mut self) -> MaintenanceStats;
    fn overlapping_into(&self, query: &Aabb, ws: &mut QueryWorkspace, out: &mut Vec<u32>);
    fn cull_into(
        &self,
        frustum: &Frustum,
        mode: CullMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<u32>,
    );
    fn cast_rays_first(&self, rays: &[Ray], ws: &mut QueryWorkspace, out: &mut RayResults<u32>);
    fn cast_ray_first(&self, ray: &Ray, ws: &mut QueryWorkspace) -> Option<RayHit<u32>>;
    /// All touching or overlapping pairs (d = 0), unsorted.
    fn self_join_into(&self, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>);
    /// Height and node count.
    fn shape(&self) -> (usize, usize);
    fn validate(&self) -> Result<(), String>;
}

/// A tree keyed by entity index, and the handle of each of its entities.
pub(crate) struct Index<const W: usize> {
    pub(crate) tree: RTree<u32, W>,
    pub(crate) ids: Vec<ProxyId>,
    /// The first entity of the range the tree holds.
    pub(crate) start: usize,
    /// A frame's moves, kept to avoid reallocating.
    pub(crate) moves: Vec<(ProxyId, Aabb)>,
}

impl<const W: usize> Index<W> {
    pub(crate) fn load(boxes: &[Aabb], range: Range<usize>, settings: TreeSettings) -> Self {
        let mut tree = RTree::<u32, W>::with_settings(settings).expect("settings in range");
        let start = range.start;
        let ids = tree
            .insert_bulk(range.map(|i| (i as u32, boxes[i])))
            .expect("scene boxes are valid");
        Index {
            tree,
            ids,
            start,
            moves: Vec::new(),
        }
    }
}

impl<const W: usize> Kept for Index<W> {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) -> (f64, f64) {
        // One batch per frame, as the plugin applies a frame's moves.
        let start = Instant::now();
        self.moves.clear();
        self.moves.extend(moved.iter().filter_map(|&i| {
            let i = i as usize;
            let id = i.checked_sub(self.start).and_then(|k| self.ids.get(k))?;
            Some((*id, boxes[i]))
        }));
        self.tree
            .update_batch(&self.moves)
            .expect("scene boxes are valid");
        let updated = Instant::now();
        self.tree.optimize(OPTIMIZE_BUDGET);
        (ms_between(start, updated), ms_since(updated))
    }

    fn take_maintenance(&mut self) -> MaintenanceStats {
        self.tree.take_maintenance_stats()
    }

    fn overlapping_into(&self, query: &Aabb, ws: &mut QueryWorkspace, out: &mut Vec<u32>) {
        self.tree.overlapping_into(query, ws, out);
    }

    fn cull_into(
        &self,
        frustum: &Frustum,
        mode: CullMode,
        ws: &mut QueryWorkspace,
        out: &mut Vec<u32>,
    ) {
        self.tree
            .visit_visible(std::slice::from_ref(frustum), mode, ws, |_, key, _| {
                out.push(key);
                std::ops::ControlFlow::Continue(())
            });
    }

    fn cast_rays_first(&self, rays: &[Ray], ws: &mut QueryWorkspace, out: &mut RayResults<u32>) {
        self.tree.cast_rays(rays, RayMode::First, ws, out);
    }

    fn cast_ray_first(&self, ray: &Ray, ws: &mut QueryWorkspace) -> Option<RayHit<u32>> {
        self.tree.cast_ray(ray, ws).expect("scene rays are valid")
    }

    fn self_join_into(&self, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>) {
        self.tree
            .self_join_into(0.0, JoinMode::Euclidean, ws, out)
            .expect("a valid distance");
    }

    fn shape(&self) -> (usize, usize) {
        (self.tree.height(), self.tree.node_count())
    }

    fn validate(&self) -> Result<(), String> {
        self.tree.validate().map_err(|e| e.0)
    }
}

/// The kept enemy and barrel trees of one node width: joins need both sides
/// of the same width, which a trait object hides.
pub(crate) trait Joined {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]);
    fn cross_join_into(&self, mode: JoinMode, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>);
}

pub(crate) struct JoinTrees<const W: usize> {
    pub(crate) enemies: Index<W>,
    pub(crate) barrels: Index<W>,
}

impl<const W: usize> Joined for JoinTrees<W> {
    fn apply(&mut self, moved: &[u32], boxes: &[Aabb]) {
        self.enemies.apply(moved, boxes);
        self.barrels.apply(moved, boxes);
    }

    fn cross_join_into(&self, mode: JoinMode, ws: &mut QueryWorkspace, out: &mut Vec<(u32, u32)>) {
        self.enemies
            .tree
            .cross_join_into(&self.barrels.tree, TownScene::JOIN_DISTANCE, mode, ws, out)
            .expect("a valid distance");
    }
}

pub(crate) fn join_trees(
    boxes: &[Aabb],
    width: usize,
    ranges: &(Range<usize>, Range<usize>),
) -> Box<dyn Joined> {
    let d = TreeSettings::default();
    let (e, b) = ranges.clone();
    match width {
        4 => Box::new(JoinTrees::<4> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
        16 => Box::new(JoinTrees::<16> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
        _ => Box::new(JoinTrees::<8> {
            enemies: Index::load(boxes, e, d),
            barrels: Index::load(boxes, b, d),
        }),
    }
}

/// Which knob a contender varies.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Knob {
    Margin,
    Fraction,
    Displacement,
    /// How much churn a level-1 node absorbs before `optimize` repacks it.
    Repack,
    Width,
}

/// Time and traversal work of one query on one tree.
#[derive(Clone, Copy, Default)]
pub(crate) struct WorkCost {
    /// Median time.
    pub(crate) ms: f64,
    /// Nodes (node pairs, for a join) visited.
    pub(crate) nodes: u64,
}

/// Cost of the box-query set on one tree.
#[derive(Clone, Copy, Default)]
pub(crate) struct BoxCost {
    /// Median time of the whole set.
    pub(crate) ms: f64,
    /// Entries tested per query beyond the oracle's answer count.
    pub(crate) extra_per_query: f64,
    /// Nodes visited per query: the other half of the traversal's work.
    pub(crate) nodes_per_query: f64,
}

pub(crate) struct Contender {
    pub(crate) knob: Knob,
    /// Row label in the tables.
    pub(crate) label: String,
    /// Tick label in the plots.
    pub(crate) tick: String,
    pub(crate) width: usize,
    pub(crate) settings: TreeSettings,
    pub(crate) index: Box<dyn Kept>,
    /// Update plus optimize, per measured frame.
    pub(crate) update_ms: Vec<f64>,
    /// The optimize part alone, per measured frame.
    pub(crate) optimize_ms: Vec<f64>,
    /// Maintenance over the measured frames.
    pub(crate) moves: MaintenanceStats,
    pub(crate) fresh: BoxCost,
    pub(crate) churned: BoxCost,
    pub(crate) churned_cull_ms: f64,
    /// Self join (d = 0) on the churned tree.
    pub(crate) churned_self_join: WorkCost,
    /// The incoherent ray set on the churned tree.
    pub(crate) churned_rays: WorkCost,
}

impl Contender {
    pub(crate) fn is_default(&self) -> bool {
        self.width == DEFAULT_WIDTH && self.settings == TreeSettings::default()
    }
}

/// Restructuring moves a level-1 node absorbs before it is repacked, at
/// the default width (`TreeSettings::repack_fraction` of its capacity).
pub(crate) fn repack_moves(settings: &TreeSettings) -> u32 {
    (settings.repack_fraction * (DEFAULT_WIDTH * DEFAULT_WIDTH) as f32).ceil() as u32
}

/// The contenders: every bounds policy at the default width, then the other
/// widths with default settings (the default width with default settings is
/// the margin 0.1 row).
pub(crate) fn contenders(boxes: &[Aabb]) -> Vec<Contender> {
    let d = TreeSettings::default();
    let mut specs: Vec<(Knob, String, String, usize, TreeSettings)> = Vec::new();
    for margin in [0.0f32, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0] {
        let settings = TreeSettings {
            margin,
            margin_fraction: 0.0,
            ..d
        };
        let (label, tick) = (format!("margin {margin} m"), format!("{margin}"));
        specs.push((Knob::Margin, label, tick, DEFAULT_WIDTH, settings));
    }
    for fraction in [0.05f32, 0.1, 0.25] {
        let settings = TreeSettings {
            margin: 0.0,
            margin_fraction: fraction,
            ..d
        };
        let percent = fraction * 100.0;
        let label = format!("margin 0, {percent:.0} % of extent");
        specs.push((
            Knob::Fraction,
            label,
            format!("{percent:.0} %"),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for factor in [0.0f32, 1.0, 8.0, 16.0, 32.0] {
        let settings = TreeSettings {
            displacement_factor: factor,
            ..d
        };
        let label = format!("margin {} m, displacement x{factor}", d.margin);
        specs.push((
            Knob::Displacement,
            label,
            format!("x{factor}"),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for fraction in [0.0625f32, 1.0] {
        let settings = TreeSettings {
            repack_fraction: fraction,
            ..d
        };
        let moves = repack_moves(&settings);
        specs.push((
            Knob::Repack,
            format!("margin {} m, repack after {moves} moves", d.margin),
            moves.to_string(),
            DEFAULT_WIDTH,
            settings,
        ));
    }
    for width in WIDTHS.into_iter().filter(|&w| w != DEFAULT_WIDTH) {
        specs.push((
            Knob::Width,
            format!("width {width}"),
            width.to_string(),
            width,
            d,
        ));
    }
    specs
        .into_iter()
        .map(|(knob, label, tick, width, settings)| {
            let all = 0..boxes.len();
            let index: Box<dyn Kept> = match width {
                4 => Box::new(Index::<4>::load(boxes, all, settings)),
                16 => Box::new(Index::<16>::load(boxes, all, settings)),
                _ => Box::new(Index::<8>::load(boxes, all, settings)),
            };
            Contender {
                knob,
                label,
                tick,
                width,
                settings,
                index,
                update_ms: Vec::new(),
                optimize_ms: Vec::new(),
                moves: MaintenanceStats::default(),
                fresh: BoxCost::default(),
                churned: BoxCost::default(),
                churned_cull_ms: 0.0,
                churned_self_join: WorkCost::default(),
                churned_rays: WorkCost::default(),
            }
        })
        .collect()
}
