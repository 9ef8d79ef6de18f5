//! `retrocomp circle FILE.csv --radius-mm R --feed-mm-min F [--cyclic-period-x-mm P] [--json]
//! [--svg POLAR.svg] [--svg-angle ANGLE.svg] [--html OUT …]`
//!
//! FILE.csv: `angle_deg,dr_um,direction` with direction `ccw` or `cw`, rows in sampling order;
//! dr_um = measured radius − nominal radius (ballbar reading).

use std::path::PathBuf;

use retrocomp_analysis::chart::PALETTE;
use retrocomp_analysis::circular::{self, CircleReport, CircleSetup, CircleTrace, parse_traces};
use retrocomp_analysis::html::{Block, Section};
use retrocomp_analysis::polar;
use retrocomp_analysis::report::{Series, xy_svg_notes};

use super::report_args::ReportArgs;
use super::util::{read, write};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Ballbar CSV: `angle_deg,dr_um,direction` (direction ccw or cw; dr = measured − nominal
    /// radius), rows in sampling order.
    pub file: PathBuf,
    /// Nominal radius of the circle, mm.
    #[arg(long)]
    pub radius_mm: f64,
    /// Feed of the test, mm/min.
    #[arg(long)]
    pub feed_mm_min: f64,
    /// Also look for a cyclic error of X with this period (e.g. the ball screw lead), mm.
    #[arg(long)]
    pub cyclic_period_x_mm: Option<f64>,
    /// Also look for a cyclic error of Y with this period (e.g. the ball screw lead), mm.
    #[arg(long)]
    pub cyclic_period_y_mm: Option<f64>,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Write the ISO 230-4 polar plot as SVG: each direction's measured path on a polar grid with
    /// its radial deviation magnified (ring step and magnification printed), start points marked,
    /// G, G(b), H (circular hysteresis) and F beside it; radius and feed in the title.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Write the radial deviation Δr against angle (Cartesian) as SVG, one line per direction.
    #[arg(long)]
    pub svg_angle: Option<PathBuf>,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// Δr against angle, one series per direction, the G values beside it.
fn angle_svg(rep: &CircleReport, traces: &[CircleTrace]) -> anyhow::Result<String> {
    let series: Vec<Series> = traces
        .iter()
        .map(|t| {
            let c = match t.rotation {
                circular::Rotation::Ccw => PALETTE[0],
                circular::Rotation::Cw => PALETTE[1],
            };
            Series::line(
                &format!("{:?}", t.rotation).to_uppercase(),
                t.angle_rad
                    .iter()
                    .map(|r| r.to_degrees())
                    .zip(t.dr_um.iter().cloned())
                    .collect(),
            )
            .with_colour(c)
        })
        .collect();
    let notes: Vec<String> = rep
        .iso230_4
        .g_um
        .iter()
        .map(|(k, g)| format!("G ({k}) = {g:.2} µm"))
        .chain(
            rep.iso230_4
                .g_bidirectional_um
                .map(|g| format!("G(b) = {g:.2} µm")),
        )
        .collect();
    Ok(xy_svg_notes(
        &format!(
            "radial deviation, R = {} mm, F = {} mm/min",
            rep.radius_mm, rep.feed_mm_per_min
        ),
        "angle from +X / °",
        "radial deviation Δr / µm",
        &series,
        &notes,
    )?)
}

fn sections(rep: &CircleReport, traces: &[CircleTrace]) -> anyhow::Result<Vec<Section>> {
    let mut values: Vec<Vec<String>> = polar::notes(rep, traces, 1.0)
        .into_iter()
        .filter(|n| !n.starts_with("error scale"))
        .map(|n| vec![n])
        .collect();
    values.push(vec![format!(
        "radius error {:.2} µm, centre offset ({:.2}, {:.2}) µm",
        rep.radius_error_um, rep.centre_x_um, rep.centre_y_um
    )]);
    let terms = rep
        .terms
        .iter()
        .map(|t| {
            let p: Vec<String> = t
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {v:.3}"))
                .collect();
            vec![
                t.effect.clone(),
                format!("{:.2}", t.contribution_um),
                format!("{:.1}", t.share_pct),
                p.join(", "),
            ]
        })
        .collect();
    Ok(vec![
        Section {
            heading: "Figures".into(),
            blocks: vec![
                Block::Figure {
                    svg: polar::svg(rep, traces)?,
                    caption: "ISO 230-4 polar plot: measured paths with the radial deviation \
                              magnified about the nominal circle (ring step in the notes); \
                              dots mark where each run started."
                        .into(),
                },
                Block::Figure {
                    svg: angle_svg(rep, traces)?,
                    caption: "The same radial deviation against angle.".into(),
                },
            ],
        },
        Section {
            heading: format!("{} values", rep.standard),
            blocks: vec![Block::Table {
                head: vec!["value".into()],
                rows: values,
            }],
        },
        Section {
            heading: "Diagnosis (fitted error sources)".into(),
            blocks: vec![
                Block::Table {
                    head: vec![
                        "effect".into(),
                        "peak-to-valley / µm".into(),
                        "share / %".into(),
                        "parameters".into(),
                    ],
                    rows: terms,
                },
                Block::Para(format!("residual rms {:.3} µm", rep.residual_rms_um)),
            ],
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(vec![
                "Δr = measured − nominal radius (µm), about the nominal centre (ballbar pivot)"
                    .into(),
                "angle from +X towards +Y; X reverses at 0°/180°, Y at 90°/270°".into(),
                "G about the least-squares centre; F about the nominal centre and radius".into(),
                "H: largest CCW − CW radial difference at the same angle (CW interpolated)".into(),
            ])],
        },
    ])
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    let name = a.file.display().to_string();
    let traces = parse_traces(&name, &read(&a.file)?)?;
    let setup = CircleSetup {
        radius_mm: a.radius_mm,
        feed_mm_per_min: a.feed_mm_min,
        cyclic_period_x_mm: a.cyclic_period_x_mm,
        cyclic_period_y_mm: a.cyclic_period_y_mm,
    };
    let rep = circular::analyse(&traces, &setup)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rep)?);
    } else {
        print!("{}", circular::to_text(&rep));
    }
    if let Some(p) = &a.svg {
        write(p, &polar::svg(&rep, &traces)?)?;
    }
    if let Some(p) = &a.svg_angle {
        write(p, &angle_svg(&rep, &traces)?)?;
    }
    a.report.write(
        &format!("{} circular test", rep.standard),
        &[a.file.as_path()],
        || sections(&rep, &traces),
    )
}
