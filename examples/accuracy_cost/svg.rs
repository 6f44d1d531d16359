//! The report's plots, drawn with plotters' SVG backend: a figure is a
//! grid of panels, each a line chart or a grouped bar chart over named
//! categories, with a zero-based y axis, an axis label carrying the unit,
//! and a legend.

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Colours that stay distinguishable for common colour-vision deficiencies.
const PALETTE: [RGBColor; 6] = [
    RGBColor(0x4e, 0x79, 0xa7),
    RGBColor(0xf2, 0x8e, 0x2b),
    RGBColor(0x59, 0xa1, 0x4f),
    RGBColor(0xe1, 0x57, 0x59),
    RGBColor(0x76, 0xb7, 0xb2),
    RGBColor(0xb0, 0x7a, 0xa1),
];

/// Height of the figure's title band, in pixels.
const TITLE: f64 = 36.0;

/// One named line or bar colour: a value per category (`None` leaves a gap).
pub struct Series {
    pub name: String,
    pub values: Vec<Option<f64>>,
}

impl Series {
    pub fn new(name: &str, values: Vec<Option<f64>>) -> Self {
        Series {
            name: name.to_string(),
            values,
        }
    }
}

/// How a panel draws its series.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Points joined by lines within a group of categories.
    Lines,
    /// One bar per series in every category, labelled with its value.
    Bars,
}

/// One chart of a figure.
pub struct Panel {
    pub title: String,
    /// The y axis label, with its unit.
    pub y_label: String,
    pub categories: Vec<String>,
    /// Consecutive runs of categories that belong together (label, count).
    /// Lines are not drawn across a group boundary, because neighbouring
    /// groups vary different knobs. Empty means one unnamed group.
    pub groups: Vec<(String, usize)>,
    pub series: Vec<Series>,
    pub kind: Kind,
}

/// A titled grid of panels.
pub struct Figure {
    pub title: String,
    pub columns: usize,
    pub panel_width: f64,
    pub panel_height: f64,
    pub panels: Vec<Panel>,
}

impl Figure {
    /// The whole figure as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        let columns = self.columns.max(1);
        let rows = self.panels.len().div_ceil(columns);
        let width = (self.panel_width * columns as f64) as u32;
        let height = (TITLE + self.panel_height * rows as f64) as u32;
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, (width, height)).into_drawing_area();
            root.fill(&WHITE).expect("an SVG string takes any drawing");
            let title = ("sans-serif", 18).into_font().style(FontStyle::Bold);
            let root = root.titled(&self.title, title).expect("room for the title");
            for (panel, area) in self.panels.iter().zip(root.split_evenly((rows, columns))) {
                panel.draw(&area);
            }
            root.present().expect("an SVG string takes any drawing");
        }
        svg
    }
}

impl Panel {
    /// The panel in `area`: categories at `i + 0.5` on an x axis from 0 to
    /// their count (ordinal, which keeps unevenly spaced settings such as
    /// 0, 0.02, ..., 1 m readable), values from 0 up.
    fn draw(&self, area: &DrawingArea<SVGBackend<'_>, Shift>) {
        let n = self.categories.len().max(1);
        // Times and counts are compared as ratios, so the axis starts at 0.
        let max = self
            .series
            .iter()
            .flat_map(|series| series.values.iter().flatten())
            .fold(0.0f64, |m, &v| m.max(v));
        // Head room above the highest value for the legend.
        let room = if self.series.len() > 1 { 1.4 } else { 1.15 };
        let top = if max > 0.0 && max.is_finite() {
            max * room
        } else {
            1.0
        };
        // Enough decimals to tell the y ticks apart.
        let decimals = (1.0 - (top / 5.0).log10().floor()).max(0.0) as usize;
        let mut chart = ChartBuilder::on(area)
            .caption(
                &self.title,
                ("sans-serif", 14).into_font().style(FontStyle::Bold),
            )
            .margin(12)
            .x_label_area_size(30)
            .y_label_area_size(64)
            .build_cartesian_2d(0f64..n as f64, 0f64..top)
            .expect("a finite, non-empty range");
        let categories = &self.categories;
        let groups = self.group_spans();
        // Category names under their centres (the ticks at the integers
        // between them stay unlabelled).
        let label_of = |x: &f64| {
            (0..categories.len())
                .find(|&i| (x - (i as f64 + 0.5)).abs() < 1e-6)
                .map(|i| categories[i].clone())
                .unwrap_or_default()
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(2 * n + 1)
            .x_label_formatter(&label_of)
            .y_label_formatter(&|y| format!("{y:.decimals$}"))
            .y_desc(&self.y_label)
            .max_light_lines(0)
            .bold_line_style(RGBColor(0xe3, 0xe3, 0xe3))
            .draw()
            .expect("an SVG string takes any drawing");
        // Group names at the top of their span.
        let group_font = ("sans-serif", 12)
            .into_font()
            .color(&RGBColor(0x55, 0x55, 0x55))
            .pos(Pos::new(HPos::Center, VPos::Top));
        let names = groups.iter().filter(|(label, ..)| !label.is_empty());
        let names = names.map(|(label, start, end)| {
            Text::new(
                label.clone(),
                ((start + end) as f64 / 2.0, top),
                group_font.clone(),
            )
        });
        chart.draw_series(names).expect("drawn");
        // Group boundaries.
        for (_, start, _) in groups.iter().skip(1) {
            let x = *start as f64;
            let dashed = DashedLineSeries::new(
                [(x, 0.0), (x, top)],
                4,
                3,
                RGBColor(0x99, 0x99, 0x99).into(),
            );
            chart.draw_series(dashed).expect("drawn");
        }
        match self.kind {
            Kind::Lines => self.draw_lines(&mut chart, &groups),
            Kind::Bars => self.draw_bars(&mut chart, top),
        }
        // A lone series is named by the panel's title already.
        if self.series.len() > 1 {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .draw()
                .expect("drawn");
        }
    }

    /// `(label, first category, one past the last)` of every group.
    fn group_spans(&self) -> Vec<(String, usize, usize)> {
        if self.groups.is_empty() {
            return vec![(String::new(), 0, self.categories.len())];
        }
        let mut start = 0;
        self.groups
            .iter()
            .map(|(label, count)| {
                let span = (label.clone(), start, start + count);
                start += count;
                span
            })
            .collect()
    }

    fn draw_lines<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
        groups: &[(String, usize, usize)],
    ) {
        for (k, series) in self.series.iter().enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            let point = |i: usize| series.values.get(i).copied().flatten();
            // One line per run of values: a group boundary or a gap (None)
            // breaks it.
            for (_, start, end) in groups {
                let mut run: Vec<(f64, f64)> = Vec::new();
                for i in *start..=*end {
                    match (i < *end).then(|| point(i)).flatten() {
                        Some(v) => run.push((i as f64 + 0.5, v)),
                        None => {
                            let line = LineSeries::new(run.drain(..), colour.stroke_width(2));
                            chart.draw_series(line).expect("drawn");
                        }
                    }
                }
            }
            let dots = (0..series.values.len()).filter_map(|i| {
                point(i).map(|v| Circle::new((i as f64 + 0.5, v), 3, colour.filled()))
            });
            chart
                .draw_series(dots)
                .expect("drawn")
                .label(series.name.as_str())
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 16, y)], colour.stroke_width(2))
                });
        }
    }

    fn draw_bars<DB: DrawingBackend>(
        &self,
        chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
        top: f64,
    ) {
        let count = self.series.len().max(1) as f64;
        let bar = 0.7 / count;
        for (k, series) in self.series.iter().enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            let placed = series.values.iter().enumerate().filter_map(|(i, v)| {
                let left = i as f64 + 0.15 + bar * k as f64;
                v.map(|v| (left, v))
            });
            let bars: Vec<(f64, f64)> = placed.collect();
            chart
                .draw_series(bars.iter().map(|&(left, v)| {
                    Rectangle::new([(left, 0.0), (left + bar * 0.9, v)], colour.filled())
                }))
                .expect("drawn")
                .label(series.name.as_str())
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], colour.filled())
                });
            // The value itself, so close bars can still be told apart.
            let font = ("sans-serif", 11)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Center, VPos::Bottom));
            chart
                .draw_series(bars.iter().map(|&(left, v)| {
                    let centre = left + bar * 0.45;
                    Text::new(format_value(v), (centre, v + top * 0.01), font.clone())
                }))
                .expect("drawn");
        }
    }
}

/// A value on a bar: three significant digits or so.
fn format_value(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}
