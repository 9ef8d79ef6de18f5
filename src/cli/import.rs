//! `retrocomp import FILE [--format laser|fanuc|linuxcnc|isg] [--out table.csv] [--json] [--svg OUT]`
//!
//! Reads measurement or controller files into the toolkit's bidirectional table CSV
//! (`position_mm,forward_um,reverse_um`, error = actual − nominal). Laser runs are averaged per
//! target and direction; a Fanuc tape gives one table per axis (`--axis`).

use std::path::PathBuf;

use anyhow::Context;
use retrocomp_analysis::export::{fanuc, isg, linuxcnc};
use retrocomp_analysis::iso230_2::{self, runs_per_direction};
use retrocomp_analysis::report::{Series, xy_svg};
use retrocomp_analysis::table::BidirectionalTable;

use super::util::{emit, read, table_csv, write};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Format {
    Laser,
    Fanuc,
    Linuxcnc,
    Isg,
}

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The file to read: laser runs CSV, Fanuc pitch tape, LinuxCNC comp file or ISG table.
    pub file: PathBuf,
    /// What FILE is.
    #[arg(long, value_enum, default_value = "laser")]
    pub format: Format,
    /// Remove linear drift across runs (laser format).
    #[arg(long)]
    pub remove_drift: bool,
    /// Fanuc: axis number (`A<n>`) to import.
    #[arg(long, default_value_t = 1)]
    pub axis: u8,
    /// Fanuc: detection unit in µm.
    #[arg(long, default_value_t = 1.0)]
    pub detection_unit_um: f64,
    /// Fanuc: machine position of the reference point, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub ref_position_mm: f64,
    /// LinuxCNC: COMP_FILE_TYPE (0 = actual positions, 1 = nominal − actual).
    #[arg(long, default_value_t = 0)]
    pub comp_type: u8,
    /// Write the table CSV (position_mm,forward_um,reverse_um) here (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print a JSON summary (and the table) instead of the CSV.
    #[arg(long)]
    pub json: bool,
    /// Write the imported table (error per direction against position) as an SVG chart.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    let name = a.file.display().to_string();
    let text = read(&a.file)?;
    let mut summary =
        serde_json::json!({ "file": name, "format": format!("{:?}", a.format).to_lowercase() });
    let table: BidirectionalTable = match a.format {
        Format::Laser => {
            let (rs, slope) = super::iso230_2::load(&a.file, a.remove_drift)?;
            let rep = iso230_2::evaluate(&rs)?;
            summary["readings"] = rs.len().into();
            summary["runs_per_direction"] = serde_json::to_value(runs_per_direction(&rs))?;
            summary["drift_removed_um_per_run"] = slope.into();
            iso230_2::mean_table(&rep)
        }
        Format::Fanuc => {
            let axes = fanuc::read_tape(&name, &text)?;
            let ax = axes
                .iter()
                .find(|x| x.axis == a.axis)
                .with_context(|| format!("{name}: no axis A{} in the tape", a.axis))?;
            summary["cumulative_sum_units"] = fanuc::cumulative_sum(ax).into();
            summary["backlash_1851_units"] = ax.p1851_backlash_units.into();
            summary["points"] = ax.values.len().into();
            fanuc::from_fanuc(ax, a.detection_unit_um, a.ref_position_mm)?
        }
        Format::Linuxcnc => {
            let kind = match a.comp_type {
                0 => linuxcnc::CompFileType::Actual,
                1 => linuxcnc::CompFileType::Offset,
                k => anyhow::bail!("--comp-type must be 0 or 1, found {k}"),
            };
            linuxcnc::read_comp(&name, &text, kind)?
        }
        Format::Isg => {
            let m = isg::read_isg(&name, &text)?;
            let k = ['X', 'Y', 'Z']
                .iter()
                .position(|c| *c == m.axis)
                .unwrap_or(0);
            summary["axis"] = m.axis.to_string().into();
            summary["note"] = format!("positioning component E{0}{0} only", m.axis).into();
            BidirectionalTable::unidirectional(
                m.positions_mm.clone(),
                m.translations_um[k].clone(),
            )?
        }
    };
    if a.json {
        summary["table"] = serde_json::to_value(&table)?;
        println!("{}", serde_json::to_string_pretty(&summary)?);
        if let Some(p) = &a.out {
            write(p, &table_csv(&table))?;
        }
    } else {
        emit(a.out.as_deref(), &table_csv(&table))?;
    }
    if let Some(p) = &a.svg {
        let pts = |v: &[f64]| {
            table
                .positions_mm
                .iter()
                .cloned()
                .zip(v.iter().cloned())
                .collect::<Vec<_>>()
        };
        let series = [
            Series::line("forward", pts(&table.forward_um)),
            Series::line("reverse", pts(&table.reverse_um)),
        ];
        write(
            p,
            &xy_svg(
                &format!("imported {name}"),
                "position_mm",
                "error_um (actual − nominal)",
                &series,
            )?,
        )?;
    }
    Ok(())
}
