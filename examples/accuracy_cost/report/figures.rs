//! The report's plots: the SVG figures `docs/accuracy_cost_*.svg` are
//! drawn from the same figures as the tables.

use bevy_rtree::scene::TownScene;

use super::{Report, thousands};
use crate::contenders::{BoxCost, Contender, Knob, repack_moves};
use crate::measure::median;
use crate::svg::{Figure, Kind, Panel, Series};
use crate::{BOX_QUERIES, BOX_QUERY_HALF, DEFAULT_WIDTH, RAY_COUNT, WIDTHS};

impl Report<'_> {
    /// The SVG files and their figures.
    pub fn figures(&self) -> Vec<(&'static str, Figure)> {
        let [margin_time, margin_extra] = self.bounds_figures();
        vec![
            ("accuracy_cost_margin_time.svg", margin_time),
            ("accuracy_cost_margin_extra.svg", margin_extra),
            ("accuracy_cost_width.svg", self.width_figure()),
            ("accuracy_cost_modes.svg", self.modes_figure()),
        ]
    }

    fn bounds_figures(&self) -> [Figure; 2] {
        // One categorical x axis for every bounds policy: absolute margins,
        // then fractions, then displacement factors, then repack thresholds.
        // The default tree appears in the first group and again in the last
        // two, where its displacement factor and threshold belong.
        let mut bounds: Vec<&Contender> = Vec::new();
        let mut ticks: Vec<String> = Vec::new();
        let mut groups = Vec::new();
        for (knob, name) in [
            (Knob::Margin, "margin (m)"),
            (Knob::Fraction, "fraction of extent"),
            (Knob::Displacement, "displacement factor"),
            (Knob::Repack, "repack (moves)"),
        ] {
            let mut members: Vec<(&Contender, String)> =
                self.by_knob(knob).map(|c| (c, c.tick.clone())).collect();
            let d = self.default();
            if knob == Knob::Displacement {
                members.push((d, format!("x{}", d.settings.displacement_factor)));
                members.sort_by(|a, b| {
                    a.0.settings
                        .displacement_factor
                        .total_cmp(&b.0.settings.displacement_factor)
                });
            }
            if knob == Knob::Repack {
                members.push((d, repack_moves(&d.settings).to_string()));
                members.sort_by(|a, b| {
                    a.0.settings
                        .repack_fraction
                        .total_cmp(&b.0.settings.repack_fraction)
                });
            }
            groups.push((name.to_string(), members.len()));
            for (c, tick) in members {
                bounds.push(c);
                ticks.push(tick);
            }
        }
        let values = |get: &dyn Fn(&Contender) -> f64| -> Vec<Option<f64>> {
            bounds.iter().map(|c| Some(get(c))).collect()
        };
        let fresh_and_churned = |get: &dyn Fn(&BoxCost) -> f64| {
            vec![
                Series::new("freshly loaded", values(&|c| get(&c.fresh))),
                Series::new(&self.churn(), values(&|c| get(&c.churned))),
            ]
        };
        let panel = |title: String, y_label: &str, series: Vec<Series>| Panel {
            title,
            y_label: y_label.to_string(),
            categories: ticks.clone(),
            groups: groups.clone(),
            series,
            kind: Kind::Lines,
        };
        let time = Figure {
            title: format!(
                "Enlarged bounds: update and query time (town, {} entities, width {DEFAULT_WIDTH})",
                thousands(self.count)
            ),
            columns: 1,
            panel_width: 860.0,
            panel_height: 260.0,
            panels: vec![
                panel(
                    format!(
                        "Update of {} moves + optimize, median per frame",
                        thousands(self.count / 10)
                    ),
                    "ms per frame",
                    vec![Series::new(
                        "update + optimize",
                        values(&|c| median(&c.update_ms)),
                    )],
                ),
                panel(
                    format!(
                        "{} box queries (half extent {BOX_QUERY_HALF} m)",
                        thousands(BOX_QUERIES)
                    ),
                    "ms per set",
                    fresh_and_churned(&|cost| cost.ms),
                ),
                panel(
                    format!("Frustum cull, conservative, {}", self.churn()),
                    "ms per cull",
                    vec![Series::new("frustum cull", values(&|c| c.churned_cull_ms))],
                ),
                panel(
                    format!("Self join (d = 0), {}", self.churn()),
                    "ms per join",
                    vec![Series::new(
                        "self join",
                        values(&|c| c.churned_self_join.ms),
                    )],
                ),
                panel(
                    format!(
                        "{} incoherent rays (first hit), {}",
                        thousands(RAY_COUNT),
                        self.churn()
                    ),
                    "ms per set",
                    vec![Series::new("rays", values(&|c| c.churned_rays.ms))],
                ),
            ],
        };
        let extra = Figure {
            title: "Enlarged bounds: traversal work per box query and self join (answers exact)"
                .to_string(),
            columns: 1,
            panel_width: 860.0,
            panel_height: 280.0,
            panels: vec![
                panel(
                    format!(
                        "Entries tested beyond the true answers ({:.1} per query)",
                        self.true_answers
                    ),
                    "extra candidates per query",
                    fresh_and_churned(&|cost| cost.extra_per_query),
                ),
                panel(
                    "Nodes visited".to_string(),
                    "nodes per query",
                    fresh_and_churned(&|cost| cost.nodes_per_query),
                ),
                panel(
                    format!("Self join (d = 0): node pairs visited, {}", self.churn()),
                    "node pairs",
                    vec![Series::new(
                        "self join",
                        values(&|c| c.churned_self_join.nodes as f64),
                    )],
                ),
            ],
        };
        [time, extra]
    }

    fn width_figure(&self) -> Figure {
        let w = self.widths;
        let contenders = self.widths();
        let panel = |title: String, y_label: &str, series: Vec<(&str, [f64; 3])>| Panel {
            title,
            y_label: y_label.to_string(),
            categories: WIDTHS.iter().map(usize::to_string).collect(),
            groups: vec![("node width W (lanes per node)".to_string(), WIDTHS.len())],
            series: series
                .into_iter()
                .map(|(name, v)| Series::new(name, v.map(Some).to_vec()))
                .collect(),
            kind: Kind::Lines,
        };
        Figure {
            title: format!(
                "Node width: build, update and query times (town, {} entities)",
                thousands(self.count)
            ),
            columns: 3,
            panel_width: 380.0,
            panel_height: 270.0,
            panels: vec![
                panel(
                    "Bulk build".to_string(),
                    "ms",
                    vec![("bulk build", w.build_ms)],
                ),
                panel(
                    "Update + optimize".to_string(),
                    "ms per frame",
                    vec![("update", contenders.map(|c| median(&c.update_ms)))],
                ),
                panel(
                    format!("{} box queries", thousands(BOX_QUERIES)),
                    "ms per set",
                    vec![("box queries", contenders.map(|c| c.churned.ms))],
                ),
                panel(
                    "Frustum cull".to_string(),
                    "ms per cull",
                    vec![("cull", contenders.map(|c| c.churned_cull_ms))],
                ),
                panel(
                    "1,000 rays, batched, first hit".to_string(),
                    "ms per batch",
                    vec![
                        ("incoherent", w.rays_ms.map(|r| r[0])),
                        ("coherent", w.rays_ms.map(|r| r[1])),
                    ],
                ),
                panel(
                    format!("Cross join at {} m", TownScene::JOIN_DISTANCE),
                    "ms per join",
                    vec![("join", w.join_ms)],
                ),
            ],
        }
    }

    fn modes_figure(&self) -> Figure {
        let f = self.figures;
        let pair = |title: &str, category: String, names: [&str; 2], v: [f64; 2]| Panel {
            title: title.to_string(),
            y_label: "ms (median)".to_string(),
            categories: vec![category],
            groups: Vec::new(),
            series: vec![
                Series::new(names[0], vec![Some(v[0])]),
                Series::new(names[1], vec![Some(v[1])]),
            ],
            kind: Kind::Bars,
        };
        let rays = |r: usize| [median(&f.ray_ms[r][0]), median(&f.ray_ms[r][1])];
        Figure {
            title: format!("Mode comparisons on the default tree (town, width {DEFAULT_WIDTH})"),
            columns: 2,
            panel_width: 420.0,
            panel_height: 280.0,
            panels: vec![
                pair(
                    "Frustum cull",
                    format!(
                        "false positives: {:.0} per frame ({:.2} %)",
                        median(&f.cull_false_positives),
                        100.0 * median(&f.cull_false_share)
                    ),
                    ["conservative", "exact"],
                    [median(&f.cull_ms[0]), median(&f.cull_ms[1])],
                ),
                pair(
                    &format!("Cross join at {} m", TownScene::JOIN_DISTANCE),
                    format!(
                        "extra pairs: {:.0} per frame ({:.1} %)",
                        median(&f.join_extra),
                        100.0 * median(&f.join_extra_share)
                    ),
                    ["Euclidean", "Chebyshev"],
                    [median(&f.join_ms[1]), median(&f.join_ms[0])],
                ),
                pair(
                    "1,000 incoherent rays, first hit",
                    "same answers".to_string(),
                    ["batched cast_rays", "loop of cast_ray"],
                    rays(0),
                ),
                pair(
                    "1,000 coherent rays, first hit",
                    "same answers".to_string(),
                    ["batched cast_rays", "loop of cast_ray"],
                    rays(1),
                ),
            ],
        }
    }
}
