//! `retrocomp iso230-2 FILE.csv [--json] [--svg OUT] [--html OUT …] [--remove-drift]`

use std::path::PathBuf;

use retrocomp_analysis::iso230_2::{self, Reading};
use retrocomp_analysis::iso230_2_figure;
use retrocomp_analysis::laser_import::{parse_readings, remove_linear_drift};

use super::report_args::ReportArgs;
use super::util::{read, write};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Laser runs: `target_mm,run,direction,deviation_um` or `target_mm,run1_fwd_um,run1_rev_um,…`.
    pub file: PathBuf,
    /// Print the report as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write the ISO 230-2 figure as SVG: forward and reverse mean deviations x̄↑, x̄↓ per target
    /// with their x̄ ± 2s bands (when every target has two or more runs per direction), the
    /// bidirectional mean x̄, every reading, and E, M, B, R, A with their values beside the plot;
    /// axes "target position / mm" and "deviation (actual − target) / µm".
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Title of the figure and the report (e.g. the machine and axis).
    #[arg(long, default_value = "positioning accuracy")]
    pub title: String,
    #[command(flatten)]
    pub report: ReportArgs,
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
    if a.svg.is_none() && a.report.html.is_none() {
        return Ok(());
    }
    let (svg, _) = iso230_2_figure::svg(&a.title, &rep, &rs)?;
    if let Some(p) = &a.svg {
        write(p, &svg)?;
    }
    a.report.write(
        &format!("{} — {}", a.title, rep.standard),
        &[a.file.as_path()],
        || {
            let mut assumed = vec![
                "deviation = actual − target position (µm); ↑ = approached in the positive direction".into(),
                format!("definitions of {} (s with n − 1; R, A need two runs per direction)", rep.standard),
            ];
            assumed.push(if a.remove_drift {
                format!("a linear drift across runs was removed: {slope:.3} µm per run")
            } else {
                "no drift removed (readings as measured)".into()
            });
            Ok(iso230_2_figure::sections(&rep, svg, assumed))
        },
    )
}
