use super::*;
use crate::chart_geometry::parse;

#[test]
fn robust_limits_ignore_a_few_outliers_but_keep_ordinary_data_whole() {
    // 1000 readings within ±50 µm and five servo-lag spikes at −2700 µm.
    let mut v: Vec<f64> = (0..1000)
        .map(|i| 50.0 * (f64::from(i) * 0.37).sin())
        .collect();
    v.extend([-2700.0; 5]);
    let (lo, hi) = robust_limits(&v);
    assert!(lo > -130.0 && lo < -50.0, "lo {lo}");
    assert!(hi > 50.0 && hi < 60.0, "hi {hi}");
    // Without outliers the limits are the data range padded 5 %.
    let (lo, hi) = robust_limits(&[0.0, 10.0, 5.0]);
    assert!((lo + 0.5).abs() < 1e-9 && (hi - 10.5).abs() < 1e-9);
    assert_eq!(robust_limits(&[]), (-1.0, 1.0));
}

/// Data crowded into the top-right corner, where plotters puts its legend by default.
fn crowded() -> Vec<Series> {
    let mut pts: Vec<(f64, f64)> = (0..200)
        .map(|i| (f64::from(i), (f64::from(i) / 20.0).powi(2)))
        .collect();
    pts.push((150.0, -5000.0));
    vec![
        Series::markers("readings", pts.clone()),
        Series::line_markers("mean", pts.iter().map(|p| (p.0, p.1 + 1.0)).collect()),
        Series::band(
            "mean ± 2s",
            pts.iter().map(|p| (p.0, p.1 - 2.0)).collect(),
            pts.iter().map(|p| (p.0, p.1 + 2.0)).collect(),
        ),
    ]
}

#[test]
fn legend_beside_the_plot_area_covers_no_data_point() {
    let series = crowded();
    let notes = vec!["E = 11.6 µm".to_string()];
    let chart = Chart {
        title: "crowded",
        x_label: "target position / mm",
        y_label: "deviation / µm",
        series: &series,
        notes: &notes,
        robust_y: true,
    };
    let (svg, layout) = render(&chart).unwrap();
    let g = parse(&svg);
    assert_eq!(g.legend_boxes.len(), 1);
    // The box read back from the SVG is the one the layout reports, right of the plot area.
    let b = g.legend_boxes[0];
    assert_eq!(b, layout.legend_px.map(f64::from));
    assert!(layout.legend_px[0] > layout.plot_px[2]);
    // Every data element was drawn (200 markers, 200 line markers, polyline, band polygon) …
    assert!(g.data_points.len() > 600, "{}", g.data_points.len());
    // … and none of it lies in the legend box.
    assert!(g.covered().is_empty(), "covered: {:?}", g.covered());
    // The −5000 outlier does not set the scale; it is counted and marked at the edge.
    assert!(layout.y_range.0 > -100.0, "{:?}", layout.y_range);
    assert!(layout.beyond_scale >= 3, "{}", layout.beyond_scale);
    for text in [
        "target position / mm",
        "deviation / µm",
        "E = 11.6 µm",
        "beyond the scale",
    ] {
        assert!(svg.contains(text), "missing {text}");
    }
}

#[test]
fn geometry_check_sees_a_point_inside_a_legend_box() {
    let svg = r##"<svg><rect x="10" y="10" width="50" height="20" stroke="#555555"/>
        <circle cx="20" cy="15" r="2"/><polyline points="0,0 100,100"/></svg>"##;
    let g = parse(svg);
    assert_eq!(g.covered(), vec![(20.0, 15.0)]);
}

#[test]
fn empty_and_non_finite_data_are_errors() {
    let chart = |s: &'static [Series]| Chart {
        title: "t",
        x_label: "x",
        y_label: "y",
        series: s,
        notes: &[],
        robust_y: false,
    };
    assert!(render(&chart(&[])).is_err());
    let bad = vec![Series::line("a", vec![(0.0, f64::NAN)])];
    let c = Chart {
        series: &bad,
        ..chart(&[])
    };
    assert!(render(&c).is_err());
}
