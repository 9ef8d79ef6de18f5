//! The figures and the `--html` report of `retrocomp fit`: the axis fit (measured deviations per
//! direction against the fitted curve over position, mm) and the context fit (the error signal
//! against the fitted thermal/load terms over time, s), each with its numbers beside the plot,
//! drawn with the shared chart. Deviations and errors are actual − nominal, µm.

use std::path::Path;

use anyhow::Context;
use retrocomp_analysis::chart::{self, PALETTE};
use retrocomp_analysis::fit::workflow::{AxisFit, ContextFit, source_values};
use retrocomp_analysis::html::{Block, Section};
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_analysis::report::{Series, xy_svg_notes};
use retrocomp_analysis::table::Direction;
use retrocomp_model::ComponentId;
use retrocomp_model::recording::Recording;

/// Points per series of a time plot at most.
const MAX_POINTS: usize = 3000;

/// The axis fit's numbers, as printed beside its figure and in the report's table.
fn axis_numbers(fit: &AxisFit) -> Vec<String> {
    let mut n = vec![
        format!("fit rms = {:.3} µm", fit.fit_rms_um),
        format!(
            "knots: {} forward, {} reverse",
            fit.forward.knots_mm.len(),
            fit.reverse.knots_mm.len()
        ),
    ];
    match &fit.heldout {
        Some(h) => {
            n.push(format!("held-out δ = {:.1} %", 100.0 * h.delta));
            n.push(format!("max residual = {:.2} µm", h.max_residual_um));
        }
        None => n.push("no held-out run: δ not computed".into()),
    }
    n
}

/// The axis fit's figure: measured deviations of each direction as markers and the fitted curve
/// across the measured targets.
pub(crate) fn axis_svg(
    id: ComponentId,
    rs: &[Reading],
    fit: &AxisFit,
    targets: &[f64],
) -> anyhow::Result<String> {
    let (lo, hi) = (
        targets.iter().cloned().fold(f64::INFINITY, f64::min),
        targets.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    );
    let mut series = Vec::new();
    for (d, name, col) in [
        (Direction::Forward, "forward", PALETTE[0]),
        (Direction::Reverse, "reverse", PALETTE[1]),
    ] {
        let pq = if d == Direction::Forward {
            &fit.forward
        } else {
            &fit.reverse
        };
        series.push(
            Series::markers(
                &format!("measured {name}"),
                rs.iter()
                    .filter(|r| r.direction == d)
                    .map(|r| (r.target_mm, r.deviation_um))
                    .collect(),
            )
            .with_colour(col),
        );
        series.push(
            Series::line(
                &format!("fit {name}"),
                (0..=200)
                    .map(|i| lo + (hi - lo) * f64::from(i) / 200.0)
                    .map(|x| (x, pq.eval(x)))
                    .collect(),
            )
            .with_colour(if d == Direction::Forward {
                PALETTE[9]
            } else {
                PALETTE[3]
            }),
        );
    }
    Ok(xy_svg_notes(
        &format!("{} fit", id.iso_name()),
        "position / mm",
        "deviation (actual − nominal) / µm",
        &series,
        &axis_numbers(fit),
    )?)
}

/// The axis fit's report: the fit's table, its figure, the model written and what was assumed.
pub(crate) fn axis_sections(
    id: ComponentId,
    fit: &AxisFit,
    slope_um_per_run: f64,
    svg: String,
    toml: &str,
) -> Vec<Section> {
    let knots = |k: &[f64]| {
        k.iter()
            .map(|v| format!("{v:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut rows = vec![
        vec!["component".into(), id.iso_name()],
        vec!["forward knots / mm".into(), knots(&fit.forward.knots_mm)],
        vec!["reverse knots / mm".into(), knots(&fit.reverse.knots_mm)],
        vec!["fit rms / µm".into(), format!("{:.3}", fit.fit_rms_um)],
        vec![
            "drift removed / µm per run".into(),
            format!("{slope_um_per_run:.3}"),
        ],
    ];
    match (&fit.heldout, fit.heldout_run) {
        (Some(h), run) => {
            rows.push(vec![
                "held-out run".into(),
                run.map_or("?".into(), |r| r.to_string()),
            ]);
            rows.push(vec![
                "held-out δ / %".into(),
                format!("{:.1}", 100.0 * h.delta),
            ]);
            rows.push(vec![
                "held-out max residual / µm".into(),
                format!("{:.2}", h.max_residual_um),
            ]);
        }
        (None, _) => rows.push(vec!["held-out run".into(), "none: δ not computed".into()]),
    }
    let assumed = vec![
        "deviation = actual − target position (µm), per approach direction".into(),
        "piecewise-quadratic fit per direction, knots kept at the given significance (Spaan)"
            .into(),
        "δ = 1 − Σ|Δm − Δs| / Σ|Δm| on the held-out run only (Spaan)".into(),
    ];
    sections(
        rows,
        svg,
        format!(
            "{}: measured deviations and the fitted curve per direction",
            id.iso_name()
        ),
        toml,
        assumed,
    )
}

/// Measured (less the base model's prediction when fitting the residual) against the fitted terms
/// over time.
pub(crate) fn context_svg(
    rec: &Recording,
    f: &ContextFit,
    base_um: Option<&[f64]>,
) -> anyhow::Result<String> {
    let t = rec.t_s();
    let mut y = rec.col(&f.signal).context("signal")?.to_vec();
    if let Some(b) = base_um {
        y.iter_mut().zip(b).for_each(|(y, b)| *y -= b);
    }
    let pred = f
        .model
        .predict(t, &|n: &str| source_values(rec, n))
        .context("prediction")?;
    let label = if base_um.is_some() {
        "measured − base model"
    } else {
        "measured"
    };
    let series = [
        Series::line(label, chart::thinned(t, &y, MAX_POINTS)).with_colour(PALETTE[7]),
        Series::line("model", chart::thinned(t, &pred, MAX_POINTS)).with_colour(PALETTE[1]),
    ];
    let notes = vec![
        format!("held-out δ = {:.1} %", 100.0 * f.heldout.delta),
        format!("max residual = {:.2} µm", f.heldout.max_residual_um),
        format!("terms chosen: {}", f.model.terms.len()),
    ];
    Ok(xy_svg_notes(
        &format!("{}: measured and model", f.signal),
        "time / s",
        "error (actual − nominal) / µm",
        &series,
        &notes,
    )?)
}

/// The context fit's report: the selection path and the chosen terms, the figure, the model and
/// what was assumed.
pub(crate) fn context_sections(
    f: &ContextFit,
    residual: bool,
    svg: String,
    toml: &str,
) -> Vec<Section> {
    let mut rows = vec![
        vec!["signal".into(), f.signal.clone()],
        vec![
            "criterion".into(),
            format!(
                "{:?}, chosen p = {}",
                f.selection.criterion, f.selection.chosen_p
            ),
        ],
        vec![
            "intercept / µm".into(),
            format!("{:.3}", f.model.intercept_um),
        ],
    ];
    for t in &f.model.terms {
        let lag = match t.tau_s > 0.0 {
            true => format!(" (lag {} s)", t.tau_s),
            false => String::new(),
        };
        rows.push(vec![
            format!("{}{lag} / µm per unit", t.signal),
            format!("{:.4}", t.coef),
        ]);
    }
    rows.push(vec!["held out".into(), f.heldout_rule.clone()]);
    rows.push(vec![
        "held-out δ / %".into(),
        format!("{:.1}", 100.0 * f.heldout.delta),
    ]);
    rows.push(vec![
        "held-out max residual / µm".into(),
        format!("{:.2}", f.heldout.max_residual_um),
    ]);
    let mut assumed = vec![
        "error = actual − nominal (µm); sources are the recording's columns (docs/recording-csv.md)"
            .into(),
        "terms chosen by best subsets on the training rows; δ scored on the held-out rows only"
            .into(),
    ];
    if residual {
        assumed.push("fitted what the base model leaves (signal − base model's error)".into());
    }
    if f.model_rows == "all" {
        assumed.push("the written model was chosen again on every row".into());
    }
    let mut s = sections(
        rows,
        svg,
        format!(
            "{}: the error signal and the fitted terms over time",
            f.signal
        ),
        toml,
        assumed,
    );
    s.insert(
        1,
        Section {
            heading: "Selection path".into(),
            blocks: vec![Block::Table {
                head: ["p", "SSE", "Cp", "BIC", "signals"]
                    .map(String::from)
                    .to_vec(),
                rows: f
                    .selection
                    .path
                    .iter()
                    .map(|st| {
                        vec![
                            st.p.to_string(),
                            format!("{:.3}", st.sse),
                            format!("{:.1}", st.cp),
                            format!("{:.1}", st.bic),
                            st.signals.join(", "),
                        ]
                    })
                    .collect(),
            }],
        },
    );
    s
}

fn sections(
    rows: Vec<Vec<String>>,
    svg: String,
    caption: String,
    toml: &str,
    assumed: Vec<String>,
) -> Vec<Section> {
    vec![
        Section {
            heading: "Fit".into(),
            blocks: vec![Block::Table {
                head: vec!["quantity".into(), "value".into()],
                rows,
            }],
        },
        Section {
            heading: "Figure".into(),
            blocks: vec![Block::Figure { svg, caption }],
        },
        Section {
            heading: "Model written".into(),
            blocks: vec![Block::Pre(toml.to_string())],
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(assumed)],
        },
    ]
}

/// The input files a fit names: the data and, when given, the base model.
pub(crate) fn inputs<'a>(data: &'a Path, base: Option<&'a Path>) -> Vec<&'a Path> {
    std::iter::once(data).chain(base).collect()
}
