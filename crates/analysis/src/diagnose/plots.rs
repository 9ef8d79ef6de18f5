//! Figures of a diagnosis, drawn with the shared chart (`analysis::chart`: legend and numbers
//! beside the plot, robust y-limits from the residual's own quantiles, outliers marked at the edge,
//! one colour per series). Per error signal and feature (each axis position, mm; time, s; the first
//! temperature, °C):
//! - `residual_<signal>_vs_<feature>.svg`: the residual before the findings and after all of them;
//! - `residual_after_<signal>_vs_<feature>.svg` (with findings): the residual after all findings
//!   alone, on its own scale, with the rms after each finding beside it — what is left, not
//!   flattened by the scale of what was found.
//!
//! Residual = measured − simulated error, µm.

use std::path::{Path, PathBuf};

use super::{DiagnoseError, Diagnosis, SignalResult};
use crate::chart::{self, PALETTE};
use crate::report::{PlotError, Series, xy_svg_notes};

/// Points per series in a figure at most (evenly thinned): a 10⁶-row recording stays a readable,
/// printable page.
pub const MAX_POINTS: usize = 3000;

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// The residual before the findings (grey) and after all of them (blue) against `x`.
pub fn before_after_svg(
    s: &SignalResult,
    after: &[Vec<f64>],
    x_label: &str,
    x: &[f64],
) -> Result<String, PlotError> {
    let last = after.last().unwrap_or(&s.residual_before);
    let names: Vec<&str> = s.models.iter().map(|m| m.id()).collect();
    let notes = vec![
        format!("rms before = {:.2} µm", rms(&s.residual_before)),
        format!("rms after = {:.2} µm", rms(last)),
        format!(
            "findings: {}",
            if names.is_empty() {
                "none".into()
            } else {
                names.join(", ")
            }
        ),
    ];
    let mut series = vec![
        Series::markers(
            "residual before the findings",
            chart::thinned(x, &s.residual_before, MAX_POINTS),
        )
        .with_colour(PALETTE[7]),
    ];
    // Nothing found: "after" would be "before" drawn over it.
    if !after.is_empty() {
        series.push(
            Series::markers(
                "residual after all findings",
                chart::thinned(x, last, MAX_POINTS),
            )
            .with_colour(PALETTE[0]),
        );
    }
    xy_svg_notes(
        &format!("{} residual (measured − simulated)", s.signal),
        x_label,
        "residual / µm",
        &series,
        &notes,
    )
}

/// The residual after all findings alone, on its own scale; the rms after each finding beside it.
fn after_svg(
    s: &SignalResult,
    after: &[Vec<f64>],
    x_label: &str,
    x: &[f64],
) -> Result<Option<String>, PlotError> {
    let Some(last) = after.last() else {
        return Ok(None);
    };
    let mut notes = vec![format!("rms before = {:.2} µm", rms(&s.residual_before))];
    for (m, r) in s.models.iter().zip(after) {
        notes.push(format!("after {}: rms {:.2} µm", m.id(), rms(r)));
    }
    let series = [Series::markers(
        "residual after all findings",
        chart::thinned(x, last, MAX_POINTS),
    )
    .with_colour(PALETTE[0])];
    xy_svg_notes(
        &format!("{} residual after the findings", s.signal),
        x_label,
        "residual / µm",
        &series,
        &notes,
    )
    .map(Some)
}

/// The features a residual is drawn against: (file tag, axis label, values).
pub fn features(d: &Diagnosis) -> Vec<(String, String, &[f64])> {
    let ctx = &d.context;
    let mut feats: Vec<(String, String, &[f64])> = ctx
        .axes
        .iter()
        .zip(['x', 'y', 'z'])
        .filter_map(|(f, a)| {
            f.as_ref().map(|f| {
                (
                    format!("{a}_mm"),
                    format!("{a} position / mm"),
                    &f.pos_mm[..],
                )
            })
        })
        .collect();
    feats.push(("t_s".into(), "time / s".into(), &ctx.t_s[..]));
    if let Some((name, t)) = ctx.temps.first() {
        feats.push((name.clone(), format!("temperature {name} / °C"), &t[..]));
    }
    feats
}

pub fn write_plots(d: &Diagnosis, dir: &Path) -> Result<Vec<PathBuf>, DiagnoseError> {
    let plot_err = |e: PlotError| DiagnoseError::Plot(e.to_string());
    let write = |p: PathBuf, svg: &str| -> Result<PathBuf, DiagnoseError> {
        std::fs::write(&p, svg)
            .map_err(|e| DiagnoseError::Plot(format!("{}: {e}", p.display())))?;
        Ok(p)
    };
    let feats = features(d);
    let mut out = vec![];
    for s in &d.signals {
        let after = s.residual_after(&d.context);
        for (tag, label, x) in &feats {
            let svg = before_after_svg(s, &after, label, x).map_err(plot_err)?;
            out.push(write(
                dir.join(format!("residual_{}_vs_{tag}.svg", s.signal)),
                &svg,
            )?);
            if let Some(svg) = after_svg(s, &after, label, x).map_err(plot_err)? {
                out.push(write(
                    dir.join(format!("residual_after_{}_vs_{tag}.svg", s.signal)),
                    &svg,
                )?);
            }
        }
    }
    Ok(out)
}
