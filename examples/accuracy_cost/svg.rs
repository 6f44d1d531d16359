//! A small SVG plotter for the report: a figure is a grid of panels, each a
//! line chart or a grouped bar chart over named categories, with a zero-based
//! y axis, "nice" ticks, an axis label carrying the unit, and a legend.
//!
//! Hand-written so the example needs no plotting dependency; it only has to
//! draw a handful of small charts legibly.

use std::fmt::Write;

/// Colours that stay distinguishable for common colour-vision deficiencies.
const PALETTE: [&str; 6] = [
    "#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#b07aa1",
];

/// Space around a panel's plotting area, in pixels.
const LEFT: f64 = 72.0;
const RIGHT: f64 = 16.0;
const TOP: f64 = 34.0;
/// Room under the axis for tick labels, group labels and the legend.
const BOTTOM: f64 = 78.0;
/// Height of the figure's title band.
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
        let width = self.panel_width * columns as f64;
        let height = TITLE + self.panel_height * rows as f64;
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(
            s,
            r#"<rect width="{width}" height="{height}" fill="white"/>"#
        );
        let _ = writeln!(
            s,
            r#"<text x="{}" y="24" text-anchor="middle" font-size="16" font-weight="bold">{}</text>"#,
            width / 2.0,
            escape(&self.title)
        );
        for (i, panel) in self.panels.iter().enumerate() {
            let x = self.panel_width * (i % columns) as f64;
            let y = TITLE + self.panel_height * (i / columns) as f64;
            panel.draw(&mut s, x, y, self.panel_width, self.panel_height);
        }
        s.push_str("</svg>\n");
        s
    }
}

impl Panel {
    fn draw(&self, s: &mut String, x0: f64, y0: f64, width: f64, height: f64) {
        let (left, top) = (x0 + LEFT, y0 + TOP);
        let plot_w = width - LEFT - RIGHT;
        let plot_h = height - TOP - BOTTOM;
        let bottom = top + plot_h;
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle" font-size="13" font-weight="bold">{}</text>"#,
            left + plot_w / 2.0,
            y0 + 20.0,
            escape(&self.title)
        );

        // Times and counts are compared as ratios, so the axis starts at 0.
        let max = self
            .series
            .iter()
            .flat_map(|series| series.values.iter().flatten())
            .fold(0.0f64, |m, &v| m.max(v));
        let (step, top_value) = nice_axis(max);
        let y_of = |v: f64| bottom - v / top_value * plot_h;
        let decimals = tick_decimals(step);
        let ticks = (top_value / step).round() as usize;
        for k in 0..=ticks {
            let value = step * k as f64;
            let y = y_of(value);
            let _ = writeln!(
                s,
                r##"<line x1="{left}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#e3e3e3"/>"##,
                left + plot_w
            );
            let _ = writeln!(
                s,
                r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{value:.decimals$}</text>"#,
                left - 6.0,
                y + 4.0
            );
        }
        let _ = writeln!(
            s,
            r#"<text transform="translate({:.1},{:.1}) rotate(-90)" text-anchor="middle">{}</text>"#,
            x0 + 16.0,
            top + plot_h / 2.0,
            escape(&self.y_label)
        );
        let _ = writeln!(
            s,
            r#"<polyline points="{left},{top} {left},{bottom:.1} {:.1},{bottom:.1}" fill="none" stroke="black"/>"#,
            left + plot_w
        );

        // Categories share the width equally; the x positions are ordinal,
        // which keeps unevenly spaced settings (0, 0.02, ..., 1 m) readable.
        let n = self.categories.len().max(1);
        let slot = plot_w / n as f64;
        let x_of = |i: usize| left + slot * (i as f64 + 0.5);
        for (i, category) in self.categories.iter().enumerate() {
            let _ = writeln!(
                s,
                r#"<line x1="{x:.1}" y1="{bottom:.1}" x2="{x:.1}" y2="{:.1}" stroke="black"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
                bottom + 4.0,
                bottom + 17.0,
                escape(category),
                x = x_of(i)
            );
        }
        let groups = self.group_spans();
        for (g, (label, start, end)) in groups.iter().enumerate() {
            let _ = writeln!(
                s,
                r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#555">{}</text>"##,
                (x_of(*start) + x_of(end - 1)) / 2.0,
                bottom + 34.0,
                escape(label)
            );
            if g > 0 {
                let x = left + slot * *start as f64;
                let _ = writeln!(
                    s,
                    r##"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{:.1}" stroke="#999" stroke-dasharray="4 3"/>"##,
                    bottom + 36.0
                );
            }
        }

        match self.kind {
            Kind::Lines => self.draw_lines(s, &groups, &x_of, &y_of),
            Kind::Bars => self.draw_bars(s, slot, &x_of, &y_of),
        }
        self.draw_legend(s, left, bottom + 56.0, plot_w);
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

    fn draw_lines(
        &self,
        s: &mut String,
        groups: &[(String, usize, usize)],
        x_of: &dyn Fn(usize) -> f64,
        y_of: &dyn Fn(f64) -> f64,
    ) {
        for (k, series) in self.series.iter().enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            for (_, start, end) in groups {
                // A gap (None) also breaks the line.
                let mut run: Vec<String> = Vec::new();
                let flush = |run: &mut Vec<String>, s: &mut String| {
                    if run.len() > 1 {
                        let _ = writeln!(
                            s,
                            r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="2"/>"#,
                            run.join(" ")
                        );
                    }
                    run.clear();
                };
                for i in *start..*end {
                    match series.values.get(i).copied().flatten() {
                        Some(v) => run.push(format!("{:.1},{:.1}", x_of(i), y_of(v))),
                        None => flush(&mut run, s),
                    }
                }
                flush(&mut run, s);
            }
            for (i, v) in series.values.iter().enumerate() {
                if let Some(v) = v {
                    let _ = writeln!(
                        s,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="3.5" fill="{colour}"><title>{}: {}</title></circle>"#,
                        x_of(i),
                        y_of(*v),
                        escape(&series.name),
                        format_value(*v)
                    );
                }
            }
        }
    }

    fn draw_bars(
        &self,
        s: &mut String,
        slot: f64,
        x_of: &dyn Fn(usize) -> f64,
        y_of: &dyn Fn(f64) -> f64,
    ) {
        let count = self.series.len().max(1) as f64;
        let bar = (slot * 0.7 / count).min(60.0);
        let zero = y_of(0.0);
        for (k, series) in self.series.iter().enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            for (i, v) in series.values.iter().enumerate() {
                let Some(v) = v else { continue };
                let x = x_of(i) - bar * count / 2.0 + bar * k as f64;
                let y = y_of(*v);
                let _ = writeln!(
                    s,
                    r#"<rect x="{x:.1}" y="{y:.1}" width="{:.1}" height="{:.1}" fill="{colour}"><title>{}: {}</title></rect>"#,
                    bar - 2.0,
                    zero - y,
                    escape(&series.name),
                    format_value(*v)
                );
                // The value itself, so close bars can still be told apart.
                let _ = writeln!(
                    s,
                    r#"<text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="11">{}</text>"#,
                    x + (bar - 2.0) / 2.0,
                    y - 4.0,
                    format_value(*v)
                );
            }
        }
    }

    fn draw_legend(&self, s: &mut String, left: f64, y: f64, width: f64) {
        // A lone series is named by the panel's title already.
        if self.series.len() < 2 {
            return;
        }
        // Entries laid out left to right, each as wide as its text needs
        // (about 7 px per character at this font size).
        let widths: Vec<f64> = self
            .series
            .iter()
            .map(|series| 22.0 + 7.0 * series.name.chars().count() as f64 + 14.0)
            .collect();
        let total: f64 = widths.iter().sum();
        let mut x = left + ((width - total) / 2.0).max(0.0);
        for (k, (series, w)) in self.series.iter().zip(&widths).enumerate() {
            let colour = PALETTE[k % PALETTE.len()];
            let swatch = match self.kind {
                Kind::Lines => format!(
                    r#"<line x1="{x:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="{colour}" stroke-width="2"/><circle cx="{:.1}" cy="{y:.1}" r="3.5" fill="{colour}"/>"#,
                    x + 16.0,
                    x + 8.0
                ),
                Kind::Bars => format!(
                    r#"<rect x="{x:.1}" y="{:.1}" width="14" height="10" fill="{colour}"/>"#,
                    y - 5.0
                ),
            };
            let _ = writeln!(
                s,
                r#"{swatch}<text x="{:.1}" y="{:.1}">{}</text>"#,
                x + 22.0,
                y + 4.0,
                escape(&series.name)
            );
            x += w;
        }
    }
}

/// A tick step of 1, 2 or 5 times a power of ten giving about five ticks,
/// and the axis top: the first tick at or above `max`.
fn nice_axis(max: f64) -> (f64, f64) {
    if max <= 0.0 || !max.is_finite() {
        return (1.0, 1.0);
    }
    let raw = max / 5.0;
    let magnitude = 10f64.powf(raw.log10().floor());
    let step = match raw / magnitude {
        r if r <= 1.0 => magnitude,
        r if r <= 2.0 => 2.0 * magnitude,
        r if r <= 5.0 => 5.0 * magnitude,
        _ => 10.0 * magnitude,
    };
    let top = (max / step).ceil() * step;
    (step, if top > 0.0 { top } else { step })
}

/// Decimals needed to print multiples of `step` exactly.
fn tick_decimals(step: f64) -> usize {
    (-step.log10().floor()).max(0.0) as usize
}

/// A value for a tooltip: three significant digits or so.
fn format_value(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
