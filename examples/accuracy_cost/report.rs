//! The tables and plots of a run: markdown for stdout and
//! `docs/accuracy_cost.md`, SVG figures for `docs/`.

use std::fmt::Write as _;

use bevy_rtree::TreeSettings;
use bevy_rtree::scene::TownScene;

mod figures;

use crate::contenders::repack_moves;
use crate::modes::FrameFigures;
use crate::{
    BOX_QUERIES, BOX_QUERY_HALF, BUILD_REPS, CHURNED_CULL_REPS, CULL_REPS, Contender,
    DEFAULT_WIDTH, JOIN_RAY_REPS, Knob, QUERY_REPS, RAY_COUNT, RAY_REPS, SEED, WIDTH_REPS, WIDTHS,
    WidthFigures, mean, median, min_max,
};

/// Everything the tables and plots are made of.
pub struct Report<'a> {
    /// Section 6, the long session.
    pub sessions: &'a [crate::long_session::SessionRow],
    /// Section 7's markdown (feature `bevy_camera`), or empty.
    pub bevy_section: String,
    pub count: usize,
    pub frames: usize,
    pub warmup: usize,
    pub contenders: &'a [Contender],
    /// The contender with the crate's default settings and width.
    pub default: usize,
    pub widths: &'a WidthFigures,
    pub figures: &'a FrameFigures,
    /// Oracle answers per box query on the churned trees.
    pub true_answers: f64,
    pub run_seconds: f64,
    /// 1-minute load average at the start and the end of the run.
    pub load: (Option<String>, Option<String>),
}

/// Logical core count and CPU model, from `/proc/cpuinfo` where there is one.
fn machine() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cores = match info.lines().filter(|l| l.starts_with("processor")).count() {
        0 => std::thread::available_parallelism().map_or(0, |n| n.get()),
        n => n,
    };
    let model = info
        .lines()
        .find_map(|l| {
            l.strip_prefix("model name")
                .and_then(|rest| rest.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "CPU model unknown".to_string());
    format!("{cores} logical cores, {model}")
}

/// The 1-minute load average, where the system reports one: on a shared
/// machine other work lengthens every time, and readers should know.
pub fn load_average() -> Option<String> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next().map(str::to_string)
}

/// `100000` as `100,000`.
pub(crate) fn thousands(n: usize) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, d) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(d);
    }
    out
}

/// Milliseconds with about three significant digits.
pub fn ms(v: f64) -> String {
    if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else if v >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn percent(part: u64, whole: u64) -> String {
    format!("{:.1}", 100.0 * part as f64 / whole.max(1) as f64)
}

impl Report<'_> {
    fn command(&self) -> String {
        let mut command = "cargo run --release --example accuracy_cost".to_string();
        if !self.bevy_section.is_empty() {
            command.push_str(" --features bevy_camera");
        }
        let mut args = String::new();
        if self.count != TownScene::STANDARD_COUNT {
            let _ = write!(args, " --count {}", self.count);
        }
        if self.frames != 60 {
            let _ = write!(args, " --frames {}", self.frames);
        }
        if self.warmup != crate::WARMUP_FRAMES {
            let _ = write!(args, " --warmup {}", self.warmup);
        }
        if !args.is_empty() {
            let _ = write!(command, " --{args}");
        }
        command
    }

    fn default(&self) -> &Contender {
        &self.contenders[self.default]
    }

    fn by_knob(&self, knob: Knob) -> impl Iterator<Item = &Contender> {
        self.contenders.iter().filter(move |c| c.knob == knob)
    }

    /// The width contenders in the order of `WIDTHS`.
    fn widths(&self) -> [&Contender; 3] {
        WIDTHS.map(|w| {
            self.contenders
                .iter()
                .find(|c| c.width == w && c.settings == TreeSettings::default())
                .expect("a contender per width")
        })
    }

    /// The bounds contenders, the default marked.
    fn bounds_rows(&self) -> impl Iterator<Item = (String, &Contender)> {
        self.contenders
            .iter()
            .filter(|c| c.knob != Knob::Width)
            .map(|c| {
                let label = if c.is_default() {
                    format!("**{} (default)**", c.label)
                } else {
                    c.label.clone()
                };
                (label, c)
            })
    }

    /// "after N frames", counting the warm-up.
    fn churn(&self) -> String {
        format!("after {} frames", self.warmup + self.frames)
    }

    pub fn markdown(&self) -> String {
        let mut s = String::new();
        self.header(&mut s);
        self.bounds(&mut s);
        self.culling(&mut s);
        self.joins(&mut s);
        self.node_width(&mut s);
        self.rays(&mut s);
        crate::long_session::markdown(self.sessions, self.count, &mut s);
        s.push_str(&self.bevy_section);
        s
    }

    fn header(&self, s: &mut String) {
        let _ = writeln!(s, "# Accuracy against time\n");
        let _ = writeln!(
            s,
            "Generated by `{}` (examples/accuracy_cost); do not edit by hand.\n",
            self.command()
        );
        let load = |l: &Option<String>| l.clone().unwrap_or_else(|| "n/a".into());
        let _ = writeln!(
            s,
            "- Machine: {}; 1-minute load average {} at the start of the run, {} at \
             the end. The machine is shared with other work: distrust differences \
             under ~15 %.",
            machine(),
            load(&self.load.0),
            load(&self.load.1)
        );
        let warmup = if self.warmup > 0 {
            format!("{} untimed warm-up frames, then ", self.warmup)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "- Scene: town (`bevy_rtree::scene::TownScene`), {} entities, seed {SEED}; {warmup}{} \
             measured frames, 10 % of the entities moving in each. The run took \
             {:.0} s.",
            thousands(self.count),
            self.frames,
            self.run_seconds
        );
        let _ = writeln!(
            s,
            "- Single-threaded; times are medians of single runs. Every answer \
             was asserted equal to the brute-force oracle's on the same frame \
             (rays: see section 5); the accuracy figures are counted from those \
             answers, not estimated.\n- Knobs with no row here: the node split \
             strategy (`TreeSettings::split`, which changes no answer; `cargo \
             bench --bench tree` times the three on single inserts, moves and \
             churned box queries) and width 12 (allowed, between 8 and 16).\n"
        );
    }

    fn bounds(&self, s: &mut String) {
        let d = TreeSettings::default();
        let _ = writeln!(s, "## 1. Enlarged bounds (TreeSettings)\n");
        let _ = writeln!(
            s,
            "Each policy is bulk-loaded from the same boxes at width \
             {DEFAULT_WIDTH} (the default) and lives through the same frames: each \
             frame's moves go to one `update_batch`, then `optimize` repairs all \
             pending churn. Settings not varied in a row keep their defaults \
             (absolute margin {} m, fraction {}, displacement factor {}, a level-1 \
             node repacked after {} restructuring moves), except that the fraction \
             rows set the absolute margin to 0. The repack rows vary how much churn \
             a level-1 node absorbs before `optimize` re-tiles its leaves \
             (`TreeSettings::repack_fraction`). The plugin repairs with a budget \
             (`SpatialIndexPlugin::optimize_budget`); here every pending repair is \
             made each frame, so that the rows compare the policies alone.\n",
            d.margin,
            d.margin_fraction,
            d.displacement_factor,
            repack_moves(&d),
        );
        let _ = writeln!(s, "### Update side\n");
        let _ = writeln!(
            s,
            "Per measured frame ({} moves): median and mean of update + optimize, \
             and the median of optimize alone. Moves: how the tree absorbed them \
             over the measured frames (in place: inside the fat box; in leaf: new \
             fat box inside the leaf's bound; grown: the leaf's bound grew; \
             reinserted: from the root).\n",
            thousands(self.count / 10)
        );
        let _ = writeln!(
            s,
            "| enlarged bounds | update + optimize, median (ms) | mean (ms) | optimize alone, median (ms) | moves in place / in leaf / grown / reinserted (%) | repacks per frame |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---|---:|");
        for (label, c) in self.bounds_rows() {
            let m = &c.moves;
            let total =
                m.moves_in_place + m.moves_in_leaf + m.moves_leaf_grown + m.moves_reinserted;
            let _ = writeln!(
                s,
                "| {label} | {} | {} | {} | {} / {} / {} / {} | {:.1} |",
                ms(median(&c.update_ms)),
                ms(mean(&c.update_ms)),
                ms(median(&c.optimize_ms)),
                percent(m.moves_in_place, total),
                percent(m.moves_in_leaf, total),
                percent(m.moves_leaf_grown, total),
                percent(m.moves_reinserted, total),
                m.repacks as f64 / self.frames as f64,
            );
        }
        let frames = self.warmup + self.frames;
        let moves = frames as f64 / 10.0;
        // The largest drift of the run against the largest margin measured:
        // only a drift within the margin keeps every move in place, which a
        // long-running game would not.
        let drift = 0.1 * moves;
        let within = if drift <= 1.0 {
            "A 1 m margin can absorb all of that drift, so its in-place share is \
             higher than it would stay in a long-running game, where every entity \
             eventually leaves any fat box; `-- --warmup N` measures after N \
             untimed frames."
        } else {
            "That drift is more than the largest margin measured (1 m): every \
             policy has seen its entities leave their fat boxes, as in a \
             long-running game."
        };
        let _ = writeln!(
            s,
            "\nIn {frames} frames an entity moves {moves:.1} times on average, each \
             time by its fixed step (at most 0.1 m per axis, up to {drift:.1} m in \
             all). {within} The scene's constant per-entity steps also suit the \
             displacement factor, which stretches the fat box along the last \
             move.\n"
        );
        let _ = writeln!(s, "### Query side\n");
        let _ = writeln!(
            s,
            "{} box queries of half extent {BOX_QUERY_HALF} m around the centres of \
             random entities, the same entities before and after the churn ({:.1} \
             true answers per query on the churned trees); time: \
             median of {QUERY_REPS} runs of the whole set, trees interleaved, on the \
             freshly loaded trees and {}. Extra candidates: entries tested \
             (`QueryStats::entries_tested`) per query beyond the oracle's answer \
             count. Nodes: nodes visited per query. Frustum: conservative cull of \
             each measured frame's camera, {CHURNED_CULL_REPS} passes, median, on \
             the churned trees. Self join: all touching or overlapping pairs \
             (d = 0) and the node pairs it visits; rays: {} incoherent rays (first \
             hit) and the nodes they visit; both on the churned trees, median of \
             {JOIN_RAY_REPS} runs, trees interleaved. These two descend the most \
             internal nodes, whose bounds hold the fat boxes. Answers are exact in \
             every row: imprecision here costs work, never correctness.\n",
            thousands(BOX_QUERIES),
            self.true_answers,
            self.churn(),
            thousands(RAY_COUNT),
        );
        // The rows that only vary what moves do (displacement, repack) load
        // the very same fresh tree: their fresh box-query times show how
        // far this machine's noise alone moves a figure in this run.
        let same_load: Vec<f64> = self
            .by_knob(Knob::Margin)
            .chain(self.by_knob(Knob::Displacement))
            .chain(self.by_knob(Knob::Repack))
            .filter(|c| {
                let d = TreeSettings::default();
                c.width == DEFAULT_WIDTH
                    && c.settings.margin == d.margin
                    && c.settings.margin_fraction == d.margin_fraction
            })
            .map(|c| c.fresh.ms)
            .collect();
        if same_load.len() > 1 {
            let (lo, hi) = min_max(&same_load);
            let _ = writeln!(
                s,
                "The noise floor of this run: {} rows load the same fresh tree, \
                 and their fresh box queries took {} to {} ms ({:.0} % apart); \
                 differences between rows smaller than that are noise, and the \
                 node counts, which no noise moves, are the surer cost.\n",
                same_load.len(),
                ms(lo),
                ms(hi),
                100.0 * (hi / lo - 1.0),
            );
        }
        let _ = writeln!(
            s,
            "| enlarged bounds | box queries, fresh (ms) | box queries, churned (ms) | extra candidates / query, fresh | extra candidates / query, churned | nodes / query, fresh | nodes / query, churned | frustum cull, churned (ms) | self join, churned (ms) | self join node pairs | rays, churned (ms) | nodes / ray |"
        );
        let _ = writeln!(
            s,
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        for (label, c) in self.bounds_rows() {
            let _ = writeln!(
                s,
                "| {label} | {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {} | {} | {} | {:.2} |",
                ms(c.fresh.ms),
                ms(c.churned.ms),
                c.fresh.extra_per_query,
                c.churned.extra_per_query,
                c.fresh.nodes_per_query,
                c.churned.nodes_per_query,
                ms(c.churned_cull_ms),
                ms(c.churned_self_join.ms),
                thousands(c.churned_self_join.nodes as usize),
                ms(c.churned_rays.ms),
                c.churned_rays.nodes as f64 / RAY_COUNT as f64,
            );
        }
        let _ = writeln!(
            s,
            "\n![Enlarged bounds: update and query time](accuracy_cost_margin_time.svg)\n\n\
             ![Enlarged bounds: extra candidates and nodes per box query, node pairs per self join](accuracy_cost_margin_extra.svg)\n"
        );
    }

    fn culling(&self, s: &mut String) {
        let f = self.figures;
        let (fp_lo, fp_hi) = min_max(&f.cull_false_positives);
        let (share_lo, share_hi) = min_max(&f.cull_false_share);
        let _ = writeln!(
            s,
            "## 2. Frustum culling: conservative vs exact (CullMode)\n"
        );
        let _ = writeln!(
            s,
            "The default tree after each measured frame's updates, culled with that \
             frame's camera: {CULL_REPS} timed culls per mode and frame, the modes \
             interleaved. False positives per frame: conservative count minus exact \
             count (the exact answer equals the oracle's exact mode, the \
             conservative one the oracle's conservative mode), and their share of \
             the exact visible set.\n"
        );
        let _ = writeln!(
            s,
            "| mode | ms per cull | visible per frame (median) | false positives per frame: median (min–max) | share of the visible set: median (min–max) |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        let visible = median(&f.visible_exact);
        let _ = writeln!(
            s,
            "| **conservative (default)** | {} | {:.0} | {:.0} ({fp_lo:.0}–{fp_hi:.0}) | {:.2} % ({:.2}–{:.2} %) |",
            ms(median(&f.cull_ms[0])),
            median(&f.visible_conservative),
            median(&f.cull_false_positives),
            100.0 * median(&f.cull_false_share),
            100.0 * share_lo,
            100.0 * share_hi,
        );
        let _ = writeln!(
            s,
            "| exact | {} | {visible:.0} | 0 | 0 % |",
            ms(median(&f.cull_ms[1])),
        );
        let _ = writeln!(
            s,
            "\nExact takes {:.2}x the conservative time.\n",
            median(&f.cull_ms[1]) / median(&f.cull_ms[0])
        );
    }

    fn joins(&self, s: &mut String) {
        let f = self.figures;
        let (extra_lo, extra_hi) = min_max(&f.join_extra);
        let (share_lo, share_hi) = min_max(&f.join_extra_share);
        let _ = writeln!(s, "## 3. Cross join: Chebyshev vs Euclidean (JoinMode)\n");
        let _ = writeln!(
            s,
            "Enemies (entities 0..10,000) x barrels (10,000..15,000) within {} m, \
             on two width-{DEFAULT_WIDTH} trees kept up to date through the frames; one timed \
             join per mode and measured frame, the first mode alternating. Extra \
             pairs: Chebyshev pairs minus Euclidean pairs (each list equal to the \
             oracle's in its mode), and their share of the Euclidean pairs.\n",
            TownScene::JOIN_DISTANCE
        );
        let _ = writeln!(
            s,
            "| mode | ms per join | pairs per frame (median) | extra pairs per frame: median (min–max) | share of the exact pairs: median (min–max) |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        let pairs = median(&f.pairs_euclidean);
        let _ = writeln!(
            s,
            "| **Euclidean (default)** | {} | {pairs:.0} | 0 | 0 % |",
            ms(median(&f.join_ms[1])),
        );
        let _ = writeln!(
            s,
            "| Chebyshev | {} | {:.0} | {:.0} ({extra_lo:.0}–{extra_hi:.0}) | {:.1} % ({:.1}–{:.1} %) |",
            ms(median(&f.join_ms[0])),
            median(&f.pairs_chebyshev),
            median(&f.join_extra),
            100.0 * median(&f.join_extra_share),
            100.0 * share_lo,
            100.0 * share_hi,
        );
        let _ = writeln!(
            s,
            "\nChebyshev takes {:.2}x the Euclidean time.\n",
            median(&f.join_ms[0]) / median(&f.join_ms[1])
        );
    }

    fn node_width(&self, s: &mut String) {
        let w = self.widths;
        let _ = writeln!(s, "## 4. Node width (RTree<u32, W>)\n");
        let _ = writeln!(
            s,
            "Default settings at every width. Bulk build: median of {BUILD_REPS} \
             loads of the whole scene, widths interleaved, each timed with dropping \
             the tree it made (as a rebuild replaces one). Update: as in section 1. \
             The same query can take other times here than in sections 2 and 5: \
             there one tree answers the same query back to back, warm; here the \
             widths take turns, and each meets caches the others left. \
             Box queries and frustum culls: as in section 1, on the churned trees. \
             Rays: batched `cast_rays`, first hit, on the churned trees (one set of \
             each kind from the final frame). Join: Euclidean enemies x barrels on \
             kept trees of that width. Rays and joins: median of {WIDTH_REPS} runs, \
             widths interleaved, answers equal to the oracle's.\n"
        );
        let _ = writeln!(
            s,
            "| width | bulk build (ms) | update + optimize (ms/frame) | {} box queries (ms) | frustum cull (ms) | 1,000 incoherent rays (ms) | 1,000 coherent rays (ms) | cross join (ms) |",
            thousands(BOX_QUERIES)
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|");
        for (i, c) in self.widths().iter().enumerate() {
            let label = if c.is_default() {
                format!("**{} (default)**", c.width)
            } else {
                c.width.to_string()
            };
            let _ = writeln!(
                s,
                "| {label} | {} | {} | {} | {} | {} | {} | {} |",
                ms(w.build_ms[i]),
                ms(median(&c.update_ms)),
                ms(c.churned.ms),
                ms(c.churned_cull_ms),
                ms(w.rays_ms[i][0]),
                ms(w.rays_ms[i][1]),
                ms(w.join_ms[i]),
            );
        }
        let _ = writeln!(s, "\nThe work behind those times, on the churned trees:\n");
        let _ = writeln!(
            s,
            "| width | extra candidates / box query | nodes / box query | height | nodes |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        for c in self.widths() {
            let (height, nodes) = c.index.shape();
            let _ = writeln!(
                s,
                "| {} | {:.1} | {:.1} | {height} | {} |",
                c.width,
                c.churned.extra_per_query,
                c.churned.nodes_per_query,
                thousands(nodes)
            );
        }
        let _ = writeln!(s, "\n![Node width: times](accuracy_cost_width.svg)\n");
    }

    fn rays(&self, s: &mut String) {
        let f = self.figures;
        let _ = writeln!(s, "## 5. Rays: batched cast_rays vs a loop of cast_ray\n");
        let _ = writeln!(
            s,
            "First hit, on the default tree after each measured frame's updates; \
             {RAY_REPS} timed runs of each per frame, batched and single \
             alternating. The two answers \
             were asserted equal (key and `t`) on all {} frames, and equal to the \
             oracle's on {} of them (the ray oracle tests every box, so it runs on \
             every tenth frame and the last).\n",
            f.ray_frames_compared, f.ray_frames_oracle
        );
        let _ = writeln!(
            s,
            "| 1,000 rays | batched cast_rays (ms) | loop of cast_ray (ms) | loop / batched | rays that hit (median) |"
        );
        let _ = writeln!(s, "|---|---:|---:|---:|---:|");
        for (r, name) in ["incoherent (200 m)", "coherent (500 m, pixel grid)"]
            .iter()
            .enumerate()
        {
            let batched = median(&f.ray_ms[r][0]);
            let single = median(&f.ray_ms[r][1]);
            let _ = writeln!(
                s,
                "| {name} | {} | {} | {:.2} | {:.0} |",
                ms(batched),
                ms(single),
                single / batched,
                median(&f.ray_hits[r])
            );
        }
        let _ = writeln!(
            s,
            "\n![Mode comparisons: culling, joins, rays](accuracy_cost_modes.svg)"
        );
    }
}
