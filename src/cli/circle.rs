//! `retrocomp circle FILE.csv --radius-mm R --feed-mm-min F [--cyclic-period-x-mm P] [--json] [--svg OUT]`
//!
//! FILE.csv: `angle_deg,dr_um,direction` with direction `ccw` or `cw`, rows in sampling order;
//! dr_um = measured radius − nominal radius (ballbar reading).

use std::path::PathBuf;

use crate::analysis::circular::{self, CircleSetup, CircleTrace, Rotation};
use crate::analysis::import_error::ErrorSink;
use crate::analysis::report::{Series, xy_svg};

use super::util::{read, write};

#[derive(Debug, clap::Args)]
pub struct Args {
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

pub fn parse_traces(
    file: &str,
    text: &str,
) -> Result<Vec<CircleTrace>, crate::analysis::import_error::ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut ccw = CircleTrace {
        rotation: Rotation::Ccw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    let mut cw = CircleTrace {
        rotation: Rotation::Cw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    let mut header_seen = false;
    for (i, raw) in text.lines().enumerate() {
        let line = i as u64 + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let f: Vec<&str> = body.split(',').map(str::trim).collect();
        if !header_seen {
            if f != ["angle_deg", "dr_um", "direction"] {
                sink.push(
                    line,
                    None,
                    format!("expected header `angle_deg,dr_um,direction`, found `{body}`"),
                );
                return sink.finish(vec![]);
            }
            header_seen = true;
            continue;
        }
        if f.len() != 3 {
            sink.push(line, None, format!("expected 3 fields, found {}", f.len()));
            continue;
        }
        let a = sink.parse_f64(line, "angle_deg", f[0]);
        let d = sink.parse_f64(line, "dr_um", f[1]);
        let t = match f[2] {
            "ccw" | "CCW" => Some(&mut ccw),
            "cw" | "CW" => Some(&mut cw),
            other => {
                sink.push(
                    line,
                    Some("direction"),
                    format!("expected `ccw` or `cw`, found `{other}`"),
                );
                None
            }
        };
        if let (Some(a), Some(d), Some(t)) = (a, d, t) {
            t.angle_rad.push(a.to_radians());
            t.dr_um.push(d);
        }
    }
    if !header_seen {
        sink.push(0, None, "empty file");
    }
    let traces: Vec<CircleTrace> = [ccw, cw]
        .into_iter()
        .filter(|t| !t.angle_rad.is_empty())
        .collect();
    if traces.is_empty() && sink.is_empty() {
        sink.push(0, None, "no data rows");
    }
    sink.finish(traces)
}

pub fn run(a: &Args) -> anyhow::Result<()> {
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
