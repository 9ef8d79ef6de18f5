//! SVG plots of a diagnosis (plotters, SVG backend): per error signal, the residual before and after
//! each finding against own/other positions, time and the first temperature channel.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::{DiagnoseError, Diagnosis};

/// plotters' errors carry no source: their message is the whole story.
fn plot_err(e: impl std::fmt::Display) -> DiagnoseError {
    DiagnoseError::Plot(e.to_string())
}

fn minmax(v: &[f64]) -> (f64, f64) {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if hi > lo {
        (lo, hi)
    } else {
        (lo - 1.0, hi + 1.0)
    }
}

/// One scatter plot: residual series (label, values) against `x`. Long series are thinned to ≤ 4000
/// points (evenly) so the SVG stays small.
fn scatter(
    path: &Path,
    title: &str,
    x_name: &str,
    x: &[f64],
    series: &[(String, &[f64])],
) -> Result<(), DiagnoseError> {
    let root = SVGBackend::new(path, (900, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    let (x0, x1) = minmax(x);
    let all: Vec<f64> = series.iter().flat_map(|(_, v)| v.iter().copied()).collect();
    let (y0, y1) = minmax(&all);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(x_name)
        .y_desc("residual (µm)")
        .draw()
        .map_err(plot_err)?;
    let stride = (x.len() / 4000).max(1);
    let colors = [RGBColor(150, 150, 150), BLUE, RED, GREEN, MAGENTA];
    for (k, (label, v)) in series.iter().enumerate() {
        let c = colors[k % colors.len()];
        chart
            .draw_series(
                x.iter()
                    .zip(v.iter())
                    .step_by(stride)
                    .map(|(a, b)| Circle::new((*a, *b), 2, c.filled())),
            )
            .map_err(plot_err)?
            .label(label.as_str())
            .legend(move |(px, py)| Circle::new((px + 8, py), 3, c.filled()));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
}

pub fn write_plots(d: &Diagnosis, dir: &Path) -> Result<Vec<PathBuf>, DiagnoseError> {
    let ctx = &d.context;
    let mut feats: Vec<(String, &[f64])> = ctx
        .axes
        .iter()
        .enumerate()
        .filter_map(|(k, f)| {
            f.as_ref()
                .map(|f| (format!("{}_mm", ['x', 'y', 'z'][k]), &f.pos_mm[..]))
        })
        .collect();
    feats.push(("t_s".into(), &ctx.t_s[..]));
    if let Some((name, t)) = ctx.temps.first() {
        feats.push((name.clone(), &t[..]));
    }
    let mut out = vec![];
    for s in &d.signals {
        let after = s.residual_after(ctx);
        let mut series: Vec<(String, &[f64])> = vec![("before".into(), &s.residual_before)];
        for (k, r) in after.iter().enumerate() {
            series.push((format!("after {}", s.models[k].id()), r));
        }
        for (name, x) in &feats {
            let p = dir.join(format!("residual_{}_vs_{}.svg", s.signal, name));
            scatter(
                &p,
                &format!("{} residual vs {}", s.signal, name),
                name,
                x,
                &series,
            )?;
            out.push(p);
        }
    }
    Ok(out)
}
