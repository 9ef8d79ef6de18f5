//! `retrocomp nc IN.nc (--model MACHINE.toml | --plane-model PLANE.toml) [--diameter-x] [--split-mm S]
//! [--max-pieces N] [--start X,Y,Z] [--work-offset G55=X,Y,Z …] [--semicolon-comment]
//! [--out OUT.nc] [--points POINTS.csv] [--json] [--svg OUT]`
//!
//! The program is read and written line by line (memory does not grow with its length); with
//! `--out` the file is written under a temporary name and renamed only when the whole rewrite
//! succeeded, so a refused program never leaves a half-written output. `--points` writes every
//! motion point (nominal machine position, approach directions) in `retrocomp eval --path` form.
//!
//! `--model` takes the machine model (docs/model.md; evaluated exactly, temperatures and loads at
//! their references). `--plane-model` takes a two-axis Z–X table model (tables are CSV files, paths
//! relative to the TOML file):
//! ```toml
//! terms = "geometric"        # or "positional"
//! szx_urad = -382.35         # squareness Szx, µrad
//! [dzz]                      # δzz(z); likewise [dxz], [dxx], [dzx]
//! file = "table_6_1.csv"
//! position = "target_z_mm"
//! forward = "dzz_f_mm"
//! reverse = "dzz_r_mm"
//! to_um = 1000.0             # table printed in mm
//! ```

use std::io::{BufReader, BufWriter, Write};
use std::path::PathBuf;

use anyhow::Context;
use retrocomp_analysis::nc::ErrorFunction;
use retrocomp_analysis::nc::ModelErrors;
use retrocomp_analysis::nc::rewrite::{
    POINTS_HEADER, Point, RewriteConfig, RewriteSink, RewriteStats, rewrite_stream,
};
use retrocomp_analysis::plane_model::load_plane_model;
use retrocomp_analysis::report::{Series, xy_svg};
use retrocomp_analysis::table::Direction;
use retrocomp_model::MachineModel;

use super::util::write;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The NC program to rewrite (G-code, ISO/Fanuc or LinuxCNC dialect).
    pub program: PathBuf,
    /// Machine model TOML (the error function to compensate).
    #[arg(
        long,
        required_unless_present = "plane_model",
        conflicts_with = "plane_model"
    )]
    pub model: Option<PathBuf>,
    /// Two-axis Z–X table model (see docs/toolkit.md).
    #[arg(long)]
    pub plane_model: Option<PathBuf>,
    /// Use the model's first-order closed form instead of the exact 4×4 evaluation.
    #[arg(long)]
    pub first_order: bool,
    /// X words are diameters (lathe, cylindrical grinder).
    #[arg(long)]
    pub diameter_x: bool,
    /// Split G1/G2/G3 moves into pieces of at most this length, mm.
    #[arg(long)]
    pub split_mm: Option<f64>,
    /// Refuse a move that would be split into more pieces than this.
    #[arg(long, default_value_t = 100_000)]
    pub max_pieces: usize,
    /// Machine position at program start, in the program's coordinates (X a diameter with
    /// --diameter-x): "X,Y,Z" in mm. Without it, split moves and arcs before every axis has been
    /// programmed are refused.
    #[arg(long, value_parser = parse_xyz)]
    pub start: Option<[f64; 3]>,
    /// A work offset the controller holds, "G55=X,Y,Z" in mm (X radial); repeatable. G54 not
    /// given is taken as zero.
    #[arg(long, value_parser = parse_work_offset)]
    pub work_offset: Vec<(usize, [f64; 3])>,
    /// Write every motion point (nominal, directions) as CSV for `retrocomp eval --path`.
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// Refuse corrections larger than this, µm.
    #[arg(long, default_value_t = 500.0)]
    pub max_correction_um: f64,
    /// `;` starts a comment (LinuxCNC) instead of ending a block (Fanuc/ISO).
    #[arg(long)]
    pub semicolon_comment: bool,
    /// Write the rewritten program here (written whole or not at all; default: stdout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print a JSON summary (counts, largest correction; the program too without --out).
    #[arg(long)]
    pub json: bool,
    /// Write the nominal position of every motion point as an SVG chart.
    #[arg(long)]
    pub svg: Option<PathBuf>,
}

fn parse_xyz(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>().map_err(|e| format!("`{t}`: {e}")))
        .collect::<Result<_, _>>()?;
    match <[f64; 3]>::try_from(v) {
        Ok(a) if a.iter().all(|x| x.is_finite()) => Ok(a),
        _ => Err(format!(
            "expected X,Y,Z (three finite numbers in mm), found `{s}`"
        )),
    }
}

fn parse_work_offset(s: &str) -> Result<(usize, [f64; 3]), String> {
    const NAMES: [&str; 9] = [
        "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
    ];
    let (name, xyz) = s
        .split_once('=')
        .ok_or_else(|| format!("expected G5x=X,Y,Z, found `{s}`"))?;
    let i = NAMES
        .iter()
        .position(|n| n.eq_ignore_ascii_case(name.trim()))
        .ok_or_else(|| format!("`{name}`: expected one of {}", NAMES.join(", ")))?;
    Ok((i, parse_xyz(xyz)?))
}

/// Output lines to a writer, points to an optional CSV, and (for --svg) a bounded sample of
/// the corrections.
struct CliSink<'a> {
    out: &'a mut dyn Write,
    points: Option<BufWriter<std::fs::File>>,
    svg: Option<SvgPoints>,
    n: usize,
}

/// (motion point #, nominal X, nominal Z) kept for the SVG plot.
type SvgPoints = Vec<(f64, f64, f64)>;

/// Points kept for the SVG plot (a plot of more is unreadable anyway).
const SVG_MAX_POINTS: usize = 20_000;

impl RewriteSink for CliSink<'_> {
    fn line(&mut self, text: &str) -> std::io::Result<()> {
        writeln!(self.out, "{text}")
    }
    fn point(&mut self, p: &Point) -> std::io::Result<()> {
        if let Some(w) = &mut self.points {
            let d = p.dirs.map(|d| if d == Direction::Forward { 1 } else { -1 });
            writeln!(
                w,
                "{},{},{:.9},{:.9},{:.9},{},{},{},{}",
                p.line,
                p.move_index,
                p.nominal_mm[0],
                p.nominal_mm[1],
                p.nominal_mm[2],
                d[0],
                d[1],
                d[2],
                u8::from(p.compensated)
            )?;
        }
        if let Some(v) = &mut self.svg
            && v.len() < SVG_MAX_POINTS
        {
            v.push((self.n as f64, p.nominal_mm[0], p.nominal_mm[2]));
        }
        self.n += 1;
        Ok(())
    }
}

fn rewrite_to(
    a: &Args,
    model: &dyn ErrorFunction,
    cfg: &RewriteConfig,
    out: &mut dyn Write,
) -> anyhow::Result<(RewriteStats, Option<SvgPoints>)> {
    let file = std::fs::File::open(&a.program)
        .with_context(|| format!("cannot read {}", a.program.display()))?;
    let points = match &a.points {
        Some(p) => {
            let mut w = BufWriter::new(
                std::fs::File::create(p)
                    .with_context(|| format!("cannot write {}", p.display()))?,
            );
            writeln!(w, "{POINTS_HEADER}")?;
            Some(w)
        }
        None => None,
    };
    let mut sink = CliSink {
        out,
        points,
        svg: a.svg.as_ref().map(|_| Vec::new()),
        n: 0,
    };
    let stats = rewrite_stream(
        &a.program.display().to_string(),
        BufReader::new(file),
        !a.semicolon_comment,
        model,
        cfg,
        &mut sink,
    )
    .with_context(|| format!("{}", a.program.display()))?;
    if let Some(w) = &mut sink.points {
        w.flush()?;
    }
    Ok((stats, sink.svg))
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    if let Some(s) = a.split_mm
        && !(s.is_finite() && s > 0.0)
    {
        anyhow::bail!("--split-mm: expected a length > 0 mm, found {s}");
    }
    let mut work_offsets_mm = [None; 9];
    for (i, o) in &a.work_offset {
        work_offsets_mm[*i] = Some(*o);
    }
    let cfg = RewriteConfig {
        diameter_x: a.diameter_x,
        split_step_mm: a.split_mm,
        max_pieces_per_move: a.max_pieces,
        max_correction_um: a.max_correction_um,
        start_mm: a.start,
        work_offsets_mm,
    };
    let machine;
    let model: Box<dyn ErrorFunction + '_> = match (&a.model, &a.plane_model) {
        (Some(m), _) => {
            machine = MachineModel::from_toml_path(m)?;
            Box::new(ModelErrors::new(&machine, !a.first_order))
        }
        (None, Some(p)) => Box::new(load_plane_model(p)?),
        (None, None) => anyhow::bail!("give --model or --plane-model"),
    };
    // Output: the --out file (under a temporary name until the rewrite succeeded), a buffer for
    // --json without --out, or stdout.
    let mut buffer = Vec::new();
    let (stats, svg) = match &a.out {
        Some(p) => {
            let tmp = p.with_extension("retrocomp-tmp");
            let mut w = BufWriter::new(
                std::fs::File::create(&tmp)
                    .with_context(|| format!("cannot write {}", tmp.display()))?,
            );
            let r = rewrite_to(a, model.as_ref(), &cfg, &mut w)
                .and_then(|r| w.flush().map(|_| r).map_err(Into::into));
            drop(w);
            match r {
                Ok(r) => {
                    std::fs::rename(&tmp, p)
                        .with_context(|| format!("cannot write {}", p.display()))?;
                    r
                }
                Err(e) => {
                    let _ = std::fs::remove_file(&tmp);
                    return Err(e);
                }
            }
        }
        None if a.json => rewrite_to(a, model.as_ref(), &cfg, &mut buffer)?,
        None => {
            let stdout = std::io::stdout();
            let mut lock = stdout.lock();
            let r = rewrite_to(a, model.as_ref(), &cfg, &mut lock)?;
            lock.flush()?;
            r
        }
    };
    if a.json {
        let mut v =
            serde_json::json!({ "program": a.program.display().to_string(), "stats": stats });
        if a.out.is_none() {
            v["output"] = String::from_utf8(buffer)?.into();
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if a.out.is_some() {
        println!(
            "{} blocks in, {} moves compensated, {} points written, {} moves outside the model kept as programmed, {} moves before every axis was known kept as programmed, {} arc centres moved onto the bisector of the compensated ends (max {:.2} µm), max |correction| {:.2} µm",
            stats.blocks_in,
            stats.moves_compensated,
            stats.points_emitted,
            stats.moves_outside_domain,
            stats.moves_unknown_start,
            stats.arc_centres_moved,
            stats.max_centre_shift_um,
            stats.max_abs_correction_um
        );
    }
    if let (Some(p), Some(pts)) = (&a.svg, svg) {
        let series = [
            Series::markers("X nominal", pts.iter().map(|q| (q.0, q.1)).collect()),
            Series::markers("Z nominal", pts.iter().map(|q| (q.0, q.2)).collect()),
        ];
        write(
            p,
            &xy_svg(
                "rewritten program: nominal position per motion point",
                "motion point #",
                "mm",
                &series,
            )?,
        )?;
    }
    Ok(())
}
