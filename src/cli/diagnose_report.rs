//! `retrocomp diagnose --html OUT`: the diagnosis as one self-contained report. Consumes
//! [`retrocomp::diagnose::Diagnosis`] only (its report and per-signal residuals); the figures are
//! drawn with the shared chart (robust y-limits, legend beside the plot), residual before the
//! findings and after all of them, against time and against the signal's own axis position.

use retrocomp::analysis::chart::PALETTE;
use retrocomp::analysis::html::{Block, Section};
use retrocomp::analysis::report::{Series, xy_svg_notes};
use retrocomp::diagnose::Diagnosis;

/// Points per series in a report figure at most (evenly thinned): a 10⁶-row recording stays a
/// readable, printable page.
const MAX_POINTS: usize = 3000;

fn thinned(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    let stride = x.len().div_ceil(MAX_POINTS).max(1);
    x.iter()
        .zip(y)
        .step_by(stride)
        .map(|(a, b)| (*a, *b))
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn figures(d: &Diagnosis) -> anyhow::Result<Vec<Block>> {
    let ctx = &d.context;
    let mut out = vec![];
    for s in &d.signals {
        let after = s.residual_after(ctx);
        let last = after.last().unwrap_or(&s.residual_before);
        let names: Vec<String> = s.models.iter().map(|m| m.id().to_string()).collect();
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
        let own = ctx.axes[(s.axis as u8).saturating_sub(b'x').min(2) as usize]
            .as_ref()
            .map(|f| (format!("{} position / mm", s.axis), &f.pos_mm[..]));
        let xs = [("time / s".to_string(), &ctx.t_s[..])]
            .into_iter()
            .chain(own);
        for (x_label, x) in xs {
            let series = [
                Series::markers(
                    "residual before the findings",
                    thinned(x, &s.residual_before),
                )
                .with_colour(PALETTE[7]),
                Series::markers("residual after all findings", thinned(x, last))
                    .with_colour(PALETTE[0]),
            ];
            let svg = xy_svg_notes(
                &format!("{} residual (measured − simulated)", s.signal),
                &x_label,
                "residual / µm",
                &series,
                &notes,
            )?;
            out.push(Block::Figure {
                svg,
                caption: format!(
                    "{}: residual before and after the findings against {x_label}; y scale from \
                     the 1–99 % quantiles, points beyond it marked at the edge",
                    s.signal
                ),
            });
        }
    }
    Ok(out)
}

pub(crate) fn sections(d: &Diagnosis) -> anyhow::Result<Vec<Section>> {
    let r = &d.report;
    let rows = r
        .findings
        .iter()
        .map(|f| {
            vec![
                f.effect.clone(),
                f.axis.clone(),
                f.signal.clone(),
                format!("{:.2}", f.rms_after_um),
                format!("{:.2}", f.heldout_rms_before_um),
                format!("{:.2}", f.heldout_rms_after_um),
                format!("{:.1}", f.evidence.delta_bic),
            ]
        })
        .collect();
    Ok(vec![
        Section {
            heading: "Verdict".into(),
            blocks: vec![Block::Para(format!(
                "{} (rms before {:.2} µm)",
                r.verdict, r.rms_before_um
            ))],
        },
        Section {
            heading: "Findings".into(),
            blocks: vec![Block::Table {
                head: [
                    "effect",
                    "axis",
                    "signal",
                    "rms after / µm",
                    "held-out before / µm",
                    "held-out after / µm",
                    "ΔBIC",
                ]
                .map(String::from)
                .to_vec(),
                rows,
            }],
        },
        Section {
            heading: "Figures".into(),
            blocks: figures(d)?,
        },
        Section {
            heading: "Full text report".into(),
            blocks: vec![Block::Pre(r.to_text())],
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(vec![
                "residual = measured − simulated error, µm (recording CSV: docs/recording-csv.md)"
                    .into(),
                "default selection options (significance, held-out blocks) of `diagnose`".into(),
            ])],
        },
    ])
}
