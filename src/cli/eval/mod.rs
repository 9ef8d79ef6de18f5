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
//! temporary file) copied to stdout once every row was good. Rows are assembled in one reused chunk
//! (`decimal::push_fixed6` for the numbers).

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};

use retrocomp::models::{EvalFlags, MachineModel, ModelInput};

mod plain;

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

    // One pass: every row is checked as it is evaluated, and the output goes where it can be taken
    // back or held (`Output`), so a bad row anywhere still means nothing is written. Memory stays
    // bounded whatever the file's length (holding the rows took 865 MB for 10⁶ of them). Reading
    // and tokenising the file once instead of twice (check, then evaluate) was the largest cost
    // after the output's own.
    let rows = RowReader {
        file: &file,
        headers: &headers,
        cols: &cols,
        held_mm,
    };
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
    let header = hw.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
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

/// Every row checked and evaluated, in order; rows reach `output` only until the first problem.
fn evaluate_rows(
    args: &Args,
    model: &MachineModel,
    rows: &RowReader<'_>,
    mut rdr: csv::Reader<std::fs::File>,
    header: &[u8],
    output: &mut Output,
) -> anyhow::Result<Problems> {
    let file = rows.file;
    let mut input = model.new_input();
    let mut state = model.new_state();
    let mut out = model.new_breakdown();
    let mut problems = Problems::default();
    // Rows are assembled straight into one reused chunk (no allocation per row) rather than through
    // csv::Writer, whose per-field state machine was a fifth of the command's CPU on 10⁶ rows; the
    // chunk goes out in one write when it is full.
    let mut chunk: Vec<u8> = Vec::with_capacity(CHUNK + 4096);
    chunk.extend_from_slice(header);
    let mut last_t = None;
    let mut evaluate = |chunk: &mut Vec<u8>, input: &ModelInput| -> std::io::Result<()> {
        if args.first_order {
            model.evaluate_first_order(input, &mut state, &mut out);
        } else {
            model.evaluate(input, &mut state, &mut out);
        }
        // Fixed 6 decimals (1 pm).
        for v in out.total_um.iter().chain(out.terms_um.iter().flatten()) {
            chunk.push(b',');
            retrocomp::decimal::push_fixed6(chunk, *v);
        }
        chunk.push(b',');
        write_flags(chunk, &out.flags)?;
        chunk.push(b'\n');
        if chunk.len() >= CHUNK {
            output.write_all(chunk)?;
            chunk.clear();
        }
        Ok(())
    };

    // Plain lines first (`plain.rs`): a plain line is its own passed-through columns.
    let p = rdr.position().clone();
    let at = plain::At {
        byte: p.byte(),
        line: p.line(),
        record: p.record(),
    };
    let mut src =
        std::fs::File::open(&args.path).with_context(|| format!("{file}: cannot open"))?;
    std::io::Seek::seek(&mut src, std::io::SeekFrom::Start(at.byte))?;
    let mut lines = plain::PlainLines::new(src, at, rows.headers.len());
    loop {
        match lines
            .next_line()
            .with_context(|| format!("{file}: cannot read"))?
        {
            plain::Next::Plain(l) => {
                rows.parse(&l, &mut input, &mut last_t, &mut problems);
                if problems.count == 0 {
                    chunk.extend_from_slice(l.text);
                    evaluate(&mut chunk, &input)?;
                }
            }
            plain::Next::HandOver(at) => {
                let mut pos = csv::Position::new();
                pos.set_byte(at.byte)
                    .set_line(at.line)
                    .set_record(at.record);
                rdr.seek_raw(std::io::SeekFrom::Start(at.byte), pos)?;
                break;
            }
            plain::Next::End => {
                if problems.count == 0 {
                    output.write_all(&chunk)?;
                }
                return Ok(problems);
            }
        }
    }

    // The rest, from the first line that is not plain, through the csv crate.
    let mut rec = csv::ByteRecord::new();
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
        for (i, field) in rec.iter().enumerate() {
            if i > 0 {
                chunk.push(b',');
            }
            push_csv_field(&mut chunk, field);
        }
        evaluate(&mut chunk, &input)?;
    }
    if problems.count == 0 {
        output.write_all(&chunk)?;
    }
    Ok(problems)
}

/// Output is written in chunks of about this many bytes.
const CHUNK: usize = 1 << 18;

/// Where the output goes while rows are still being checked: a bad row anywhere means nothing is
/// written, so either the output can be taken back, or it is held until the end.
enum Output {
    /// stdout is a regular file positioned at its end (`> out.csv`): rows go straight into it, and
    /// a bad row truncates it back to `start`, the length it had, so it then holds what it held
    /// before. Writing the rows once instead of twice (spool, then copy) halved the command's CPU
    /// time on 10⁶ rows: the kernel's copies of the ≈ 290 MB were half of it.
    Direct { file: std::fs::File, start: u64 },
    /// Anything else (a pipe, a terminal, a file opened for appending or rewriting in place): held
    /// in memory up to [`Output::IN_MEMORY`], then in an unlinked temporary file (removed by the OS
    /// however the process ends), and copied to stdout once every row was good.
    Spool(tempfile::SpooledTempFile),
}

impl Output {
    const IN_MEMORY: usize = 4 << 20;

    fn for_stdout() -> Self {
        use std::io::Seek as _;
        use std::os::fd::AsFd as _;
        let direct = std::io::stdout()
            .as_fd()
            .try_clone_to_owned()
            .ok()
            .map(std::fs::File::from)
            .and_then(|mut file| {
                let meta = file.metadata().ok()?;
                // Taking rows back is exact only when nothing follows them: position = length.
                // (`>>` opens with the position at 0, so a non-empty appended file is spooled.)
                let start = file.stream_position().ok()?;
                (meta.is_file() && start == meta.len()).then_some(Output::Direct { file, start })
            });
        direct.unwrap_or_else(|| Output::Spool(tempfile::SpooledTempFile::new(Self::IN_MEMORY)))
    }

    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        match self {
            Output::Direct { file, .. } => file.write_all(buf),
            Output::Spool(s) => s.write_all(buf).map_err(|e| {
                std::io::Error::new(e.kind(), format!("cannot spool the output: {e}"))
            }),
        }
    }

    /// Every row was good: make the output final.
    fn finish(self) -> anyhow::Result<()> {
        use std::io::Seek as _;
        let Output::Spool(mut s) = self else {
            return Ok(());
        };
        let stdout = std::io::stdout();
        let mut w = stdout.lock();
        s.rewind()?;
        match s.into_inner() {
            tempfile::SpooledData::InMemory(c) => w.write_all(c.get_ref())?,
            // File → stdout: std uses copy_file_range/sendfile/splice here, no user-space copy.
            tempfile::SpooledData::OnDisk(mut f) => {
                std::io::copy(&mut f, &mut w)?;
            }
        }
        w.flush()?;
        Ok(())
    }

    /// A row was bad: take back what was written.
    fn discard(self) -> std::io::Result<()> {
        use std::io::Seek as _;
        if let Output::Direct { mut file, start } = self {
            file.set_len(start)?;
            // The position is shared with the shell's descriptor (and stderr's, with `2>&1`).
            file.seek(std::io::SeekFrom::Start(start))?;
        }
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

/// One input row, read by the csv crate or split as a plain line.
trait Row {
    fn field(&self, i: usize) -> &[u8];
    /// Its line in the file (1-based), for messages.
    fn line(&self) -> u64;
}

impl Row for csv::ByteRecord {
    fn field(&self, i: usize) -> &[u8] {
        &self[i]
    }
    fn line(&self) -> u64 {
        self.position().map_or(0, |p| p.line())
    }
}

impl Row for plain::PlainLine<'_> {
    fn field(&self, i: usize) -> &[u8] {
        plain::PlainLine::field(self, i)
    }
    fn line(&self) -> u64 {
        self.line
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
        rec: &impl Row,
        input: &mut ModelInput,
        last_t: &mut Option<f64>,
        problems: &mut Problems,
    ) {
        let (file, cols) = (self.file, self.cols);
        let line = rec.line();
        let text = |col: usize| String::from_utf8_lossy(rec.field(col)).trim().to_string();
        let mut num = |col: usize| -> Option<f64> {
            let v = std::str::from_utf8(rec.field(col))
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
            match rec.field(c).trim_ascii() {
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
