//! `retrocomp check-config FILE`: load a machine model and print a summary, or every problem found
//! (file:line:column, key, what was expected).

use std::fmt::Write;
use std::path::PathBuf;

use retrocomp::models::function::ErrorFunction;
use retrocomp::models::spec::{Branch, ThermalKind};
use retrocomp::models::{MachineModel, ModelSpec};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Machine model TOML file.
    #[arg(required_unless_present = "field")]
    pub file: Option<PathBuf>,
    /// Field file: print the systemd drop-in (`IPAddressAllow=`) its peers need under the shipped
    /// unit (docs/install.md, "The unit's network").
    #[arg(long, value_name = "FIELD_FILE")]
    pub field: Option<PathBuf>,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(field) = &args.field {
        print_unit_network(field)?;
    }
    let Some(file) = &args.file else {
        return Ok(());
    };
    let model = MachineModel::from_toml_path(file).map_err(|e| anyhow::anyhow!("{e}"))?;
    print!("{}", summary(&model));
    Ok(())
}

/// The drop-in the field file's peers need under the shipped unit (its `IPAddressAllow=` line).
fn print_unit_network(field: &std::path::Path) -> anyhow::Result<()> {
    let cfg = retrocomp::gateway::config::FieldConfig::load(field)?;
    print!(
        "{}",
        retrocomp::gateway::unit_network::UnitNetwork::of(&cfg).drop_in()
    );
    Ok(())
}

fn function_summary(f: &ErrorFunction) -> String {
    match f {
        ErrorFunction::Table(t) => {
            let n = t.positions_mm.len();
            let all = t.forward.iter().chain(&t.reverse);
            let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
            format!(
                "table {n} pts {}..{} mm, {}, {}, values {lo:.3}..{hi:.3}",
                t.positions_mm[0],
                t.positions_mm[n - 1],
                if t.is_bidirectional() {
                    "bidirectional"
                } else {
                    "one direction"
                },
                t.interpolation.as_str()
            )
        }
        ErrorFunction::Polynomial { coefficients, .. } => {
            format!("polynomial degree {}", coefficients.len() - 1)
        }
        ErrorFunction::PiecewiseQuadratic { knots_mm, .. } => {
            format!("piecewise quadratic, {} knots", knots_mm.len())
        }
    }
}

/// The text printed by `check-config` for a valid model.
pub(crate) fn summary(model: &MachineModel) -> String {
    let s: &ModelSpec = model.spec();
    let mut o = String::new();
    let _ = writeln!(
        o,
        "model {:?}{}: OK",
        s.name,
        if s.synthetic { " (synthetic data)" } else { "" }
    );
    if !s.description.is_empty() {
        let _ = writeln!(o, "  {}", s.description);
    }
    let _ = writeln!(o, "chain: {} (workpiece → tool)", s.chain_string());
    for a in &s.axes {
        let side = if a.branch == Branch::Workpiece {
            "workpiece side"
        } else {
            "tool side"
        };
        let _ = writeln!(o, "  axis {}: {side}, offset {:?} mm", a.axis, a.offset_mm);
    }
    for t in &s.tools {
        let _ = writeln!(o, "tool {:?}: offset {:?} mm", t.name, t.offset_mm);
    }
    let _ = writeln!(o, "components ({}):", s.components.len());
    for c in &s.components {
        let unit = if c.id.is_rotation() { "µrad" } else { "µm" };
        let _ = writeln!(
            o,
            "  {} [{unit}]: {}",
            c.id.iso_name(),
            function_summary(&c.function)
        );
    }
    for q in &s.squareness {
        let _ = writeln!(
            o,
            "squareness {} on {}: {:.3} µrad",
            q.kind.iso_name(),
            q.on_axis,
            q.value_urad
        );
    }
    for x in &s.sensors {
        let lag = x
            .tau_s
            .map_or("no lag".to_string(), |t| format!("τ = {t} s"));
        let _ = writeln!(
            o,
            "sensor T_{}_C: reference {} °C, {lag}",
            x.name, x.reference_c
        );
    }
    for t in &s.thermal {
        let kind = match &t.kind {
            ThermalKind::PolynomialDt { sensors, .. } => {
                format!("polynomial in ΔT of {} sensors", sensors.len())
            }
            ThermalKind::Slope { sensors, .. } => {
                format!("position × ΔT slope, {} sensors", sensors.len())
            }
            ThermalKind::Expansion {
                sensor,
                alpha_ppm_per_k,
                ..
            } => format!("expansion {alpha_ppm_per_k} ppm/K on {sensor}"),
            ThermalKind::Stations {
                along, stations_mm, ..
            } => format!("{} stations along {along}", stations_mm.len()),
        };
        let _ = writeln!(o, "thermal {} → {}: {kind}", t.name, t.target.iso_name());
    }
    for f in &s.forces {
        match &f.from_strain {
            None => {
                let _ = writeln!(o, "force F_{}_N", f.name);
            }
            Some(src) => {
                let _ = writeln!(
                    o,
                    "force {} = {} N/µε × (strain_{}_ue − {})",
                    f.name, src.gain_n_per_ue, src.strain, src.offset_ue
                );
            }
        }
    }
    for l in &s.load {
        let _ = writeln!(o, "load {} → {}", l.name, l.target.iso_name());
    }
    let _ = writeln!(o, "terms: {}", model.term_names().len());
    o
}
