//! SVG plots of the demo, drawn by the project's chart module ([`retrocomp_analysis::chart`]): per
//! axis the tool-tip error over time of the four runs, and the volumetric error |e| over time.
//! Each figure has two panels on one time scale: every run (the uncompensated error sets the
//! scale), then the full and fitted runs alone on their own scale: the headline, which on the
//! first panel is a flat line at 0–2 µm under a 0–55 µm scale. The program's phases (warm-up, cut,
//! cool-down, found in the uncompensated run's recording) are shaded on both panels; the legend and
//! each run's largest |value| sit beside the plot, never over it. Runs are thinned evenly to at
//! most `MAX_POINTS` points per figure, so the report stays a printable page; the largest values
//! beside the plot are the runs' own (unthinned). Error = actual − nominal, µm.

use std::path::Path;

use super::error::{Context as _, DemoError};
use super::{Mode, RunResult};
use retrocomp_analysis::chart::{
    self, Figure, FigureLayout, PALETTE, Panel, Series, XSpan, render_figure,
};

/// Points per run and figure at most (evenly thinned), so the report stays a printable page.
const MAX_POINTS: usize = 3000;

/// One written figure: its file (under the demo's folder), title and SVG.
#[derive(Debug, Clone)]
pub struct DemoFigure {
    pub file: String,
    pub title: String,
    pub svg: String,
}

/// The runs of the second panel: the models that compensate geometry, heat and load.
pub(crate) const DETAIL_RUNS: [Mode; 2] = [Mode::Full, Mode::Fitted];

/// Writes `error_x.svg`, `error_y.svg`, `error_z.svg` and `volumetric.svg` into `out` and returns
/// them (the `--html` report embeds them).
pub(crate) fn write_plots(out: &Path, runs: &[RunResult]) -> Result<Vec<DemoFigure>, DemoError> {
    let mut written = vec![];
    for ((file, svg, _), title) in figures(runs)?.into_iter().zip(titles()) {
        let path = out.join(&file);
        std::fs::write(&path, &svg).with_context(|| format!("plot {}", path.display()))?;
        written.push(DemoFigure { file, title, svg });
    }
    Ok(written)
}

/// The figures' titles, in [`figures`]' order.
fn titles() -> [String; 4] {
    let axis = |a: &str| format!("tool-tip error e{a} (actual − nominal)");
    [
        axis("x"),
        axis("y"),
        axis("z"),
        "volumetric error |e|".to_string(),
    ]
}

/// The four figures: file name, SVG text and where the chart put its panels and phase bands.
pub(crate) fn figures(
    runs: &[RunResult],
) -> Result<Vec<(String, String, FigureLayout)>, DemoError> {
    let mut out = vec![];
    let titles = titles();
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        let max = |r: &RunResult| [r.stats.x, r.stats.y, r.stats.z][k].max_um;
        let (svg, layout) = figure(runs, &titles[k], &format!("e{axis} / µm"), |e| e[k], max)?;
        out.push((format!("error_{axis}.svg"), svg, layout));
    }
    let norm = |e: &[f64; 3]| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
    let max = |r: &RunResult| r.stats.volumetric_max_um;
    let (svg, layout) = figure(runs, &titles[3], "|e| / µm", norm, max)?;
    out.push(("volumetric.svg".to_string(), svg, layout));
    Ok(out)
}

fn colour(mode: Mode) -> plotters::style::RGBColor {
    match mode {
        Mode::Uncompensated => PALETTE[1],
        Mode::Geometric => PALETTE[0],
        Mode::Full => PALETTE[2],
        Mode::Fitted => PALETTE[4],
    }
}

fn figure(
    runs: &[RunResult],
    title: &str,
    y: &str,
    value: impl Fn(&[f64; 3]) -> f64,
    max_of: impl Fn(&RunResult) -> f64,
) -> Result<(String, FigureLayout), DemoError> {
    let series = |r: &RunResult| {
        let v: Vec<f64> = r.trace.e_um.iter().map(&value).collect();
        Series::line(r.mode.key(), chart::thinned(&r.trace.t_s, &v, MAX_POINTS))
            .with_colour(colour(r.mode))
    };
    let all: Vec<Series> = runs.iter().map(series).collect();
    let detail: Vec<Series> = runs
        .iter()
        .filter(|r| DETAIL_RUNS.contains(&r.mode))
        .map(series)
        .collect();
    let mut notes = vec!["largest |value| per run:".to_string()];
    notes.extend(
        runs.iter()
            .map(|r| format!("{} {:.2} µm", r.mode.key(), max_of(r))),
    );
    // Every run plays the same program: the uncompensated run's recording dates the phases.
    let spans: Vec<XSpan> = runs
        .iter()
        .find(|r| r.mode == Mode::Uncompensated)
        .or(runs.first())
        .map(|r| &r.trace.phases[..])
        .unwrap_or_default()
        .iter()
        .map(|p| XSpan {
            name: p.name.to_string(),
            x0: p.from_s,
            x1: p.to_s,
        })
        .collect();
    if !spans.is_empty() {
        notes.push(
            "shaded: warm-up (spindle on), cut (tool below the stock top), cool-down (spindle off)"
                .to_string(),
        );
    }
    let detail_y = format!("{y} (full, fitted)");
    let mut panels = vec![Panel {
        y_label: y,
        series: &all,
        robust_y: false,
    }];
    if !detail.is_empty() {
        panels.push(Panel {
            y_label: &detail_y,
            series: &detail,
            robust_y: false,
        });
    }
    render_figure(&Figure {
        title,
        x_label: "time / s",
        panels: &panels,
        spans: &spans,
        notes: &notes,
    })
    .context("drawing the demo's plots")
}

#[cfg(test)]
#[path = "plot_tests.rs"]
mod tests;
