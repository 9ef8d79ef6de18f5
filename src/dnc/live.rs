//! The correction a DNC block carries: the live model evaluated at the block's nominal end point
//! and approach directions ([`CorrectionAt`]; [`EngineAtPoint`] is the gateway's engine, its
//! health checks and model, fed by the live sources), passed through the last-step guard ([`WriteGuard`]: clamp, and
//! per-block cap from the correction the previous block carried), as the NC rewriter's
//! [`ErrorFunction`] so modal state and approach directions are the rewriter's own.
//!
//! The guard's "what the controller holds" is the correction of the last block handed to the
//! controller (0 before the first): [`LiveCorrections::commit`] is called once a block has left the
//! box. The rewriter may ask twice for one end point (domain check, then the piece): the second
//! answer is the first one, cached, so a block carries one value however often it is asked.
//!
//! With [`LiveCorrections::with_drift`] a block carries the correction predicted for when it is
//! estimated to end on the control ([`LiveCorrections::set_end_s`]; `drift.rs` says how and
//! within which bounds), still through the same guard.
//!
//! Signs and units: corrections µm, = −error; the rewriter writes `nominal − error/1000` mm, so
//! the block's end point is `nominal + correction`. Positions mm, machine coordinates, X radial.

use std::cell::RefCell;

use retrocomp_analysis::nc::ErrorFunction;
use retrocomp_bus::Sample;
use retrocomp_model::approach::Approach;

use retrocomp_gateway::engine::{Engine, ErrorModel};
use retrocomp_gateway::sinks::guard::{GuardLimits, Verdict, WriteGuard};
use retrocomp_gateway::status::StatusSnapshot;

use super::drift::{DriftConfig, DriftPredictor};

/// Output resolution of a compensated block, µm (the rewriter writes 4 decimals in mm).
pub(crate) const BLOCK_LSB_UM: f64 = 0.1;

/// Where the live correction comes from.
pub trait CorrectionAt {
    /// Correction per axis X, Y, Z (µm, = −error) at the nominal machine position `pos_mm`
    /// approached in `dirs`, at `now_s`; `None` for an axis not corrected. `Err`: the model could
    /// not be evaluated now (a missing input): the block carries the previous correction.
    fn correction_um(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
        now_s: f64,
    ) -> Result<[Option<f64>; 3], String>;

    /// `Ok` once the model can be evaluated at `now_s` (every required input usable); `Err` says
    /// which inputs are missing. A source without inputs is always ready.
    fn ready(&mut self, _now_s: f64) -> Result<(), String> {
        Ok(())
    }

    /// [`Self::correction_um`] another point at the `now_s` of the last call, with no sample
    /// observed since (the drift prediction's second point per block): a source that judges its
    /// inputs does not judge them again.
    fn correction_again_um(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
        now_s: f64,
    ) -> Result<[Option<f64>; 3], String> {
        self.correction_um(pos_mm, dirs, now_s)
    }

    /// A sample from the live sources (a source that reads none ignores it).
    fn observe(&mut self, _s: &Sample) {}

    /// What `/status` and `/metrics` show of the source (None: it has no status).
    fn snapshot(&self) -> Option<StatusSnapshot> {
        None
    }

    /// The last successful [`Self::correction_um`] used an input that is not a healthy reading
    /// of its own (substituted, an optional one missing): not a value to extrapolate from.
    fn inputs_degraded(&self) -> bool {
        false
    }
}

/// What one block carries: the end point asked for, and the correction sent per axis (µm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Applied {
    pub pos_mm: [f64; 3],
    pub dirs: [Approach; 3],
    pub correction_um: [f64; 3],
}

struct Inner {
    src: Box<dyn CorrectionAt>,
    /// Axes with a clamp (the ones the field config drives).
    driven: [bool; 3],
    guard: WriteGuard,
    now_s: f64,
    /// When the block being prepared is estimated to end on the control, s (None: at `now_s`).
    end_s: Option<f64>,
    /// The drift prediction, when asked for.
    drift: Option<DriftPredictor>,
    /// The block being prepared (not yet committed).
    pending: Option<Applied>,
    /// Corrections carried by the last committed block.
    held_um: [f64; 3],
    /// Blocks before the resume point: modal state only, no correction asked.
    bypass: bool,
    /// The model could not be evaluated for the last block (why).
    model_fault: Option<String>,
    /// The guard refused the wanted value of the last block (the previous value was kept).
    guard_refused: bool,
}

/// The rewriter's error function during a DNC transfer.
pub struct LiveCorrections {
    inner: RefCell<Inner>,
}

// By hand: the correction source is a trait object.
impl std::fmt::Debug for LiveCorrections {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let i = self.inner.borrow();
        f.debug_struct("LiveCorrections")
            .field("held_um", &i.held_um)
            .field("pending", &i.pending)
            .finish_non_exhaustive()
    }
}

impl LiveCorrections {
    /// `limits` per axis X, Y, Z (an axis the config does not drive: clamp 0, cap 0).
    pub fn new(src: Box<dyn CorrectionAt>, limits: [(f64, f64); 3]) -> Self {
        let mut guard = WriteGuard::new(limits.map(|(max, cap)| GuardLimits {
            max_correction_um: max,
            max_change_um_per_write: cap,
            lsb_um: BLOCK_LSB_UM,
        }));
        // The controller holds no correction before the first compensated block.
        for k in 0..3 {
            guard.observe_read(k, 0.0);
        }
        Self {
            inner: RefCell::new(Inner {
                src,
                driven: limits.map(|(max, _)| max > 0.0),
                guard,
                now_s: 0.0,
                end_s: None,
                drift: None,
                pending: None,
                held_um: [0.0; 3],
                bypass: false,
                model_fault: None,
                guard_refused: false,
            }),
        }
    }

    /// A sample from the live sources, for the model's inputs.
    pub fn observe(&self, s: &Sample) {
        self.inner.borrow_mut().src.observe(s);
    }

    /// `Ok` once the source can give a correction at `now_s`; `Err`: which inputs it still lacks.
    pub fn ready(&self, now_s: f64) -> Result<(), String> {
        self.inner.borrow_mut().src.ready(now_s)
    }

    /// The time corrections are asked at (the send time of the next block), s.
    pub fn set_now(&self, now_s: f64) {
        self.inner.borrow_mut().now_s = now_s;
    }

    /// Predict each block's correction for when it is estimated to end ([`Self::set_end_s`]).
    #[must_use]
    pub fn with_drift(self, cfg: DriftConfig) -> Self {
        self.inner.borrow_mut().drift = Some(DriftPredictor::new(cfg));
        self
    }

    /// When the next block is estimated to end on the control, s (the drift prediction's target).
    pub fn set_end_s(&self, end_s: f64) {
        self.inner.borrow_mut().end_s = Some(end_s);
    }

    /// Blocks are only interpreted (before the operator's resume point): no correction is asked.
    pub fn set_bypass(&self, bypass: bool) {
        self.inner.borrow_mut().bypass = bypass;
    }

    /// The block prepared since the last commit has left the box: its correction is what the
    /// controller holds now. Returns it (None for a block without a compensated end point).
    pub fn commit(&self) -> Option<Applied> {
        let mut i = self.inner.borrow_mut();
        let a = i.pending.take()?;
        for k in 0..3 {
            i.guard.wrote(k, a.correction_um[k], true);
        }
        i.held_um = a.correction_um;
        Some(a)
    }

    /// Forget a prepared block that will not be sent (the rewrite failed after it asked).
    pub fn discard(&self) {
        self.inner.borrow_mut().pending = None;
    }

    /// Why the model could not be evaluated for the last block, if it could not.
    pub fn model_fault(&self) -> Option<String> {
        self.inner.borrow().model_fault.clone()
    }

    /// The correction the last block sent carried, per axis X, Y, Z (what the control holds), µm.
    pub fn held_um(&self) -> [f64; 3] {
        self.inner.borrow().held_um
    }

    /// The guard refused the wanted correction of the last block.
    pub fn guard_refused(&self) -> bool {
        self.inner.borrow().guard_refused
    }

    /// The source's status (the engine's channels, faults, targets), with each driven axis'
    /// applied value the correction the last block sent carried; None for a source without one.
    pub fn snapshot(&self) -> Option<StatusSnapshot> {
        let i = self.inner.borrow();
        let mut s = i.src.snapshot()?;
        for a in &mut s.axes {
            if let Some(ax) = retrocomp_model::Axis::from_name(&a.axis) {
                a.applied_um = i.held_um[ax.index()];
            }
        }
        Some(s)
    }
}

impl Inner {
    /// The correction the block at `pos_mm`/`dirs` wants before the guard, µm per axis: the
    /// source's at `now_s`, plus, with a drift prediction, the drift to the block's estimated end.
    fn wanted_um(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
    ) -> Result<[Option<f64>; 3], String> {
        let now = self.now_s;
        let Some(d) = self.drift.as_mut() else {
            return self.src.correction_um(pos_mm, dirs, now);
        };
        // The drift series' reference point first, at the same `now` (the engine's lag states
        // do not move at Δt = 0), so that the source's snapshot shows this block's point, which
        // is then asked without judging the inputs again.
        let got = match d.reference() {
            Some((rp, rd))
                if (rp.map(f64::to_bits) != pos_mm.map(f64::to_bits) || rd != dirs)
                    && d.due(now) =>
            {
                match self.src.correction_um(rp, rd, now) {
                    Ok(c) if !self.src.inputs_degraded() => d.record(rp, rd, now, c),
                    _ => d.reset(),
                }
                self.src.correction_again_um(pos_mm, dirs, now)
            }
            _ => self.src.correction_um(pos_mm, dirs, now),
        };
        let Ok(mut w) = got else {
            d.reset();
            return got;
        };
        if self.src.inputs_degraded() {
            d.reset();
        } else {
            d.record(pos_mm, dirs, now, w);
            let ahead = d.ahead_um(now, self.end_s.unwrap_or(now));
            for (c, a) in w.iter_mut().zip(ahead) {
                *c = c.map(|v| v + a);
            }
        }
        Ok(w)
    }
}

impl ErrorFunction for LiveCorrections {
    /// Only the driven axes need a known position and get a correction.
    fn axes(&self) -> [bool; 3] {
        self.inner.borrow().driven
    }

    fn error_um(&self, pos_mm: [f64; 3], dirs: [Approach; 3]) -> Option<[f64; 3]> {
        let mut guard = self.inner.borrow_mut();
        let i = &mut *guard;
        if i.bypass {
            return Some([0.0; 3]);
        }
        if let Some(a) = i.pending
            && a.pos_mm.map(f64::to_bits) == pos_mm.map(f64::to_bits)
            && a.dirs == dirs
        {
            return Some(a.correction_um.map(|c| -c));
        }
        let want = match i.wanted_um(pos_mm, dirs) {
            Ok(w) => {
                i.model_fault = None;
                w
            }
            Err(why) => {
                i.model_fault = Some(why);
                [None; 3]
            }
        };
        i.guard_refused = false;
        let mut sent = [0.0; 3];
        for k in 0..3 {
            // No value (axis not driven, model fault): hold what the controller has.
            let w = want[k].unwrap_or(i.held_um[k]);
            sent[k] = match i.guard.check(k, w) {
                Verdict::Write(v) => v,
                _ => {
                    i.guard_refused = true;
                    i.held_um[k]
                }
            };
        }
        i.pending = Some(Applied {
            pos_mm,
            dirs,
            correction_um: sent,
        });
        Some(sent.map(|c| -c))
    }
}

/// The gateway's engine evaluated at a block's end point: samples go through
/// [`Engine::handle_sample`] (the gateway's range, rate, stuck and staleness checks, neighbour recovery,
/// thermal latching), and a block's correction is [`Engine::correction_at`] its nominal end point
/// and approach directions. A refusal (an input the engine judges unusable, a model failure) is
/// the block's model fault: it carries the previous correction.
pub struct EngineAtPoint {
    engine: Engine,
    model: Box<dyn ErrorModel>,
}

// By hand: the model is a trait object.
impl std::fmt::Debug for EngineAtPoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EngineAtPoint")
            .field("engine", &self.engine)
            .finish_non_exhaustive()
    }
}

impl EngineAtPoint {
    pub fn new(engine: Engine, model: Box<dyn ErrorModel>) -> Self {
        Self { engine, model }
    }
}

impl CorrectionAt for EngineAtPoint {
    fn observe(&mut self, s: &Sample) {
        self.engine.handle_sample(s);
    }

    fn ready(&mut self, now_s: f64) -> Result<(), String> {
        self.engine
            .inputs_ready(now_s, self.model.as_ref())
            .map_err(|e| e.to_string())
    }

    fn correction_um(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
        now_s: f64,
    ) -> Result<[Option<f64>; 3], String> {
        self.engine
            .correction_at(now_s, self.model.as_mut(), pos_mm, dirs)
            .map_err(|e| e.to_string())
    }

    fn correction_again_um(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
        _now_s: f64,
    ) -> Result<[Option<f64>; 3], String> {
        self.engine
            .correction_at_again(self.model.as_mut(), pos_mm, dirs)
            .map_err(|e| e.to_string())
    }

    fn inputs_degraded(&self) -> bool {
        self.engine.inputs_degraded()
    }

    fn snapshot(&self) -> Option<StatusSnapshot> {
        let mut s = self.engine.snapshot();
        s.model = self.model.identity();
        Some(s)
    }
}
