//! The sans-IO DNC drip-feed core: program lines in, controller lines out, one block at a time.
//!
//! - A block is compensated when it is about to be sent (the previous one has left the box), so
//!   its correction is the live one at send time ([`LiveCorrections`]: the model at the block's
//!   nominal end point through the last-step guard). Modal state and approach directions are the
//!   NC rewriter's (`retrocomp_analysis::nc::rewrite`), as in `retrocomp nc`.
//! - A compensated line longer than the control's `max_line_chars` is refused
//!   ([`DncError::LineTooLong`]: the transfer stops there), never truncated.
//! - Flow: XOFF (DC3) stops and XON (DC1) resumes sending at the next line boundary; RTS/CTS is
//!   the same through [`DncCore::flow`]. Stopped longer than `stall_timeout_s` is a stall fault
//!   ([`DncCore::poll_stall`]: an edge on start and on clear); the line waiting stays queued, so it
//!   is neither lost nor sent twice.
//! - Resume: blocks before the operator's line number are interpreted for modal state only and
//!   not sent; [`DncCore::resume_point`] is the first block not completely sent.
//! - Lead: with `[dnc] lead_blocks` below `buffer_lines` the next block is held (compensated
//!   later) while the estimate of the control's buffer ([`ExecEstimate`]) says that many lines
//!   still wait there; the controller's XOFF stops the transfer whatever the estimate says.
//! - Every block sent yields a [`SentBlock`] (its line, nominal end point, correction, time) for
//!   the CSV log ([`LOG_HEADER`]).
//!
//! Time is the caller's (s, any epoch); nothing here sleeps or reads a clock. Units: mm, µm.

use std::collections::VecDeque;

use retrocomp_analysis::nc::parser::{Block, parse_line};
use retrocomp_analysis::nc::rewrite::{Point, RewriteConfig, RewriteSink, Rewriter};

use super::lead::{ExecEstimate, LeadConfig};
use super::live::{Applied, LiveCorrections};
use retrocomp_gateway::sinks::dnc::LineEnd;

pub(crate) const XON: u8 = 0x11;
pub(crate) const XOFF: u8 = 0x13;

/// Header of the send log: source line, nominal end point (machine, X radial, mm), correction
/// carried per axis (µm, = −error; the block's end point is nominal + correction), send time (s,
/// from the start of the transfer) and the text sent.
pub(crate) const LOG_HEADER: &str = "line,x_mm,y_mm,z_mm,cx_um,cy_um,cz_um,t_s,text";

/// What the core needs to know of the link and the program.
#[derive(Clone, Debug)]
pub struct CoreConfig {
    pub line_end: LineEnd,
    pub max_line_chars: usize,
    pub leader_nuls: usize,
    pub trailer_nuls: usize,
    pub stall_timeout_s: f64,
    /// Longest wait for the model's inputs before the first byte, s ([`DncError::NoInputs`]).
    pub start_timeout_s: f64,
    pub semicolon_is_eob: bool,
    pub diameter_x: bool,
    /// First source line to send (operator's choice after an interrupted transfer); 1 = all.
    pub resume_from: u64,
    /// Clamp of the correction, µm (the rewriter's own limit sits just above it).
    pub max_correction_um: f64,
    /// How far ahead of its estimated execution a block is compensated.
    pub lead: LeadConfig,
}

/// Why the transfer cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum DncError {
    #[error(
        "line {line}: the compensated block has {chars} characters, more than the control's {max} (dnc.max_line_chars): refused, not truncated"
    )]
    LineTooLong { line: u64, chars: usize, max: usize },
    #[error("{0}")]
    Program(String),
    #[error(
        "no correction after waiting {waited_s:.1} s (dnc.start_timeout_s) for the model's inputs: {why}; nothing was sent"
    )]
    NoInputs { waited_s: f64, why: String },
}

/// One block that left the box.
#[derive(Clone, Debug, PartialEq)]
pub struct SentBlock {
    pub line: u64,
    /// Nominal end point and its correction (None: no compensated end point in this block).
    pub applied: Option<Applied>,
    pub t_s: f64,
    pub text: String,
}

impl SentBlock {
    /// One row of the send log (`LOG_HEADER`).
    pub fn csv_row(&self) -> String {
        let text = self.text.replace('"', "\"\"");
        match &self.applied {
            Some(a) => format!(
                "{},{:.4},{:.4},{:.4},{:.1},{:.1},{:.1},{:.3},\"{text}\"",
                self.line,
                a.pos_mm[0],
                a.pos_mm[1],
                a.pos_mm[2],
                a.correction_um[0],
                a.correction_um[1],
                a.correction_um[2],
                self.t_s
            ),
            None => format!("{},,,,,,,{:.3},\"{text}\"", self.line, self.t_s),
        }
    }
}

/// A stall episode's edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StallEdge {
    /// Stopped since `since_s`, longer than the timeout; `line` is the block waiting.
    Started {
        since_s: f64,
        line: u64,
    },
    Cleared {
        after_s: f64,
    },
}

/// Collects what the rewriter writes for one block.
#[derive(Default)]
struct BlockOut {
    lines: Vec<String>,
    point: Option<[f64; 3]>,
}

impl RewriteSink for BlockOut {
    fn line(&mut self, text: &str) -> std::io::Result<()> {
        // The rewriter ends blocks with `;` (how Fanuc shows EOB); on the wire the line end is
        // the EOB, and a literal `;` is not ISO tape code some controls accept.
        self.lines
            .push(text.strip_suffix(';').unwrap_or(text).to_string());
        Ok(())
    }
    fn point(&mut self, p: &Point) -> std::io::Result<()> {
        self.point = Some(p.nominal_mm);
        Ok(())
    }
}

/// One queued output unit: bytes, and the block it completes (if it is a block's last line).
struct Unit {
    bytes: Vec<u8>,
    line: u64,
    text: String,
    last_of_block: bool,
    /// Estimated run time on the control, s; None: not a line the control buffers (leader,
    /// trailer, tape mark).
    exec_s: Option<f64>,
}

pub struct DncCore<'m> {
    cfg: CoreConfig,
    live: &'m LiveCorrections,
    rw: Rewriter<'m>,
    blocks: VecDeque<Block>,
    out: VecDeque<Unit>,
    stopped_since: Option<f64>,
    stalled: bool,
    input_done: bool,
    tape_marks: u32,
    trailer_queued: bool,
    /// First source line not completely sent.
    resume_point: u64,
    blocks_sent: u64,
    lead: ExecEstimate,
    /// Before the first byte: the start gate's wait (None once the model was ready).
    start: Option<StartWait>,
}

/// The start gate's wait for the model's inputs.
#[derive(Debug, Default)]
struct StartWait {
    /// First asked at, s (None before the first ask).
    since_s: Option<f64>,
    /// The inputs the model still lacks, as the engine says it ("T_spindle_C (stale)").
    missing: String,
}

// By hand: the rewriter holds a trait object.
impl std::fmt::Debug for DncCore<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DncCore")
            .field("cfg", &self.cfg)
            .field("stopped_since", &self.stopped_since)
            .field("resume_point", &self.resume_point)
            .finish_non_exhaustive()
    }
}

impl<'m> DncCore<'m> {
    pub fn new(cfg: CoreConfig, live: &'m LiveCorrections) -> Self {
        let rc = RewriteConfig {
            diameter_x: cfg.diameter_x,
            // The guard clamps; the rewriter's own limit only catches what slipped past it.
            max_correction_um: cfg.max_correction_um + 2.0 * super::live::BLOCK_LSB_UM,
            ..RewriteConfig::default()
        };
        let cfg_lead = cfg.lead;
        let mut out = VecDeque::new();
        if cfg.leader_nuls > 0 {
            out.push_back(Unit {
                bytes: vec![0; cfg.leader_nuls],
                line: 0,
                text: String::new(),
                last_of_block: false,
                exec_s: None,
            });
        }
        Self {
            rw: Rewriter::new(live, &rc),
            live,
            resume_point: cfg.resume_from.max(1),
            cfg,
            blocks: VecDeque::new(),
            out,
            stopped_since: None,
            stalled: false,
            input_done: false,
            tape_marks: 0,
            trailer_queued: false,
            blocks_sent: 0,
            lead: ExecEstimate::new(cfg_lead),
            start: Some(StartWait::default()),
        }
    }

    /// More program may be given: nothing parsed is waiting (input is read one line ahead at most,
    /// so a slow controller holds the sender back).
    pub fn wants_input(&self) -> bool {
        !self.input_done && self.blocks.is_empty()
    }

    /// Source line `line_no` (1-based) of the program. The second `%` ends the program (ISO tape
    /// end): what follows is not sent.
    pub fn feed_line(&mut self, line_no: u64, raw: &str) -> Result<(), DncError> {
        let blocks = parse_line("program", line_no, raw, self.cfg.semicolon_is_eob)
            .map_err(|e| DncError::Program(e.to_string()))?;
        for b in blocks {
            if b.words.is_empty() && b.source == "%" {
                self.tape_marks += 1;
            }
            self.blocks.push_back(b);
            // The second `%` is the tape end: a sender that keeps its line open ends here.
            if self.tape_marks == 2 {
                self.input_done = true;
                break;
            }
        }
        Ok(())
    }

    /// The program has ended (end of file, sender closed).
    pub fn end_of_input(&mut self) {
        self.input_done = true;
    }

    /// Everything, trailer included, has been sent.
    pub fn done(&self) -> bool {
        self.input_done && self.blocks.is_empty() && self.out.is_empty() && self.trailer_queued
    }

    /// The next bytes to write (a whole line with its line end, or leader/trailer), or None while
    /// the controller said stop or nothing is ready. The block is compensated here, at `now_s`.
    pub fn next_to_send(&mut self, now_s: f64) -> Result<Option<&[u8]>, DncError> {
        if self.stopped_since.is_some() || !self.inputs_ready(now_s)? {
            return Ok(None);
        }
        while self.out.is_empty() {
            if !self.blocks.is_empty() && self.lead.holds(now_s) {
                return Ok(None);
            }
            let Some(b) = self.blocks.pop_front() else {
                if self.input_done && !self.trailer_queued {
                    self.trailer_queued = true;
                    if self.cfg.trailer_nuls > 0 {
                        self.out.push_back(Unit {
                            bytes: vec![0; self.cfg.trailer_nuls],
                            line: 0,
                            text: String::new(),
                            last_of_block: false,
                            exec_s: None,
                        });
                    }
                    continue;
                }
                return Ok(None);
            };
            self.prepare(&b, now_s)?;
        }
        Ok(self.out.front().map(|u| u.bytes.as_slice()))
    }

    /// The start gate: nothing leaves the box before the model can be evaluated (a block sent
    /// earlier would carry no correction). Once open it stays open: later input faults are the
    /// blocks' model faults (they carry the held correction).
    fn inputs_ready(&mut self, now_s: f64) -> Result<bool, DncError> {
        let Some(wait) = &mut self.start else {
            return Ok(true);
        };
        match self.live.ready(now_s) {
            Ok(()) => {
                self.start = None;
                Ok(true)
            }
            Err(w) => {
                let since = *wait.since_s.get_or_insert(now_s);
                if now_s - since >= self.cfg.start_timeout_s {
                    return Err(DncError::NoInputs {
                        waited_s: now_s - since,
                        why: w,
                    });
                }
                wait.missing = w;
                Ok(false)
            }
        }
    }

    /// Waiting at the start for these model inputs (what [`Self::next_to_send`] last found
    /// missing); None once the first byte may go.
    pub fn waiting_for_inputs(&self) -> Option<&str> {
        self.start
            .as_ref()
            .map(|w| w.missing.as_str())
            .filter(|w| !w.is_empty())
    }

    /// Rewrite one block with the live correction at `now_s` and queue its lines.
    fn prepare(&mut self, b: &Block, now_s: f64) -> Result<(), DncError> {
        let skip = b.line < self.cfg.resume_from;
        self.live.set_bypass(skip);
        self.live.set_now(now_s);
        let exec_s = self.lead.duration_s(b);
        self.live.set_end_s(self.lead.end_if_sent_s(exec_s, now_s));
        let mut bo = BlockOut::default();
        let res = self.rw.block(b, &mut bo);
        self.live.set_bypass(false);
        if let Err(e) = res {
            self.live.discard();
            return Err(DncError::Program(e.to_string()));
        }
        if skip {
            self.live.discard();
            return Ok(());
        }
        if let Some(long) = bo.lines.iter().find(|l| l.len() > self.cfg.max_line_chars) {
            self.live.discard();
            return Err(DncError::LineTooLong {
                line: b.line,
                chars: long.len(),
                max: self.cfg.max_line_chars,
            });
        }
        if bo.point.is_none() {
            // A block without a compensated end point carries the held correction.
            self.live.discard();
        }
        let n = bo.lines.len();
        let tape_mark = b.words.is_empty() && b.source == "%";
        for (k, text) in bo.lines.into_iter().enumerate() {
            let mut bytes = text.clone().into_bytes();
            bytes.extend_from_slice(self.cfg.line_end.bytes());
            self.out.push_back(Unit {
                bytes,
                line: b.line,
                text,
                last_of_block: k + 1 == n,
                // The block runs with its last line; a tape mark is not buffered.
                exec_s: (!tape_mark).then_some(if k + 1 == n { exec_s } else { 0.0 }),
            });
        }
        Ok(())
    }

    /// The bytes last given by [`Self::next_to_send`] were written; the block they complete (if
    /// any) is returned for the log and its correction is what the controller holds now.
    pub fn sent(&mut self, now_s: f64) -> Option<SentBlock> {
        let u = self.out.pop_front()?;
        if let Some(d) = u.exec_s {
            self.lead.sent(d, now_s);
        }
        if !u.last_of_block {
            return None;
        }
        self.blocks_sent += 1;
        self.resume_point = u.line + 1;
        Some(SentBlock {
            line: u.line,
            applied: self.live.commit(),
            t_s: now_s,
            text: u.text,
        })
    }

    /// Bytes the controller sent (XON/XOFF mode): DC3 stops, DC1 resumes; others are ignored.
    pub fn on_bytes(&mut self, bytes: &[u8], now_s: f64) {
        for &b in bytes {
            match b {
                XOFF => self.flow(true, now_s),
                XON => self.flow(false, now_s),
                _ => {}
            }
        }
    }

    /// The controller says stop (`true`: XOFF, CTS low) or go.
    pub fn flow(&mut self, stop: bool, now_s: f64) {
        if stop {
            self.stopped_since.get_or_insert(now_s);
        } else {
            self.stopped_since = None;
        }
    }

    /// Whether the controller holds the transfer now.
    pub fn stopped(&self) -> bool {
        self.stopped_since.is_some()
    }

    /// A stall starting (stopped longer than the timeout) or clearing, once per edge.
    pub fn poll_stall(&mut self, now_s: f64) -> Option<StallEdge> {
        match (self.stopped_since, self.stalled) {
            (Some(since), false) if now_s - since > self.cfg.stall_timeout_s => {
                self.stalled = true;
                Some(StallEdge::Started {
                    since_s: since,
                    line: self.out.front().map_or(self.resume_point, |u| u.line),
                })
            }
            (None, true) => {
                self.stalled = false;
                Some(StallEdge::Cleared { after_s: now_s })
            }
            _ => None,
        }
    }

    pub fn stalled(&self) -> bool {
        self.stalled
    }

    /// The first block not completely sent: where an interrupted transfer resumes (operator's
    /// `--resume-from`).
    pub fn resume_point(&self) -> u64 {
        self.out
            .iter()
            .find(|u| u.line > 0)
            .map_or(self.resume_point, |u| u.line)
    }

    /// When a lead hold is estimated to release (for a shell that sleeps until something
    /// happens); None when nothing is held.
    pub fn lead_release_s(&self) -> Option<f64> {
        self.lead.release_s()
    }

    pub fn blocks_sent(&self) -> u64 {
        self.blocks_sent
    }

    /// When the next stall check is due (for a shell that sleeps until something happens).
    pub fn stall_deadline_s(&self) -> Option<f64> {
        (!self.stalled)
            .then_some(self.stopped_since?)
            .map(|s| s + self.cfg.stall_timeout_s)
    }
}
