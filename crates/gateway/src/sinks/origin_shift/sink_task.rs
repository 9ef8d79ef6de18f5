//! The origin-shift sink's async shell: when the cycle's output changes, and every
//! `write_period_ms` without a change, it runs one period of the sans-IO
//! [`SinkCore`] (read what the controller holds → last-step guard → write cycle) through the
//! tokio-modbus client, sends reseeds back to the engine, and turns the core's flags into fault
//! episodes (one log line at start, one at clear; in status and metrics):
//!
//! - `sink.origin_shift` `Disconnected`: no connection to the controller;
//! - `sink.origin_shift` `WriteFailed`: a request was refused (Modbus exception), failed, or the
//!   controller did not acknowledge / read back a write (connected, but values are not getting in);
//! - `sink.origin_shift.<axis>` `BeyondClamp`: the controller holds a value beyond the clamp; that
//!   axis is not written until it is back in range (policy in `origin_shift/guard.rs`);
//! - `sink.origin_shift.<axis>` `WriteFailed`: the controller's value is uncertain (a foreign value
//!   arrived while a write of ours was unconfirmed); that axis is not written this period.
//!
//! The heartbeat (`map.heartbeat_address`) goes out at the start of every period (`sink.rs`). On
//! `stop` (SIGTERM/SIGINT with `[gateway] on_stop = "ramp_out"`) the task ramps every axis to 0
//! within the per-write cap, then returns: once the controller holds 0, after `stop_ramp_max_s`, or
//! at once when the controller cannot be reached (its watchdog rule then removes the correction).
//!
//! Start ([`OriginShiftClientSink`] as a [`Sink`]): the controller's current values are read first,
//! retrying until it answers, and the engine continues from them (no jump after a gateway restart);
//! a value beyond the clamp is not a start value (see [`OriginShiftClientSink`]).
//!
//! Units: µm.

use std::collections::BTreeMap;

use super::client::OriginShiftSink;
use super::map::RegisterMap;
use super::{OriginShiftClient, SinkAxis, SinkCore};
use crate::sinks::guard::{AxisLimits, SinkFaults};
use crate::sinks::{LocalFuture, Sink, SinkError, SinkIo, StartValues};
use retrocomp_bus::fault::{FaultEvent, FaultKind, FaultLog, FaultSource};
use retrocomp_model::Axis;

pub(crate) const SOURCE: &str = "sink.origin_shift";

/// The sink's fault sources, named once: the link (`sink.origin_shift`) and each map axis
/// (`sink.origin_shift.<axis>`, map order).
#[derive(Clone, Debug)]
pub struct SinkSources {
    link: FaultSource,
    axes: Vec<FaultSource>,
}

impl SinkSources {
    pub fn of(core: &SinkCore) -> Self {
        Self::named(SOURCE, core.axes().iter().map(|a| a.axis.as_str()))
    }

    /// A sink's sources: `link` and `<link>.<axis>` per axis (the sink's axis order).
    pub fn named<'a>(link: &str, axes: impl IntoIterator<Item = &'a str>) -> Self {
        SinkSources {
            link: FaultSource::named(link),
            axes: axes
                .into_iter()
                .map(|a| FaultSource::named(&format!("{link}.{a}")))
                .collect(),
        }
    }
}

/// The sink's fault episodes from the core's flags after a period (sans-IO; `now_s` on the
/// gateway clock), with the sources named once; returns every start and clear. Allocates only
/// when a fault starts or clears.
pub fn update_faults_of(
    log: &mut FaultLog,
    sources: &SinkSources,
    core: &SinkCore,
    connected: bool,
    now_s: f64,
) -> Vec<FaultEvent> {
    update_sink_faults(log, sources, core.faults(), connected, now_s)
}

/// The fault episodes of any sink from its guard's flags (`f`) and its link: the one mapping every
/// sink shares (`BeyondClamp` and `Uncertain` per axis, `Disconnected`/`WriteFailed` for the link).
pub(crate) fn update_sink_faults(
    log: &mut FaultLog,
    sources: &SinkSources,
    f: &SinkFaults,
    connected: bool,
    now_s: f64,
) -> Vec<FaultEvent> {
    let link: &[FaultKind] = if !connected {
        &[FaultKind::Disconnected]
    } else if f.write_failed {
        &[FaultKind::WriteFailed]
    } else {
        &[]
    };
    let mut events = log.update(&sources.link, link, now_s);
    for (i, source) in sources.axes.iter().enumerate() {
        let mut kinds = [FaultKind::BeyondClamp; 2];
        let mut n = 0;
        if f.beyond_clamp.get(i) == Some(&true) {
            kinds[n] = FaultKind::BeyondClamp;
            n += 1;
        }
        if f.uncertain.get(i) == Some(&true) {
            kinds[n] = FaultKind::WriteFailed;
            n += 1;
        }
        let ev = log.update(source, &kinds[..n], now_s);
        if !ev.is_empty() {
            events.extend(ev);
        }
    }
    events
}

/// What one period of the origin-shift sink leaves for the rest of the gateway: the values the
/// engine continues from (the controller held another value) and the fault episodes that started
/// or cleared.
#[derive(Debug, Default)]
pub(crate) struct PeriodEnd {
    pub reseeds: Vec<(Axis, f64)>,
    pub events: Vec<FaultEvent>,
}

/// The end of one period (sans-IO; `connected`: the client's link after it, `now_s` on the
/// gateway clock). Every driver of the sink ends its periods here (the task below and
/// `gateway_core`).
pub(crate) fn end_period(
    core: &mut SinkCore,
    log: &mut FaultLog,
    sources: &SinkSources,
    connected: bool,
    now_s: f64,
) -> PeriodEnd {
    PeriodEnd {
        reseeds: core.take_reseeds(),
        events: update_faults_of(log, sources, core, connected, now_s),
    }
}

/// What the controller holds that the engine may continue from: the held values the last-step
/// guard would take as within the clamp
/// ([`GuardLimits::holds_within_clamp`](crate::sinks::guard::GuardLimits::holds_within_clamp) with `map`'s
/// resolution; an axis `limits` do not name has a clamp of 0). Any other value is not a start
/// value — the sink refuses to write that axis (a `BeyondClamp` fault) until the controller's value
/// is back in range, and the engine continues from it then.
pub(crate) fn start_values_within(
    held_um: BTreeMap<String, f64>,
    map: &RegisterMap,
    limits: &[AxisLimits],
) -> BTreeMap<String, f64> {
    let mut held_um = held_um;
    held_um.retain(|axis, held_um| {
        let lsb_um = map
            .axes
            .iter()
            .find(|r| r.axis == *axis)
            .map_or(0.0, |r| r.lsb_um);
        let within = AxisLimits::of(limits, axis, lsb_um);
        let ok = within.holds_within_clamp(*held_um);
        if !ok {
            tracing::error!(axis, held_um, max = within.max_correction_um, "controller holds a correction beyond the clamp: not writing this axis until it is back in range");
        }
        ok
    });
    held_um
}

/// Until a period may run: the cycle's output differs from `ran_with` (what the last period
/// wrote toward: a new correction goes out at once) or `period` passed since the last period (the
/// heartbeat, the controller read, retries, the stop ramp). The cycle publishes every cycle; an
/// unchanged output is no reason to run early.
async fn wait_for_period(
    out_rx: &mut tokio::sync::watch::Receiver<Vec<(Axis, f64)>>,
    period: std::time::Duration,
    last: &mut Option<tokio::time::Instant>,
    ran_with: &[(Axis, f64)],
) {
    let due = last.map_or_else(tokio::time::Instant::now, |t| t + period);
    loop {
        if out_rx.has_changed().is_err() {
            // The cycle ended (a stop ramp-out, or the run is over): the period alone paces.
            tokio::time::sleep_until(due).await;
            break;
        }
        tokio::select! {
            r = out_rx.changed() => {
                if r.is_ok() && out_rx.borrow().as_slice() != ran_with {
                    break;
                }
            }
            () = tokio::time::sleep_until(due) => break,
        }
    }
    *last = Some(tokio::time::Instant::now());
}

/// Write the engine's outputs when they change, and every `write_period_ms` without a change,
/// until the runtime drops the output channel.
pub(crate) async fn origin_shift_task(
    os: OriginShiftSink,
    mut client: OriginShiftClient,
    axes: Vec<SinkAxis>,
    channels: SinkIo,
    epoch: std::time::Instant,
) {
    let SinkIo {
        mut out_rx,
        reseed_tx,
        status,
        stop,
        ..
    } = channels;
    let mut core = SinkCore::new(os.map.clone(), axes);
    let period = std::time::Duration::from_millis(os.write_period_ms.max(1));
    let mut last_period: Option<tokio::time::Instant> = None;
    let mut faults = FaultLog::default();
    let sources = SinkSources::of(&core);
    let mut wants: Vec<(Axis, f64)> = Vec::new();
    let mut stop_by: Option<std::time::Instant> = None;
    loop {
        wait_for_period(&mut out_rx, period, &mut last_period, &wants).await;
        if let (None, Some(max_s)) = (stop_by, *stop.borrow()) {
            stop_by = Some(std::time::Instant::now() + std::time::Duration::from_secs_f64(max_s));
            core.begin_ramp_out();
            tracing::info!(
                max_s,
                "stopping: ramping the correction out within the per-write cap"
            );
        }
        wants.clone_from(&out_rx.borrow());
        if wants.is_empty() && stop_by.is_none() {
            if out_rx.has_changed().is_err() {
                return;
            }
            continue;
        }
        client.run_period(&mut core, &wants).await;
        if let Some(by) = stop_by {
            let held: BTreeMap<&str, Option<f64>> = core.held_um().collect();
            if core.is_ramped_out() {
                tracing::info!(?held, "ramped out: the controller holds 0");
                return;
            }
            if !client.is_connected() || std::time::Instant::now() >= by {
                tracing::warn!(
                    ?held,
                    connected = client.is_connected(),
                    "stopping before the correction is ramped out: the controller's watchdog rule must remove it"
                );
                return;
            }
        }
        let connected = client.is_connected();
        let now_s = epoch.elapsed().as_secs_f64();
        let PeriodEnd { reseeds, events } =
            end_period(&mut core, &mut faults, &sources, connected, now_s);
        // Stopping: the engine no longer runs (nobody drains the channel).
        for (axis, held_um) in reseeds.into_iter().filter(|_| stop_by.is_none()) {
            if reseed_tx.send((axis, held_um)).await.is_err() {
                return;
            }
        }
        for e in events.iter().filter(|e| e.started) {
            let held: BTreeMap<&str, Option<f64>> = core.held_um().collect();
            tracing::warn!(
                source = e.source.as_str(),
                kind = e.kind.as_str(),
                reason = core.last_error.as_deref().unwrap_or(""),
                ?held,
                "origin-shift sink fault"
            );
        }
        // The status in place (no copy per period; the cycle reads it at ≤ 10 Hz): steady state
        // allocates nothing.
        status.send_modify(|st| {
            if st.kind.is_empty() {
                st.kind = "origin_shift".into();
            }
            st.connected = connected;
            st.writes_ok = core.writes_ok;
            st.writes_failed = core.writes_failed;
            st.last_error.clone_from(&core.last_error);
            for (a, v) in core.held_um() {
                match (st.held_um.get_mut(a), v) {
                    (Some(held), Some(v)) => *held = v,
                    (None, Some(v)) => {
                        st.held_um.insert(a.to_string(), v);
                    }
                    (Some(_), None) => {
                        st.held_um.remove(a);
                    }
                    (None, None) => {}
                }
            }
            if !events.is_empty() {
                st.faults = faults.active_by_name();
            }
        });
    }
}

/// The origin-shift client as the run loop's [`Sink`]: [`Sink::start`] reads what the controller
/// holds, [`Sink::run`] is [`origin_shift_task`].
#[derive(Debug)]
pub(crate) struct OriginShiftClientSink {
    os: OriginShiftSink,
    client: OriginShiftClient,
    axes: Vec<SinkAxis>,
    epoch: std::time::Instant,
}

impl OriginShiftClientSink {
    /// `axes`: clamp and per-write cap per axis; `epoch`: the gateway's clock (fault times).
    pub(crate) fn new(
        os: OriginShiftSink,
        axes: Vec<SinkAxis>,
        epoch: std::time::Instant,
    ) -> Result<Self, SinkError> {
        let client = OriginShiftClient::new(os.client(), os.map.clone())
            .map_err(|e| SinkError::setup("sink.origin_shift.map", e))?;
        Ok(Self {
            os,
            client,
            axes,
            epoch,
        })
    }
}

impl Sink for OriginShiftClientSink {
    fn start<'a>(&'a mut self, io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>> {
        Box::pin(async move {
            let initial = read_initial(&mut self.client, &io.status, self.epoch).await;
            Ok(start_values_within(initial, &self.os.map, &self.axes))
        })
    }

    fn run(self: Box<Self>, io: SinkIo) -> LocalFuture<'static, ()> {
        let Self {
            os,
            client,
            axes,
            epoch,
            ..
        } = *self;
        Box::pin(origin_shift_task(os, client, axes, io, epoch))
    }
}

/// Read the controller's current values, retrying until it answers (without them the first write
/// could jump). Logs every 20th failure. Meanwhile the sink's status says so: not connected, the
/// last error, and a `disconnected` fault of `sink.origin_shift` from the first failed read (the
/// runtime publishes it before the first cycle); the fault clears when the controller answers.
async fn read_initial(
    client: &mut OriginShiftClient,
    status: &tokio::sync::watch::Sender<crate::sinks::SinkStatus>,
    epoch: std::time::Instant,
) -> BTreeMap<String, f64> {
    let mut attempt = 0u64;
    let mut faults = FaultLog::default();
    let link = FaultSource::named(SOURCE);
    loop {
        match client.read_current().await {
            Ok(v) => {
                tracing::info!(
                    ?v,
                    "controller holds these corrections; continuing from them"
                );
                faults.update(&link, &[], epoch.elapsed().as_secs_f64());
                status.send_modify(|st| {
                    st.connected = true;
                    st.last_error = None;
                    st.faults.clear();
                });
                return v.into_iter().collect();
            }
            Err(e) => {
                if attempt.is_multiple_of(20) {
                    tracing::warn!(%e, "waiting for the controller before starting");
                }
                let now_s = epoch.elapsed().as_secs_f64();
                let started = !faults
                    .update(&link, &[FaultKind::Disconnected], now_s)
                    .is_empty();
                status.send_modify(|st| {
                    if st.kind.is_empty() {
                        st.kind = "origin_shift".into();
                    }
                    st.connected = false;
                    st.last_error = Some(e.to_string());
                    if started {
                        st.faults = faults.active_by_name();
                    }
                });
                attempt += 1;
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::sync::watch;
    use tokio::time::{Duration, Instant};

    const PERIOD: Duration = Duration::from_millis(80);

    #[tokio::test(start_paused = true)]
    async fn a_changed_output_wakes_the_sink_at_once_and_the_period_paces_the_rest() {
        let (tx, mut rx) = watch::channel::<Vec<(Axis, f64)>>(Vec::new());
        let mut last = None;
        let t0 = Instant::now();
        // The first period at once; then, without a change, one period later.
        wait_for_period(&mut rx, PERIOD, &mut last, &[]).await;
        assert_eq!(Instant::now(), t0);
        wait_for_period(&mut rx, PERIOD, &mut last, &[]).await;
        assert_eq!(Instant::now() - t0, PERIOD);
        // A new output 30 ms later: at once.
        tokio::time::sleep(Duration::from_millis(30)).await;
        let t1 = Instant::now();
        tx.send_replace(vec![(Axis::X, 1.0)]);
        wait_for_period(&mut rx, PERIOD, &mut last, &[]).await;
        assert_eq!(Instant::now(), t1, "a new output waits for no clock");
        // The cycle publishing the same output again is no reason to run: the period is.
        let ran_with = [(Axis::X, 1.0)];
        tokio::spawn(async move {
            for _ in 0..20 {
                tokio::time::sleep(Duration::from_millis(1)).await;
                tx.send_replace(vec![(Axis::X, 1.0)]);
            }
        });
        wait_for_period(&mut rx, PERIOD, &mut last, &ran_with).await;
        assert_eq!(Instant::now() - t1, PERIOD);
    }

    #[tokio::test(start_paused = true)]
    async fn after_the_cycle_ends_the_period_paces_the_stop_ramp() {
        let (tx, mut rx) = watch::channel::<Vec<(Axis, f64)>>(Vec::new());
        drop(tx);
        let mut last = None;
        let t0 = Instant::now();
        for k in 0..3u32 {
            wait_for_period(&mut rx, PERIOD, &mut last, &[]).await;
            assert_eq!(Instant::now() - t0, PERIOD * k);
        }
    }

    /// The engine starts from exactly the held values the last-step guard takes as within the
    /// clamp: the same half-count tolerance, the same resolution per axis, the same clamp of 0 for
    /// an axis without limits. (They were two rules: the start rule had no tolerance and gave an
    /// axis without limits the default clamp.)
    #[test]
    fn the_start_values_are_what_the_guard_takes_as_within_the_clamp() {
        use crate::sinks::guard::{Verdict, WriteGuard};
        let map: RegisterMap = toml::from_str(
            "[[axis]]\naxis = \"x\"\naddress = 0\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
             [[axis]]\naxis = \"y\"\naddress = 2\nkind = \"int16\"\nlsb_um = 1.0\nsign = -1\n\
             [[axis]]\naxis = \"z\"\naddress = 3\nkind = \"int16\"\nlsb_um = 1.0\nsign = 1\n",
        )
        .unwrap();
        let limits = [
            AxisLimits {
                axis: "x".into(),
                max_correction_um: 50.0,
                max_change_um_per_write: 1.0,
            },
            AxisLimits {
                axis: "y".into(),
                max_correction_um: 50.0,
                max_change_um_per_write: 1.0,
            },
        ];
        let lsb_um = |axis: &str| map.axes.iter().find(|r| r.axis == axis).unwrap().lsb_um;
        let guard_takes = |axis: &str, held_um: f64| {
            let mut g = WriteGuard::new([AxisLimits::of(&limits, axis, lsb_um(axis))]);
            g.observe_read(0, held_um);
            !matches!(g.check(0, 0.0), Verdict::BeyondClamp { .. })
        };
        let cases = [
            ("x", 50.0, true),
            ("x", 50.04, true),
            ("x", 50.06, false),
            ("x", -50.04, true),
            ("x", f64::NAN, false),
            ("x", f64::INFINITY, false),
            ("y", 50.4, true),
            ("y", -50.6, false),
            ("z", 0.0, true),
            ("z", 0.4, true),
            ("z", 2.0, false),
        ];
        for (axis, held_um, within) in cases {
            let start = start_values_within([(axis.to_string(), held_um)].into(), &map, &limits);
            assert_eq!(start.contains_key(axis), within, "{axis} {held_um}");
            assert_eq!(guard_takes(axis, held_um), within, "{axis} {held_um}");
            let rule = AxisLimits::of(&limits, axis, lsb_um(axis));
            assert_eq!(rule.holds_within_clamp(held_um), within, "{axis} {held_um}");
        }
    }
}
