//! `retrocomp export TABLE.csv --format fanuc|linuxcnc|isg [options] [--out FILE] [--json] [--svg OUT]`
//!
//! TABLE.csv is the toolkit table (`position_mm,forward_um,reverse_um`, error = actual − nominal).

use std::path::PathBuf;

use retrocomp_analysis::export::{fanuc, isg, linuxcnc};
use retrocomp_analysis::report::{Series, xy_svg};

use super::util::{emit, read_table, write};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Format {
    Fanuc,
    Linuxcnc,
    Isg,
}

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The toolkit table CSV (position_mm,forward_um,reverse_um; error = actual − nominal).
    pub table: PathBuf,
    /// The controller's format to write.
    #[arg(long, value_enum)]
    pub format: Format,
    /// Fanuc: axis number in the tape.
    #[arg(long, default_value_t = 1)]
    pub axis_number: u8,
    /// Fanuc 3620: point number of the reference position.
    #[arg(long, default_value_t = 100)]
    pub ref_point: u32,
    /// Fanuc: machine position of the reference point, mm.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub ref_position_mm: f64,
    /// Fanuc: point interval, mm.
    #[arg(long, default_value_t = 20.0)]
    pub interval_mm: f64,
    /// Fanuc: detection unit in µm (one tape count).
    #[arg(long, default_value_t = 1.0)]
    pub detection_unit_um: f64,
    /// Fanuc 3623.
    #[arg(long, default_value_t = 1)]
    pub magnification: u32,
    /// Fanuc: largest |value| per point the control accepts.
    #[arg(long, default_value_t = 127)]
    pub max_value: i64,
    /// LinuxCNC COMP_FILE_TYPE (0 = actual positions, 1 = nominal − actual).
    #[arg(long, default_value_t = 0)]
    pub comp_type: u8,
    /// ISG: moving axis letter.
    #[arg(long, default_value = "X")]
    pub axis: char,
    /// Write the controller file here (default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print a JSON summary (with the file's text) instead of the file.
    #[arg(long)]
    pub json: bool,
    /// Write the correction the controller will apply, per direction against position, as SVG.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    let t = read_table(&a.table)?;
    let mut summary =
        serde_json::json!({ "table": a.table.display().to_string(), "points_in": t.len() });
    let text = match a.format {
        Format::Fanuc => {
            let cfg = fanuc::FanucAxisConfig {
                axis: a.axis_number,
                ref_point: a.ref_point,
                ref_position_mm: a.ref_position_mm,
                interval_mm: a.interval_mm,
                detection_unit_um: a.detection_unit_um,
                magnification: a.magnification,
                max_abs_value: a.max_value,
            };
            let ax = fanuc::to_fanuc(&t, &cfg)?;
            summary["p3621"] = ax.p3621_min_point.into();
            summary["p3622"] = ax.p3622_max_point.into();
            summary["p1851"] = ax.p1851_backlash_units.into();
            // The error at the reference point is not in the pitch table: it goes to 1850.
            summary["p1850"] = ax.p1850_ref_shift_units.into();
            summary["p1850_note"] = format!(
                "1850 (grid shift / reference-position shift) = {} detection units: the correction −error at the reference point {} mm, which the pitch table (0 there by definition) cannot carry",
                ax.p1850_ref_shift_units, a.ref_position_mm
            )
            .into();
            summary["cumulative_sum_units"] = fanuc::cumulative_sum(&ax).into();
            fanuc::write_tape(&[ax])
        }
        Format::Linuxcnc => {
            let kind = match a.comp_type {
                0 => linuxcnc::CompFileType::Actual,
                1 => linuxcnc::CompFileType::Offset,
                k => anyhow::bail!("--comp-type must be 0 or 1, found {k}"),
            };
            linuxcnc::write_comp(&t, kind)?
        }
        Format::Isg => {
            let k = ['X', 'Y', 'Z']
                .iter()
                .position(|c| *c == a.axis.to_ascii_uppercase())
                .ok_or_else(|| anyhow::anyhow!("--axis must be X, Y or Z"))?;
            let n = t.len();
            let mut m = isg::AxisErrorMotions {
                axis: a.axis.to_ascii_uppercase(),
                positions_mm: t.positions_mm.clone(),
                ..Default::default()
            };
            for c in 0..3 {
                m.translations_um[c] = if c == k { t.mean_um() } else { vec![0.0; n] };
                m.rotations_urad[c] = vec![0.0; n];
            }
            summary["note"] = "ISG tables are unidirectional: the mean of forward and reverse is written; other components are 0 (not measured)".into();
            isg::write_isg(&m)
        }
    };
    if a.json {
        summary["output"] = text.clone().into();
        println!("{}", serde_json::to_string_pretty(&summary)?);
        if let Some(p) = &a.out {
            write(p, &text)?;
        }
    } else {
        emit(a.out.as_deref(), &text)?;
    }
    if let Some(p) = &a.svg {
        let corr = |v: &[f64]| {
            t.positions_mm
                .iter()
                .cloned()
                .zip(v.iter().map(|e| -e))
                .collect::<Vec<_>>()
        };
        let series = [
            Series::line("correction forward", corr(&t.forward_um)),
            Series::line("correction reverse", corr(&t.reverse_um)),
        ];
        write(
            p,
            &xy_svg(
                "exported correction (−error)",
                "position_mm",
                "correction_um",
                &series,
            )?,
        )?;
    }
    Ok(())
}
