//! Report helpers shared by the toolkit commands: SVG line/point plots (plotters SVG backend,
//! no TrueType fonts needed: the SVG backend writes `<text>` elements and the viewer renders them).
//! The drawing itself is [`super::chart`]; this is the short form most commands call.

use super::chart::{Chart, render};
pub use super::chart::{PlotError, Series, Style};

/// Renders an x–y chart to an SVG string ([`super::chart`]: legend and notes beside the plot area,
/// robust y-limits). Empty or non-finite data is an error, not a blank plot.
pub fn xy_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<String, PlotError> {
    xy_svg_notes(title, x_label, y_label, series, &[])
}

/// [`xy_svg`] with lines of text (the figure's numbers) printed under the legend.
pub fn xy_svg_notes(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    notes: &[String],
) -> Result<String, PlotError> {
    let chart = Chart {
        title,
        x_label,
        y_label,
        series,
        notes,
        robust_y: true,
    };
    Ok(render(&chart)?.0)
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
