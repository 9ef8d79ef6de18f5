//! The legacy controller's DNC input (sans-IO): a part program that arrives over RS-232 while it
//! runs, as old controls take it in "tape" / DNC mode. Received characters are assembled into lines
//! (LF ends a line, CR and NUL are ignored, `%` tape marks are skipped) and held in a buffer of
//! `buffer_lines` lines; the interpreter takes the next line when it has executed everything before
//! it. Flow control is the control's own: DC3 (XOFF, 0x13) goes out when the buffer holds
//! `xoff_at_lines` lines, DC1 (XON, 0x11) when it has drained to `xon_at_lines`. A line arriving
//! while the buffer is full is an overrun: counted and logged (a real control alarms; this one keeps
//! the line, so a run with overruns still shows what the rest of the program did).
//!
//! Times are simulated seconds. The shell ([`crate::io::serve`]) moves bytes between the serial
//! device and [`DncInput::receive`] / [`DncInput::take_output`].

use super::gcode::{Block, GcodeError, Parser};
use super::interp::ProgramRunner;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::path::PathBuf;

pub(crate) const XON: u8 = 0x11;
pub(crate) const XOFF: u8 = 0x13;

/// `[io.dnc]`: the DNC input of `hil-sim serve`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DncConfig {
    /// The serial device the program arrives on (one end of a socat pty pair in tests).
    pub device: PathBuf,
    /// Baud rate the device is opened with (a pty ignores it).
    #[serde(default = "d_baud")]
    pub baud: u32,
    /// Lines the control buffers.
    #[serde(default = "d_buffer")]
    pub buffer_lines: usize,
    /// Send XOFF when the buffer holds this many lines (default `buffer_lines − 1`: the line
    /// already on the wire when XOFF leaves still finds room).
    #[serde(default)]
    pub xoff_at_lines: Option<usize>,
    /// Send XON when the buffer has drained to this many lines.
    #[serde(default = "d_xon")]
    pub xon_at_lines: usize,
}
fn d_baud() -> u32 {
    9600
}
fn d_buffer() -> usize {
    5
}
fn d_xon() -> usize {
    1
}

impl DncConfig {
    pub fn xoff_at(&self) -> usize {
        self.xoff_at_lines
            .unwrap_or(self.buffer_lines.saturating_sub(1).max(1))
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        let (n, off, on) = (self.buffer_lines, self.xoff_at(), self.xon_at_lines);
        anyhow::ensure!(
            (1..=1000).contains(&n),
            "io.dnc.buffer_lines must be 1..=1000, got {n}"
        );
        anyhow::ensure!(
            (1..=n).contains(&off),
            "io.dnc.xoff_at_lines must be 1..=buffer_lines ({n}), got {off}"
        );
        anyhow::ensure!(
            on < off,
            "io.dnc.xon_at_lines must be below xoff_at_lines ({off}), got {on}"
        );
        Ok(())
    }
}

/// What happened on the DNC input, for `dnc.csv`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DncEventKind {
    /// A line arrived and was buffered.
    Received,
    /// A line arrived while the buffer was full (kept, counted).
    Overrun,
    /// The interpreter took a line.
    Taken,
    Xoff,
    Xon,
}

impl DncEventKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Received => "received",
            Self::Overrun => "overrun",
            Self::Taken => "taken",
            Self::Xoff => "xoff",
            Self::Xon => "xon",
        }
    }
}

/// One event: its time, the line number (1 = first line received) and the buffer fill after it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DncEvent {
    pub t_s: f64,
    pub kind: DncEventKind,
    pub line: usize,
    pub fill: usize,
}

/// Counters of a DNC transfer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DncCounts {
    pub lines: u64,
    pub overruns: u64,
    pub xoffs: u64,
    pub max_fill: usize,
}

#[derive(Debug)]
pub struct DncInput {
    cfg: DncConfig,
    partial: Vec<u8>,
    buffer: VecDeque<(usize, String)>,
    held: bool,
    out: Vec<u8>,
    events: Vec<DncEvent>,
    counts: DncCounts,
}

impl DncInput {
    pub fn new(cfg: DncConfig) -> Self {
        let n = cfg.buffer_lines;
        Self {
            cfg,
            partial: Vec::with_capacity(256),
            buffer: VecDeque::with_capacity(n + 1),
            held: false,
            out: Vec::new(),
            events: Vec::new(),
            counts: DncCounts::default(),
        }
    }

    pub fn config(&self) -> &DncConfig {
        &self.cfg
    }

    pub fn counts(&self) -> DncCounts {
        self.counts
    }

    pub fn fill(&self) -> usize {
        self.buffer.len()
    }

    /// Characters from the line at simulated time `t_s`.
    pub fn receive(&mut self, bytes: &[u8], t_s: f64) {
        for &b in bytes {
            match b {
                b'\n' => self.end_line(t_s),
                b'\r' | 0 => {}
                _ => self.partial.push(b),
            }
        }
    }

    fn end_line(&mut self, t_s: f64) {
        let text = String::from_utf8_lossy(&self.partial).trim().to_string();
        self.partial.clear();
        if text.is_empty() || text == "%" {
            return;
        }
        self.counts.lines += 1;
        let line = usize::try_from(self.counts.lines).unwrap_or(usize::MAX);
        let kind = if self.buffer.len() >= self.cfg.buffer_lines {
            self.counts.overruns += 1;
            DncEventKind::Overrun
        } else {
            DncEventKind::Received
        };
        self.buffer.push_back((line, text));
        self.counts.max_fill = self.counts.max_fill.max(self.buffer.len());
        self.event(t_s, kind, line);
        if !self.held && self.buffer.len() >= self.cfg.xoff_at() {
            self.held = true;
            self.counts.xoffs += 1;
            self.out.push(XOFF);
            self.event(t_s, DncEventKind::Xoff, line);
        }
    }

    /// The interpreter takes the next line (its number and text), if one is buffered.
    pub fn take_line(&mut self, t_s: f64) -> Option<(usize, String)> {
        let (line, text) = self.buffer.pop_front()?;
        self.event(t_s, DncEventKind::Taken, line);
        if self.held && self.buffer.len() <= self.cfg.xon_at_lines {
            self.held = false;
            self.out.push(XON);
            self.event(t_s, DncEventKind::Xon, line);
        }
        Some((line, text))
    }

    /// Bytes to send back to the sender (XON/XOFF), oldest first.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.out)
    }

    /// Events since the last call.
    pub fn take_events(&mut self) -> Vec<DncEvent> {
        std::mem::take(&mut self.events)
    }

    fn event(&mut self, t_s: f64, kind: DncEventKind, line: usize) {
        let fill = self.buffer.len();
        self.events.push(DncEvent {
            t_s,
            kind,
            line,
            fill,
        });
    }
}

/// The DNC input feeding the interpreter: lines taken from the buffer are parsed with the modal
/// state of the lines before them and handed to the streaming runner whenever it has executed
/// everything it holds. A line the controller cannot parse ends the program (an alarm).
#[derive(Debug)]
pub struct DncStream {
    pub input: DncInput,
    parser: Parser,
    scratch: Vec<Block>,
    ended: bool,
    /// The line that stopped the program, if one did.
    pub error: Option<GcodeError>,
}

impl DncStream {
    pub fn new(cfg: DncConfig, start_mm: [f64; 3], rapid_mm_min: f64) -> Self {
        Self {
            input: DncInput::new(cfg),
            parser: Parser::new(start_mm, rapid_mm_min),
            scratch: Vec::with_capacity(8),
            ended: false,
            error: None,
        }
    }

    /// Give the runner the next lines' blocks if it has run out (lines without blocks, such as
    /// `G90` or a comment, are taken in the same call).
    pub fn feed(&mut self, runner: &mut ProgramRunner, t_s: f64) {
        while runner.starved() && !self.ended {
            let Some((line, text)) = self.input.take_line(t_s) else {
                return;
            };
            match self.parser.line(&text, line, &mut self.scratch) {
                Ok(end) => self.ended = end,
                Err(e) => {
                    self.scratch.push(Block::End { line });
                    self.error = Some(e);
                    self.ended = true;
                }
            }
            runner.push(&mut self.scratch);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(n: usize) -> DncInput {
        DncInput::new(DncConfig {
            device: "/dev/null".into(),
            baud: 9600,
            buffer_lines: n,
            xoff_at_lines: None,
            xon_at_lines: 1,
        })
    }

    #[test]
    fn xoff_with_one_line_of_room_xon_when_drained_and_an_overrun_is_counted() {
        let mut d = input(5);
        d.receive(b"%\r\nG1 X1 F100\r\nX2\r\nX3\r\n", 0.0);
        assert!(d.take_output().is_empty());
        d.receive(b"X4\r\nX", 1.0);
        assert_eq!(d.take_output(), vec![XOFF], "4 of 5 held: XOFF");
        d.receive(b"5\r\n", 1.1);
        assert_eq!((d.fill(), d.counts().overruns), (5, 0));
        d.receive(b"X6\n", 1.2);
        assert_eq!(d.counts().overruns, 1, "a sixth line into five");
        for want in 1..=4 {
            assert_eq!(d.take_line(2.0).unwrap().0, want);
        }
        assert!(d.take_output().is_empty(), "2 left: still held");
        assert_eq!(d.take_line(3.0).unwrap(), (5, "X5".to_string()));
        assert_eq!(d.take_output(), vec![XON]);
        let c = d.counts();
        assert_eq!((c.lines, c.xoffs, c.max_fill), (6, 1, 6));
        let kinds: Vec<_> = d.take_events().iter().map(|e| e.kind.name()).collect();
        assert_eq!(kinds.iter().filter(|k| **k == "overrun").count(), 1);
        assert_eq!(kinds.last(), Some(&"xon"));
    }

    #[test]
    fn the_runner_executes_lines_as_they_arrive_and_waits_between_them() {
        let mut d = DncStream::new(input(5).cfg, [0.0; 3], 6000.0);
        let mut r = ProgramRunner::streaming([0.0; 3]);
        d.input.receive(b"G90\nG1 X10 F600\n", 0.0);
        d.feed(&mut r, 0.0);
        assert_eq!(
            d.input.fill(),
            0,
            "G90 has no block: the move's line is taken too"
        );
        let mut sp = r.advance(0.5);
        assert!((sp.pos_mm[0] - 5.0).abs() < 1e-9);
        sp = r.advance(1.0);
        assert!(!sp.done && sp.pos_mm[0] == 10.0, "waits at the end: {sp:?}");
        d.feed(&mut r, 1.5);
        assert!(r.starved());
        d.input.receive(b"G4 P1\nM30\n", 1.6);
        d.feed(&mut r, 1.6);
        assert_eq!(r.dwell_ending(0.5), None);
        r.advance(0.6);
        assert_eq!(
            r.dwell_ending(0.5),
            Some(3),
            "the dwell's line ends within 0.5 s"
        );
        r.advance(0.5);
        d.feed(&mut r, 2.7);
        assert!(r.advance(0.001).done);
        assert!(d.error.is_none());
    }

    #[test]
    fn a_line_the_controller_cannot_parse_ends_the_program() {
        let mut d = DncStream::new(input(5).cfg, [0.0; 3], 6000.0);
        let mut r = ProgramRunner::streaming([0.0; 3]);
        d.input.receive(b"G1 X10 F600\nG81 X1\nX20\n", 0.0);
        d.feed(&mut r, 0.0);
        while !r.advance(0.1).done {
            d.feed(&mut r, 0.0);
        }
        assert_eq!(d.error.as_ref().map(|e| e.line), Some(2));
        assert_eq!(d.input.fill(), 1, "nothing after the refused line is taken");
    }

    #[test]
    fn a_buffer_that_cannot_hold_back_is_refused() {
        let mut c = input(5).cfg;
        c.xon_at_lines = 4;
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("xon_at_lines")
        );
        c.xon_at_lines = 1;
        c.xoff_at_lines = Some(6);
        assert!(
            c.validate()
                .unwrap_err()
                .to_string()
                .contains("xoff_at_lines")
        );
    }
}
