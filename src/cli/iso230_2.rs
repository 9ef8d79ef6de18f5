//! `retrocomp iso230-2 FILE.csv [--json] [--svg OUT] [--remove-drift]`

use std::path::PathBuf;

use retrocomp::analysis::iso230_2::{self, Reading};
use retrocomp::analysis::laser_import::{parse_readings, remove_linear_drift};
use retrocomp::analysis::report::{Series, xy_svg};
use retrocomp::analysis::table::Direction;

use super::util::{read, write};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Laser runs: `target_mm,run,direction,deviation_um` or `target_mm,run1_fwd_um,run1_rev_um,…`.
    pub file: PathBuf,
    /// Print the report as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write an SVG plot of the mean deviations and ±2s bands.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Remove a linear drift across runs (cycles) before evaluating (Spaan Ch3).
    #[arg(long)]
    pub remove_drift: bool,
}

pub(crate) fn load(
    file: &std::path::Path,
    remove_drift: bool,
) -> anyhow::Result<(Vec<Reading>, f64)> {
    let text = read(file)?;
    let mut rs = parse_readings(&file.display().to_string(), &text)?;
    let slope = if remove_drift {
        remove_linear_drift(&mut rs)
    } else {
        0.0
    };
    Ok((rs, slope))
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    let (rs, slope) = load(&a.file, a.remove_drift)?;
    let rep = iso230_2::evaluate(&rs)?;
    if a.json {
        let mut v = serde_json::to_value(&rep)?;
        v["drift_removed_um_per_run"] = serde_json::json!(slope);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print!("{}", iso230_2::to_text(&rep));
        if a.remove_drift {
            println!("drift removed: {slope:.3} µm per run");
        }
    }
    if let Some(p) = &a.svg {
        let mut series = vec![
            Series::line(
                "x̄↑ (forward)",
                rep.targets
                    .iter()
                    .map(|t| (t.target_mm, t.mean_up_um))
                    .collect(),
            ),
            Series::line(
                "x̄↓ (reverse)",
                rep.targets
                    .iter()
                    .map(|t| (t.target_mm, t.mean_down_um))
                    .collect(),
            ),
        ];
        for (name, dir) in [
            ("readings ↑", Direction::Forward),
            ("readings ↓", Direction::Reverse),
        ] {
            series.push(Series::markers(
                name,
                rs.iter()
                    .filter(|r| r.direction == dir)
                    .map(|r| (r.target_mm, r.deviation_um))
                    .collect(),
            ));
        }
        let title = format!(
            "{}: E = {:.2} µm, B = {:.2} µm",
            rep.standard, rep.axis.e_um, rep.axis.b_um
        );
        write(
            p,
            &xy_svg(
                &title,
                "target_mm",
                "deviation_um (actual − target)",
                &series,
            )?,
        )?;
    }
    Ok(())
}
