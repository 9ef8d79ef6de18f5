//! The status snapshot as the plain-text table `retrocomp status` prints (`GET /text`): one line
//! per axis with its terms, per channel, per source, then the model error and the sink. Units as
//! the snapshot keeps them: µm for corrections, mm for positions, channel units for channels,
//! s for times; states in their one spelling (`northbound::state_name`).

use std::fmt::Write as _;

use crate::northbound::state_name;
use crate::status::{SinkStatus, StatusSnapshot};

impl StatusSnapshot {
    /// Human-readable table for `retrocomp status`.
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "t = {:.3} s, {} cycles, compensation {}",
            self.t_s,
            self.cycles,
            if self.enabled { "ENABLED" } else { "disabled" }
        );
        self.render_axes(&mut s);
        self.render_channels(&mut s);
        self.render_sources(&mut s);
        if let Some(e) = &self.model_error {
            let _ = writeln!(s, "model error: {e}");
        }
        if let Some(k) = &self.sink {
            render_sink(&mut s, k);
        }
        s
    }

    /// The axis table: header, then one row per axis with its terms.
    fn render_axes(&self, s: &mut String) {
        let _ = writeln!(
            s,
            "{:<4} {:>12} {:>9} {:>12} {:>12}  {:<11} terms (µm)",
            "axis", "pos_mm", "dir", "target_um", "applied_um", "mode"
        );
        for a in &self.axes {
            let terms: Vec<String> = a
                .terms_um
                .iter()
                .map(|(k, v)| format!("{k}={v:+.2}"))
                .collect();
            let _ = writeln!(
                s,
                "{:<4} {:>12} {:>9} {:>12} {:>12.3}  {:<11} {}",
                a.axis,
                a.position_mm.map_or("-".into(), |p| format!("{p:.4}")),
                retrocomp_model::approach::latched_name(a.direction),
                a.target_um.map_or("-".into(), |t| format!("{t:.3}")),
                a.applied_um,
                state_name(&a.mode),
                terms.join(" ")
            );
        }
    }

    /// `channels:` and one line per channel (the heading even without channels).
    fn render_channels(&self, s: &mut String) {
        let _ = writeln!(s, "channels:");
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "  {:<20} {:>12} {}{}{}",
                name,
                c.value.map_or("-".into(), |v| format!("{v:.3}")),
                state_name(&c.health),
                if c.substituted {
                    " (substituted from neighbours)"
                } else {
                    ""
                },
                if c.faults.is_empty() {
                    String::new()
                } else {
                    format!(" faults={}", names(&c.faults))
                }
            );
        }
    }

    /// `sources:` and one line per source, only when there are sources.
    fn render_sources(&self, s: &mut String) {
        if !self.sources.is_empty() {
            let _ = writeln!(s, "sources:");
        }
        for src in &self.sources {
            let _ = writeln!(
                s,
                "  {:<20} {} reconnects={}{}{}{}",
                src.name,
                if src.connected {
                    "connected"
                } else {
                    "disconnected"
                },
                src.reconnects,
                src.can
                    .map(|c| format!(
                        " bus={} error_frames={}",
                        state_name(&c.state),
                        c.error_frames
                    ))
                    .unwrap_or_default(),
                if src.faults.is_empty() {
                    String::new()
                } else {
                    format!(" faults={}", names(src.faults.iter().map(|(k, _)| k)))
                },
                src.last_error
                    .as_ref()
                    .map(|e| format!(" last_error={e}"))
                    .unwrap_or_default(),
            );
        }
    }
}

/// The sink's line (link, writes, what the controller holds) and its active faults.
fn render_sink(s: &mut String, k: &SinkStatus) {
    let held: Vec<String> = k
        .held_um
        .iter()
        .map(|(a, v)| format!("{a}={v:+.3}"))
        .collect();
    let _ = writeln!(
        s,
        "sink {}: {}, {} writes ok, {} failed; controller holds (µm) {}",
        k.kind,
        if k.connected {
            "connected"
        } else {
            "disconnected"
        },
        k.writes_ok,
        k.writes_failed,
        held.join(" ")
    );
    for (source, kind, since) in &k.faults {
        let _ = writeln!(
            s,
            "  fault {source} {} since {since:.3} s",
            state_name(kind)
        );
    }
}

/// `[stale, stuck]`: the states' one spelling, as a list.
fn names<'a, T: serde::Serialize + 'a>(v: impl IntoIterator<Item = &'a T>) -> String {
    let n: Vec<String> = v.into_iter().map(state_name).collect();
    format!("[{}]", n.join(", "))
}
