//! `retrocomp circle FILE.csv --radius-mm R --feed-mm-min F [--cyclic-period-x-mm P] [--json] [--svg OUT]`
//!
//! FILE.csv: `angle_deg,dr_um,direction` with direction `ccw` or `cw`, rows in sampling order;
//! dr_um = measured radius − nominal radius (ballbar reading).

use std::path::PathBuf;

use retrocomp::analysis::circular::{self, CircleSetup, parse_traces};
use retrocomp::analysis::report::{Series, xy_svg};

use super::util::{read, write};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    pub file: PathBuf,
    #[arg(long)]
    pub radius_mm: f64,
    #[arg(long)]
    pub feed_mm_min: f64,
    #[arg(long)]
    pub cyclic_period_x_mm: Option<f64>,
    #[arg(long)]
    pub cyclic_period_y_mm: Option<f64>,
    #[arg(long)]
    pub json: bool,
    #[arg(long)]
    pub svg: Option<PathBuf>,
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
        let series: Vec<Series> = traces
            .iter()
            .map(|t| {
                Series::line(
                    &format!("{:?}", t.rotation),
                    t.angle_rad
                        .iter()
                        .map(|r| r.to_degrees())
                        .zip(t.dr_um.iter().cloned())
                        .collect(),
                )
            })
            .collect();
        let g = rep
            .iso230_4
            .g_bidirectional_um
            .or_else(|| rep.iso230_4.g_um.values().next().copied())
            .unwrap_or(0.0);
        write(
            p,
            &xy_svg(
                &format!("circular test R {} mm: G = {g:.2} µm", a.radius_mm),
                "angle_deg",
                "dr_um",
                &series,
            )?,
        )?;
    }
    Ok(())
}
