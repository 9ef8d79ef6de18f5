//! Start-time checks of a field config: what makes a config unsafe or useless is refused here, with
//! the key and what was expected (the caller adds file and line). Split from `config.rs`, which holds
//! the schema; units as there (ms, s, µm).

use crate::config::*;
use retrocomp_model::units::ChannelKind;

fn safety_key(prefix: &str, e: &SafetyError) -> String {
    use crate::engine::safety::SafetyError::*;
    match e {
        BadConfig { key, .. } | Absurd { key, .. } => format!("{prefix}.{key}"),
        InitialBeyondClamp { .. } => prefix.to_string(),
    }
}

/// `key` (an integer setting) must lie in `range`.
fn in_range(
    key: &str,
    v: u64,
    range: std::ops::RangeInclusive<u64>,
    unit: &str,
) -> Result<(), (String, String)> {
    if range.contains(&v) {
        return Ok(());
    }
    Err((
        key.to_string(),
        format!(
            "expected {}..={} {unit}, got {v}",
            range.start(),
            range.end()
        ),
    ))
}

/// The client sink's heartbeat: `heartbeat_timeout_ms` (the controller's watchdog timeout) comes with
/// `heartbeat_address` and leaves a live box at least three write periods per timeout.
fn heartbeat_timeout(k: &str, os: &OriginShiftSink) -> Result<(), (String, String)> {
    let key = format!("{k}.map.heartbeat_timeout_ms");
    match (os.map.heartbeat_address, os.map.heartbeat_timeout_ms) {
        (None, None) => Ok(()),
        (None, Some(_)) => Err((
            format!("{k}.map.heartbeat_address"),
            "heartbeat_timeout_ms is set: expected the heartbeat register's address too".into(),
        )),
        (Some(_), None) => Err((
            key,
            "expected the controller's heartbeat timeout in ms (its watchdog rule's setting)"
                .into(),
        )),
        (Some(_), Some(t)) => in_range(
            &key,
            t,
            (3 * os.write_period_ms).max(1)..=60_000,
            "ms (≥ 3 × write_period_ms)",
        ),
    }
}

/// Every [[axis]] appears exactly once among a sink's axis names.
fn mapped_once<'a>(
    axes: &[AxisSection],
    sink_key: &str,
    mapped: impl Iterator<Item = &'a str>,
) -> Result<(), (String, String)> {
    let mapped: Vec<&str> = mapped.collect();
    for (i, m) in mapped.iter().enumerate() {
        if let Some(j) = mapped[..i].iter().position(|n| n == m) {
            return Err((
                format!("{sink_key}.axis[{i}].axis"),
                format!(
                    "axis {m} is mapped twice (also {sink_key}.axis[{j}]): expected each axis once"
                ),
            ));
        }
        if !axes.iter().any(|a| a.name == *m) {
            return Err((
                format!("{sink_key}.axis[{i}].axis"),
                format!("{m} is not an [[axis]]"),
            ));
        }
    }
    for a in axes {
        if !mapped.contains(&a.name.as_str()) {
            return Err((
                sink_key.to_string(),
                format!(
                    "axis {} has no entry: expected every [[axis]] mapped once (it would never be corrected)",
                    a.name
                ),
            ));
        }
    }
    Ok(())
}

/// `[gateway]`: cycle and timing ranges, the realtime priority, the status address, the API
/// token, and the names of switchable models.
fn validate_gateway(g: &GatewaySection) -> Result<(), (String, String)> {
    if !(1..=1000).contains(&g.cycle_ms) {
        return Err((
            "gateway.cycle_ms".into(),
            format!("expected 1..=1000 ms, got {}", g.cycle_ms),
        ));
    }
    if !(g.stop_ramp_max_s.is_finite() && g.stop_ramp_max_s > 0.0 && g.stop_ramp_max_s <= 300.0) {
        return Err((
            "gateway.stop_ramp_max_s".into(),
            format!("expected 0 < s ≤ 300, got {}", g.stop_ramp_max_s),
        ));
    }
    if !(g.thermal_period_s.is_finite()
        && g.thermal_period_s > 0.0
        && g.thermal_period_s <= 86_400.0)
    {
        return Err((
            "gateway.thermal_period_s".into(),
            format!("expected 0 < s ≤ 86400, got {}", g.thermal_period_s),
        ));
    }
    if let Some(p) = g.realtime_priority
        && !(1..=99).contains(&p)
    {
        return Err((
            "gateway.realtime_priority".into(),
            format!("expected a SCHED_FIFO priority 1..=99, got {p}"),
        ));
    }
    if g.status_listen.parse::<std::net::SocketAddr>().is_err() {
        return Err((
            "gateway.status_listen".into(),
            format!("expected ip:port, got {:?}", g.status_listen),
        ));
    }
    if let Some(t) = &g.api_token
        && (t.trim().len() < 16 || t.trim() != t)
    {
        return Err((
            "gateway.api_token".into(),
            "expected at least 16 characters without surrounding spaces".into(),
        ));
    }
    g.listen_policy.check("gateway")?;
    for name in g.models.keys() {
        crate::engine::model_switch::check_name(name)
            .map_err(|what| (format!("gateway.models.{name}"), what))?;
    }
    Ok(())
}

impl FieldConfig {
    pub(super) fn check_position_sources(&self) -> Result<(), (String, String)> {
        let have = self.source_channels();
        for (i, a) in self.axes.iter().enumerate() {
            if !have.contains(&a.position_channel.as_str()) {
                return Err((
                    format!("axis[{i}].position_channel"),
                    format!(
                        "no source delivers {:?} (sources deliver {have:?}): axis {} would never be compensated",
                        a.position_channel, a.name
                    ),
                ));
            }
        }
        Ok(())
    }

    pub(super) fn validate(&self, built: Built) -> Result<(), (String, String)> {
        self.check_built_in(built)?;
        if let Some(m) = self.telemetry.as_ref().and_then(|t| t.mqtt.as_ref()) {
            m.check()?;
        }
        validate_gateway(&self.gateway)?;
        self.safety
            .validate()
            .map_err(|e| (safety_key("safety", &e), e.to_string()))?;
        if let Some(o) = &self.opcua {
            o.validate()?;
        }
        self.validate_axes()?;
        self.validate_channels()?;
        self.validate_recoveries()?;
        if let Some(os) = &self.sink.origin_shift {
            self.validate_origin_shift(os)?;
        }
        if let Some(srv) = &self.sink.origin_shift_server {
            self.validate_server(srv)?;
        }
        if let Some(q) = &self.sink.quadrature {
            self.validate_quadrature(q)?;
        }
        if let Some(d) = &self.dnc {
            d.validate(self.safety.max_correction_um)?;
        }
        self.validate_buses()?;
        limits::check(self)?;
        if self.sink.origin_shift.is_none()
            && self.sink.quadrature.is_none()
            && self.sink.origin_shift_server.is_none()
            && self.dnc.is_none()
        {
            tracing::warn!(
                "no [sink] configured: the gateway computes and reports, but corrects nothing"
            );
        }
        Ok(())
    }

    /// A section whose server or output this build leaves out (the gateway crate's features
    /// `opcua`, `mqtt`, `gpio`) is refused, not ignored: the plant would wait for data that never
    /// comes, or the technician would see a healthy status while no pulse reaches the controller.
    fn check_built_in(&self, built: Built) -> Result<(), (String, String)> {
        if self.opcua.is_some() && !built.opcua {
            return Err((
                "opcua".into(),
                "this build has no OPC UA server (built without the cargo feature `opcua`)".into(),
            ));
        }
        if self.telemetry.as_ref().is_some_and(|t| t.mqtt.is_some()) && !built.mqtt {
            return Err((
                "telemetry.mqtt".into(),
                "this build has no MQTT telemetry (built without the cargo feature `mqtt`)".into(),
            ));
        }
        let mut axes = self.sink.quadrature.iter().flat_map(|q| &q.axes);
        if let Some(i) = axes.position(|a| a.gpio.is_some()).filter(|_| !built.gpio) {
            return Err((
                format!("sink.quadrature.axis[{i}].gpio"),
                "this build drives no GPIO lines (built without the cargo feature `gpio`, or not \
                 on Linux): rebuild with it (on by default), or remove `gpio = …` to run the \
                 injector in simulation"
                    .into(),
            ));
        }
        Ok(())
    }

    /// `[[axis]]`: at least one, each of x/y/z once, a position channel in mm, and its own safety
    /// override (if any) valid.
    fn validate_axes(&self) -> Result<(), (String, String)> {
        if self.axes.is_empty() {
            return Err(("axis".into(), "at least one [[axis]] is required".into()));
        }
        for (i, a) in self.axes.iter().enumerate() {
            if !matches!(a.name.as_str(), "x" | "y" | "z") {
                return Err((
                    format!("axis[{i}].name"),
                    format!("expected x, y or z, got {:?}", a.name),
                ));
            }
            if self.axes[..i].iter().any(|b| b.name == a.name) {
                return Err((
                    format!("axis[{i}].name"),
                    format!("axis {} configured twice", a.name),
                ));
            }
            if ChannelKind::of(&a.position_channel) != ChannelKind::LengthMm {
                return Err((
                    format!("axis[{i}].position_channel"),
                    format!(
                        "a position channel carries mm: expected a name ending in _mm, got {:?}",
                        a.position_channel
                    ),
                ));
            }
            if let Some(s) = &a.safety {
                s.validate()
                    .map_err(|e| (safety_key(&format!("axis[{i}].safety"), &e), e.to_string()))?;
            }
        }
        Ok(())
    }

    /// `[[channel]]`: a usable range and a staleness timeout.
    fn validate_channels(&self) -> Result<(), (String, String)> {
        for (i, c) in self.channels.iter().enumerate() {
            let l = c.limits();
            if !(l.min.is_finite() && l.max.is_finite() && l.min < l.max) {
                return Err((
                    format!("channel[{i}]"),
                    format!("{}: min {} must be < max {}", c.name, l.min, l.max),
                ));
            }
            if !(l.stale_after_s.is_finite() && l.stale_after_s > 0.0 && l.stale_after_s <= 3600.0)
            {
                return Err((
                    format!("channel[{i}].stale_after_s"),
                    format!("expected 0 < s ≤ 3600, got {}", l.stale_after_s),
                ));
            }
        }
        Ok(())
    }

    /// `[[recovery]]`: one coefficient per neighbour plus the intercept.
    fn validate_recoveries(&self) -> Result<(), (String, String)> {
        for (i, r) in self.recoveries.iter().enumerate() {
            if r.coefficients.len() != r.neighbours.len() + 1 {
                return Err((
                    format!("recovery[{i}].coefficients"),
                    format!(
                        "expected {} (intercept + one per neighbour), got {}",
                        r.neighbours.len() + 1,
                        r.coefficients.len()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// `[sink.origin_shift]`: timing in range, every axis mapped once, a consistent register map,
    /// and heartbeat settings that fit the write period.
    fn validate_origin_shift(&self, os: &OriginShiftSink) -> Result<(), (String, String)> {
        let k = "sink.origin_shift";
        in_range(
            &format!("{k}.write_period_ms"),
            os.write_period_ms,
            1..=10_000,
            "ms",
        )?;
        in_range(
            &format!("{k}.request_timeout_ms"),
            os.request_timeout_ms,
            1..=60_000,
            "ms",
        )?;
        in_range(
            &format!("{k}.reconnect_min_ms"),
            os.reconnect_min_ms,
            1..=60_000,
            "ms",
        )?;
        in_range(
            &format!("{k}.reconnect_max_ms"),
            os.reconnect_max_ms,
            os.reconnect_min_ms..=600_000,
            "ms (≥ reconnect_min_ms)",
        )?;
        if let Some(h) = &os.map.handshake {
            in_range(
                &format!("{k}.map.handshake.timeout_ms"),
                h.timeout_ms,
                1..=60_000,
                "ms",
            )?;
            in_range(
                &format!("{k}.map.handshake.poll_ms"),
                h.poll_ms,
                1..=h.timeout_ms,
                "ms (≤ timeout_ms)",
            )?;
        }
        mapped_once(
            &self.axes,
            &format!("{k}.map"),
            os.map.axes.iter().map(|r| r.axis.as_str()),
        )?;
        os.map.validate().map_err(|e| {
            let key = match &e {
                crate::sinks::origin_shift::MapError::Axis { index, .. } => {
                    format!("{k}.map.axis[{index}]")
                }
                crate::sinks::origin_shift::MapError::Overlap { a, b, .. }
                    if a == "heartbeat_address" || b == "heartbeat_address" =>
                {
                    format!("{k}.map.heartbeat_address")
                }
                _ => format!("{k}.map"),
            };
            (key, e.to_string())
        })?;
        heartbeat_timeout(k, os)?;
        Ok(())
    }

    /// `[sink.quadrature]`: every axis mapped once, each with valid edge timing (the injection
    /// scheduler's) and a usable count resolution.
    fn validate_quadrature(&self, q: &QuadratureSink) -> Result<(), (String, String)> {
        mapped_once(
            &self.axes,
            "sink.quadrature",
            q.axes.iter().map(|a| a.axis.as_str()),
        )?;
        for (i, a) in q.axes.iter().enumerate() {
            let sc = crate::sinks::quadrature::SchedulerConfig {
                min_edge_gap_ns: a.min_edge_gap_ns,
                max_inject_rate_hz: a.max_inject_rate_hz,
            };
            sc.validate()
                .map_err(|e| (format!("sink.quadrature.axis[{i}]"), e.to_string()))?;
            crate::sinks::quadrature::CountQuantizer::new(a.resolution_um, a.count_sign).map_err(
                |e| {
                    (
                        format!("sink.quadrature.axis[{i}].resolution_um"),
                        e.to_string(),
                    )
                },
            )?;
            if let Some(sim) = &a.simulated_native {
                let key = format!("sink.quadrature.axis[{i}].simulated_native");
                if a.gpio.is_some() {
                    return Err((key, "no simulated scale on GPIO lines (they carry injected counts only): remove `gpio` or `simulated_native`".into()));
                }
                sim.check(a.min_edge_gap_ns).map_err(|what| (key, what))?;
            }
        }
        q.trace.as_ref().map_or(Ok(()), check_trace)
    }

    /// The bus sections: CANopen needs a CAN backend, then the bus module's own checks with every
    /// problem in one message.
    fn validate_buses(&self) -> Result<(), (String, String)> {
        if self.canopen.is_some() && self.can.is_none() {
            return Err((
                "canopen".into(),
                "[canopen] nodes need a [can] backend".into(),
            ));
        }
        // The bus sections' own checks (transport keys, register types, channel names with a unit
        // suffix, a channel defined by two sources): the same as `crates/bus/src/config.rs` applies.
        let bus = retrocomp_bus::config::FieldConfig {
            can: self.can.clone(),
            canopen: self.canopen.clone(),
            modbus: self.modbus.clone().unwrap_or_default(),
            serial: self.serial.clone().unwrap_or_default(),
        };
        let problems = retrocomp_bus::config::validate(&bus);
        if let Some(((key, first), rest)) = problems.split_first() {
            // Every problem at once: the first under its key, the others after it with theirs.
            let mut what = first.clone();
            for (k, m) in rest {
                what.push_str(&format!("; also `{k}`: {m}"));
            }
            return Err((key.clone(), what));
        }
        Ok(())
    }

    /// `[sink.origin_shift_server]`: one sink only, a valid register image mapping every corrected
    /// axis, and a register LSB the per-update cap can move by.
    fn validate_server(
        &self,
        srv: &crate::sinks::origin_shift::server::ServerConfig,
    ) -> Result<(), (String, String)> {
        const KEY: &str = "sink.origin_shift_server";
        srv.listen_policy.check(KEY)?;
        if self.sink.origin_shift.is_some() || self.sink.quadrature.is_some() {
            return Err((
                KEY.into(),
                "expected one sink: remove [sink.origin_shift] / [sink.quadrature] or this one"
                    .into(),
            ));
        }
        if !(1..=10_000).contains(&srv.update_period_ms) {
            return Err((
                format!("{KEY}.update_period_ms"),
                format!("expected 1..=10000 ms, got {}", srv.update_period_ms),
            ));
        }
        if let crate::sinks::origin_shift::server::ServerTransport::Tcp { listen } = &srv.transport
            && listen.parse::<std::net::SocketAddr>().is_err()
        {
            return Err((
                format!("{KEY}.transport.listen"),
                format!("expected ip:port, got {listen:?}"),
            ));
        }
        let axes: Vec<&str> = self.axes.iter().map(|a| a.name.as_str()).collect();
        srv.map
            .validate(&axes)
            .map_err(|e| (format!("{KEY}.map.{}", e.key), e.what))?;
        for (i, r) in srv.map.axes.iter().enumerate() {
            let cap = self.safety_for(&r.axis).max_change_um_per_cycle;
            if r.lsb_um > cap {
                return Err((
                    format!("{KEY}.map.axis[{i}].lsb_um"),
                    format!(
                        "expected at most the dosing cap max_change_um_per_cycle = {cap} µm, got {} µm: the output could never move",
                        r.lsb_um
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// `[sink.quadrature.trace]`: a bounded file and a buffer the writer can keep up with.
fn check_trace(t: &crate::sinks::quadrature::trace::TraceConfig) -> Result<(), (String, String)> {
    use crate::sinks::quadrature::trace::{BUFFER_EDGES_RANGE, MAX_BYTES_RANGE};
    if !MAX_BYTES_RANGE.contains(&t.max_bytes) {
        return Err((
            "sink.quadrature.trace.max_bytes".into(),
            format!("expected {MAX_BYTES_RANGE:?} bytes, got {}", t.max_bytes),
        ));
    }
    if !BUFFER_EDGES_RANGE.contains(&t.buffer_edges) {
        return Err((
            "sink.quadrature.trace.buffer_edges".into(),
            format!(
                "expected {BUFFER_EDGES_RANGE:?} edges, got {}",
                t.buffer_edges
            ),
        ));
    }
    Ok(())
}
