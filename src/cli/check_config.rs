//! `retrocomp check-config FILE`: check a machine model, or a field file and the model it names,
//! without opening any source, sink or listener; print a summary, or every problem found
//! (file:line:column, key, what was expected). A file with a `[gateway]` table is a field file;
//! `--field FILE` says so explicitly.

use std::fmt::Write;
use std::path::{Path, PathBuf};

use retrocomp_gateway::config::{CheckedField, check_field};
use retrocomp_model::ErrorFunction;
use retrocomp_model::{Branch, ThermalKind};
use retrocomp_model::{MachineModel, ModelSpec};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Machine model TOML, or a field file (one with a `[gateway]` table).
    #[arg(required_unless_present = "field", conflicts_with = "field")]
    pub file: Option<PathBuf>,
    /// Field file (`retrocomp run --config`): checked with the model it names.
    #[arg(long, value_name = "FIELD.toml")]
    pub field: Option<PathBuf>,
    /// With a field file: check this model instead of its `[model] path` (as `run --model`).
    #[arg(long, value_name = "MODEL.toml")]
    pub model: Option<PathBuf>,
}

/// A field file has a `[gateway]` table; a model never does.
fn is_field_file(path: &Path) -> bool {
    std::fs::read_to_string(path).is_ok_and(|t| {
        t.lines().any(|l| {
            l.trim_start().starts_with("[gateway]") || l.trim_start().starts_with("[gateway.")
        })
    })
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let field = match (&args.field, &args.file) {
        (Some(f), _) => Some(f.clone()),
        (None, Some(f)) if is_field_file(f) => Some(f.clone()),
        _ => None,
    };
    if let Some(f) = field {
        let checked = check_field(&f, args.model.as_deref()).map_err(|e| anyhow::anyhow!("{e}"))?;
        print!("{}", field_summary(&f, &checked));
        return Ok(());
    }
    if args.model.is_some() {
        anyhow::bail!(
            "--model goes with a field file (check-config --field FIELD.toml --model MODEL.toml)"
        );
    }
    let file = args.file.as_ref().expect("clap requires FILE or --field");
    let model = MachineModel::from_toml_path(file).map_err(|e| anyhow::anyhow!("{e}"))?;
    print!("{}", summary(&model));
    Ok(())
}

/// The text printed by `check-config` for a valid field file: what it runs, then its model.
pub(crate) fn field_summary(path: &Path, c: &CheckedField) -> String {
    let cfg = &c.cfg;
    let mut o = String::new();
    let _ = writeln!(o, "field config {}: OK", path.display());
    let axes: Vec<&str> = cfg.axes.iter().map(|a| a.name.as_str()).collect();
    let _ = writeln!(
        o,
        "  gateway {:?}: cycle {} ms, axes {}",
        cfg.gateway.name,
        cfg.gateway.cycle_ms,
        axes.join(", ")
    );
    let _ = writeln!(o, "  sources deliver: {}", cfg.source_channels().join(", "));
    let sink = match (
        &cfg.sink.origin_shift,
        &cfg.sink.origin_shift_server,
        &cfg.sink.quadrature,
    ) {
        (Some(_), _, _) => "origin shift (Modbus client)",
        (_, Some(_), _) => "origin shift served (Modbus server)",
        (_, _, Some(_)) => "quadrature counts",
        _ => "none (computes and reports only)",
    };
    let _ = writeln!(o, "  sink: {sink}");
    for ch in &c.optional_missing {
        let _ = writeln!(
            o,
            "  warning: no source delivers {ch} (optional): its load terms stay out"
        );
    }
    let _ = writeln!(o, "model file {}:", c.model_path.display());
    o.push_str(&summary(c.model.model()));
    // The drop-in its peers need under the shipped unit (docs/install.md, "The unit's network").
    o.push_str(&retrocomp_gateway::config::UnitNetwork::of(cfg).drop_in());
    o
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
