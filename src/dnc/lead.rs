//! How far ahead of its execution a block is compensated: the box's estimate of the control's
//! buffer (Spaan 1995, Ch7: the control's fill level is watched).
//!
//! A block's correction is taken when it is sent, but the control executes it only after the
//! blocks already in its buffer. The box estimates when the control runs each line it sent: a
//! line's duration is its nominal path length / its modal feed (G0 at `rapid_mm_min`; a G4 dwell
//! its time; anything it cannot time counts 0 s), divided by `control_speed`; the control runs
//! lines in order, each starting when the previous one ends and not before it arrived. With
//! `lead_blocks = N < buffer_lines` the next block is held until fewer than N sent lines are
//! estimated to be still waiting, so its correction is taken at most ≈ N lines before it runs.
//! `lead_blocks = buffer_lines` never holds (the control's XON/XOFF alone paces the transfer).
//!
//! This is an estimate, not an observation: a control faster than estimated (feed override above
//! what `control_speed` says) waits between blocks; a slower one fills its buffer and says XOFF,
//! which the core obeys regardless. Nothing here claims what the control actually did.
//!
//! Units: mm, mm/min, s of the box's clock. The chord stands for an arc's length (an arc's
//! duration is underestimated: the box sends earlier, never later).

use std::collections::VecDeque;

use retrocomp_analysis::nc::parser::Block;

/// The `[dnc]` keys of the estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeadConfig {
    /// Hold while this many sent lines are estimated to wait in the control.
    pub lead_blocks: usize,
    pub buffer_lines: usize,
    /// G0 feed, mm/min.
    pub rapid_mm_min: f64,
    /// The control runs the program this many times faster than programmed (1 on a machine at
    /// 100 % override; a simulator paced faster than real time: its speed).
    pub control_speed: f64,
    /// Fanuc dialect (`;` ends a block): G4 P is milliseconds; otherwise seconds.
    pub dwell_p_ms: bool,
}

impl LeadConfig {
    /// Today's behaviour: never hold.
    pub fn off(buffer_lines: usize) -> Self {
        Self {
            lead_blocks: buffer_lines,
            buffer_lines,
            rapid_mm_min: 5000.0,
            control_speed: 1.0,
            dwell_p_ms: false,
        }
    }
}

/// The modal state a duration needs and the estimated schedule of the lines sent.
#[derive(Debug)]
pub(crate) struct ExecEstimate {
    cfg: LeadConfig,
    pos_mm: [f64; 3],
    feed_mm_min: Option<f64>,
    rapid: bool,
    incremental: bool,
    inch: bool,
    inverse_time: bool,
    /// Estimated start (s) of each sent line not yet started, in order.
    starts: VecDeque<f64>,
    /// Estimated end (s) of the last line sent.
    busy_until_s: f64,
}

impl ExecEstimate {
    pub(crate) fn new(cfg: LeadConfig) -> Self {
        Self {
            cfg,
            pos_mm: [0.0; 3],
            feed_mm_min: None,
            rapid: false,
            incremental: false,
            inch: false,
            inverse_time: false,
            starts: VecDeque::new(),
            busy_until_s: f64::NEG_INFINITY,
        }
    }

    fn holds_ever(&self) -> bool {
        self.cfg.lead_blocks < self.cfg.buffer_lines
    }

    /// Interpret `b` (every block, sent or not, in program order) and return its estimated
    /// duration on the control, s of the box's clock.
    pub(crate) fn duration_s(&mut self, b: &Block) -> f64 {
        let mut dwell = false;
        for g in b.g_codes() {
            #[allow(
                clippy::cast_possible_truncation,
                reason = "saturating: a G code past i64 is no code timed here and falls to `_`"
            )]
            let tenths = (g * 10.0).round() as i64;
            match tenths {
                0 => self.rapid = true,
                10 | 20 | 30 => self.rapid = false,
                40 => dwell = true,
                200 => self.inch = true,
                210 => self.inch = false,
                900 => self.incremental = false,
                910 => self.incremental = true,
                930 => self.inverse_time = true,
                940 | 950 => self.inverse_time = false,
                _ => {}
            }
        }
        let unit = if self.inch { 25.4 } else { 1.0 };
        if let Some(f) = b.get('F') {
            self.feed_mm_min = Some(f.value * unit);
        }
        let speed = self.cfg.control_speed;
        if dwell {
            let t = match (b.get('P'), b.get('X')) {
                (Some(p), _) if self.cfg.dwell_p_ms => p.value / 1000.0,
                (Some(p), _) => p.value,
                (None, Some(x)) => x.value,
                _ => 0.0,
            };
            return t.max(0.0) / speed;
        }
        let mut to = self.pos_mm;
        let mut moved = false;
        for (k, l) in ['X', 'Y', 'Z'].into_iter().enumerate() {
            if let Some(w) = b.get(l) {
                moved = true;
                let v = w.value * unit;
                to[k] = if self.incremental { to[k] + v } else { v };
            }
        }
        if !moved {
            return 0.0;
        }
        let len_mm = (0..3)
            .map(|k| (to[k] - self.pos_mm[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        self.pos_mm = to;
        let min = if self.rapid {
            len_mm / self.cfg.rapid_mm_min
        } else if self.inverse_time {
            // G93: F is the inverse of the move's time in minutes.
            self.feed_mm_min.map_or(0.0, |f| 1.0 / (f / unit))
        } else {
            self.feed_mm_min.map_or(0.0, |f| len_mm / f)
        };
        (min * 60.0).max(0.0) / speed
    }

    /// A line of `duration_s` left the box at `now_s`.
    pub(crate) fn sent(&mut self, duration_s: f64, now_s: f64) {
        let start = now_s.max(self.busy_until_s);
        self.busy_until_s = start + duration_s;
        // The schedule of waiting lines is only kept for a hold (without one nothing pops it).
        if self.holds_ever() {
            self.starts.push_back(start);
        }
    }

    /// When a line of `duration_s` sent at `now_s` is estimated to end on the control: after the
    /// lines sent before it, and not before it arrives. What the drift prediction extrapolates
    /// to (`drift.rs`).
    pub(crate) fn end_if_sent_s(&self, duration_s: f64, now_s: f64) -> f64 {
        now_s.max(self.busy_until_s) + duration_s
    }

    /// Sent lines estimated to be still waiting in the control at `now_s`.
    pub(crate) fn waiting(&mut self, now_s: f64) -> usize {
        while self.starts.front().is_some_and(|&s| s <= now_s) {
            self.starts.pop_front();
        }
        self.starts.len()
    }

    /// Whether the next block is held at `now_s`.
    pub(crate) fn holds(&mut self, now_s: f64) -> bool {
        self.holds_ever() && self.waiting(now_s) >= self.cfg.lead_blocks
    }

    /// When the hold is estimated to release (for a shell that sleeps until then).
    pub(crate) fn release_s(&self) -> Option<f64> {
        if !self.holds_ever() {
            return None;
        }
        let n = self.starts.len();
        let lead = self.cfg.lead_blocks;
        (n >= lead).then(|| self.starts[n - lead])
    }
}
