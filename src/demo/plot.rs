//! SVG figures of the demo, drawn with the shared chart (legend and numbers beside the plot, robust
//! y-limits, one colour per run): per axis, the tool-tip error over time of the four runs, and the
//! volumetric error |e| over time. Error = actual − nominal, µm; time in s from the run's start.

use std::path::Path;

use super::RunResult;
use super::error::{Context as _, DemoError};
use crate::analysis::chart;
use crate::analysis::report::{Series, xy_svg_notes};

/// Points per run and figure at most (evenly thinned), so the report stays a printable page.
const MAX_POINTS: usize = 3000;

/// One figure: the file it is written to (under the demo's folder) and its SVG.
#[derive(Debug, Clone)]
pub struct Figure {
    pub file: String,
    pub title: String,
    pub svg: String,
}

fn figure(
    runs: &[RunResult],
    file: &str,
    title: &str,
    y_label: &str,
    abs_name: &str,
    value: impl Fn(&RunResult, &[f64; 3]) -> f64,
    max_of: impl Fn(&RunResult) -> f64,
) -> Result<Figure, DemoError> {
    let mut series = vec![];
    let mut notes = vec![format!("max {abs_name} per run:")];
    for (i, r) in runs.iter().enumerate() {
        let v: Vec<f64> = r.trace.e_um.iter().map(|e| value(r, e)).collect();
        series.push(
            Series::line(r.mode.key(), chart::thinned(&r.trace.t_s, &v, MAX_POINTS))
                .with_colour(chart::PALETTE[i % chart::PALETTE.len()]),
        );
        notes.push(format!("{} {:.2} µm", r.mode.key(), max_of(r)));
    }
    let svg = xy_svg_notes(title, "time / s", y_label, &series, &notes)
        .map_err(|e| DemoError::Failed(format!("plot {file}: {e}")))?;
    Ok(Figure {
        file: file.to_string(),
        title: title.to_string(),
        svg,
    })
}

/// The four figures: `error_x.svg`, `error_y.svg`, `error_z.svg` and `volumetric.svg`.
pub fn figures(runs: &[RunResult]) -> Result<Vec<Figure>, DemoError> {
    let mut out = vec![];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        out.push(figure(
            runs,
            &format!("error_{axis}.svg"),
            &format!("tool-tip error e{axis} of the four runs"),
            &format!("error e{axis} (actual − nominal) / µm"),
            &format!("|e{axis}|"),
            |_, e| e[k],
            |r| [r.stats.x, r.stats.y, r.stats.z][k].max_um,
        )?);
    }
    out.push(figure(
        runs,
        "volumetric.svg",
        "volumetric error |e| of the four runs",
        "volumetric error |e| / µm",
        "|e|",
        |_, e| (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt(),
        |r| r.stats.volumetric_max_um,
    )?);
    Ok(out)
}

/// Writes [`figures`] into `out` and returns them.
pub fn write_plots(out: &Path, runs: &[RunResult]) -> Result<Vec<Figure>, DemoError> {
    let figs = figures(runs)?;
    for f in &figs {
        let path = out.join(&f.file);
        std::fs::write(&path, &f.svg).with_context(|| format!("plot {}", path.display()))?;
    }
    Ok(figs)
}
