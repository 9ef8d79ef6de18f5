//! `retrocomp eval --model FILE --path PATH.csv`: evaluate a model along a path.
//!
//! Input columns: `x_mm`, `y_mm`, `z_mm` (those of the model's axes are required), optional
//! `dir_x`, `dir_y`, `dir_z` (+1/−1/0), `t_s`, `tool_mm`, `T_<sensor>_C`, `F_<force>_N`,
//! `strain_<name>_ue`, and any column a sensor names with `column` (e.g. `rpm`); other columns
//! are passed through. A model with no position-dependent term needs no axis column. Output (stdout): the input columns, then
//! `ex_um`, `ey_um`, `ez_um`, then `term_<name>_ex_um`, `term_<name>_ey_um`, `term_<name>_ez_um`
//! per term, and `flags` (empty when nothing was assumed). Every bad row is reported with its line
//! number and nothing is written. Streams in one pass (each row checked as it is evaluated), so
//! memory stays bounded for any length: into stdout directly when it is a regular file (truncated
//! back to where it was if a row turns out bad), otherwise into a spool (memory, then an unlinked
//! temporary file) copied to stdout once every row was good (`output.rs`). Rows are read, parsed
//! and checked on one thread (`rows.rs`, plain lines split by `plain.rs`) and evaluated and
//! formatted on another, in batches, so the two halves of the work use two cores; each row is
//! assembled in one reused chunk (`decimal::push_fixed6` for the numbers).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};

use retrocomp_model::{EvalFlags, LagStart, MachineModel, ModelState};

mod output;
mod plain;
mod rows;

use output::Output;
use rows::{Batch, Columns, Feed, Problems, RowReader};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
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

fn find(headers: &csv::StringRecord, name: &str) -> Option<usize> {
    headers.iter().position(|h| h.trim() == name)
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let model = MachineModel::from_toml_path(&args.model).map_err(|e| anyhow::anyhow!("{e}"))?;
    let file = args.path.display().to_string();
    let headers = open(&args.path, &file)?
        .headers()
        .with_context(|| format!("{file}:1: cannot read the header row"))?
        .clone();
    let cols = columns(&headers, &model);
    let missing_axes: Vec<String> = model
        .axes()
        .iter()
        .filter(|a| cols.pos[a.index()].is_none())
        .map(|a| format!("{a}_mm"))
        .collect();
    // A model with no position-dependent term (e.g. thermal-only, from `diagnose --out` on an
    // ISO 230-3 recording) runs over a recording without axis columns: missing axes are held at
    // the start of their travel (0 mm without one), which no term reads.
    let held_mm = held_axes_mm(&model);
    if !missing_axes.is_empty() && model.is_position_dependent() {
        bail!(
            "{file}:1: missing column(s) {} (the model's axes need them)",
            missing_axes.join(", ")
        );
    }
    warn_missing_columns(&file, &model, &cols);

    // One pass: every row is checked as it is evaluated, and the output goes where it can be taken
    // back or held (`Output`), so a bad row anywhere still means nothing is written. Memory stays
    // bounded whatever the file's length (no row is held), and the file is read and tokenised once.
    let rows = RowReader {
        file: &file,
        headers: &headers,
        cols: &cols,
        held_mm,
    };
    let header = output_header(&headers, &model)?;
    let mut output = Output::for_stdout();
    let rdr = open(&args.path, &file)?;
    match evaluate_rows(args, &model, &rows, rdr, &header, &mut output) {
        Ok(problems) if problems.count == 0 => output.finish(),
        Ok(problems) => {
            output.discard()?;
            let n = problems.count;
            let more = if n > problems.shown.len() {
                format!("\n… and {} more", n - problems.shown.len())
            } else {
                String::new()
            };
            bail!(
                "{n} bad row(s) in the path file, nothing evaluated:\n{}{more}",
                problems.shown.join("\n")
            );
        }
        Err(e) => {
            // The error (e.g. a full disk) is what is reported; nothing is left written either way.
            let _ = output.discard();
            Err(e)
        }
    }
}

/// Where each input the model reads sits in the header (`None`: the column is absent).
fn columns(headers: &csv::StringRecord, model: &MachineModel) -> Columns {
    let axis_col = |a: char| find(headers, &format!("{a}_mm"));
    Columns {
        pos: [axis_col('x'), axis_col('y'), axis_col('z')],
        dir: [
            find(headers, "dir_x"),
            find(headers, "dir_y"),
            find(headers, "dir_z"),
        ],
        t: find(headers, "t_s"),
        tool: find(headers, "tool_mm"),
        temps: model
            .sensor_columns()
            .iter()
            .map(|n| find(headers, n))
            .collect(),
        forces: model
            .force_channels()
            .iter()
            .map(|n| find(headers, &format!("F_{n}_N")))
            .collect(),
        strains: model
            .strain_channels()
            .iter()
            .map(|n| find(headers, &format!("strain_{n}_ue")))
            .collect(),
    }
}

/// Where a missing axis is held: the start of its travel, 0 mm for an axis without one.
fn held_axes_mm(model: &MachineModel) -> [f64; 3] {
    std::array::from_fn(|a| {
        model
            .spec()
            .axes
            .iter()
            .find(|s| s.axis.index() == a)
            .and_then(|s| s.travel_mm)
            .map_or(0.0, |t| t.0)
    })
}

/// One stderr warning per sensor, force or strain input of the model that has no column, saying
/// what the evaluation assumes instead.
fn warn_missing_columns(file: &str, model: &MachineModel, cols: &Columns) {
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
}

/// The output's header row as CSV bytes: the input's columns, the totals, each term's three
/// components and `flags`.
fn output_header(headers: &csv::StringRecord, model: &MachineModel) -> anyhow::Result<Vec<u8>> {
    let mut header: Vec<String> = headers.iter().map(|s| s.to_string()).collect();
    header.extend(["ex_um", "ey_um", "ez_um"].map(String::from));
    for n in model.term_names() {
        for d in ["ex", "ey", "ez"] {
            header.push(format!("term_{n}_{d}_um"));
        }
    }
    header.push("flags".into());
    let mut hw = csv::Writer::from_writer(Vec::new());
    hw.write_record(&header)?;
    hw.into_inner().map_err(|e| anyhow::anyhow!("{e}"))
}

/// Space-separated flag words, e.g. `clamped_x missing_input`, written into `out`.
fn write_flags(out: &mut Vec<u8>, f: &EvalFlags) -> std::io::Result<()> {
    let mut sep = "";
    let mut word = |out: &mut Vec<u8>, on: bool, w: &str, a: &str| -> std::io::Result<()> {
        if on {
            write!(out, "{sep}{w}{a}")?;
            sep = " ";
        }
        Ok(())
    };
    for (i, a) in ["x", "y", "z"].iter().enumerate() {
        word(out, f.clamped[i], "clamped_", a)?;
        word(out, f.outside_travel[i], "outside_travel_", a)?;
    }
    word(out, f.invalid_input, "invalid_input", "")?;
    word(out, f.missing_input, "missing_input", "")?;
    word(out, f.time_backwards, "time_backwards", "")
}

/// Every row checked and evaluated, in order: read and parsed on a thread of its own
/// ([`rows::read_rows`]), evaluated and formatted on this one, so the two halves of the work run
/// on two cores. Rows reach `output` only until the first problem; the problems are returned.
fn evaluate_rows(
    args: &Args,
    model: &MachineModel,
    rows: &RowReader<'_>,
    rdr: csv::Reader<std::fs::File>,
    header: &[u8],
    output: &mut Output,
) -> anyhow::Result<Problems> {
    // Two filled batches in flight: the reader stays ahead of a short stall of the writer (a slow
    // disk write) without holding more than a few MB.
    let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<Batch>(2);
    let (empty_tx, empty_rx) = std::sync::mpsc::channel::<Batch>();
    std::thread::scope(|s| {
        let reader = std::thread::Builder::new()
            .name("eval-read".into())
            .spawn_scoped(s, move || {
                let feed = Feed::new(full_tx, &empty_rx);
                rows::read_rows(&args.path, rows, model.new_input(), rdr, feed)
            })
            .context("cannot start the reading thread")?;
        // On an error here `full_rx` is dropped with the function's frame, so the reader stops at
        // its next batch instead of reading the file to its end.
        let has_t = rows.cols.t.is_some();
        let written = evaluate_batches(args, model, has_t, header, full_rx, empty_tx, output);
        let problems = match reader.join() {
            Ok(problems) => problems?,
            Err(panic) => std::panic::resume_unwind(panic),
        };
        written?;
        Ok(problems)
    })
}

/// The evaluating side: each row of each batch through the model, formatted after its
/// passed-through columns into one reused chunk that goes out in one write when full.
fn evaluate_batches(
    args: &Args,
    model: &MachineModel,
    has_t: bool,
    header: &[u8],
    full: std::sync::mpsc::Receiver<Batch>,
    empty: std::sync::mpsc::Sender<Batch>,
    output: &mut Output,
) -> std::io::Result<()> {
    // The lags start at the first row: from the model's `[lag_state]` when the recording continues
    // the one the model was fitted on (`MachineModel::new_state_at`), else at their first readings.
    let mut state: Option<ModelState> = None;
    let mut out = model.new_breakdown();
    // Rows are assembled straight into one reused chunk (no allocation per row) rather than through
    // csv::Writer, whose per-field state machine was a fifth of the command's CPU on 10⁶ rows.
    let mut chunk: Vec<u8> = Vec::with_capacity(CHUNK + (1 << 20));
    chunk.extend_from_slice(header);
    let progress = super::term::Progress::counter("eval: rows evaluated");
    // Ends when the reader drops its sender: after the last row, or at the first bad row.
    for batch in full.iter() {
        let mut n = 0;
        for (text, input) in batch.rows() {
            n += 1;
            let state = state.get_or_insert_with(|| first_state(model, has_t, input.t_s));
            if args.first_order {
                model.evaluate_first_order(input, state, &mut out);
            } else {
                model.evaluate(input, state, &mut out);
            }
            chunk.extend_from_slice(text);
            // Fixed 6 decimals (1 pm).
            for v in out.total_um.iter().chain(out.terms_um.iter().flatten()) {
                chunk.push(b',');
                retrocomp_model::decimal::push_fixed6(&mut chunk, *v);
            }
            chunk.push(b',');
            write_flags(&mut chunk, &out.flags)?;
            chunk.push(b'\n');
        }
        progress.inc(n);
        // The reader may already have gone (the file is read): then the batch is simply dropped.
        let _ = empty.send(batch);
        if chunk.len() >= CHUNK {
            output.write_all(&chunk)?;
            chunk.clear();
        }
    }
    // Written even if a later row turned out bad: the caller then takes the output back.
    output.write_all(&chunk)
}

/// The state for a recording whose first row is at `first_t_s`, saying on stderr how the lags
/// start when the model stores lag states.
fn first_state(model: &MachineModel, has_t: bool, first_t_s: f64) -> ModelState {
    if !has_t {
        if model.spec().lag_state.is_some() {
            eprintln!(
                "note: no t_s column: the model's [lag_state] is not used; lags start at their first readings"
            );
        }
        return model.new_state();
    }
    let (state, start) = model.new_state_at(first_t_s);
    match start {
        LagStart::FirstReading => {}
        LagStart::StoredNotBefore { stored_t_s } => eprintln!(
            "note: the model's [lag_state] is of t_s = {stored_t_s}, not before this recording's first row (t_s = {first_t_s}): lags start at their first readings"
        ),
        LagStart::Resumed {
            stored_t_s,
            sensors,
        } => eprintln!(
            "note: {sensors} lag(s) continue from the model's [lag_state] at t_s = {stored_t_s} (first row t_s = {first_t_s})"
        ),
    }
    state
}

/// Output is written in chunks of about this many bytes.
const CHUNK: usize = 1 << 18;

fn open(path: &std::path::Path, file: &str) -> anyhow::Result<csv::Reader<std::fs::File>> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(false)
        .buffer_capacity(1 << 16)
        .from_path(path)
        .with_context(|| format!("{file}: cannot open"))?;
    rdr.byte_headers()
        .with_context(|| format!("{file}:1: cannot read the header row"))?;
    Ok(rdr)
}
