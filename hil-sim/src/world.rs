//! The deterministic stepped world: legacy controller + true machine + sensors. Sans-IO: it takes
//! time steps and register writes as arguments and exposes its state; the clock, the buses and the
//! files are shells around it.
//!
//! Per step: interpolator → PLC scan (latches origin shifts) → position loops → drive train (backlash,
//! lead-screw error, screw expansion) → thermal network → cutting force. The tool-tip error
//! (actual − nominal, µm) is the sum, in this fixed order, of:
//! `loop` (motor − nominal: following error, origin shift, injected counts, quantization),
//! `backlash`, `cyclic`, `expansion` (slide − motor), `geometric` (visible model at the slide
//! position), `growth` (thermal drift of the tool point), `force` (deflection under cutting load).

use crate::config::SimConfig;
use crate::controller::dnc::DncStream;
use crate::controller::gcode;
use crate::controller::interp::{ProgramRunner, ScriptRunner, Setpoint, Trajectory};
use crate::controller::plc::OriginShiftPlc;
use crate::controller::servo::AxisServo;
use crate::physics::cutting::CuttingConfig;
use crate::physics::faults::Fault;
use crate::physics::mechanics::{Backlash, CyclicConfig};
use crate::physics::thermal::ThermalNet;
pub use crate::recording::DwellEnd;
use crate::rng::Noise;
use crate::truth::TruthModel;

const EPS_S: f64 = 1e-9;

/// Per-axis error terms, µm. `total_um` is their sum in declaration order.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Breakdown {
    pub loop_um: [f64; 3],
    pub backlash_um: [f64; 3],
    pub cyclic_um: [f64; 3],
    pub expansion_um: [f64; 3],
    pub geometric_um: [f64; 3],
    pub growth_um: [f64; 3],
    pub force_um: [f64; 3],
    pub total_um: [f64; 3],
}

/// One sampled sensor channel; `None` = no reading (dropout).
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    pub name: String,
    pub value: Option<f64>,
}

/// What the instruments and sensors reported at the last sample time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Readings {
    pub t_s: f64,
    pub nominal_mm: [f64; 3],
    /// Measured tool-tip error (truth + instrument noise), µm.
    pub error_um: [f64; 3],
    /// The visible model's prediction at the nominal position plus the correction the controller received.
    pub sim_error_um: [f64; 3],
    /// Correction the controller received (origin shift − injected counts), µm.
    pub correction_um: [f64; 3],
    pub rpm: f64,
    pub temps: Vec<Channel>,
    pub force: Option<Channel>,
    pub strains: Vec<Channel>,
}

pub struct World {
    cfg: SimConfig,
    t_s: f64,
    ticks: u64,
    traj: Trajectory,
    sp: Setpoint,
    v_sp_mm_s: [f64; 3],
    servos: [AxisServo; 3],
    plc: OriginShiftPlc,
    next_scan_s: f64,
    backlash: [Option<Backlash>; 3],
    cyclic: [Option<CyclicConfig>; 3],
    thermal: Option<ThermalNet>,
    cutting: Option<CuttingConfig>,
    force_N: f64,
    truth: Box<dyn TruthModel>,
    faults: Vec<Fault>,
    temp_noise: Vec<Noise>,
    force_noise: Noise,
    strain_noise: Vec<Noise>,
    error_noise: Noise,
    readings: Readings,
    next_sample_s: f64,
    sampled: bool,
    /// Latched direction of each motor (last non-zero motion), for bidirectional truth tables.
    dir: [i8; 3],
    /// The DNC input (`[io.dnc]`): the program arrives while it runs.
    dnc: Option<DncStream>,
    dwell_end: Option<DwellEnd>,
}

// By hand: the truth model is a trait object (and the machine's state is long).
impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("World")
            .field("t_s", &self.t_s)
            .field("ticks", &self.ticks)
            .field("force_N", &self.force_N)
            .field("dir", &self.dir)
            .finish_non_exhaustive()
    }
}

impl World {
    /// A world whose visible geometry is the config's `truth.model_path` model, or its built-in one.
    pub fn new(cfg: SimConfig) -> anyhow::Result<Self> {
        let truth: Box<dyn TruthModel> = match &cfg.truth.model_path {
            Some(p) => Box::new(crate::truth::VolumetricTruth::from_toml_path(p)?),
            None => Box::new(cfg.truth.builtin.clone()),
        };
        Self::with_truth(cfg, truth)
    }

    /// A world with any geometric truth model (e.g. the project's `VolumetricModel`).
    pub fn with_truth(cfg: SimConfig, truth: Box<dyn TruthModel>) -> anyhow::Result<Self> {
        cfg.validate()?;
        let (traj, start_pos) = trajectory(&cfg)?;
        let dnc = cfg
            .io
            .dnc
            .clone()
            .map(|d| DncStream::new(d, cfg.program.start_mm, cfg.servo.rapid_mm_min));
        let servos = start_pos.map(AxisServo::new);
        let backlash = std::array::from_fn(|k| {
            cfg.hidden
                .backlash
                .get(k)
                .map(|b| Backlash::new(b.clone(), start_pos[k]))
        });
        let cyclic = std::array::from_fn(|k| cfg.hidden.cyclic.get(k).cloned());
        let thermal = cfg.hidden.thermal.clone().map(ThermalNet::new);
        let seed = cfg.seed;
        let (temp_noise, strain_noise) = sensor_noises(&cfg, thermal.as_ref());
        let faults = cfg
            .faults
            .iter()
            .enumerate()
            .map(|(i, f)| Fault::new(f.clone(), seed, i))
            .collect();
        let mut w = World {
            t_s: 0.0,
            ticks: 0,
            sp: Setpoint {
                pos_mm: start_pos,
                ..Default::default()
            },
            v_sp_mm_s: [0.0; 3],
            servos,
            plc: OriginShiftPlc::new(cfg.plc.clone()),
            next_scan_s: 0.0,
            backlash,
            cyclic,
            thermal,
            cutting: cfg.hidden.cutting.clone(),
            force_N: 0.0,
            truth,
            faults,
            temp_noise,
            force_noise: Noise::new(seed, "force"),
            strain_noise,
            error_noise: Noise::new(seed, "error_instrument"),
            readings: Readings::default(),
            next_sample_s: 0.0,
            sampled: false,
            dir: [0; 3],
            dnc,
            dwell_end: None,
            traj,
            cfg,
        };
        w.sample();
        w.check_fault_channels()?;
        Ok(w)
    }

    /// Every sensor fault must name a channel the world records (known only once it is built).
    fn check_fault_channels(&self) -> anyhow::Result<()> {
        let names = self.channel_names();
        for (i, f) in self.cfg.faults.iter().enumerate() {
            anyhow::ensure!(
                names.contains(&f.channel),
                "faults[{i}]: unknown channel `{}` (known: {})",
                f.channel,
                names.join(", ")
            );
        }
        Ok(())
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    pub fn t_s(&self) -> f64 {
        self.t_s
    }

    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// The program reached M30 (or the script its last point), or the duration guard tripped.
    pub fn done(&self) -> bool {
        self.sp.done || self.t_s >= self.cfg.clock.max_duration_s - EPS_S
    }

    pub fn setpoint(&self) -> &Setpoint {
        &self.sp
    }

    pub fn plc(&self) -> &OriginShiftPlc {
        &self.plc
    }

    /// Register writes from a client (Modbus shell, in-process compensator).
    pub fn plc_mut(&mut self) -> &mut OriginShiftPlc {
        &mut self.plc
    }

    /// Quadrature feedback input: `counts` added to the axis' measured position.
    pub fn inject_counts(&mut self, axis: usize, counts: i64) {
        self.servos[axis].inject_counts(counts);
    }

    /// Feedback encoder counts (what the CiA 406 encoder of the axis reports: the motor side).
    pub fn encoder_counts(&self, axis: usize) -> i64 {
        self.servos[axis].encoder_counts(self.cfg.servo.count_um)
    }

    /// The controller's measured position (encoder + injected counts), mm.
    pub fn measured_mm(&self, axis: usize) -> f64 {
        self.servos[axis].measured_mm(self.cfg.servo.count_um)
    }

    pub fn motor_mm(&self, axis: usize) -> f64 {
        self.servos[axis].motor_mm()
    }

    /// True slide position (motor + backlash + lead-screw error + screw expansion), mm: what a linear
    /// scale on the slide would read.
    pub fn slide_mm(&self, axis: usize) -> f64 {
        let motor = self.servos[axis].motor_mm();
        let backlash = self.backlash[axis].as_ref().map_or(0.0, |b| b.offset_um());
        let cyclic = self.cyclic[axis]
            .as_ref()
            .map_or(0.0, |c| c.error_um(motor));
        let expansion = self
            .thermal
            .as_ref()
            .map_or(0.0, |t| t.terms().expansion_um_per_mm[axis] * motor);
        motor + (backlash + cyclic + expansion) / 1000.0
    }

    pub fn force_N(&self) -> f64 {
        self.force_N
    }

    pub fn thermal(&self) -> Option<&ThermalNet> {
        self.thermal.as_ref()
    }

    /// Visible static geometric error at any position (what an oracle would know), µm.
    pub fn static_error_um(&mut self, q_mm: [f64; 3]) -> [f64; 3] {
        self.truth
            .static_error_um(q_mm, self.dir, self.cfg.program.tool_mm)
    }

    /// Latched direction per axis (+1/−1; 0 before the first motion).
    pub fn direction(&self) -> [i8; 3] {
        self.dir
    }

    pub fn truth_model(&self) -> &dyn TruthModel {
        &*self.truth
    }

    /// True if the last step produced a new sample (readings refreshed: a recording row is due).
    pub fn sampled(&self) -> bool {
        self.sampled
    }

    pub fn readings(&self) -> &Readings {
        &self.readings
    }

    /// Step with the configured servo period.
    pub fn tick(&mut self) {
        self.step(self.cfg.dt_s());
    }

    /// The DNC input, if the program arrives on one.
    pub fn dnc_mut(&mut self) -> Option<&mut DncStream> {
        self.dnc.as_mut()
    }

    /// The dwell end of the last step, if one was reached (taken once).
    pub fn take_dwell_end(&mut self) -> Option<DwellEnd> {
        self.dwell_end.take()
    }

    /// Advance the world by `dt_s`.
    pub fn step(&mut self, dt_s: f64) {
        let prev_nominal = self.sp.pos_mm;
        if let (Some(d), Trajectory::Program(r)) = (&mut self.dnc, &mut self.traj) {
            d.feed(r, self.t_s);
        }
        self.sp = self.traj.advance(dt_s);
        self.ticks += 1;
        self.t_s = if (dt_s - self.cfg.dt_s()).abs() < 1e-15 {
            self.ticks as f64 * dt_s
        } else {
            self.t_s + dt_s
        };
        while self.t_s + EPS_S >= self.next_scan_s {
            self.plc.scan();
            self.next_scan_s += self.cfg.plc.scan_s;
        }
        let mut motor_vel = [0.0; 3];
        for k in 0..3 {
            self.v_sp_mm_s[k] = (self.sp.pos_mm[k] - prev_nominal[k]) / dt_s;
            let target = self.sp.pos_mm[k] + self.plc.shift_um(k) / 1000.0;
            let prev_motor = self.servos[k].motor_mm();
            self.servos[k].step(&self.cfg.servo, target, self.v_sp_mm_s[k], dt_s);
            let motor = self.servos[k].motor_mm();
            if let Some(b) = &mut self.backlash[k] {
                b.update(prev_motor, motor);
            }
            motor_vel[k] = (motor - prev_motor) / dt_s;
            #[allow(clippy::float_cmp, reason = "any motion at all, however small")]
            if motor != prev_motor {
                self.dir[k] = if motor > prev_motor { 1 } else { -1 };
            }
        }
        if let Some(t) = &mut self.thermal {
            t.step(dt_s, self.sp.rpm, motor_vel);
        }
        self.force_N = match &self.cutting {
            Some(c) => c.force_N(
                self.sp.feeding,
                self.sp.pos_mm[2],
                self.sp.feed_mm_min,
                self.sp.rpm,
            ),
            None => 0.0,
        };
        self.sampled = false;
        if self.t_s + EPS_S >= self.next_sample_s {
            self.sample();
        }
        self.note_dwell_end(dt_s);
    }

    /// At the last step inside a dwell: the set-point and the true error, for [`DwellEnd`].
    fn note_dwell_end(&mut self, dt_s: f64) {
        let Trajectory::Program(r) = &self.traj else {
            return;
        };
        if let Some(line) = r.dwell_ending(dt_s) {
            let error_um = self.truth_error().total_um;
            self.dwell_end = Some(DwellEnd {
                t_s: self.t_s,
                line,
                pos_mm: self.sp.pos_mm,
                error_um,
            });
        }
    }

    /// The true tool-tip error now, term by term (no instrument noise).
    pub fn truth_error(&mut self) -> Breakdown {
        let mut b = Breakdown::default();
        let thermal = self.thermal.as_ref().map(|t| t.terms()).unwrap_or_default();
        let force = self
            .cutting
            .as_ref()
            .map(|c| c.deflection_um(self.force_N))
            .unwrap_or([0.0; 3]);
        let mut slide = [0.0; 3];
        for k in 0..3 {
            let motor = self.servos[k].motor_mm();
            b.loop_um[k] = (motor - self.sp.pos_mm[k]) * 1000.0;
            b.backlash_um[k] = self.backlash[k].as_ref().map_or(0.0, |x| x.offset_um());
            b.cyclic_um[k] = self.cyclic[k].as_ref().map_or(0.0, |c| c.error_um(motor));
            b.expansion_um[k] = thermal.expansion_um_per_mm[k] * motor;
            slide[k] = motor + (b.backlash_um[k] + b.cyclic_um[k] + b.expansion_um[k]) / 1000.0;
            b.growth_um[k] = thermal.growth_um[k];
            b.force_um[k] = force[k];
        }
        b.geometric_um = self
            .truth
            .static_error_um(slide, self.dir, self.cfg.program.tool_mm);
        for k in 0..3 {
            b.total_um[k] = b.loop_um[k]
                + b.backlash_um[k]
                + b.cyclic_um[k]
                + b.expansion_um[k]
                + b.geometric_um[k]
                + b.growth_um[k]
                + b.force_um[k];
        }
        b
    }

    fn sample(&mut self) {
        self.sampled = true;
        self.next_sample_s += self.cfg.record.every_s;
        let t = self.t_s;
        let truth = self.truth_error();
        let noise_um = self.cfg.hidden.error_noise_um;
        let nominal = self.sp.pos_mm;
        let visible = self
            .truth
            .static_error_um(nominal, self.dir, self.cfg.program.tool_mm);
        let count_um = self.cfg.servo.count_um;
        let mut r = Readings {
            t_s: t,
            nominal_mm: nominal,
            rpm: self.sp.rpm,
            ..Default::default()
        };
        for k in 0..3 {
            r.error_um[k] = truth.total_um[k] + self.error_noise.gauss(noise_um);
            r.correction_um[k] =
                self.plc.shift_um(k) - self.servos[k].injected_counts() as f64 * count_um;
            r.sim_error_um[k] = visible[k] + r.correction_um[k];
        }
        if let Some(net) = &self.thermal {
            for (i, s) in net.config().sensors.iter().enumerate() {
                let v = net.sensor_C(i) + self.temp_noise[i].gauss(s.noise_C);
                r.temps.push(Channel {
                    name: format!("T_{}_C", s.name),
                    value: Some(v),
                });
            }
        }
        if let Some(c) = &self.cutting {
            let f = self.force_N + self.force_noise.gauss(c.force_noise_N);
            r.force = Some(Channel {
                name: format!("F_{}_N", c.force_name),
                value: Some(f),
            });
            for (i, g) in c.gauges.iter().enumerate() {
                let dtemp = match (&g.node, &self.thermal) {
                    (Some(n), Some(net)) => {
                        let idx = net.config().node_index(n).expect("validated");
                        net.node_C(idx)
                            - net.config().nodes[idx]
                                .start_C
                                .unwrap_or(net.config().ambient_C)
                    }
                    _ => 0.0,
                };
                let v = g.ue_per_N * self.force_N
                    + g.ue_per_K * dtemp
                    + self.strain_noise[i].gauss(g.noise_ue);
                r.strains.push(Channel {
                    name: format!("strain_{}_ue", g.name),
                    value: Some(v),
                });
            }
        }
        for f in &mut self.faults {
            let ch = r
                .temps
                .iter_mut()
                .chain(r.force.iter_mut())
                .chain(r.strains.iter_mut())
                .find(|c| c.name == f.cfg.channel);
            if let Some(ch) = ch {
                ch.value = f.apply(t, ch.value);
            }
        }
        self.readings = r;
    }

    /// Every channel a fault may name: the sampled sensors and the encoders `enc_x`, `enc_y`, `enc_z`.
    pub fn channel_names(&self) -> Vec<String> {
        let r = &self.readings;
        let mut v: Vec<String> = r
            .temps
            .iter()
            .chain(r.force.iter())
            .chain(r.strains.iter())
            .map(|c| c.name.clone())
            .collect();
        v.extend(["enc_x", "enc_y", "enc_z"].map(String::from));
        v
    }

    /// Apply the faults of encoder channel `enc_<axis>` to a count the encoder is about to send.
    /// `None` = the encoder is silent (dropout; an integer encoder cannot send NaN, so `nan` is silence
    /// too). Spikes add `spike_size` counts.
    pub fn encoder_fault(&mut self, axis: usize, counts: i64) -> Option<i64> {
        let name = ["enc_x", "enc_y", "enc_z"][axis];
        let t = self.t_s;
        let mut v = Some(counts as f64);
        for f in self.faults.iter_mut().filter(|f| f.cfg.channel == name) {
            v = f.apply(t, v);
        }
        v.filter(|x| x.is_finite())
            .map(retrocomp_analysis::numeric::round_i64)
    }

    /// Add a sensor fault while running (faults "on demand"); the channel must exist.
    pub fn inject_fault(&mut self, f: crate::config::FaultConfig) -> anyhow::Result<()> {
        let names = self.channel_names();
        anyhow::ensure!(
            names.contains(&f.channel),
            "fault: unknown channel `{}` (known: {})",
            f.channel,
            names.join(", ")
        );
        anyhow::ensure!(
            f.to_s >= f.from_s && f.spike_every_s > 0.0,
            "fault on `{}`: bad window or spike rate",
            f.channel
        );
        let i = self.faults.len();
        self.faults.push(Fault::new(f, self.cfg.seed, i));
        Ok(())
    }

    /// Manifest of the hidden truth: effect ids and parameters in docs/diagnose-json.md conventions, plus the raw
    /// config of every hidden effect.
    pub fn manifest(&self) -> serde_json::Value {
        crate::manifest::build(&self.cfg, &*self.truth)
    }
}

/// The program to run (a script, or G-code parsed from the config or its file) and where the axes
/// start: a script's first point, or the program's `start_mm`.
fn trajectory(cfg: &SimConfig) -> anyhow::Result<(Trajectory, [f64; 3])> {
    let start = cfg.program.start_mm;
    let traj = if cfg.io.dnc.is_some() {
        Trajectory::Program(ProgramRunner::streaming(start))
    } else if !cfg.program.script.is_empty() {
        Trajectory::Script(ScriptRunner::new(cfg.program.script.clone()))
    } else {
        let text = match (&cfg.program.gcode, &cfg.program.gcode_path) {
            (Some(t), _) => t.clone(),
            (None, Some(p)) => std::fs::read_to_string(p)
                .map_err(|e| anyhow::anyhow!("program.gcode_path {}: {e}", p.display()))?,
            _ => unreachable!("validated"),
        };
        let source = match &cfg.program.gcode_path {
            Some(p) => format!("program.gcode_path {}", p.display()),
            None => "program.gcode".to_string(),
        };
        let blocks = gcode::parse(&text, start, cfg.servo.rapid_mm_min)
            .map_err(|e| anyhow::anyhow!("{source}: {e}"))?;
        Trajectory::Program(ProgramRunner::new(blocks, start))
    };
    let start_pos = match &traj {
        Trajectory::Script(_) => {
            let p = &cfg.program.script[0];
            [p.x_mm, p.y_mm, p.z_mm]
        }
        Trajectory::Program(_) => start,
    };
    Ok((traj, start_pos))
}

/// Noise streams of the temperature sensors and strain gauges, one per channel name (so adding a
/// channel leaves the others' noise unchanged).
fn sensor_noises(cfg: &SimConfig, thermal: Option<&ThermalNet>) -> (Vec<Noise>, Vec<Noise>) {
    let seed = cfg.seed;
    let temp_noise = thermal
        .map(|t| {
            t.config()
                .sensors
                .iter()
                .map(|s| Noise::new(seed, &format!("T_{}_C", s.name)))
                .collect()
        })
        .unwrap_or_default();
    let strain_noise = cfg
        .hidden
        .cutting
        .as_ref()
        .map(|c| {
            c.gauges
                .iter()
                .map(|g| Noise::new(seed, &format!("strain_{}_ue", g.name)))
                .collect()
        })
        .unwrap_or_default();
    (temp_noise, strain_noise)
}
