//! `retrocomp eval --model FILE --path PATH.csv`: evaluate a model along a path.
//!
//! Input columns: `x_mm`, `y_mm`, `z_mm` (those of the model's axes are required), optional
//! `dir_x`, `dir_y`, `dir_z` (+1/−1/0), `t_s`, `tool_mm`, `T_<sensor>_C`, `F_<force>_N`,
//! `strain_<name>_ue`, and any column a sensor names with `column` (e.g. `rpm`); other columns
//! are passed through. A model with no position-dependent term needs no axis column. Output (stdout): the input columns, then
//! `ex_um`, `ey_um`, `ez_um`, then `term_<name>_ex_um`, `term_<name>_ey_um`, `term_<name>_ez_um`
//! per term, and `flags` (empty when nothing was assumed). Every bad row is reported with its line
//! number and nothing is written. Streams in one pass (each row checked as it is evaluated; the
//! output is held in a spool, memory then an unlinked temporary file, and copied to stdout once every
//! row was good), so memory stays bounded for any length; each output line is assembled in one
//! reused buffer (`decimal::push_fixed6` for the numbers).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};

use retrocomp::models::{EvalFlags, MachineModel, ModelInput};

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

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let model = MachineModel::from_toml_path(&args.model).map_err(|e| anyhow::anyhow!("{e}"))?;
    let file = args.path.display().to_string();
    let headers = open(&args.path, &file)?
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

    // One pass: every row is checked as it is evaluated, and the output goes to a spool (memory,
    // then an unlinked temporary file past `Spool::IN_MEMORY`) that reaches stdout only when every
    // row was good, so a bad row anywhere still means nothing is written. Memory stays bounded
    // whatever the file's length (holding the rows took 865 MB for 10⁶ of them); the spool's copy
    // to stdout is a kernel copy. Reading and tokenising the file once instead of twice (check,
    // then evaluate) was the largest remaining cost.
    let rows = RowReader {
        file: &file,
        headers: &headers,
        cols: &cols,
        held_mm,
    };
    let mut spool = Spool::default();
    let mut header: Vec<String> = headers.iter().map(|s| s.to_string()).collect();
    header.extend(["ex_um", "ey_um", "ez_um"].map(String::from));
    for n in model.term_names() {
        for d in ["ex", "ey", "ez"] {
            header.push(format!("term_{n}_{d}_um"));
        }
    }
    header.push("flags".into());
    {
        let mut hw = csv::Writer::from_writer(&mut spool);
        hw.write_record(&header)?;
        hw.flush()?;
    }
    let mut input = model.new_input();
    let mut state = model.new_state();
    let mut out = model.new_breakdown();
    let mut problems = Problems::default();
    let mut rdr = open(&args.path, &file)?;
    let mut rec = csv::ByteRecord::new();
    // One output line, reused: no allocation per row. Rows are assembled here rather than through
    // csv::Writer, whose per-field state machine was a fifth of the command's CPU on 10⁶ rows.
    let mut line: Vec<u8> = Vec::with_capacity(1024);
    let mut last_t = None;
    loop {
        match rdr.read_byte_record(&mut rec) {
            Ok(true) => rows.parse(&rec, &mut input, &mut last_t, &mut problems),
            Ok(false) => break,
            Err(e) => {
                let line = e.position().map_or(0, |p| p.line());
                problems.push(format!("{file}:{line}: {e}"));
            }
        }
        // After the first bad row nothing will be written: only the checking goes on.
        if problems.count > 0 {
            continue;
        }
        if args.first_order {
            model.evaluate_first_order(&input, &mut state, &mut out);
        } else {
            model.evaluate(&input, &mut state, &mut out);
        }
        line.clear();
        for (i, field) in rec.iter().enumerate() {
            if i > 0 {
                line.push(b',');
            }
            push_csv_field(&mut line, field);
        }
        // Fixed 6 decimals (1 pm).
        for v in out.total_um.iter().chain(out.terms_um.iter().flatten()) {
            line.push(b',');
            retrocomp::decimal::push_fixed6(&mut line, *v);
        }
        line.push(b',');
        write_flags(&mut line, &out.flags)?;
        line.push(b'\n');
        spool.write_all(&line)?;
    }
    if problems.count > 0 {
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
    spool.copy_to_stdout()
}

/// Output held back until every row has been checked: in memory up to [`Spool::IN_MEMORY`]
/// bytes, then in an unlinked temporary file (removed by the OS however the process ends), so
/// memory stays bounded for any length of input.
#[derive(Default)]
struct Spool {
    mem: Vec<u8>,
    file: Option<std::io::BufWriter<std::fs::File>>,
}

impl Spool {
    const IN_MEMORY: usize = 4 << 20;

    fn copy_to_stdout(self) -> anyhow::Result<()> {
        let stdout = std::io::stdout();
        let mut w = stdout.lock();
        match self.file {
            None => w.write_all(&self.mem)?,
            Some(f) => {
                use std::io::Seek as _;
                let mut f = f.into_inner().map_err(|e| e.into_error())?;
                f.rewind()?;
                // File → stdout: std uses copy_file_range/sendfile/splice here, no user-space copy.
                std::io::copy(&mut f, &mut w)?;
            }
        }
        w.flush()?;
        Ok(())
    }
}

/// A new file in `std::env::temp_dir()`, removed from its directory at once: it lives while open.
/// (The `tempfile` crate does the same; it is only a dev-dependency here, and making it a normal
/// one changed the dependency features of the whole release build.)
fn unlinked_temp_file() -> std::io::Result<std::fs::File> {
    let dir = std::env::temp_dir();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let mut last = None;
    for attempt in 0..16u32 {
        let path = dir.join(format!(
            ".retrocomp-eval-{}-{nanos}-{attempt}",
            std::process::id()
        ));
        match std::fs::File::options()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(f) => {
                std::fs::remove_file(&path)?;
                return Ok(f);
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no free temporary file name")))
}

impl Write for Spool {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.file.is_none() && self.mem.len() + buf.len() > Self::IN_MEMORY {
            let f = unlinked_temp_file().map_err(|e| {
                std::io::Error::new(e.kind(), format!("cannot create a temporary file: {e}"))
            })?;
            let mut f = std::io::BufWriter::with_capacity(1 << 16, f);
            f.write_all(&self.mem)?;
            self.mem = Vec::new();
            self.file = Some(f);
        }
        match &mut self.file {
            Some(f) => f.write(buf),
            None => {
                self.mem.extend_from_slice(buf);
                Ok(buf.len())
            }
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A passed-through field as the csv crate writes one (its `QuoteStyle::Necessary`): as is, or
/// quoted with inner quotes doubled when it holds a comma, a quote or a line break.
fn push_csv_field(line: &mut Vec<u8>, field: &[u8]) {
    if !field
        .iter()
        .any(|b| matches!(b, b',' | b'"' | b'\n' | b'\r'))
    {
        line.extend_from_slice(field);
        return;
    }
    line.push(b'"');
    for &b in field {
        if b == b'"' {
            line.push(b'"');
        }
        line.push(b);
    }
    line.push(b'"');
}

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

/// The first [`Problems::SHOWN`] problems word for word, and how many there were in all.
#[derive(Default)]
struct Problems {
    shown: Vec<String>,
    count: usize,
}

impl Problems {
    const SHOWN: usize = 50;
    fn push(&mut self, msg: String) {
        if self.shown.len() < Self::SHOWN {
            self.shown.push(msg);
        }
        self.count += 1;
    }
}

/// Turns one CSV row into a [`ModelInput`] (reused), noting every bad cell with its line.
struct RowReader<'a> {
    file: &'a str,
    headers: &'a csv::StringRecord,
    cols: &'a Columns,
    held_mm: [f64; 3],
}

impl RowReader<'_> {
    fn parse(
        &self,
        rec: &csv::ByteRecord,
        input: &mut ModelInput,
        last_t: &mut Option<f64>,
        problems: &mut Problems,
    ) {
        let (file, cols) = (self.file, self.cols);
        let line = rec.position().map_or(0, |p| p.line());
        let text = |col: usize| String::from_utf8_lossy(&rec[col]).trim().to_string();
        let mut num = |col: usize| -> Option<f64> {
            let v = std::str::from_utf8(&rec[col])
                .ok()
                .and_then(|s| s.trim().parse::<f64>().ok());
            match v {
                Some(v) if v.is_finite() => Some(v),
                _ => {
                    problems.push(format!(
                        "{file}:{line}: column {}: expected a finite number, found {:?}",
                        &self.headers[col],
                        text(col)
                    ));
                    None
                }
            }
        };
        for ((p, c), held) in input.pos_mm.iter_mut().zip(cols.pos).zip(self.held_mm) {
            *p = match c {
                Some(c) => num(c).unwrap_or(f64::NAN),
                None => held,
            };
        }
        let channels = [
            (&cols.temps, &mut input.temps_c),
            (&cols.forces, &mut input.forces_n),
            (&cols.strains, &mut input.strains_ue),
        ];
        for (cs, values) in channels {
            for (c, v) in cs.iter().zip(values.iter_mut()) {
                if let Some(c) = c {
                    *v = num(*c).unwrap_or(f64::NAN);
                }
            }
        }
        if let Some(c) = cols.tool {
            input.tool_mm = num(c);
        }
        if let Some(c) = cols.t
            && let Some(t) = num(c)
        {
            if let Some(prev) = *last_t
                && t < prev
            {
                problems.push(format!(
                    "{file}:{line}: column t_s: time goes backwards ({t} after {prev})"
                ));
            }
            *last_t = Some(t);
            input.t_s = t;
        }
        for (a, c) in cols.dir.iter().enumerate() {
            let Some(c) = *c else { continue };
            match rec[c].trim_ascii() {
                b"1" | b"+1" | b"1.0" => input.dir[a] = 1,
                b"-1" | b"-1.0" => input.dir[a] = -1,
                b"0" | b"0.0" | b"" => input.dir[a] = 0,
                _ => problems.push(format!(
                    "{file}:{line}: column {}: expected +1, -1 or 0, found {:?}",
                    &self.headers[c],
                    text(c)
                )),
            }
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passed_through_fields_are_quoted_as_the_csv_crate_quotes_them() {
        for field in [
            "12.5",
            "",
            "a,b",
            "say \"hi\"",
            "two\nlines",
            "cr\r",
            "plain text",
        ] {
            let mut ours = Vec::new();
            push_csv_field(&mut ours, field.as_bytes());
            ours.extend_from_slice(b",x\n");
            let mut theirs = csv::Writer::from_writer(Vec::new());
            theirs.write_record([field, "x"]).unwrap();
            assert_eq!(ours, theirs.into_inner().unwrap(), "{field:?}");
        }
    }
}
