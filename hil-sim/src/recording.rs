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
    cell: Vec<u8>,
    /// The `run` label, formatted once: it is the same on every row.
    run: Option<String>,
    shift_columns: bool,
    tool_mm: f64,
    columns: usize,
    rows: u64,
}

/// One cell, formatted into `cell` (reused: no allocation per row). `NaN` for a NaN fault.
fn num(cell: &mut Vec<u8>, v: f64) -> &[u8] {
    cell.clear();
    if v.is_nan() {
        cell.extend_from_slice(b"NaN");
    } else {
        // Writing into a Vec cannot fail.
        let _ = write!(cell, "{v}");
    }
    cell
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
            cell: Vec::with_capacity(32),
            run: cfg.record.run.map(|r| r.to_string()),
            shift_columns: cfg.record.shift_columns,
            tool_mm: cfg.program.tool_mm,
            columns: h.len(),
            rows: 0,
        })
    }

    pub fn write(&mut self, r: &Readings) -> anyhow::Result<()> {
        let (csv, cell) = (&mut self.csv, &mut self.cell);
        let mut n = 0usize;
        let mut put = |bytes: &[u8]| -> csv::Result<()> {
            n += 1;
            csv.write_field(bytes)
        };
        cell.clear();
        write!(cell, "{:.6}", r.t_s)?;
        put(cell)?;
        let plain = r
            .nominal_mm
            .iter()
            .chain(&r.error_um)
            .chain(&r.sim_error_um);
        for v in plain {
            put(num(cell, *v))?;
        }
        // A dropped-out sensor is an empty cell.
        let mut opt = |v: Option<f64>, put: &mut dyn FnMut(&[u8]) -> csv::Result<()>| match v {
            Some(v) => put(num(cell, v)),
            None => put(b""),
        };
        for c in &r.temps {
            opt(c.value, &mut put)?;
        }
        opt(Some(r.rpm), &mut put)?;
        for c in r.force.iter().chain(&r.strains) {
            opt(c.value, &mut put)?;
        }
        opt(Some(self.tool_mm), &mut put)?;
        if let Some(run) = &self.run {
            put(run.as_bytes())?;
        }
        if self.shift_columns {
            for v in &r.correction_um {
                opt(Some(*v), &mut put)?;
            }
        }
        anyhow::ensure!(
            n == self.columns,
            "recording: channel layout changed mid-run"
        );
        self.csv.write_record(None::<&[u8]>)?;
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
