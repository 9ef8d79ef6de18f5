//! `retrocomp eval --model FILE --path PATH.csv`: evaluate a model along a path.
//!
//! Input columns: `x_mm`, `y_mm`, `z_mm` (those of the model's axes are required), optional
//! `dir_x`, `dir_y`, `dir_z` (+1/−1/0), `t_s`, `tool_mm`, `T_<sensor>_C`, `F_<force>_N`,
//! `strain_<name>_ue`, and any column a sensor names with `column` (e.g. `rpm`); other columns
//! are passed through. A model with no position-dependent term needs no axis column. Output (stdout): the input columns, then
//! `ex_um`, `ey_um`, `ez_um`, then `term_<name>_ex_um`, `term_<name>_ey_um`, `term_<name>_ez_um`
//! per term, and `flags` (empty when nothing was assumed). Every bad row is reported with its line
//! number and nothing is written.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};

use crate::models::{EvalFlags, MachineModel, ModelInput};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Machine model TOML file.
    #[arg(long)]
    pub model: PathBuf,
    /// Path CSV (one header row).
    #[arg(long)]
    pub path: PathBuf,
    /// Use the first-order closed form instead of the exact 4×4 chain.
    #[arg(long)]
    pub first_order: bool,
}

/// Where each model input comes from in the CSV.
struct Columns {
    pos: [Option<usize>; 3],
    dir: [Option<usize>; 3],
    t: Option<usize>,
    tool: Option<usize>,
    temps: Vec<Option<usize>>,
    forces: Vec<Option<usize>>,
    strains: Vec<Option<usize>>,
}

fn find(headers: &csv::StringRecord, name: &str) -> Option<usize> {
    headers.iter().position(|h| h.trim() == name)
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let model = MachineModel::from_toml_path(&args.model).map_err(|e| anyhow::anyhow!("{e}"))?;
    let file = args.path.display().to_string();
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(false)
        .from_path(&args.path)
        .with_context(|| format!("{file}: cannot open"))?;
    let headers = rdr
        .headers()
        .with_context(|| format!("{file}:1: cannot read the header row"))?
        .clone();
    let axis_col = |a: char| find(&headers, &format!("{a}_mm"));
    let cols = Columns {
        pos: [axis_col('x'), axis_col('y'), axis_col('z')],
        dir: [
            find(&headers, "dir_x"),
            find(&headers, "dir_y"),
            find(&headers, "dir_z"),
        ],
        t: find(&headers, "t_s"),
        tool: find(&headers, "tool_mm"),
        temps: model
            .sensor_columns()
            .iter()
            .map(|n| find(&headers, n))
            .collect(),
        forces: model
            .force_channels()
            .iter()
            .map(|n| find(&headers, &format!("F_{n}_N")))
            .collect(),
        strains: model
            .strain_channels()
            .iter()
            .map(|n| find(&headers, &format!("strain_{n}_ue")))
            .collect(),
    };
    let missing_axes: Vec<String> = model
        .axes()
        .iter()
        .filter(|a| cols.pos[a.index()].is_none())
        .map(|a| format!("{a}_mm"))
        .collect();
    // A model with no position-dependent term (e.g. thermal-only, from `diagnose --out` on an
    // ISO 230-3 recording) runs over a recording without axis columns: missing axes are held at
    // the start of their travel (0 mm without one), which no term reads.
    let held_mm: [f64; 3] = std::array::from_fn(|a| {
        model
            .spec()
            .axes
            .iter()
            .find(|s| s.axis.index() == a)
            .and_then(|s| s.travel_mm)
            .map_or(0.0, |t| t.0)
    });
    if !missing_axes.is_empty() && model.is_position_dependent() {
        bail!(
            "{file}:1: missing column(s) {} (the model's axes need them)",
            missing_axes.join(", ")
        );
    }
    let warn_missing =
        |names: &[String], c: &[Option<usize>], fmt: &dyn Fn(&str) -> String, what: &str| {
            for (n, c) in names.iter().zip(c) {
                if c.is_none() {
                    eprintln!("warning: {file}: no column {}; {what}", fmt(n));
                }
            }
        };
    warn_missing(
        model.sensor_columns(),
        &cols.temps,
        &|n| n.to_string(),
        "the sensor is held at its reference temperature",
    );
    warn_missing(
        model.force_channels(),
        &cols.forces,
        &|n| format!("F_{n}_N"),
        "the force is taken as 0 N",
    );
    warn_missing(
        model.strain_channels(),
        &cols.strains,
        &|n| format!("strain_{n}_ue"),
        "the strain is taken as 0",
    );

    // Read and check every row before evaluating anything.
    let mut rows: Vec<(csv::StringRecord, ModelInput)> = Vec::new();
    let mut problems: Vec<String> = Vec::new();
    let mut last_t: Option<f64> = None;
    for rec in rdr.records() {
        let rec = match rec {
            Ok(r) => r,
            Err(e) => {
                let line = e.position().map_or(0, |p| p.line());
                problems.push(format!("{file}:{line}: {e}"));
                continue;
            }
        };
        let line = rec.position().map_or(0, |p| p.line());
        let mut input = model.new_input();
        let mut bad = |col: usize, what: &str| {
            problems.push(format!(
                "{file}:{line}: column {}: {what}, found {:?}",
                &headers[col], &rec[col]
            ));
        };
        let mut num = |col: usize| -> Option<f64> {
            match rec[col].trim().parse::<f64>() {
                Ok(v) if v.is_finite() => Some(v),
                _ => {
                    bad(col, "expected a finite number");
                    None
                }
            }
        };
        for ((p, c), held) in input.pos_mm.iter_mut().zip(cols.pos).zip(held_mm) {
            *p = match c {
                Some(c) => num(c).unwrap_or(f64::NAN),
                None => held,
            };
        }
        for (i, c) in cols.temps.iter().enumerate() {
            if let Some(c) = c {
                input.temps_c[i] = num(*c).unwrap_or(f64::NAN);
            }
        }
        for (i, c) in cols.forces.iter().enumerate() {
            if let Some(c) = c {
                input.forces_n[i] = num(*c).unwrap_or(f64::NAN);
            }
        }
        for (i, c) in cols.strains.iter().enumerate() {
            if let Some(c) = c {
                input.strains_ue[i] = num(*c).unwrap_or(f64::NAN);
            }
        }
        if let Some(c) = cols.tool {
            input.tool_mm = num(c);
        }
        if let Some(c) = cols.t
            && let Some(t) = num(c)
        {
            if let Some(prev) = last_t
                && t < prev
            {
                problems.push(format!(
                    "{file}:{line}: column t_s: time goes backwards ({t} after {prev})"
                ));
            }
            last_t = Some(t);
            input.t_s = t;
        }
        for a in 0..3 {
            if let Some(c) = cols.dir[a] {
                match rec[c].trim() {
                    "1" | "+1" | "1.0" => input.dir[a] = 1,
                    "-1" | "-1.0" => input.dir[a] = -1,
                    "0" | "0.0" | "" => input.dir[a] = 0,
                    other => problems.push(format!(
                        "{file}:{line}: column {}: expected +1, -1 or 0, found {other:?}",
                        &headers[c]
                    )),
                }
            }
        }
        rows.push((rec, input));
    }
    if !problems.is_empty() {
        let n = problems.len();
        let shown: Vec<&String> = problems.iter().take(50).collect();
        let more = if n > 50 {
            format!("\n… and {} more", n - 50)
        } else {
            String::new()
        };
        bail!(
            "{n} bad row(s) in the path file, nothing evaluated:\n{}{more}",
            shown
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join("\n")
        );
    }

    let stdout = std::io::stdout();
    let mut w = csv::Writer::from_writer(stdout.lock());
    let mut header: Vec<String> = headers.iter().map(|s| s.to_string()).collect();
    header.extend(["ex_um", "ey_um", "ez_um"].map(String::from));
    for n in model.term_names() {
        for d in ["ex", "ey", "ez"] {
            header.push(format!("term_{n}_{d}_um"));
        }
    }
    header.push("flags".into());
    w.write_record(&header)?;
    let mut state = model.new_state();
    let mut out = model.new_breakdown();
    for (rec, input) in &rows {
        if args.first_order {
            model.evaluate_first_order(input, &mut state, &mut out);
        } else {
            model.evaluate(input, &mut state, &mut out);
        }
        let mut fields: Vec<String> = rec.iter().map(|s| s.to_string()).collect();
        fields.extend(out.total_um.iter().map(|v| format!("{v:.6}")));
        for t in &out.terms_um {
            fields.extend(t.iter().map(|v| format!("{v:.6}")));
        }
        fields.push(flags_text(&out.flags));
        w.write_record(&fields)?;
    }
    w.flush()?;
    std::io::stdout().flush()?;
    Ok(())
}

/// Space-separated flag words, e.g. `clamped_x missing_input`.
pub fn flags_text(f: &EvalFlags) -> String {
    let mut words: Vec<String> = Vec::new();
    for (i, a) in ["x", "y", "z"].iter().enumerate() {
        if f.clamped[i] {
            words.push(format!("clamped_{a}"));
        }
        if f.outside_travel[i] {
            words.push(format!("outside_travel_{a}"));
        }
    }
    if f.invalid_input {
        words.push("invalid_input".into());
    }
    if f.missing_input {
        words.push("missing_input".into());
    }
    if f.time_backwards {
        words.push("time_backwards".into());
    }
    words.join(" ")
}
