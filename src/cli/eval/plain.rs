//! The fast path of `retrocomp eval`'s reader: lines that are plain CSV (no quote, no carriage return
//! except in a final `\r\n`, not empty, as many fields as the header) are split here, on commas; the
//! first line that is not plain is handed to the csv crate, which reads the rest of the file (quoted
//! fields, blank lines, wrong field counts and their error messages are all its own).
//!
//! Why: for a plain line the fields joined by commas are the line itself, so the passed-through
//! columns are one copy of the line, and splitting with `memchr` is several times cheaper than the
//! csv crate's byte-at-a-time state machine (which, with the per-field copies, was about a third of
//! `eval`'s user time on 10⁶ rows). A plain line splits the same way under both readers; the unit
//! tests below check records and positions against the csv crate on mixed inputs.

use std::io::Read;

/// Where the next record starts: byte offset, line (1-based) and record index, as `csv::Position`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct At {
    pub(super) byte: u64,
    pub(super) line: u64,
    pub(super) record: u64,
}

/// One plain line: its bytes without the terminator, and where each field ends.
pub(super) struct PlainLine<'a> {
    pub(super) text: &'a [u8],
    ends: &'a [usize],
    pub(super) line: u64,
}

impl PlainLine<'_> {
    pub(super) fn field(&self, i: usize) -> &[u8] {
        let start = if i == 0 { 0 } else { self.ends[i - 1] + 1 };
        &self.text[start..self.ends[i]]
    }
}

pub(super) enum Next<'a> {
    Plain(PlainLine<'a>),
    /// The line at `At` is not plain: the csv crate takes over there.
    HandOver(At),
    End,
}

/// Reads plain lines from `R` from a given position on.
pub(super) struct PlainLines<R> {
    src: R,
    buf: Vec<u8>,
    /// Unread bytes are `buf[start..end]`; `at` is where `buf[start]` lies in the file.
    start: usize,
    end: usize,
    eof: bool,
    at: At,
    fields: usize,
    ends: Vec<usize>,
}

impl<R: Read> PlainLines<R> {
    const BUF: usize = 1 << 20;

    /// `src` positioned at `at` (just after the header); `fields` = the header's field count.
    pub(super) fn new(src: R, at: At, fields: usize) -> Self {
        PlainLines {
            src,
            buf: vec![0; Self::BUF],
            start: 0,
            end: 0,
            eof: false,
            at,
            fields,
            ends: Vec::with_capacity(fields),
        }
    }

    /// The next line, if plain.
    pub(super) fn next_line(&mut self) -> std::io::Result<Next<'_>> {
        let (len, term) = loop {
            let rest = &self.buf[self.start..self.end];
            match memchr::memchr(b'\n', rest) {
                Some(i) => break (i, 1),
                None if self.eof => break (rest.len(), 0),
                None => self.fill()?,
            }
        };
        if len == 0 && term == 0 {
            return Ok(Next::End);
        }
        let mut text = &self.buf[self.start..self.start + len];
        if let [head @ .., b'\r'] = text {
            text = head;
        }
        let plain = !text.is_empty() && memchr::memchr2(b'"', b'\r', text).is_none() && {
            self.ends.clear();
            self.ends.extend(memchr::memchr_iter(b',', text));
            self.ends.push(text.len());
            self.ends.len() == self.fields
        };
        if !plain {
            return Ok(Next::HandOver(self.at));
        }
        let line = self.at.line;
        self.start += len + term;
        self.at.byte += (len + term) as u64;
        self.at.line += 1;
        self.at.record += 1;
        Ok(Next::Plain(PlainLine {
            text,
            ends: &self.ends,
            line,
        }))
    }

    /// Keeps the unread bytes and reads more after them (the buffer grows for a line longer than it).
    fn fill(&mut self) -> std::io::Result<()> {
        self.buf.copy_within(self.start..self.end, 0);
        self.end -= self.start;
        self.start = 0;
        if self.end == self.buf.len() {
            self.buf.resize(self.buf.len() * 2, 0);
        }
        loop {
            match self.src.read(&mut self.buf[self.end..]) {
                Ok(0) => {
                    self.eof = true;
                    return Ok(());
                }
                Ok(n) => {
                    self.end += n;
                    return Ok(());
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records (fields, line) as the csv crate reads them, and as plain lines + the csv crate after
    /// the hand-over read them; the two must agree, as must the first error.
    fn both(text: &str) {
        let reader = || {
            csv::ReaderBuilder::new()
                .flexible(false)
                .from_reader(std::io::Cursor::new(text.as_bytes()))
        };
        let collect = |rdr: &mut csv::Reader<std::io::Cursor<&[u8]>>, out: &mut Vec<String>| {
            let mut rec = csv::ByteRecord::new();
            loop {
                match rdr.read_byte_record(&mut rec) {
                    Ok(true) => {
                        out.push(format!("{:?} line {}", rec, rec.position().unwrap().line()));
                    }
                    Ok(false) => break,
                    Err(e) => {
                        out.push(format!("error {e}"));
                        break;
                    }
                }
            }
        };
        let mut theirs = Vec::new();
        collect(&mut reader(), &mut theirs);

        let mut rdr = reader();
        let n = rdr.byte_headers().unwrap().len();
        let p = rdr.position().clone();
        let at = At {
            byte: p.byte(),
            line: p.line(),
            record: p.record(),
        };
        let mut src = std::io::Cursor::new(text.as_bytes());
        src.set_position(at.byte);
        let mut plain = PlainLines::new(src, at, n);
        let mut ours = Vec::new();
        loop {
            match plain.next_line().unwrap() {
                Next::Plain(l) => {
                    let fields: Vec<&[u8]> = (0..n).map(|i| l.field(i)).collect();
                    let rec = csv::ByteRecord::from(fields);
                    ours.push(format!("{rec:?} line {}", l.line));
                }
                Next::HandOver(at) => {
                    let mut pos = csv::Position::new();
                    pos.set_byte(at.byte)
                        .set_line(at.line)
                        .set_record(at.record);
                    rdr.seek_raw(std::io::SeekFrom::Start(at.byte), pos)
                        .unwrap();
                    collect(&mut rdr, &mut ours);
                    break;
                }
                Next::End => break,
            }
        }
        assert_eq!(ours, theirs, "{text:?}");
    }

    #[test]
    fn plain_lines_and_the_hand_over_read_what_the_csv_crate_reads() {
        for text in [
            "a,b,c\n1,2,3\n4,5,6\n",
            "a,b,c\n1,2,3\n4,5,6",
            "a,b,c\r\n1,2,3\r\n4,5,6\r\n",
            "\"a\",\"b\",\"c\"\n1,2,3\n",
            "a,b,c\n1,2,3\n\"x,y\",5,6\n7,8,9\n",
            "a,b,c\n1,2,3\n\"two\nlines\",5,6\n7,8,9\n",
            "a,b,c\n1,2,3\n\n4,5,6\n",
            "a,b,c\n1,2,3\n4,5\n6,7,8\n",
            "a,b,c\n1,2,3\n4,5,6,7\n",
            "a,b,c\n1,2\r3,4\n",
            "a,b,c\n,,\n1,,3\n",
            "a\n1\n\n2\n",
            "a,b,c\n",
            "a,b,c",
        ] {
            both(text);
        }
    }

    #[test]
    fn a_line_longer_than_the_buffer_is_read_whole() {
        let long = "9".repeat(3 << 20);
        both(&format!("a,b\n1,{long}\n3,4\n"));
    }
}
