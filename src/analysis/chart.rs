//! Charts a reader can trust (plotters, SVG backend), shared by every command that draws:
//! - the legend and the figure's numbers (notes) sit in a panel right of the plot area, never over
//!   data; legend swatches are `<rect>` elements, data are `<circle>`, `<polyline>` and `<polygon>`
//!   elements, so a test can check from the SVG alone that nothing of the data lies in the legend box;
//! - robust y-limits ([`robust_limits`]): the scale follows the 1 %–99 % quantiles widened by half
//!   their span, so a few outliers (servo-lag spikes) do not flatten the rest; points beyond the
//!   scale are drawn as triangles at the edge and counted in a note;
//! - one colour per series (a ten-colour palette, or the colour a series asks for).
//!
//! Axis labels are the caller's, in words with their unit ("target position / mm").

use plotters::prelude::*;

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
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
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
    let all = || {
        c.series
            .iter()
            .flat_map(|s| s.points.iter().chain(s.lower.iter()))
    };
    if all().next().is_none() {
        return Err(PlotError::Empty(c.title.to_string()));
    }
    if all().any(|(x, y)| !x.is_finite() || !y.is_finite()) {
        return Err(PlotError::NonFinite(c.title.to_string()));
    }
    let (x0, x1) = full_limits(all().map(|p| p.0));
    let (y0, y1) = if c.robust_y {
        robust_limits(&all().map(|p| p.1).collect::<Vec<_>>())
    } else {
        full_limits(all().map(|p| p.1))
    };
    let beyond_scale = all().filter(|p| p.1 < y0 || p.1 > y1).count();
    let mut notes: Vec<String> = c.notes.to_vec();
    if beyond_scale > 0 {
        notes.push(format!(
            "△ {beyond_scale} point(s) beyond the scale, drawn at its edge"
        ));
    }
    let mut svg = String::new();
    let layout = draw(&mut svg, c, (x0, x1), (y0, y1), &notes)
        .map_err(|e| PlotError::Draw(c.title.to_string(), e))?;
    Ok((
        svg,
        Layout {
            beyond_scale,
            ..layout
        },
    ))
}

fn colour_of(c: &Chart<'_>, i: usize) -> RGBColor {
    c.series[i].colour.unwrap_or(PALETTE[i % PALETTE.len()])
}

fn draw(
    svg: &mut String,
    c: &Chart<'_>,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    notes: &[String],
) -> DrawResult<Layout> {
    let root = SVGBackend::with_string(svg, (WIDTH_PX, HEIGHT_PX)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(c.title, ("sans-serif", 18))?;
    let (left, panel) = root.split_horizontally(WIDTH_PX - PANEL_PX);
    let mut chart = ChartBuilder::on(&left)
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .x_desc(c.x_label)
        .y_desc(c.y_label)
        .label_style(("sans-serif", 13))
        .draw()?;
    let clamp = |p: &(f64, f64)| (p.0, p.1.clamp(y0, y1));
    let beyond = |p: &&(f64, f64)| p.1 < y0 || p.1 > y1;
    // Bands first (under everything), then lines, then markers.
    for (i, s) in c.series.iter().enumerate() {
        if s.style == Style::Band {
            let col = colour_of(c, i);
            let mut poly: Vec<(f64, f64)> = s.points.iter().map(clamp).collect();
            poly.extend(s.lower.iter().rev().map(clamp));
            chart.draw_series(std::iter::once(Polygon::new(poly, col.mix(0.18).filled())))?;
        }
    }
    for (i, s) in c.series.iter().enumerate() {
        let col = colour_of(c, i);
        if matches!(s.style, Style::Line | Style::LineMarkers) {
            let pts: Vec<(f64, f64)> = s.points.iter().map(clamp).collect();
            chart.draw_series(LineSeries::new(pts, col.stroke_width(2)))?;
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
    let plot = chart.plotting_area().get_pixel_range();
    let legend = draw_legend(&panel, c, notes)?;
    root.present()?;
    Ok(Layout {
        plot_px: [plot.0.start, plot.1.start, plot.0.end, plot.1.end],
        legend_px: legend,
        y_range: (y0, y1),
        beyond_scale: 0,
    })
}

/// Legend (swatch + name per series) and notes in the side panel; returns the legend box.
fn draw_legend<DB: DrawingBackend>(
    panel: &DrawingArea<DB, plotters::coord::Shift>,
    c: &Chart<'_>,
    notes: &[String],
) -> DrawResult<[i32; 4]>
where
    DB::ErrorType: 'static,
{
    let font = ("sans-serif", 13).into_font();
    let (w, _) = panel.dim_in_pixel();
    let row = 20;
    let mut y = 24;
    for (i, s) in c.series.iter().enumerate() {
        let col = colour_of(c, i);
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
                (40, y - 7 + k as i32 * 15),
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
        [(4, 8), (w as i32 - 6, bottom)],
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
        px.start + w as i32 - 6,
        py.start + bottom,
    ])
}

#[cfg(test)]
#[path = "chart_tests.rs"]
mod tests;
