//! `retrocomp fit axis|thermal|load …`: measurements in, machine-model TOML out, with the held-out
//! efficiency δ = 1 − Σ|Δm − Δs| / Σ|Δm| and the max residual (Spaan). Text report by default,
//! `--json` for one JSON object, `--svg` for a measured-vs-model plot.

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::fit_report;
use super::report_args::ReportArgs;
use super::util::write;
use retrocomp_analysis::diagnose::model_sim::{final_lag_state, simulate_axes};
use retrocomp_analysis::fit::lead::check_lead;
use retrocomp_analysis::fit::regression::Criterion;
use retrocomp_analysis::fit::to_model::{
    AxisForm, add_load, add_thermal, axis_component, put_component, single_axis_spec,
    to_checked_toml,
};
use retrocomp_analysis::fit::workflow::{
    AxisFit, ContextFit, ContextOptions, Driver, fit_axis_lead, fit_context_with,
};
use retrocomp_model::parse_component;
use retrocomp_model::{ComponentId, MachineModel, ModelSpec};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(subcommand)]
    pub what: What,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Form {
    /// Forward and reverse tables at the measured targets (keeps the reversal error).
    Table,
    /// One piecewise quadratic, the mean of both directions (reversal dropped).
    Piecewise,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Crit {
    /// Bayesian information criterion (the smallest model that explains the data).
    Bic,
    /// Mallows' Cp (expected prediction error).
    Cp,
    /// The mean of the fits of every size 1…max-terms (for prediction beyond the recording's
    /// regimes; docs/diagnose.md "Compensation model").
    Average,
}

#[derive(Debug, clap::Args)]
pub(crate) struct Common {
    /// Model to extend; without it (axis fits only) a one-axis model is written.
    #[arg(long)]
    pub base_model: Option<PathBuf>,
    /// Where to write the model TOML (default: stdout in text mode).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON object (fit, δ, residuals, the model TOML) instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Write the measured-vs-model figure as SVG (numbers beside the plot).
    #[arg(long)]
    pub svg: Option<PathBuf>,
    #[command(flatten)]
    pub report: ReportArgs,
    /// fit thermal / load: keep going past bad rows of the recording (each listed on stderr, and
    /// under `skipped_rows` with --json) instead of refusing the file.
    #[arg(long)]
    pub skip_bad_rows: bool,
}

#[derive(Debug, clap::Subcommand)]
pub(crate) enum What {
    /// Piecewise-quadratic forward/reverse tables of one component from laser runs (ISO 230-2 CSV).
    Axis {
        /// Laser runs of the axis (CSV, long or wide layout as `retrocomp iso230-2` reads).
        runs: PathBuf,
        /// ISO 230-1 component, e.g. EXX.
        #[arg(long)]
        component: String,
        /// Spacing of the candidate knots across the travel, mm.
        #[arg(long, default_value_t = 50.0)]
        knot_step_mm: f64,
        /// Significance level of a knot (Spaan: 99.99 % → 1e-4).
        #[arg(long, default_value_t = 1e-4)]
        alpha: f64,
        /// Run left out of the fit and used for δ.
        #[arg(long)]
        holdout_run: Option<u32>,
        /// How the fit goes into the model.
        #[arg(long, value_enum, default_value = "table")]
        form: Form,
        /// Remove linear drift across runs before fitting.
        #[arg(long)]
        remove_drift: bool,
        /// Lead of the axis' ball screw, mm: fit a sin/cos pair at this period beside each
        /// direction's piecewise quadratic, report amplitude and phase, and write the table every
        /// lead/16 (targets every ≤ lead/4 separate it; --form table only).
        #[arg(long)]
        lead_mm: Option<f64>,
        #[command(flatten)]
        common: Common,
    },
    /// Thermal regression of an error signal on `T_<name>_C` columns of a recording.
    Thermal {
        /// Recording CSV (docs/recording-csv.md) with the error signal and `T_<name>_C` columns.
        recording: PathBuf,
        /// The error column to explain, e.g. ex_um.
        #[arg(long)]
        signal: String,
        /// Component the term adds to (default from the signal: ex_um → EXX).
        #[arg(long)]
        target: Option<String>,
        /// Lag time constants to try, s (0 = no lag).
        #[arg(long, value_delimiter = ',', default_value = "0")]
        lags_s: Vec<f64>,
        /// Most terms (sensors × lags) the model may use.
        #[arg(long, default_value_t = 4)]
        max_terms: usize,
        /// How the number of terms is chosen.
        #[arg(long, value_enum, default_value = "bic")]
        criterion: Crit,
        /// Values of the `run` column held out for δ (default: last 30 % of samples).
        #[arg(long, value_delimiter = ',')]
        holdout_runs: Vec<u32>,
        /// Context columns that heat the machine with no sensor on them, as COLUMN or
        /// COLUMN^POWER (e.g. `rpm^2`: heat ∝ n²), each entered through the lags of --lags-s > 0.
        #[arg(long, value_delimiter = ',')]
        drivers: Vec<String>,
        /// Fit what the base model leaves (the signal minus the base model's error along the
        /// target's axis, evaluated on the recording), so the written model does not count the
        /// base model's part twice.
        #[arg(long, requires = "base_model")]
        residual: bool,
        /// After scoring δ on the held-out rows, choose and fit again on every row (the written
        /// model; δ still describes the training fit).
        #[arg(long)]
        refit_all: bool,
        #[command(flatten)]
        common: Common,
    },
    /// Load regression of an error signal on `strain_<name>_ue` columns of a recording.
    Load {
        /// Recording CSV (docs/recording-csv.md) with the error signal and `strain_<name>_ue`
        /// columns.
        recording: PathBuf,
        /// The error column to explain, e.g. ez_um.
        #[arg(long)]
        signal: String,
        /// Component the term adds to (default from the signal: ez_um → EZZ).
        #[arg(long)]
        target: Option<String>,
        /// Most terms (strain gauges) the model may use.
        #[arg(long, default_value_t = 2)]
        max_terms: usize,
        /// How the number of terms is chosen.
        #[arg(long, value_enum, default_value = "bic")]
        criterion: Crit,
        /// Values of the `run` column held out for δ (default: last 30 % of samples).
        #[arg(long, value_delimiter = ',')]
        holdout_runs: Vec<u32>,
        #[command(flatten)]
        common: Common,
    },
}

fn component(name: &str) -> anyhow::Result<ComponentId> {
    parse_component(name)
        .with_context(|| format!("`{name}` is not an ISO 230-1 component name (e.g. EXX, EBZ)"))
}

fn default_target(signal: &str) -> anyhow::Result<ComponentId> {
    let a = signal
        .strip_prefix('e')
        .and_then(|s| s.chars().next())
        .filter(|c| "xyz".contains(*c));
    match a {
        Some(c) => component(&format!("E{0}{0}", c.to_ascii_uppercase())),
        None => anyhow::bail!("cannot derive a target from `{signal}`: give --target"),
    }
}

fn base_spec(p: &Path) -> anyhow::Result<ModelSpec> {
    Ok(MachineModel::from_toml_path(p)?.spec().clone())
}

fn finish(
    common: &Common,
    toml: &str,
    report_text: String,
    mut json: serde_json::Value,
) -> anyhow::Result<()> {
    if common.json {
        json["model_toml"] = toml.into();
        println!("{}", serde_json::to_string_pretty(&json)?);
        if let Some(p) = &common.out {
            write(p, toml)?;
        }
    } else {
        match &common.out {
            Some(p) => {
                write(p, toml)?;
                print!("{report_text}");
                println!("model written to {}", p.display());
            }
            None => {
                for l in report_text.lines() {
                    println!("# {l}");
                }
                print!("{toml}");
            }
        }
    }
    Ok(())
}

fn context_text(f: &ContextFit) -> String {
    let mut s = format!(
        "fit of {} ({:?} selection)\n",
        f.signal, f.selection.criterion
    );
    for st in &f.selection.path {
        s.push_str(&format!(
            "  p={} SSE={:.3} Cp={:.1} BIC={:.1} [{}]\n",
            st.p,
            st.sse,
            st.cp,
            st.bic,
            st.signals.join(", ")
        ));
    }
    let how = match (f.selection.criterion, f.model_rows.as_str()) {
        (Criterion::Average, "all") => "mean of sizes 1…max, chosen again on every row",
        (Criterion::Average, _) => "mean of sizes 1…max",
        (_, "all") => "chosen again on every row",
        _ => "",
    };
    s.push_str(&format!(
        "chosen p = {}{}{how}{}: intercept {:.3} µm",
        f.selection.chosen_p,
        if how.is_empty() { "" } else { " (" },
        if how.is_empty() { "" } else { ")" },
        f.model.intercept_um
    ));
    for t in &f.model.terms {
        s.push_str(&format!(
            ", {:.4} µm/unit × {}{}",
            t.coef,
            t.signal,
            if t.tau_s > 0.0 {
                format!(" (lag {} s)", t.tau_s)
            } else {
                String::new()
            }
        ));
    }
    s.push_str(&format!(
        "\nheld out ({}): δ = {:.1} %, max residual {:.2} µm, n = {}\n",
        f.heldout_rule,
        100.0 * f.heldout.delta,
        f.heldout.max_residual_um,
        f.heldout.n
    ));
    s
}

/// The axis fit's text report: the knots, the fit and the drift, then δ on the held-out run.
fn axis_text(id: ComponentId, fit: &AxisFit, slope: f64, holdout_run: Option<u32>) -> String {
    let mut text = format!(
        "{}: forward knots {:?}, reverse knots {:?}, fit rms {:.3} µm, drift removed {:.3} µm/run\n",
        id.iso_name(),
        fit.forward.knots_mm,
        fit.reverse.knots_mm,
        fit.fit_rms_um,
        slope
    );
    match &fit.heldout {
        Some(h) => text.push_str(&format!(
            "held-out run {}: δ = {:.1} %, max residual {:.2} µm\n",
            holdout_run.unwrap_or(0),
            100.0 * h.delta,
            h.max_residual_um
        )),
        None => text.push_str("no held-out run (--holdout-run): δ not computed\n"),
    }
    for w in [&fit.forward.lead, &fit.reverse.lead, &fit.lead]
        .into_iter()
        .flatten()
    {
        text.push_str(&format!("lead wave: {} {}\n", id.iso_name(), w.describe()));
    }
    text
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    match &a.what {
        What::Axis {
            runs,
            component: comp,
            knot_step_mm,
            alpha,
            holdout_run,
            form,
            remove_drift,
            lead_mm,
            common,
        } => {
            let id = component(comp)?;
            let lead_mm = lead_mm
                .map(check_lead)
                .transpose()
                .map_err(anyhow::Error::msg)?;
            anyhow::ensure!(
                !common.skip_bad_rows,
                "--skip-bad-rows applies to recordings (fit thermal, fit load); the ISO 230-2 runs file is read strictly"
            );
            let progress = super::term::Progress::spinner("fit: fitting the axis tables");
            let (rs, slope) = super::iso230_2::load(runs, *remove_drift)?;
            let fit = fit_axis_lead(&rs, *knot_step_mm, *alpha, *holdout_run, lead_mm)?;
            progress.finish();
            let targets: Vec<f64> = rs.iter().map(|r| r.target_mm).collect();
            let f = match form {
                Form::Table => AxisForm::Table,
                Form::Piecewise => AxisForm::Piecewise,
            };
            let c = axis_component(&fit, id, f, &targets)?;
            let mut spec = match &common.base_model {
                Some(p) => base_spec(p)?,
                None => {
                    let lo = targets.iter().cloned().fold(f64::INFINITY, f64::min);
                    let hi = targets.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                    single_axis_spec("fit", id.axis, (lo, hi))
                }
            };
            put_component(&mut spec, c)?;
            let (toml, _) = to_checked_toml(spec)?;
            let text = axis_text(id, &fit, slope, *holdout_run);
            if common.svg.is_some() || common.report.html.is_some() {
                let svg = fit_report::axis_svg(id, &rs, &fit, &targets)?;
                if let Some(p) = &common.svg {
                    write(p, &svg)?;
                }
                let inputs = fit_report::inputs(runs, common.base_model.as_deref());
                common.report.write(
                    &format!("Axis fit of {} from laser runs", id.iso_name()),
                    &inputs,
                    || Ok(fit_report::axis_sections(id, &fit, slope, svg, &toml)),
                )?;
            }
            let json = serde_json::json!({ "component": id.iso_name(), "fit": fit, "drift_removed_um_per_run": slope });
            finish(common, &toml, text, json)
        }
        What::Thermal {
            recording,
            signal,
            target,
            lags_s,
            max_terms,
            criterion,
            holdout_runs,
            drivers,
            residual,
            refit_all,
            common,
        } => run_context(
            true,
            recording,
            signal,
            target.as_deref(),
            &Extra {
                lags: lags_s,
                max_terms: *max_terms,
                criterion: *criterion,
                holdout_runs,
                drivers,
                residual: *residual,
                refit_all: *refit_all,
            },
            common,
        ),
        What::Load {
            recording,
            signal,
            target,
            max_terms,
            criterion,
            holdout_runs,
            common,
        } => run_context(
            false,
            recording,
            signal,
            target.as_deref(),
            &Extra {
                lags: &[0.0],
                max_terms: *max_terms,
                criterion: *criterion,
                holdout_runs,
                drivers: &[],
                residual: false,
                refit_all: false,
            },
            common,
        ),
    }
}

/// The context fit's settings beyond the signal (`fit load` uses only the first four).
struct Extra<'a> {
    lags: &'a [f64],
    max_terms: usize,
    criterion: Crit,
    holdout_runs: &'a [u32],
    /// As given: `rpm^2`, `load`.
    drivers: &'a [String],
    residual: bool,
    refit_all: bool,
}

fn run_context(
    thermal: bool,
    recording: &Path,
    signal: &str,
    target: Option<&str>,
    x: &Extra<'_>,
    common: &Common,
) -> anyhow::Result<()> {
    let drivers = x
        .drivers
        .iter()
        .map(|d| Driver::parse(d).map_err(|e| anyhow::anyhow!("--drivers: {e}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let base = common
        .base_model
        .as_ref()
        .context("--base-model is required: the term needs the model's axes and chain")?;
    let id = match target {
        Some(t) => component(t)?,
        None => default_target(signal)?,
    };
    let progress = super::term::Progress::spinner("fit: reading the recording");
    let (rec, bad) = super::diagnose::read_recording(recording, common.skip_bad_rows)?;
    progress.stage("fit: choosing and fitting the terms");
    let criterion = match x.criterion {
        Crit::Bic => Criterion::Bic,
        Crit::Cp => Criterion::Cp,
        Crit::Average => Criterion::Average,
    };
    let base_model = MachineModel::from_toml_path(base)?;
    // The base model's error along the target component's axis (EZZ → z), whatever the signal
    // is called.
    let base_um = match x.residual {
        true => Some(simulate_axes(&base_model, &rec)?[id.axis.index()].clone()),
        false => None,
    };
    let f = fit_context_with(
        &rec,
        signal,
        &ContextOptions {
            use_temperatures: thermal,
            use_strains: !thermal,
            lags_s: x.lags,
            max_terms: x.max_terms,
            criterion,
            heldout_runs: x.holdout_runs,
            drivers: &drivers,
            base_um: base_um.as_deref(),
            refit_all: x.refit_all,
        },
    )?;
    let mut spec = base_model.spec().clone();
    if thermal {
        let mean = |name: &str| {
            f.means
                .iter()
                .find(|(s, _)| s == name)
                .map_or(0.0, |(_, m)| *m)
        };
        add_thermal(&mut spec, &f, id, &mean)?;
        // Where the lags stand at the recording's last row, so `eval` continues this recording.
        spec.lag_state = final_lag_state(&MachineModel::from_spec(spec.clone()), &rec)?;
    } else {
        add_load(&mut spec, &f, id)?;
    }
    let (toml, _) = to_checked_toml(spec)?;
    progress.finish();
    if common.svg.is_some() || common.report.html.is_some() {
        let svg = fit_report::context_svg(&rec, &f, base_um.as_deref())?;
        if let Some(p) = &common.svg {
            write(p, &svg)?;
        }
        let kind = if thermal { "Thermal" } else { "Load" };
        common.report.write(
            &format!("{kind} fit of {} → {}", f.signal, id.iso_name()),
            &fit_report::inputs(recording, Some(base)),
            || Ok(fit_report::context_sections(&f, x.residual, svg, &toml)),
        )?;
    }
    let mut json = serde_json::json!({ "target": id.iso_name(), "fit": f });
    let mut text = context_text(&f);
    if common.skip_bad_rows {
        json["skipped_rows"] = super::diagnose::skipped_rows_json(&bad);
        text.push_str(&format!(
            "skipped {} bad row(s) of {} (listed on stderr)\n",
            bad.len(),
            recording.display()
        ));
    }
    finish(common, &toml, text, json)
}
