//! Charts a reader can trust (plotters, SVG backend), shared by every command that draws:
//! - the legend and the figure's numbers (notes) sit in a panel right of the plot area, never over
//!   data; legend swatches are `<rect>` elements, data are `<circle>`, `<polyline>` and `<polygon>`
//!   elements, so a test can check from the SVG alone that nothing of the data lies in the legend box;
//! - robust y-limits ([`robust_limits`]): the scale follows the 1 %–99 % quantiles widened by half
//!   their span, so a few outliers (servo-lag spikes) do not flatten the rest; points beyond the
//!   scale are drawn as triangles at the edge and counted in a note;
//! - one colour per series (a ten-colour palette, or the colour a series asks for);
//! - [`render_figure`]: several panels, each with its own y scale, stacked on one x scale (a
//!   detail panel scaled to the series that matter beside an overview), with x spans (phases)
//!   shaded on every panel and named in a strip above them.
//!
//! Axis labels are the caller's, in words with their unit ("target position / mm").

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Why a chart could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("nothing to plot for `{0}`")]
    Empty(String),
    #[error("non-finite value in plot `{0}`")]
    NonFinite(String),
    #[error("cannot draw plot `{0}`")]
    Draw(String, #[source] Box<dyn std::error::Error + Send + Sync>),
}

/// Size of the whole figure and of the legend panel, px.
pub const WIDTH_PX: u32 = 960;
pub const HEIGHT_PX: u32 = 540;
pub const PANEL_PX: u32 = 260;
/// Stroke of the legend box (the test finds the box by it).
pub const LEGEND_FRAME: RGBColor = RGBColor(0x55, 0x55, 0x55);
/// Lines of more points than this are drawn 1 px wide, not 2: at 2 px thousands of noisy samples
/// make a solid band that hides the curve drawn under it.
const DENSE_LINE_POINTS: usize = 1000;
/// Markers drawn per series at most (evenly thinned beyond), so an SVG of 10⁶ rows stays small.
const MAX_MARKERS: usize = 5000;

/// Ten distinguishable colours (Tableau 10).
pub const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Style {
    Line,
    Markers,
    LineMarkers,
    /// A filled band between `lower` and `points` (the upper edge).
    Band,
}

/// One plotted series.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Lower edge of a [`Style::Band`] (same x as `points`); empty otherwise.
    pub lower: Vec<(f64, f64)>,
    pub style: Style,
    pub colour: Option<RGBColor>,
}

impl Series {
    fn new(name: &str, points: Vec<(f64, f64)>, style: Style) -> Self {
        Self {
            name: name.to_string(),
            points,
            lower: vec![],
            style,
            colour: None,
        }
    }
    pub fn line(name: &str, points: Vec<(f64, f64)>) -> Self {
        Self::new(name, points, Style::Line)
    }
    pub fn markers(name: &str, points: Vec<(f64, f64)>) -> Self {
        Self::new(name, points, Style::Markers)
    }
    pub fn line_markers(name: &str, points: Vec<(f64, f64)>) -> Self {
        Self::new(name, points, Style::LineMarkers)
    }
    pub fn band(name: &str, lower: Vec<(f64, f64)>, upper: Vec<(f64, f64)>) -> Self {
        let mut s = Self::new(name, upper, Style::Band);
        s.lower = lower;
        s
    }
    pub fn with_colour(mut self, c: RGBColor) -> Self {
        self.colour = Some(c);
        self
    }
}

/// What to draw.
#[derive(Debug, Clone, Copy)]
pub struct Chart<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub series: &'a [Series],
    /// Lines printed under the legend (the figure's numbers, assumptions).
    pub notes: &'a [String],
    /// Robust y-limits (quantiles) instead of the full range.
    pub robust_y: bool,
}

/// Where things landed, px in the SVG's coordinates: `[left, top, right, bottom]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    pub plot_px: [i32; 4],
    pub legend_px: [i32; 4],
    pub y_range: (f64, f64),
    /// Points beyond the y scale, drawn as triangles at the edge.
    pub beyond_scale: usize,
}

/// A stretch of x marked on every panel of a [`Figure`] (a phase of a program): a light band behind
/// the data, its name in a strip above the top panel, never over data.
#[derive(Debug, Clone, PartialEq)]
pub struct XSpan {
    pub name: String,
    pub x0: f64,
    pub x1: f64,
}

/// One panel of a [`Figure`]: its own series and y scale.
#[derive(Debug, Clone, Copy)]
pub struct Panel<'a> {
    pub y_label: &'a str,
    pub series: &'a [Series],
    /// Robust y-limits (quantiles) instead of the full range.
    pub robust_y: bool,
}

/// Panels stacked on one x scale (the x label under the bottom one), one legend (each series name
/// once: a name keeps its colour on every panel) and the notes in the side panel.
#[derive(Debug, Clone, Copy)]
pub struct Figure<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub panels: &'a [Panel<'a>],
    pub spans: &'a [XSpan],
    pub notes: &'a [String],
}

/// Where one panel of a [`Figure`] landed, px, and its y scale.
#[derive(Debug, Clone, PartialEq)]
pub struct PanelLayout {
    pub plot_px: [i32; 4],
    pub y_range: (f64, f64),
    pub beyond_scale: usize,
}

/// Where a [`Figure`]'s parts landed, px in the SVG's coordinates: `[left, top, right, bottom]`.
#[derive(Debug, Clone, PartialEq)]
pub struct FigureLayout {
    pub panels: Vec<PanelLayout>,
    pub legend_px: [i32; 4],
    pub x_range: (f64, f64),
    /// Each span's band, from the top of its name's strip to the bottom of the last panel.
    pub spans_px: Vec<[i32; 4]>,
}

/// Height each panel after the first adds to a [`Figure`], and of the span names' strip, px.
pub const PANEL_HEIGHT_PX: u32 = 330;
const STRIP_PX: u32 = 22;
/// Backgrounds of successive spans (light orange, grey, blue): told apart, data still readable.
const SPAN_SHADES: [RGBColor; 3] = [
    RGBColor(0xFD, 0xEB, 0xD3),
    RGBColor(0xE8, 0xE8, 0xE8),
    RGBColor(0xDC, 0xEB, 0xF7),
];

/// At most `max` evenly spaced (x, y) pairs of `x` and `y` (every k-th pair), so a figure of 10⁶
/// rows stays a readable, printable page.
pub fn thinned(x: &[f64], y: &[f64], max: usize) -> Vec<(f64, f64)> {
    let stride = x.len().div_ceil(max.max(1)).max(1);
    x.iter()
        .zip(y)
        .step_by(stride)
        .map(|(a, b)| (*a, *b))
        .collect()
}

/// Quantile `p` of sorted values (nearest rank).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    sorted[crate::numeric::rank(sorted.len(), p)]
}

/// y-limits that show the bulk of `values`: the 1 %–99 % quantiles widened by half their span, never
/// wider than the data, padded 5 %. Non-finite values are ignored; no values give (−1, 1).
pub fn robust_limits(values: &[f64]) -> (f64, f64) {
    let mut v: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if v.is_empty() {
        return (-1.0, 1.0);
    }
    v.sort_by(f64::total_cmp);
    let (q_lo, q_hi) = (quantile(&v, 0.01), quantile(&v, 0.99));
    let span = q_hi - q_lo;
    let lo = v[0].max(q_lo - 0.5 * span);
    let hi = v[v.len() - 1].min(q_hi + 0.5 * span);
    padded(lo, hi)
}

fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if hi - lo < 1e-12 {
        (lo - 1.0, hi + 1.0)
    } else {
        let p = 0.05 * (hi - lo);
        (lo - p, hi + p)
    }
}

fn full_limits(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    padded(lo, hi)
}

/// Splits `s` into lines of at most `width` characters at spaces.
pub fn wrap(s: &str, width: usize) -> Vec<String> {
    let mut out: Vec<String> = vec![];
    let mut cur = String::new();
    for w in s.split_whitespace() {
        if !cur.is_empty() && cur.chars().count() + 1 + w.chars().count() > width {
            out.push(std::mem::take(&mut cur));
        }
        if !cur.is_empty() {
            cur.push(' ');
        }
        cur.push_str(w);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

type DrawResult<T> = Result<T, Box<dyn std::error::Error + Send + Sync>>;

/// Renders `c` to an SVG string and says where the plot area and the legend landed.
pub fn render(c: &Chart<'_>) -> Result<(String, Layout), PlotError> {
    let panel = [Panel {
        y_label: c.y_label,
        series: c.series,
        robust_y: c.robust_y,
    }];
    let (svg, f) = render_figure(&Figure {
        title: c.title,
        x_label: c.x_label,
        panels: &panel,
        spans: &[],
        notes: c.notes,
    })?;
    let p = &f.panels[0];
    Ok((
        svg,
        Layout {
            plot_px: p.plot_px,
            legend_px: f.legend_px,
            y_range: p.y_range,
            beyond_scale: p.beyond_scale,
        },
    ))
}

/// Renders the panels of `f` stacked on one x scale, with one legend and the notes beside them.
pub fn render_figure(f: &Figure<'_>) -> Result<(String, FigureLayout), PlotError> {
    let points = |p: &Panel<'_>| {
        p.series
            .iter()
            .flat_map(|s| s.points.iter().chain(s.lower.iter()))
            .copied()
            .collect::<Vec<_>>()
    };
    let per_panel: Vec<Vec<(f64, f64)>> = f.panels.iter().map(points).collect();
    if per_panel.is_empty() || per_panel.iter().any(Vec::is_empty) {
        return Err(PlotError::Empty(f.title.to_string()));
    }
    let spans_finite = f.spans.iter().all(|s| s.x0.is_finite() && s.x1.is_finite());
    if !spans_finite
        || per_panel
            .iter()
            .flatten()
            .any(|(x, y)| !x.is_finite() || !y.is_finite())
    {
        return Err(PlotError::NonFinite(f.title.to_string()));
    }
    let x_range = full_limits(per_panel.iter().flatten().map(|p| p.0));
    let mut panels = vec![];
    for (p, pts) in f.panels.iter().zip(&per_panel) {
        let (y0, y1) = if p.robust_y {
            robust_limits(&pts.iter().map(|p| p.1).collect::<Vec<_>>())
        } else {
            full_limits(pts.iter().map(|p| p.1))
        };
        panels.push(PanelLayout {
            plot_px: [0; 4],
            y_range: (y0, y1),
            beyond_scale: pts.iter().filter(|p| p.1 < y0 || p.1 > y1).count(),
        });
    }
    let mut notes: Vec<String> = f.notes.to_vec();
    let beyond: usize = panels.iter().map(|p| p.beyond_scale).sum();
    if beyond > 0 {
        notes.push(format!(
            "△ {beyond} point(s) beyond the scale, drawn at its edge"
        ));
    }
    let mut svg = String::new();
    let mut layout = FigureLayout {
        panels,
        legend_px: [0; 4],
        x_range,
        spans_px: vec![],
    };
    draw(&mut svg, f, &mut layout, &notes).map_err(|e| PlotError::Draw(f.title.to_string(), e))?;
    Ok((svg, layout))
}

/// Each distinct series name once (first seen first) with its colour: the series' own, else the
/// palette's by legend position, so a name keeps its colour on every panel.
fn legend_entries<'a>(f: &Figure<'a>) -> Vec<(&'a Series, RGBColor)> {
    let mut out: Vec<(&Series, RGBColor)> = vec![];
    for s in f.panels.iter().flat_map(|p| p.series.iter()) {
        if !out.iter().any(|(e, _)| e.name == s.name) {
            let c = s.colour.unwrap_or(PALETTE[out.len() % PALETTE.len()]);
            out.push((s, c));
        }
    }
    out
}

type Plot<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

fn draw(
    svg: &mut String,
    f: &Figure<'_>,
    layout: &mut FigureLayout,
    notes: &[String],
) -> DrawResult<()> {
    let n = u32::try_from(f.panels.len()).expect("a figure has a handful of panels");
    let height = HEIGHT_PX + (n - 1) * PANEL_HEIGHT_PX;
    let root = SVGBackend::with_string(svg, (WIDTH_PX, height)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(f.title, ("sans-serif", 18))?;
    let (left, side) = root.split_horizontally(WIDTH_PX - PANEL_PX);
    // The spans' names go in a strip above the top panel, where no data is drawn.
    let (strip, stack) = if f.spans.is_empty() {
        (None, left)
    } else {
        let (s, rest) = left.split_vertically(STRIP_PX);
        (Some(s), rest)
    };
    let legend = legend_entries(f);
    let colour = |s: &Series| {
        legend
            .iter()
            .find(|(e, _)| e.name == s.name)
            .map_or(PALETTE[0], |(_, c)| *c)
    };
    let (x0, x1) = layout.x_range;
    let mut spans_px: Vec<[i32; 4]> = vec![];
    for (k, area) in stack.split_evenly((n as usize, 1)).iter().enumerate() {
        let p = &f.panels[k];
        let (y0, y1) = layout.panels[k].y_range;
        let last = k + 1 == n as usize;
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(if last { 45 } else { 28 })
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        let mut mesh = chart.configure_mesh();
        mesh.y_desc(p.y_label).label_style(("sans-serif", 13));
        if last {
            mesh.x_desc(f.x_label);
        }
        mesh.draw()?;
        for (i, s) in f.spans.iter().enumerate() {
            let (a, b) = (s.x0.clamp(x0, x1), s.x1.clamp(x0, x1));
            let shade = SPAN_SHADES[i % SPAN_SHADES.len()].filled();
            chart.draw_series(std::iter::once(Rectangle::new([(a, y0), (b, y1)], shade)))?;
            let (l, t) = chart.backend_coord(&(a, y1));
            let (r, bottom) = chart.backend_coord(&(b, y0));
            match spans_px.get_mut(i) {
                Some(px) => px[3] = bottom,
                None => spans_px.push([l, t, r, bottom]),
            }
        }
        draw_series(&mut chart, p.series, &colour, (y0, y1))?;
        let plot = chart.plotting_area().get_pixel_range();
        layout.panels[k].plot_px = [plot.0.start, plot.1.start, plot.0.end, plot.1.end];
    }
    if let Some(strip) = strip {
        let (sx, sy) = strip.get_pixel_range();
        let style = ("sans-serif", 13)
            .into_font()
            .into_text_style(&strip)
            .pos(Pos::new(HPos::Center, VPos::Center));
        for (s, px) in f.spans.iter().zip(spans_px.iter_mut()) {
            let centre = (px[0] + px[2]) / 2 - sx.start;
            strip.draw(&Text::new(
                s.name.clone(),
                (centre, crate::numeric::px(STRIP_PX) / 2),
                style.clone(),
            ))?;
            px[1] = sy.start;
        }
    }
    layout.spans_px = spans_px;
    layout.legend_px = draw_legend(&side, &legend, notes)?;
    root.present()?;
    Ok(())
}

/// Bands first (under everything), then lines, then markers; points beyond the y scale as
/// triangles at its edge.
fn draw_series(
    chart: &mut Plot<'_, '_>,
    series: &[Series],
    colour: &dyn Fn(&Series) -> RGBColor,
    (y0, y1): (f64, f64),
) -> DrawResult<()> {
    let clamp = |p: &(f64, f64)| (p.0, p.1.clamp(y0, y1));
    let beyond = |p: &&(f64, f64)| p.1 < y0 || p.1 > y1;
    for s in series.iter().filter(|s| s.style == Style::Band) {
        let mut poly: Vec<(f64, f64)> = s.points.iter().map(clamp).collect();
        poly.extend(s.lower.iter().rev().map(clamp));
        let fill = colour(s).mix(0.18).filled();
        chart.draw_series(std::iter::once(Polygon::new(poly, fill)))?;
    }
    for s in series {
        let col = colour(s);
        if matches!(s.style, Style::Line | Style::LineMarkers) {
            let pts: Vec<(f64, f64)> = s.points.iter().map(clamp).collect();
            let width = if s.points.len() > DENSE_LINE_POINTS {
                1
            } else {
                2
            };
            chart.draw_series(LineSeries::new(pts, col.stroke_width(width)))?;
        }
        if matches!(s.style, Style::Markers | Style::LineMarkers) {
            let stride = s.points.len().div_ceil(MAX_MARKERS).max(1);
            let inside = s.points.iter().step_by(stride).filter(|p| !beyond(p));
            let r = if s.style == Style::Markers { 3 } else { 4 };
            chart.draw_series(inside.map(|p| Circle::new(*p, r, col.filled())))?;
        }
        let edge = s
            .points
            .iter()
            .chain(s.lower.iter())
            .filter(beyond)
            .map(|p| TriangleMarker::new(clamp(p), 6, col.filled()));
        chart.draw_series(edge)?;
    }
    Ok(())
}

/// Legend (swatch + name per series) and notes in the side panel; returns the legend box.
fn draw_legend<DB: DrawingBackend>(
    panel: &DrawingArea<DB, plotters::coord::Shift>,
    entries: &[(&Series, RGBColor)],
    notes: &[String],
) -> DrawResult<[i32; 4]>
where
    DB::ErrorType: 'static,
{
    let font = ("sans-serif", 13).into_font();
    let (w, _) = panel.dim_in_pixel();
    let row = 20;
    let mut y = 24;
    for (s, col) in entries {
        let col = *col;
        let swatch = match s.style {
            Style::Line => Rectangle::new([(12, y - 1), (34, y + 2)], col.filled()),
            Style::Markers => Rectangle::new([(19, y - 4), (27, y + 4)], col.filled()),
            Style::LineMarkers => Rectangle::new([(12, y - 2), (34, y + 3)], col.filled()),
            Style::Band => Rectangle::new([(12, y - 6), (34, y + 6)], col.mix(0.18).filled()),
        };
        panel.draw(&swatch)?;
        for (k, line) in wrap(&s.name, 28).iter().enumerate() {
            panel.draw(&Text::new(
                line.clone(),
                (40, y - 7 + crate::numeric::px_count(k) * 15),
                font.clone(),
            ))?;
            if k > 0 {
                y += 15;
            }
        }
        y += row;
    }
    let bottom = y - row + 12;
    panel.draw(&Rectangle::new(
        [(4, 8), (crate::numeric::px(w) - 6, bottom)],
        LEGEND_FRAME.stroke_width(1),
    ))?;
    let mut y = bottom + 22;
    for note in notes {
        for line in wrap(note, 34) {
            panel.draw(&Text::new(line, (8, y - 7), font.clone()))?;
            y += 16;
        }
        y += 4;
    }
    let (px, py) = panel.get_pixel_range();
    Ok([
        px.start + 4,
        py.start + 8,
        px.start + crate::numeric::px(w) - 6,
        py.start + bottom,
    ])
}

#[cfg(test)]
#[path = "chart_tests.rs"]
mod tests;
