//! The quadrature sink: per axis, the cycle's correction (µm, = −error) becomes whole counts
//! ([`CountQuantizer`]: sign, resolution, carried residual) and goes to that axis's injector — a GPIO
//! thread (`gpio` lines configured, cargo feature `gpio`) or the scheduler run in simulation (no
//! lines configured: counts and edges are planned exactly as for GPIO, without pins).
//!
//! Restart (pulses have no read-back): the counts the controller holds are persisted per axis in
//! `state_file` ([`super::held`]), written ahead of every step's edges. [`Sink::start`] reads them:
//! the quantizer continues from them, the lines start at their phase (no edge at takeover) and the
//! engine is seeded with the correction they realise. No file = first start (all 0, one INFO line);
//! a corrupt or unreadable file refuses the start (nothing is injected until it is fixed); a failed
//! write-ahead is a fault of the sink and that step injects nothing.
//!
//! A config that names GPIO lines on a build without the `gpio` feature is refused at start
//! ([`check_buildable`]) rather than silently simulated: the technician would otherwise see a
//! healthy status while nothing reaches the controller.

use crate::models::Axis;
use std::collections::BTreeMap;
use tokio::sync::watch;

use super::config::{QuadratureAxis, QuadratureSink};
use super::held::{FileHeldCounts, HeldCounts, HeldError, write_ahead};
use crate::error::Chain;
use crate::quadrature::{CountQuantizer, EdgeScheduler, SchedulerConfig, simulate};
use crate::sink::{LocalFuture, Sink, SinkError, SinkIo, SinkStatus, StartValues};

/// Refuse GPIO lines this build cannot drive.
pub fn check_buildable(q: &QuadratureSink) -> Result<(), SinkError> {
    for a in &q.axes {
        if a.gpio.is_some() && !cfg!(all(feature = "gpio", target_os = "linux")) {
            return Err(SinkError::Refused(format!(
                "sink.quadrature axis {}: `gpio` lines are configured but this build has no GPIO \
                 support; rebuild with `cargo build --release --features gpio` (Linux), or remove \
                 `gpio = …` to run the injector in simulation",
                a.axis
            )));
        }
    }
    Ok(())
}

/// Where one axis's counts go.
enum AxisInjector {
    Simulated(EdgeScheduler),
    #[cfg(all(feature = "gpio", target_os = "linux"))]
    Gpio {
        deltas: std::sync::mpsc::Sender<i64>,
        counts: std::sync::Arc<std::sync::Mutex<crate::quadrature::InjectorCounts>>,
    },
}

impl AxisInjector {
    /// Open at `held` counts: the lines start at that phase's levels.
    fn open(a: &QuadratureAxis, held: i64) -> Result<Self, SinkError> {
        let sched = EdgeScheduler::new(SchedulerConfig {
            min_edge_gap_ns: a.min_edge_gap_ns,
            max_inject_rate_hz: a.max_inject_rate_hz,
        })
        .map_err(|e| SinkError::setup(format!("sink.quadrature axis {}", a.axis), e))?
        .starting_at(held);
        match &a.gpio {
            None => Ok(Self::Simulated(sched)),
            #[cfg(all(feature = "gpio", target_os = "linux"))]
            Some(lines) => {
                use crate::quadrature::{Injector, InjectorCounts, run_injector};
                let (pin_a, pin_b) =
                    crate::quadrature::gpio::open_output_pins(lines, sched.levels()).map_err(
                        |e| SinkError::setup(format!("sink.quadrature axis {}", a.axis), e),
                    )?;
                let inj = Injector::new(sched, pin_a, pin_b)
                    .map_err(|e| SinkError::Refused(format!("axis {}: {e}", a.axis)))?;
                let (tx, rx) = std::sync::mpsc::channel();
                let counts = std::sync::Arc::new(std::sync::Mutex::new(InjectorCounts::default()));
                let shared = counts.clone();
                let axis = a.axis.clone();
                std::thread::Builder::new()
                    .name(format!("quadrature-{axis}"))
                    .spawn(move || {
                        let report = |c| *shared.lock().unwrap_or_else(|p| p.into_inner()) = c;
                        if let Err(e) = run_injector(inj, rx, report) {
                            tracing::error!(axis, %e, "GPIO injector stopped");
                        }
                    })
                    .map_err(|e| SinkError::setup("spawning the injector thread", e))?;
                Ok(Self::Gpio { deltas: tx, counts })
            }
            #[cfg(not(all(feature = "gpio", target_os = "linux")))]
            Some(_) => Err(SinkError::Refused(format!(
                "sink.quadrature axis {}: this build has no GPIO support (feature `gpio`)",
                a.axis
            ))),
        }
    }

    /// Hand over `delta` counts; false if the injector is gone.
    fn inject(&mut self, delta: i64) -> bool {
        match self {
            Self::Simulated(sched) => {
                sched.add_inject_counts(delta);
                let _ = simulate(sched, &[]);
                true
            }
            #[cfg(all(feature = "gpio", target_os = "linux"))]
            Self::Gpio { deltas, .. } => deltas.send(delta).is_ok(),
        }
    }

    fn kind(&self) -> &'static str {
        match self {
            Self::Simulated(_) => "quadrature (simulated)",
            #[cfg(all(feature = "gpio", target_os = "linux"))]
            Self::Gpio { .. } => "quadrature (gpio)",
        }
    }

    /// Counts requested but not yet written to the lines.
    fn owed(&self) -> i64 {
        match self {
            Self::Simulated(s) => s.inject_remaining(),
            #[cfg(all(feature = "gpio", target_os = "linux"))]
            Self::Gpio { counts, .. } => counts.lock().map(|c| c.owed).unwrap_or(0),
        }
    }
}

/// Read the persisted counts: per configured axis the held count (0 when none is persisted) and
/// the start values (µm the controller holds) the engine continues from.
pub fn held_at_start(
    q: &QuadratureSink,
    store: &mut dyn HeldCounts,
) -> Result<(BTreeMap<String, i64>, StartValues), HeldError> {
    let persisted = store.load()?;
    if persisted.is_none() {
        tracing::info!(
            "sink.quadrature: no held-counts file, first start: the controller holds 0 counts \
             (delete the file after homing or power-cycling the controller)"
        );
    }
    let persisted = persisted.unwrap_or_default();
    let mut held = BTreeMap::new();
    let mut start = StartValues::new();
    for a in &q.axes {
        let n = persisted.get(&a.axis).copied().unwrap_or(0);
        let quant = CountQuantizer::continuing_from(a.resolution_um, a.count_sign, n)?;
        held.insert(a.axis.clone(), n);
        start.insert(a.axis.clone(), quant.correction_um_of(n));
    }
    Ok((held, start))
}

/// The quadrature injector as the run loop's [`Sink`]: [`Sink::start`] reads the persisted held
/// counts ([`held_at_start`]); [`Sink::run`] is [`quadrature_task`].
#[derive(Debug)]
pub struct QuadratureOutput {
    cfg: QuadratureSink,
    held: BTreeMap<String, i64>,
}

impl QuadratureOutput {
    pub fn new(cfg: QuadratureSink) -> Self {
        Self {
            cfg,
            held: BTreeMap::new(),
        }
    }

    fn store(&self) -> FileHeldCounts {
        FileHeldCounts::new(self.cfg.state_path(std::path::Path::new(".")))
    }
}

impl Sink for QuadratureOutput {
    fn start<'a>(&'a mut self, _io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>> {
        Box::pin(async move {
            let (held, start) = held_at_start(&self.cfg, &mut self.store()).map_err(|e| {
                SinkError::setup(
                    "sink.quadrature state_file (nothing is injected until it is fixed)",
                    e,
                )
            })?;
            self.held = held;
            Ok(start)
        })
    }

    fn run(self: Box<Self>, io: SinkIo) -> LocalFuture<'static, ()> {
        let mut store = self.store();
        // `load` fills the store's map, so a save rewrites every axis, not only the changed one.
        if let Err(e) = store.load() {
            tracing::error!("{}", Chain(&e));
        }
        Box::pin(quadrature_task(
            self.cfg,
            self.held,
            Box::new(store),
            io.out_rx,
            io.status,
        ))
    }
}

/// Follow the cycle's outputs until the runtime drops its sender.
pub async fn quadrature_task(
    q: QuadratureSink,
    held: BTreeMap<String, i64>,
    mut store: Box<dyn HeldCounts>,
    mut out_rx: watch::Receiver<Vec<(Axis, f64)>>,
    status: watch::Sender<SinkStatus>,
) {
    let mut axes = Vec::new();
    for a in &q.axes {
        let n = held.get(&a.axis).copied().unwrap_or(0);
        let opened = CountQuantizer::continuing_from(a.resolution_um, a.count_sign, n)
            .map_err(|e| SinkError::Refused(e.to_string()))
            .and_then(|quant| Ok((quant, AxisInjector::open(a, n)?)));
        match opened {
            // Axis names are validated (x, y or z, each an [[axis]]) when the config loads.
            Ok((quant, inj)) => match Axis::from_name(&a.axis) {
                Some(axis) => axes.push((axis, quant, inj)),
                None => tracing::error!(axis = a.axis, "not an axis (x, y or z): never driven"),
            },
            Err(e) => {
                tracing::error!(axis = a.axis, "{}", Chain(&e));
                let _ = status.send(SinkStatus {
                    kind: "quadrature".into(),
                    last_error: Some(Chain(&e).to_string()),
                    ..Default::default()
                });
                return;
            }
        }
    }
    let mut st = SinkStatus {
        kind: axes.first().map_or("quadrature", |a| a.2.kind()).into(),
        connected: true,
        ..Default::default()
    };
    while out_rx.changed().await.is_ok() {
        let outs = out_rx.borrow().clone();
        for (axis, quant, inj) in &mut axes {
            let Some((_, v)) = outs.iter().find(|(a, _)| a == axis) else {
                continue;
            };
            match write_ahead(store.as_mut(), axis.name(), quant, *v) {
                Ok(d) if inj.inject(d) => st.writes_ok += 1,
                Ok(_) => {
                    st.writes_failed += 1;
                    st.connected = false;
                    st.last_error = Some(format!("axis {axis}: injector stopped"));
                }
                Err(e) => {
                    st.writes_failed += 1;
                    st.last_error = Some(format!("axis {axis}: {}", Chain(&e)));
                }
            }
            if inj.owed() != 0 {
                let axis = axis.name();
                tracing::debug!(axis, owed = inj.owed(), "counts still owed to the lines");
            }
        }
        let _ = status.send(st.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gpio_lines_need_a_gpio_build() {
        // The shipped field file's `[sink.quadrature]` section (the whole file is parsed by the
        // gateway's config tests; this module sits below the gateway and reads only its section).
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("deploy/field/mill-quadrature.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let file: toml::Table = toml::from_str(&text).unwrap();
        let q: QuadratureSink = file["sink"]["quadrature"].clone().try_into().unwrap();
        assert!(q.axes[0].gpio.is_some());
        let checked = check_buildable(&q);
        if cfg!(all(feature = "gpio", target_os = "linux")) {
            checked.unwrap();
        } else {
            let e = checked.unwrap_err().to_string();
            assert!(e.contains("--features gpio") && e.contains("axis x"), "{e}");
        }
        let mut simulated = q.clone();
        for a in &mut simulated.axes {
            a.gpio = None;
        }
        check_buildable(&simulated).unwrap();
    }
}
