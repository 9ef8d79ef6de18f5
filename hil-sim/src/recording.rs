//! Recording writer: the CSV of DESIGN §4 (one row per sample) and the JSON manifest of hidden truth.
//!
//! Columns: `t_s, x_mm, y_mm, z_mm, ex_um, ey_um, ez_um, sim_ex_um, sim_ey_um, sim_ez_um`, then
//! `T_<name>_C…`, `rpm`, `F_<name>_N`, `strain_<name>_ue…`, `tool_mm`, optional `run` and
//! `shift_<axis>_um`. `x_mm…` are nominal (commanded, before the correction); `e*_um` are the measured
//! tool-tip errors (actual − nominal, including whatever correction the controller received); `sim_e*`
//! are the visible model's prediction at the nominal position plus the received correction.
//! A dropped-out sensor leaves its cell empty; a NaN fault writes `NaN` (diagnose must report both).
//! Numbers are written with Rust's shortest round-trip formatting, so output is byte-reproducible.
//! Why not `retrocomp::recording::RecordingWriter`: that writer refuses non-finite and missing cells,
//! and the simulator must be able to produce sensor faults on demand. Fault-free recordings read back
//! with `retrocomp::recording::Recording::read_strict`; with faults, `read_lenient` reports exactly
//! the faulted rows (tested in `tests/sim_faults.rs`).

use crate::world::{Readings, World};
use std::io::Write;

pub struct Recorder<W: Write> {
    csv: csv::Writer<W>,
    run: Option<i64>,
    shift_columns: bool,
    tool_mm: f64,
    columns: usize,
    rows: u64,
}

fn num(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else {
        format!("{v}")
    }
}

impl<W: Write> Recorder<W> {
    /// Writes the header for `world`'s channel layout.
    pub fn new(out: W, world: &World) -> anyhow::Result<Self> {
        let cfg = world.config();
        let mut csv = csv::WriterBuilder::new().from_writer(out);
        let r = world.readings();
        let mut h: Vec<String> = [
            "t_s",
            "x_mm",
            "y_mm",
            "z_mm",
            "ex_um",
            "ey_um",
            "ez_um",
            "sim_ex_um",
            "sim_ey_um",
            "sim_ez_um",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        h.extend(r.temps.iter().map(|c| c.name.clone()));
        h.push("rpm".into());
        h.extend(r.force.iter().map(|c| c.name.clone()));
        h.extend(r.strains.iter().map(|c| c.name.clone()));
        h.push("tool_mm".into());
        if cfg.record.run.is_some() {
            h.push("run".into());
        }
        if cfg.record.shift_columns {
            h.extend(["shift_x_um", "shift_y_um", "shift_z_um"].map(String::from));
        }
        csv.write_record(&h)?;
        Ok(Self {
            csv,
            run: cfg.record.run,
            shift_columns: cfg.record.shift_columns,
            tool_mm: cfg.program.tool_mm,
            columns: h.len(),
            rows: 0,
        })
    }

    pub fn write(&mut self, r: &Readings) -> anyhow::Result<()> {
        let mut row = Vec::with_capacity(self.columns);
        row.push(format!("{:.6}", r.t_s));
        row.extend(r.nominal_mm.iter().map(|v| num(*v)));
        row.extend(r.error_um.iter().map(|v| num(*v)));
        row.extend(r.sim_error_um.iter().map(|v| num(*v)));
        let cell = |v: Option<f64>| v.map(num).unwrap_or_default();
        row.extend(r.temps.iter().map(|c| cell(c.value)));
        row.push(num(r.rpm));
        row.extend(r.force.iter().map(|c| cell(c.value)));
        row.extend(r.strains.iter().map(|c| cell(c.value)));
        row.push(num(self.tool_mm));
        if let Some(run) = self.run {
            row.push(run.to_string());
        }
        if self.shift_columns {
            row.extend(r.correction_um.iter().map(|v| num(*v)));
        }
        anyhow::ensure!(
            row.len() == self.columns,
            "recording: channel layout changed mid-run"
        );
        self.csv.write_record(&row)?;
        self.rows += 1;
        Ok(())
    }

    pub fn rows(&self) -> u64 {
        self.rows
    }

    pub fn finish(mut self) -> anyhow::Result<W> {
        self.csv.flush()?;
        self.csv
            .into_inner()
            .map_err(|e| anyhow::anyhow!("recording: {}", e.error()))
    }
}

/// Run `world` to the end as fast as possible, calling `each_tick` after every step (compensators,
/// bus publishers) and writing one row per sample. Returns the writer and the row count.
pub fn run_to_end<W: Write>(
    world: &mut World,
    out: W,
    mut each_tick: impl FnMut(&mut World),
) -> anyhow::Result<(W, u64)> {
    let mut rec = Recorder::new(out, world)?;
    rec.write(world.readings())?;
    while !world.done() {
        world.tick();
        each_tick(world);
        if world.sampled() {
            rec.write(world.readings())?;
        }
    }
    let rows = rec.rows();
    Ok((rec.finish()?, rows))
}
