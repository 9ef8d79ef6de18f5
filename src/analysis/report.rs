//! Report helpers shared by the toolkit commands: SVG line/point plots (plotters SVG backend,
//! no TrueType fonts needed: the SVG backend writes `<text>` elements and the viewer renders them).

use plotters::prelude::*;

/// One plotted series.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Draw markers instead of a line.
    pub markers: bool,
}

impl Series {
    pub fn line(name: &str, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.to_string(),
            points,
            markers: false,
        }
    }
    pub fn markers(name: &str, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.to_string(),
            points,
            markers: true,
        }
    }
}

const PALETTE: [RGBColor; 6] = [
    BLUE,
    RED,
    RGBColor(0, 140, 0),
    MAGENTA,
    RGBColor(200, 120, 0),
    BLACK,
];

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

/// Renders an x–y chart to an SVG string. Empty or non-finite data is an error, not a blank plot.
pub fn xy_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<String, PlotError> {
    let pts = || series.iter().flat_map(|s| s.points.iter());
    if pts().next().is_none() {
        return Err(PlotError::Empty(title.to_string()));
    }
    if pts().any(|(x, y)| !x.is_finite() || !y.is_finite()) {
        return Err(PlotError::NonFinite(title.to_string()));
    }
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (x, y) in pts() {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    let pad = |a: f64, b: f64| {
        if (b - a).abs() < 1e-12 {
            1.0
        } else {
            0.05 * (b - a)
        }
    };
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    let mut svg = String::new();
    let mut draw = || -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let root = SVGBackend::with_string(&mut svg, (900, 540)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x0 - px)..(x1 + px), (y0 - py)..(y1 + py))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .draw()?;
        for (i, s) in series.iter().enumerate() {
            let c = PALETTE[i % PALETTE.len()];
            if s.markers {
                chart
                    .draw_series(s.points.iter().map(|p| Circle::new(*p, 3, c.filled())))?
                    .label(s.name.clone())
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, c.filled()));
            } else {
                chart
                    .draw_series(LineSeries::new(s.points.iter().cloned(), c.stroke_width(2)))?
                    .label(s.name.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                    });
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| PlotError::Draw(title.to_string(), e))?;
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn svg_contains_title_axis_labels_and_legend_text() {
        let svg = xy_svg(
            "E = 11.6 µm",
            "target_mm",
            "deviation_um",
            &[
                Series::line("forward", vec![(0.0, 1.0), (10.0, 2.0)]),
                Series::markers("reverse", vec![(0.0, 0.5), (10.0, 1.5)]),
            ],
        )
        .unwrap();
        assert!(svg.starts_with("<svg"));
        for text in [
            "E = 11.6 µm",
            "target_mm",
            "deviation_um",
            "forward",
            "reverse",
        ] {
            assert!(svg.contains(text), "missing `{text}`");
        }
        assert!(svg.contains("<text"));
        assert!(svg.contains("<polyline") || svg.contains("<path"));
        assert!(xy_svg("t", "x", "y", &[Series::line("a", vec![(0.0, f64::NAN)])]).is_err());
        assert!(xy_svg("t", "x", "y", &[]).is_err());
    }
}
