//! The reading side of `retrocomp eval`: every row of the path file parsed into a [`ModelInput`] and
//! checked, in file order, on a thread of its own; while no row was bad, rows are handed to the
//! evaluating side in [`Batch`]es (each row's passed-through columns as they will be written, and its
//! input). Plain lines are split by `plain.rs`, the rest of the file from the first line that is not
//! plain by the csv crate. Batches are recycled, so after the first few nothing is allocated per row.

use std::sync::mpsc::{Receiver, SyncSender};

use anyhow::Context;

use retrocomp_model::ModelInput;

use super::plain;

/// Where each model input comes from in the CSV.
pub(super) struct Columns {
    pub(super) pos: [Option<usize>; 3],
    pub(super) dir: [Option<usize>; 3],
    pub(super) t: Option<usize>,
    pub(super) tool: Option<usize>,
    pub(super) temps: Vec<Option<usize>>,
    pub(super) forces: Vec<Option<usize>>,
    pub(super) strains: Vec<Option<usize>>,
}

/// Rows handed from the reading to the evaluating thread, in file order.
pub(super) struct Batch {
    /// Each row's passed-through columns as they are written out (no line terminator), back to back.
    text: Vec<u8>,
    /// Where each row's text ends in `text`.
    ends: Vec<usize>,
    /// Each row's input; the first `ends.len()` are this batch's (the rest are kept for reuse).
    inputs: Vec<ModelInput>,
}

impl Batch {
    /// Rows per batch: large enough that the hand-over costs nothing per row, small enough that the
    /// two threads overlap from the start (≈ 1 MB of text for the 200-byte rows of a recording).
    pub(super) const ROWS: usize = 4096;

    fn new() -> Self {
        Batch {
            text: Vec::with_capacity(Self::ROWS * 256),
            ends: Vec::with_capacity(Self::ROWS),
            inputs: Vec::with_capacity(Self::ROWS),
        }
    }

    fn len(&self) -> usize {
        self.ends.len()
    }

    /// Ends the row whose text was just appended to `text`.
    fn end_row(&mut self, input: &ModelInput) {
        let i = self.ends.len();
        match self.inputs.get_mut(i) {
            // `clone_from` reuses the channel vectors' storage.
            Some(slot) => slot.clone_from(input),
            None => self.inputs.push(input.clone()),
        }
        self.ends.push(self.text.len());
    }

    /// Each row's passed-through text and input, in order.
    pub(super) fn rows(&self) -> impl Iterator<Item = (&[u8], &ModelInput)> {
        let starts = std::iter::once(0).chain(self.ends.iter().copied());
        starts
            .zip(&self.ends)
            .map(|(s, &e)| &self.text[s..e])
            .zip(&self.inputs)
    }
}

/// The reading thread's end of the hand-over.
pub(super) struct Feed<'a> {
    batch: Batch,
    full: SyncSender<Batch>,
    empty: &'a Receiver<Batch>,
    /// False once the evaluating side has stopped (its error is the one reported).
    open: bool,
}

impl<'a> Feed<'a> {
    /// `full` carries filled batches to the evaluator, `empty` brings them back for reuse. At most
    /// the channel's bound + 2 batches exist: a new one is made only when none has come back.
    pub(super) fn new(full: SyncSender<Batch>, empty: &'a Receiver<Batch>) -> Self {
        Feed {
            batch: Batch::new(),
            full,
            empty,
            open: true,
        }
    }

    fn end_row(&mut self, input: &ModelInput) {
        self.batch.end_row(input);
        if self.batch.len() == Batch::ROWS {
            self.send();
        }
    }

    fn send(&mut self) {
        let mut next = self.empty.try_recv().unwrap_or_else(|_| Batch::new());
        next.text.clear();
        next.ends.clear();
        let full = std::mem::replace(&mut self.batch, next);
        if self.full.send(full).is_err() {
            self.open = false;
        }
    }
}

/// Reads every row after the header (`rdr` is positioned just after it; `path` is opened again for
/// the plain-line reader) and returns every problem found. While none was found, rows go out
/// through `feed`; after the first, the rows are only checked.
pub(super) fn read_rows(
    path: &std::path::Path,
    rows: &RowReader<'_>,
    mut input: ModelInput,
    mut rdr: csv::Reader<std::fs::File>,
    mut feed: Feed<'_>,
) -> anyhow::Result<Problems> {
    let file = rows.file;
    let mut problems = Problems::default();
    let mut last_t = None;

    // Plain lines first (`plain.rs`): a plain line is its own passed-through columns.
    let p = rdr.position().clone();
    let at = plain::At {
        byte: p.byte(),
        line: p.line(),
        record: p.record(),
    };
    let mut src = std::fs::File::open(path).with_context(|| format!("{file}: cannot open"))?;
    std::io::Seek::seek(&mut src, std::io::SeekFrom::Start(at.byte))?;
    let mut lines = plain::PlainLines::new(src, at, rows.headers.len());
    loop {
        if !feed.open {
            return Ok(problems);
        }
        match lines
            .next_line()
            .with_context(|| format!("{file}: cannot read"))?
        {
            plain::Next::Plain(l) => {
                rows.parse(&l, &mut input, &mut last_t, &mut problems);
                if problems.count == 0 {
                    feed.batch.text.extend_from_slice(l.text);
                    feed.end_row(&input);
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
                    feed.send();
                }
                return Ok(problems);
            }
        }
    }

    // The rest, from the first line that is not plain, through the csv crate.
    let mut rec = csv::ByteRecord::new();
    while feed.open {
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
                feed.batch.text.push(b',');
            }
            push_csv_field(&mut feed.batch.text, field);
        }
        feed.end_row(&input);
    }
    if problems.count == 0 && feed.open {
        feed.send();
    }
    Ok(problems)
}

/// A passed-through field as the csv crate writes one (its `QuoteStyle::Necessary`): as is, or
/// quoted with inner quotes doubled when it holds a comma, a quote or a line break.
pub(super) fn push_csv_field(line: &mut Vec<u8>, field: &[u8]) {
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

/// The first [`Problems::SHOWN`] problems word for word, and how many there were in all.
#[derive(Default)]
pub(super) struct Problems {
    pub(super) shown: Vec<String>,
    pub(super) count: usize,
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
pub(super) struct RowReader<'a> {
    pub(super) file: &'a str,
    pub(super) headers: &'a csv::StringRecord,
    pub(super) cols: &'a Columns,
    pub(super) held_mm: [f64; 3],
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
