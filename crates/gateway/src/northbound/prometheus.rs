//! The status snapshot's Prometheus text form (`/metrics`); the snapshot itself is
//! `crate::status` (built by the cycle at ≤ 10 Hz), its plain-text table `text.rs`.
//! Prometheus conventions: base units (lengths in metres, times in seconds, temperatures in °C,
//! forces in N, speeds in Hz), one metric per quantity, `_total` on counters only
//! (`promtool check metrics` passes on it: `tests/real_peers/gateway_prometheus.rs`). Internally the box keeps
//! µm and mm; the factors are applied here, once.

use std::fmt::Write as _;

use crate::northbound::prometheus_text::{
    ChannelQuantity, UM_PER_M, esc, family, num, prometheus_timing,
};
use crate::northbound::state_name;
use crate::status::Mode;
use retrocomp_bus::Health;

use crate::status::{SinkStatus, SourceStatus, StatusSnapshot};

/// `retrocomp_sink_*`: the output sink's link, write counts, what the controller holds, and its
/// faults.
fn prometheus_sink(s: &mut String, k: &SinkStatus) {
    family(
        s,
        "retrocomp_sink_connected",
        "gauge",
        "1 when the output sink is connected.",
    );
    let _ = writeln!(
        s,
        "retrocomp_sink_connected{{sink=\"{}\"}} {}",
        esc(&k.kind),
        u8::from(k.connected)
    );
    family(
        s,
        "retrocomp_sink_writes_total",
        "counter",
        "Sink write cycles by result.",
    );
    let _ = writeln!(
        s,
        "retrocomp_sink_writes_total{{sink=\"{}\",result=\"ok\"}} {}",
        esc(&k.kind),
        k.writes_ok
    );
    let _ = writeln!(
        s,
        "retrocomp_sink_writes_total{{sink=\"{}\",result=\"failed\"}} {}",
        esc(&k.kind),
        k.writes_failed
    );
    family(
        s,
        "retrocomp_sink_held_meters",
        "gauge",
        "Correction the controller's registers hold per axis (read back), m.",
    );
    for (axis, v) in &k.held_um {
        let _ = writeln!(
            s,
            "retrocomp_sink_held_meters{{sink=\"{}\",axis=\"{}\"}} {}",
            esc(&k.kind),
            esc(axis),
            num(*v / UM_PER_M)
        );
    }
    family(
        s,
        "retrocomp_sink_fault_active",
        "gauge",
        "1 per active sink fault (source, kind).",
    );
    for (source, kind, _) in &k.faults {
        let _ = writeln!(
            s,
            "retrocomp_sink_fault_active{{source=\"{}\",kind=\"{}\"}} 1",
            esc(source),
            state_name(kind)
        );
    }
}

impl StatusSnapshot {
    /// Prometheus text exposition format 0.0.4.
    pub fn prometheus(&self) -> String {
        let mut s = String::with_capacity(2048);
        family(
            &mut s,
            "retrocomp_cycles_total",
            "counter",
            "Gateway cycles run.",
        );
        let _ = writeln!(s, "retrocomp_cycles_total {}", self.cycles);
        family(
            &mut s,
            "retrocomp_enabled",
            "gauge",
            "1 when compensation is enabled.",
        );
        let _ = writeln!(s, "retrocomp_enabled {}", u8::from(self.enabled));
        family(
            &mut s,
            "retrocomp_build_info",
            "gauge",
            "The running build (version label); always 1.",
        );
        let _ = writeln!(
            s,
            "retrocomp_build_info{{version=\"{}\"}} 1",
            env!("CARGO_PKG_VERSION")
        );
        prometheus_timing(&mut s, &self.timing);
        self.prometheus_model(&mut s);
        self.prometheus_corrections(&mut s);
        self.prometheus_axis_safety(&mut s);
        self.prometheus_channels(&mut s);
        family(
            &mut s,
            "retrocomp_faults_active",
            "gauge",
            "Faults active now.",
        );
        let _ = writeln!(s, "retrocomp_faults_active {}", self.active_faults.len());
        if let Some(k) = &self.sink {
            prometheus_sink(&mut s, k);
        }
        self.prometheus_sources(&mut s);
        if let Some(t) = &self.telemetry {
            t.prometheus(&mut s);
        }
        s
    }

    /// `retrocomp_model_*`: which model is in use and since when (absent without a model).
    fn prometheus_model(&self, s: &mut String) {
        let Some(m) = &self.model else {
            return;
        };
        family(
            s,
            "retrocomp_model_info",
            "gauge",
            "The model in use (name, sha256 of its canonical TOML); always 1.",
        );
        let (name, sha) = (esc(&m.name), esc(&m.sha256));
        let _ = writeln!(
            s,
            "retrocomp_model_info{{name=\"{name}\",sha256=\"{sha}\"}} 1"
        );
        family(
            s,
            "retrocomp_model_loaded_timestamp_seconds",
            "gauge",
            "When the model in use was loaded, Unix time in s.",
        );
        let _ = writeln!(
            s,
            "retrocomp_model_loaded_timestamp_seconds {}",
            num(m.loaded_unix_s)
        );
    }

    /// `retrocomp_correction_*`: per axis, what was applied, what the model asked for, and its
    /// terms.
    fn prometheus_corrections(&self, s: &mut String) {
        family(
            s,
            "retrocomp_correction_applied_meters",
            "gauge",
            "Correction applied per axis after safety, m.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_correction_applied_meters{{axis=\"{}\"}} {}",
                esc(&a.axis),
                num(a.applied_um / UM_PER_M)
            );
        }
        family(
            s,
            "retrocomp_correction_target_meters",
            "gauge",
            "Correction requested by the model per axis, m.",
        );
        for a in &self.axes {
            if let Some(t) = a.target_um {
                let _ = writeln!(
                    s,
                    "retrocomp_correction_target_meters{{axis=\"{}\"}} {}",
                    esc(&a.axis),
                    num(t / UM_PER_M)
                );
            }
        }
        family(
            s,
            "retrocomp_correction_term_meters",
            "gauge",
            "Correction per axis and model term, m.",
        );
        for a in &self.axes {
            for (term, v) in &a.terms_um {
                let _ = writeln!(
                    s,
                    "retrocomp_correction_term_meters{{axis=\"{}\",term=\"{}\"}} {}",
                    esc(&a.axis),
                    esc(term),
                    num(*v / UM_PER_M)
                );
            }
        }
    }

    /// The safety layer per axis: tracking or not, and how often the clamp and the dosing cap cut.
    fn prometheus_axis_safety(&self, s: &mut String) {
        family(
            s,
            "retrocomp_axis_tracking",
            "gauge",
            "1 when the axis output tracks the model (no ramp/hold).",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_axis_tracking{{axis=\"{}\"}} {}",
                esc(&a.axis),
                u8::from(a.mode == Mode::Tracking)
            );
        }
        family(
            s,
            "retrocomp_safety_clamp_hits_total",
            "counter",
            "Cycles whose model target was beyond the clamp, per axis.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_safety_clamp_hits_total{{axis=\"{}\"}} {}",
                esc(&a.axis),
                a.clamp_hits
            );
        }
        family(
            s,
            "retrocomp_safety_cap_hits_total",
            "counter",
            "Cycles whose step was cut by the dosing cap, per axis.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_safety_cap_hits_total{{axis=\"{}\"}} {}",
                esc(&a.axis),
                a.cap_hits
            );
        }
    }

    /// `retrocomp_channel_*`: per input channel, its health, substitution, and last value.
    fn prometheus_channels(&self, s: &mut String) {
        family(
            s,
            "retrocomp_channel_healthy",
            "gauge",
            "1 when the channel's latest value is healthy.",
        );
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "retrocomp_channel_healthy{{channel=\"{}\"}} {}",
                esc(name),
                u8::from(c.health == Health::Ok)
            );
        }
        family(
            s,
            "retrocomp_channel_substituted",
            "gauge",
            "1 when the channel is replaced by its neighbour estimate.",
        );
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "retrocomp_channel_substituted{{channel=\"{}\"}} {}",
                esc(name),
                u8::from(c.substituted)
            );
        }
        for q in ChannelQuantity::ALL {
            let mut members = self
                .channels
                .iter()
                .filter(|(name, _)| ChannelQuantity::of(name) == q)
                .filter_map(|(name, c)| Some((name, c.value?)))
                .peekable();
            if members.peek().is_none() {
                continue;
            }
            let (metric, help, divisor) = q.metric();
            family(s, metric, "gauge", help);
            for (name, v) in members {
                let _ = writeln!(
                    s,
                    "{metric}{{channel=\"{}\"}} {}",
                    esc(name),
                    num(v / divisor)
                );
            }
        }
    }

    /// `retrocomp_source_*` and the CAN/Modbus link counters.
    fn prometheus_sources(&self, s: &mut String) {
        if self.sources.is_empty() {
            return;
        }
        self.prometheus_source_links(s);
        self.prometheus_can(s);
        self.prometheus_modbus(s);
    }

    /// One line per source that has a value for `name` (labelled with the source's name).
    fn each_source(&self, s: &mut String, name: &str, v: &dyn Fn(&SourceStatus) -> Option<String>) {
        for src in &self.sources {
            if let Some(v) = v(src) {
                let _ = writeln!(s, "{name}{{source=\"{}\"}} {v}", esc(&src.name));
            }
        }
    }

    /// `retrocomp_source_*`: every source's link state, reconnects, and active faults.
    fn prometheus_source_links(&self, s: &mut String) {
        family(
            s,
            "retrocomp_source_connected",
            "gauge",
            "1 when the source's link is up.",
        );
        self.each_source(s, "retrocomp_source_connected", &|x| {
            Some(u8::from(x.connected).to_string())
        });
        family(
            s,
            "retrocomp_source_reconnects_total",
            "counter",
            "Links re-established after a loss.",
        );
        self.each_source(s, "retrocomp_source_reconnects_total", &|x| {
            Some(x.reconnects.to_string())
        });
        family(
            s,
            "retrocomp_source_faults_active",
            "gauge",
            "Source-level faults active now.",
        );
        self.each_source(s, "retrocomp_source_faults_active", &|x| {
            Some(x.faults.len().to_string())
        });
    }

    /// `retrocomp_can_*`: controller state and error counters of the CAN sources (family headers
    /// even when no source is on CAN).
    fn prometheus_can(&self, s: &mut String) {
        family(
            s,
            "retrocomp_can_bus_state",
            "gauge",
            "CAN controller state: 0 active, 1 warning, 2 passive, 3 bus_off (error-active … bus off, ISO 11898-1).",
        );
        self.each_source(s, "retrocomp_can_bus_state", &|x| {
            x.can.map(|c| (c.state as u8).to_string())
        });
        family(
            s,
            "retrocomp_can_error_frames_total",
            "counter",
            "CAN error frames received.",
        );
        self.each_source(s, "retrocomp_can_error_frames_total", &|x| {
            x.can.map(|c| c.error_frames.to_string())
        });
        family(
            s,
            "retrocomp_can_bus_off_total",
            "counter",
            "Times the CAN controller went bus_off.",
        );
        self.each_source(s, "retrocomp_can_bus_off_total", &|x| {
            x.can.map(|c| c.bus_off_events.to_string())
        });
        family(
            s,
            "retrocomp_can_transmit_error_counter",
            "gauge",
            "The CAN controller's transmit error counter (TEC, 0-255).",
        );
        self.each_source(s, "retrocomp_can_transmit_error_counter", &|x| {
            x.can.and_then(|c| c.tx_error_count).map(|v| v.to_string())
        });
        family(
            s,
            "retrocomp_can_receive_error_counter",
            "gauge",
            "The CAN controller's receive error counter (REC, 0-255).",
        );
        self.each_source(s, "retrocomp_can_receive_error_counter", &|x| {
            x.can.and_then(|c| c.rx_error_count).map(|v| v.to_string())
        });
    }

    /// `retrocomp_modbus_*`: exception replies and unanswered requests of the Modbus sources.
    fn prometheus_modbus(&self, s: &mut String) {
        family(
            s,
            "retrocomp_modbus_exceptions_total",
            "counter",
            "Modbus exception replies.",
        );
        self.each_source(s, "retrocomp_modbus_exceptions_total", &|x| {
            x.modbus.map(|m| m.exceptions.to_string())
        });
        family(
            s,
            "retrocomp_modbus_failed_requests_total",
            "counter",
            "Modbus requests without an answer (timeout or transport error).",
        );
        self.each_source(s, "retrocomp_modbus_failed_requests_total", &|x| {
            x.modbus
                .map(|m| (m.timeouts + m.transport_errors).to_string())
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::status::AxisStatus;

    /// One X axis, nothing else.
    fn snapshot() -> StatusSnapshot {
        StatusSnapshot {
            t_s: 1.0,
            cycles: 10,
            enabled: true,
            axes: vec![AxisStatus {
                axis: "x".into(),
                position_mm: Some(10.0),
                direction: None,
                weight_forward: 1.0,
                target_um: None,
                applied_um: 0.0,
                mode: Mode::Tracking,
                terms_um: Default::default(),
                clamp_hits: 0,
                cap_hits: 0,
            }],
            ..Default::default()
        }
    }

    /// The sample value of the line starting with `prefix`.
    fn value_of<T: std::str::FromStr>(text: &str, prefix: &str) -> T
    where
        T::Err: std::fmt::Debug,
    {
        line(text, prefix)
            .rsplit(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    }

    fn line<'a>(text: &'a str, prefix: &str) -> &'a str {
        text.lines()
            .find(|l| l.starts_with(prefix))
            .unwrap_or_else(|| panic!("no `{prefix}` line in:\n{text}"))
    }

    #[test]
    fn corrections_are_in_metres_and_channels_in_their_own_base_unit() {
        let mut snap = snapshot();
        snap.axes[0].applied_um = -12.5;
        snap.axes[0].target_um = Some(-12.5);
        snap.axes[0].terms_um.insert("EXX".into(), -12.5);
        let ch = |v| crate::status::ChannelStatus {
            value: Some(v),
            ..crate::status::ChannelStatus::unknown()
        };
        snap.channels.insert("T_spindle_C".into(), ch(24.5));
        snap.channels.insert("x_mm".into(), ch(250.0));
        snap.channels.insert("rpm".into(), ch(3000.0));
        snap.channels.insert("strain_col_ue".into(), ch(40.0));
        let text = snap.prometheus();
        let value = |prefix| -> f64 { value_of(&text, prefix) };
        assert_eq!(
            value("retrocomp_correction_applied_meters{axis=\"x\"}"),
            -12.5e-6
        );
        assert_eq!(
            value("retrocomp_correction_target_meters{axis=\"x\"}"),
            -12.5e-6
        );
        assert_eq!(
            value("retrocomp_correction_term_meters{axis=\"x\",term=\"EXX\"}"),
            -12.5e-6
        );
        assert_eq!(
            value("retrocomp_channel_temperature_celsius{channel=\"T_spindle_C\"}"),
            24.5
        );
        assert_eq!(
            value("retrocomp_channel_position_meters{channel=\"x_mm\"}"),
            0.25
        );
        assert_eq!(
            value("retrocomp_channel_rotation_hertz{channel=\"rpm\"}"),
            50.0
        );
        assert!(
            (value("retrocomp_channel_strain_ratio{channel=\"strain_col_ue\"}") - 40e-6).abs()
                < 1e-18
        );
        assert!(!text.contains("_um{") && !text.contains("_um "), "{text}");
    }

    #[test]
    fn the_cycle_histogram_is_cumulative_and_counts_every_cycle() {
        let mut snap = snapshot();
        for took_s in [0.5e-6, 0.7e-6, 3e-6, 2e-3] {
            snap.timing.observe(took_s);
        }
        snap.timing.late_cycles = 7;
        let text = snap.prometheus();
        let value = |prefix| -> u64 { value_of(&text, prefix) };
        assert_eq!(
            value("retrocomp_cycle_duration_seconds_bucket{le=\"1e-6\"}"),
            2
        );
        assert_eq!(
            value("retrocomp_cycle_duration_seconds_bucket{le=\"5e-6\"}"),
            3
        );
        assert_eq!(
            value("retrocomp_cycle_duration_seconds_bucket{le=\"1e-3\"}"),
            3
        );
        assert_eq!(
            value("retrocomp_cycle_duration_seconds_bucket{le=\"+Inf\"}"),
            4
        );
        assert_eq!(value("retrocomp_cycle_duration_seconds_count"), 4);
        assert_eq!(value("retrocomp_cycles_late_total"), 7);
        assert!(line(&text, "retrocomp_build_info{").ends_with("} 1"));
    }
}
