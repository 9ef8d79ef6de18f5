//! Recording writer: the CSV of docs/recording-csv.md (one row per sample) and the JSON manifest of hidden truth.
//!
//! Columns: `t_s, x_mm, y_mm, z_mm, ex_um, ey_um, ez_um, sim_ex_um, sim_ey_um, sim_ez_um`, then
//! `T_<name>_C…`, `rpm`, `F_<name>_N`, `strain_<name>_ue…`, `tool_mm`, optional `run` and
//! `shift_<axis>_um`. `x_mm…` are nominal (commanded, before the correction); `e*_um` are the measured
//! tool-tip errors (actual − nominal, including whatever correction the controller received); `sim_e*`
//! are the visible model's prediction at the nominal position plus the received correction.
//! A dropped-out sensor leaves its cell empty; a NaN fault writes `NaN` (diagnose must report both).
//! Numbers are written with Rust's shortest round-trip text (`t_s` with 6 decimals), formatted without
//! allocating by `retrocomp_model::decimal` (byte for byte `{}` / `{:.6}`), so output is byte-reproducible.
//! Why not `retrocomp_model::recording::RecordingWriter`: that writer refuses non-finite and missing cells,
//! and the simulator must be able to produce sensor faults on demand. Fault-free recordings read back
//! with `retrocomp_model::recording::Recording::read_strict`; with faults, `read_lenient` reports exactly
//! the faulted rows (tested in `tests/sim/faults.rs`).

use crate::world::{Readings, World};
use std::io::Write;

#[derive(Debug)]
pub struct Recorder<W: Write> {
    out: W,
    /// Rows assembled here and handed to `out` in blocks of about [`Recorder::BLOCK`] bytes (the
    /// csv writer this replaces buffered as much): no allocation per row, bounded memory.
    buf: Vec<u8>,
    /// The `run` label, formatted once: it is the same on every row.
    run: Option<Vec<u8>>,
    shift_columns: bool,
    tool_mm: f64,
    columns: usize,
    rows: u64,
}

/// One cell: `NaN` for a NaN fault, else the shortest text that parses back to the same value
/// (`retrocomp_model::decimal::push_shortest`, byte for byte `format!("{v}")`). Numbers never need quoting.
fn num(buf: &mut Vec<u8>, v: f64) {
    if v.is_nan() {
        buf.extend_from_slice(b"NaN");
    } else {
        retrocomp_model::decimal::push_shortest(buf, v);
    }
}

impl<W: Write> Recorder<W> {
    const BLOCK: usize = 8 << 10;

    /// Writes the header for `world`'s channel layout.
    pub fn new(mut out: W, world: &World) -> anyhow::Result<Self> {
        let cfg = world.config();
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
        // The header goes through the csv crate (channel names may need quoting).
        let mut head = csv::Writer::from_writer(Vec::new());
        head.write_record(&h)?;
        out.write_all(
            &head
                .into_inner()
                .map_err(|e| anyhow::anyhow!("{}", e.error()))?,
        )?;
        // An integer label: never quoted.
        let run = cfg.record.run.map(|r| r.to_string().into_bytes());
        Ok(Self {
            out,
            buf: Vec::with_capacity(Self::BLOCK + 1024),
            run,
            shift_columns: cfg.record.shift_columns,
            tool_mm: cfg.program.tool_mm,
            columns: h.len(),
            rows: 0,
        })
    }

    pub fn write(&mut self, r: &Readings) -> anyhow::Result<()> {
        let row_start = self.buf.len();
        let buf = &mut self.buf;
        let mut n = 0usize;
        // Separator before every cell but the first.
        let mut sep = |buf: &mut Vec<u8>| {
            if n > 0 {
                buf.push(b',');
            }
            n += 1;
        };
        sep(buf);
        retrocomp_model::decimal::push_fixed6(buf, r.t_s);
        let plain = r
            .nominal_mm
            .iter()
            .chain(&r.error_um)
            .chain(&r.sim_error_um);
        for v in plain {
            sep(buf);
            num(buf, *v);
        }
        // A dropped-out sensor is an empty cell.
        let temps = r.temps.iter().map(|c| c.value);
        let rest = r.force.iter().chain(&r.strains).map(|c| c.value);
        let opt = temps
            .chain([Some(r.rpm)])
            .chain(rest)
            .chain([Some(self.tool_mm)]);
        for v in opt {
            sep(buf);
            if let Some(v) = v {
                num(buf, v);
            }
        }
        if let Some(run) = &self.run {
            sep(buf);
            buf.extend_from_slice(run);
        }
        if self.shift_columns {
            for v in &r.correction_um {
                sep(buf);
                num(buf, *v);
            }
        }
        if n != self.columns {
            self.buf.truncate(row_start);
            anyhow::bail!("recording: channel layout changed mid-run");
        }
        self.buf.push(b'\n');
        self.rows += 1;
        if self.buf.len() >= Self::BLOCK {
            self.out.write_all(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }

    pub fn rows(&self) -> u64 {
        self.rows
    }

    pub fn finish(mut self) -> anyhow::Result<W> {
        self.out.write_all(&self.buf)?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// The slide settled at the end of a dwell: the commanded (set-point) end point and the true
/// tool-tip error there, at the last step wholly inside the dwell. A part's error at that point
/// is `(pos_mm − the program's nominal)·1000 + error_um` (the set-point is the nominal unless the
/// program itself was compensated, as a DNC stream or a rewritten file is).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DwellEnd {
    pub t_s: f64,
    /// Program line of the dwell (DNC: the number of the line received).
    pub line: usize,
    pub pos_mm: [f64; 3],
    pub error_um: [f64; 3],
}

impl DwellEnd {
    pub const CSV_HEADER: &'static str = "t_s,line,x_mm,y_mm,z_mm,ex_um,ey_um,ez_um\n";

    pub fn csv_row(&self) -> String {
        let ([x, y, z], [ex, ey, ez]) = (self.pos_mm, self.error_um);
        format!("{:.6},{},{x},{y},{z},{ex},{ey},{ez}\n", self.t_s, self.line)
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
