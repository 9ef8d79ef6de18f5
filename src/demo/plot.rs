//! SVG plots of the demo (plotters, svg backend): per axis, the tool-tip error over time of the
//! four runs, and the volumetric error |e| over time. Error = actual − nominal, µm.

use std::path::Path;

use super::error::{Context as _, DemoError};
use plotters::prelude::*;

use super::RunResult;

const COLOURS: [RGBColor; 4] = [RED, BLUE, RGBColor(0, 140, 0), RGBColor(230, 140, 0)];

/// Writes `error_x.svg`, `error_y.svg`, `error_z.svg` and `volumetric.svg` into `out`.
pub fn write_plots(out: &Path, runs: &[RunResult]) -> Result<(), DemoError> {
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        let series: Vec<(&str, Vec<(f64, f64)>)> = runs
            .iter()
            .map(|r| {
                let pts = r
                    .trace
                    .t_s
                    .iter()
                    .zip(&r.trace.e_um)
                    .map(|(t, e)| (*t, e[k]));
                (r.mode.key(), pts.collect())
            })
            .collect();
        let path = out.join(format!("error_{axis}.svg"));
        chart(&path, &format!("tool-tip error e{axis} (µm)"), &series)
            .with_context(|| format!("plot {}", path.display()))?;
    }
    let series: Vec<(&str, Vec<(f64, f64)>)> = runs
        .iter()
        .map(|r| {
            let pts = r.trace.t_s.iter().zip(&r.trace.e_um);
            let v = pts.map(|(t, e)| (*t, (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt()));
            (r.mode.key(), v.collect())
        })
        .collect();
    let path = out.join("volumetric.svg");
    chart(&path, "volumetric error |e| (µm)", &series)
        .with_context(|| format!("plot {}", path.display()))
}

fn chart(path: &Path, title: &str, series: &[(&str, Vec<(f64, f64)>)]) -> Result<(), DemoError> {
    let pts = series.iter().flat_map(|(_, v)| v.iter());
    let (mut t_max, mut lo, mut hi) = (1e-9f64, 0.0f64, 0.0f64);
    for (t, v) in pts {
        t_max = t_max.max(*t);
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    let root = SVGBackend::new(path, (900, 450)).into_drawing_area();
    root.fill(&WHITE)
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    let mut c = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..t_max, (lo - pad)..(hi + pad))
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    c.configure_mesh()
        .x_desc("t (s)")
        .y_desc("µm")
        .draw()
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    for (i, (name, v)) in series.iter().enumerate() {
        let col = COLOURS[i % COLOURS.len()];
        c.draw_series(LineSeries::new(v.iter().copied(), col))
            .map_err(|e| DemoError::Failed(format!("{e}")))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col));
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    root.present()
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    Ok(())
}
