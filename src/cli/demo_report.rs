//! `retrocomp demo --html OUT`: the demo as one self-contained report: what the fit of the
//! measurement runs found, the tool-tip error table of the four runs (µm, actual − nominal, over
//! the whole program), how the gateway kept up, the four figures and what was assumed.

use retrocomp::demo::{DemoResult, Mode};
use retrocomp_analysis::html::{Block, Section};

fn error_table(r: &DemoResult) -> Block {
    let rows = r
        .runs
        .iter()
        .map(|run| {
            let s = &run.stats;
            let mut row = vec![run.mode.key().to_string()];
            for a in [s.x, s.y, s.z] {
                row.push(format!("{:.2}", a.rms_um));
                row.push(format!("{:.2}", a.max_um));
            }
            row.push(format!("{:.2}", s.volumetric_max_um));
            row
        })
        .collect();
    Block::Table {
        head: [
            "run", "x rms", "x max", "y rms", "y max", "z rms", "z max", "|e| max",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

fn gateway_table(r: &DemoResult) -> Block {
    let rows = r
        .runs
        .iter()
        .filter(|run| run.mode != Mode::Uncompensated)
        .map(|run| {
            let g = &run.gateway;
            vec![
                run.mode.key().to_string(),
                format!("{:.2}", g.not_compensating_s),
                g.not_compensating_episodes.to_string(),
                format!("{:.2}", g.partial_s),
                g.late_cycles.to_string(),
                format!("{:.1}", g.max_late_ms),
            ]
        })
        .collect();
    Block::Table {
        head: [
            "run",
            "not compensating / s",
            "episodes",
            "without load terms / s",
            "late cycles",
            "worst late / ms",
        ]
        .map(String::from)
        .to_vec(),
        rows,
    }
}

pub(crate) fn sections(r: &DemoResult, seed: u64, warmup_s: f64) -> Vec<Section> {
    let figures = r
        .figures
        .iter()
        .map(|f| Block::Figure {
            svg: f.svg.clone(),
            caption: format!(
                "{} ({}); y scale from the 1–99 % quantiles",
                f.title, f.file
            ),
        })
        .collect();
    vec![
        Section {
            heading: "Model fitted from the measurement runs".into(),
            blocks: vec![Block::List(r.fit_report.clone())],
        },
        Section {
            heading: "Tool-tip error (actual − nominal) / µm, whole program".into(),
            blocks: vec![
                error_table(r),
                Block::Para(format!(
                    "max volumetric error falls {:.1} % with the full (truth) model, {:.1} % with \
                     the fitted model",
                    r.stats.volumetric_reduction_pct(),
                    r.stats.fitted_volumetric_reduction_pct()
                )),
            ],
        },
        Section {
            heading: "Gateway".into(),
            blocks: vec![gateway_table(r)],
        },
        Section {
            heading: "Figures".into(),
            blocks: figures,
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(vec![
                "the machine is hil-sim (no hardware): its hidden geometry is models/mill-geometric.toml, \
                 its thermal and load physics are the demo's (docs/demo.md)"
                    .into(),
                format!(
                    "noise seed {seed}; accelerated warm-up {warmup_s} s simulated, then the part program"
                ),
                "uncompensated, geometric and full runs use the truth models; fitted uses the model \
                 fitted from hil-sim's own measurement runs"
                    .into(),
                "error = actual − nominal tool-tip position, µm, every sample of the program".into(),
            ])],
        },
    ]
}
