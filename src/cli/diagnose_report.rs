//! `retrocomp diagnose --html OUT`: the diagnosis as one self-contained report. Consumes
//! [`retrocomp_analysis::diagnose::Diagnosis`] only (its report and per-signal residuals); the figures are
//! those of `diagnose --out` ([`retrocomp_analysis::diagnose::plots`]): residual before the findings and
//! after all of them, against time and against the signal's own axis position.

use retrocomp_analysis::diagnose::{Diagnosis, plots};
use retrocomp_analysis::html::{Block, Section};

fn figures(d: &Diagnosis) -> anyhow::Result<Vec<Block>> {
    let ctx = &d.context;
    let mut out = vec![];
    for s in &d.signals {
        let after = s.residual_after(ctx);
        // Against time and against the signal's own axis position.
        let own = format!("{} position / mm", s.axis);
        for (_, x_label, x) in plots::features(d)
            .into_iter()
            .filter(|(_, l, _)| l == "time / s" || *l == own)
        {
            let svg = plots::before_after_svg(s, &after, &x_label, x)?;
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
