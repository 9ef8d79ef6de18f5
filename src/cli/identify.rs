//! `retrocomp identify --chain "X F Y Z" --hole-plate P1.csv … [--ballbar S1.csv …]
//! [--verify V1.csv …] --out MODEL.toml [--json] [--svg DIR]`: artefact measurements in (each CSV
//! with its side file `<stem>.toml`, docs/identify.md), the identified machine model out, with a
//! report of per-component significance and identifiability, set-up parameters, outliers and, per
//! verification plate and direction, residual, σ and efficiency δ (Spaan Tables 3.2–3.4).

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::report_args::ReportArgs;
use super::util::{read, write};
use retrocomp_analysis::fit::lead::check_lead;
use retrocomp_analysis::html::{Block, Section};
use retrocomp_analysis::identify::Geometry;
use retrocomp_analysis::identify::contracts::{BallBar, HolePlate, read_ballbar, read_hole_plate};
use retrocomp_analysis::identify::report::{DirVerify, components, lead_waves, to_spec, verify};
use retrocomp_analysis::identify::vouch::vouch;
use retrocomp_analysis::identify::{Identification, Options, identify};
use retrocomp_analysis::report::{Series, xy_svg_notes};
use retrocomp_model::MachineModel;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Kinematic chain, workpiece → tool, F = frame (e.g. "X F Y Z").
    #[arg(long)]
    pub chain: String,
    /// Hole-plate placements (CSV; side file STEM.toml).
    #[arg(long, num_args = 1..)]
    pub hole_plate: Vec<PathBuf>,
    /// Static ball-bar set-ups (CSV; side file STEM.toml).
    #[arg(long, num_args = 1..)]
    pub ballbar: Vec<PathBuf>,
    /// Held-out hole plates for residual, σ and efficiency δ.
    #[arg(long, num_args = 1..)]
    pub verify: Vec<PathBuf>,
    /// Where to write the model TOML.
    #[arg(long)]
    pub out: PathBuf,
    /// Print one JSON object (components, residuals, δ) instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Folder for SVG plots: measured vs residual per hole of each verification plate.
    #[arg(long)]
    pub svg: Option<PathBuf>,
    /// Spacing of candidate knots, mm [default: 50 with any hole plate (Spaan); 30 with ball-bar
    /// spheres only, which sample positions continuously (docs/identify.md)].
    #[arg(long)]
    pub knot_step_mm: Option<f64>,
    /// At most this many candidate knots per axis [default: 6 with any hole plate; 16 with
    /// ball-bar spheres only].
    #[arg(long)]
    pub max_knots: Option<usize>,
    /// Significance level of a knot (Spaan 99.99 % → 1e-4).
    #[arg(long, default_value_t = 1e-4)]
    pub alpha: f64,
    /// Lead of the ball screws, mm: fit a sin/cos pair at this period on EXX, EYY and EZZ, report
    /// its amplitude and phase, and write those components as tables every lead/16. Needs plates
    /// whose hole pitch is not a whole number of leads (e.g. 62.25 mm for 5 mm: docs/identify.md,
    /// "Lead wave").
    #[arg(long)]
    pub lead_mm: Option<f64>,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// The CSV's text and its side file's (same stem, `.toml`).
fn texts(csv: &Path) -> anyhow::Result<(String, String)> {
    let side = csv.with_extension("toml");
    let side_text = read(&side)
        .with_context(|| format!("side file of {} (same stem, .toml)", csv.display()))?;
    Ok((read(csv)?, side_text))
}

fn read_plate(p: &Path) -> anyhow::Result<HolePlate> {
    let (csv, side) = texts(p)?;
    Ok(read_hole_plate(
        &p.with_extension("").display().to_string(),
        &csv,
        &side,
    )?)
}

fn read_bar(p: &Path) -> anyhow::Result<BallBar> {
    let (csv, side) = texts(p)?;
    Ok(read_ballbar(
        &p.with_extension("").display().to_string(),
        &csv,
        &side,
    )?)
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let geo = Geometry::from_chain(&args.chain)?;
    let plates: Vec<HolePlate> = args
        .hole_plate
        .iter()
        .map(|p| read_plate(p))
        .collect::<Result<_, _>>()?;
    let bars: Vec<BallBar> = args
        .ballbar
        .iter()
        .map(|p| read_bar(p))
        .collect::<Result<_, _>>()?;
    let held: Vec<HolePlate> = args
        .verify
        .iter()
        .map(|p| read_plate(p))
        .collect::<Result<_, _>>()?;
    if plates.is_empty() && bars.is_empty() {
        anyhow::bail!("give at least one --hole-plate or --ballbar");
    }
    // Knot defaults depend on the artefacts; an explicit flag wins.
    let base = Options::for_artefacts(plates.len(), bars.len());
    let opts = Options {
        knot_step_mm: args.knot_step_mm.unwrap_or(base.knot_step_mm),
        max_knots: args.max_knots.unwrap_or(base.max_knots),
        alpha: args.alpha,
        lead_mm: args
            .lead_mm
            .map(check_lead)
            .transpose()
            .map_err(anyhow::Error::msg)?,
        ..base
    };
    if !(opts.knot_step_mm.is_finite() && opts.knot_step_mm > 0.0) {
        anyhow::bail!(
            "--knot-step-mm {}: expected a positive spacing in mm",
            opts.knot_step_mm
        );
    }
    let progress = super::term::Progress::spinner("identify: fitting the 21 components");
    let id = identify(&geo, &plates, &bars, &opts)?;
    progress.finish();
    let name = args
        .out
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("identified");
    let text = MachineModel::from_spec(to_spec(&id, name)).to_toml_string();
    let model = MachineModel::from_toml_str(&text, "identified model")
        .map_err(|e| anyhow::anyhow!("the identified model does not validate: {e}"))?;
    write(&args.out, &text)?;
    let ver: Vec<DirVerify> = held.iter().flat_map(|p| verify(&model, p)).collect();
    if let Some(dir) = &args.svg {
        plots(dir, &ver)?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json(&id, &opts, &ver, &args.out))?
        );
    } else {
        print!("{}", text_report(&id, &opts, &ver, &args.out));
    }
    let mut inputs: Vec<PathBuf> = vec![];
    for p in args
        .hole_plate
        .iter()
        .chain(&args.ballbar)
        .chain(&args.verify)
    {
        inputs.push(p.clone());
        inputs.push(p.with_extension("toml"));
    }
    let inputs: Vec<&Path> = inputs.iter().map(|p| p.as_path()).collect();
    args.report
        .write("Machine identification from artefacts", &inputs, || {
            html_sections(&id, &opts, &ver, &args.out)
        })
}

/// The report: the identification's text report, the verification table and one figure per
/// verification plate and direction.
fn html_sections(
    id: &Identification,
    opts: &Options,
    ver: &[DirVerify],
    out: &Path,
) -> anyhow::Result<Vec<Section>> {
    let rows = ver
        .iter()
        .map(|v| {
            vec![
                v.plate.clone(),
                v.direction.to_string(),
                format!("{:.1}", v.meas_um),
                format!("{:.1}", v.res_um),
                format!("{:.2}", v.sigma_um),
                format!("{:.1}", 100.0 * v.efficiency),
            ]
        })
        .collect();
    let figures = ver
        .iter()
        .map(|v| {
            Ok(Block::Figure {
                svg: plate_svg(v)?,
                caption: format!(
                    "{} {}: measured deviation Δm and residual after the model, per probing",
                    v.plate, v.direction
                ),
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(vec![
        Section {
            heading: "Identification".into(),
            blocks: vec![Block::Pre(text_report(id, opts, ver, out))],
        },
        Section {
            heading: "Verification on held-out plates".into(),
            blocks: vec![Block::Table {
                head: ["plate", "dir", "meas / µm", "res / µm", "σ / µm", "δ / %"]
                    .map(String::from)
                    .to_vec(),
                rows,
            }],
        },
        Section {
            heading: "Figures".into(),
            blocks: figures,
        },
        Section {
            heading: "What was assumed".into(),
            blocks: vec![Block::List(vec![
                format!(
                    "kinematic chain as given; candidate knots every {} mm, at most {} per axis, significance {}",
                    opts.knot_step_mm, opts.max_knots, opts.alpha
                ),
                "each plate's rigid pose is fitted out; deviations are actual − nominal, µm".into(),
                match opts.lead_mm {
                    Some(l) => format!(
                        "a ball-screw lead wave of {l} mm on EXX, EYY, EZZ (A·sin(2πq/L + φ)), written as tables every {} mm or less",
                        l / retrocomp_analysis::fit::lead::TABLE_STEPS_PER_LEAD
                    ),
                    None => "no lead wave fitted (--lead-mm)".into(),
                },
                "efficiency δ as Spaan (2010) Tables 3.2–3.4".into(),
            ])],
        },
    ])
}

fn json(id: &Identification, opts: &Options, ver: &[DirVerify], out: &Path) -> serde_json::Value {
    let (comp, sq) = components(id);
    serde_json::json!({
        "model": out.display().to_string(),
        "observations": id.obs.len(),
        "parameters": id.solve.coef.len(),
        "rank": id.solve.rank,
        "sigma_um": id.solve.sigma_um,
        "range_mm": id.range_mm,
        "candidate_knots": { "step_mm": opts.knot_step_mm, "max_per_axis": opts.max_knots },
        "resolution": id.resolution,
        "vouch": vouch(id, &sq),
        "components": comp,
        "lead_waves": lead_waves(id),
        "squareness": sq,
        "setups": id.setups.iter().map(|s| serde_json::json!({
            "name": s.name, "kind": s.kind,
            "parameters": s.names.iter().enumerate().map(|(k, n)| serde_json::json!({
                "name": n, "value": id.solve.coef[id.solve.coef.len() - total_setup(id) + s.first + k],
                "se": id.solve.se[id.solve.coef.len() - total_setup(id) + s.first + k],
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "outliers": id.outliers,
        "verification": ver,
    })
}

fn total_setup(id: &Identification) -> usize {
    id.setups.iter().map(|s| s.names.len()).sum()
}

fn text_report(id: &Identification, opts: &Options, ver: &[DirVerify], out: &Path) -> String {
    use std::fmt::Write as _;
    let (comp, sq) = components(id);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "identify: {} set-ups, {} observations, {} parameters (rank {}), σ = {:.2} µm → {}",
        id.setups.len(),
        id.obs.len(),
        id.solve.coef.len(),
        id.solve.rank,
        id.solve.sigma_um,
        out.display()
    );
    let _ = writeln!(
        s,
        "candidate knots every {} mm, at most {} per axis",
        opts.knot_step_mm, opts.max_knots
    );
    let _ = writeln!(
        s,
        "component  range_mm        knots  F        p         max     ±se    identified (to 2 µm/µrad, 3 σ)"
    );
    for c in &comp {
        let _ = writeln!(
            s,
            "{:<9}  {:>6.0}…{:<6.0}  {:>5}  {:>8}  {:>8}  {:>6.2}  {:>5.2}  {}",
            c.name,
            c.range_mm.0,
            c.range_mm.1,
            c.knots_mm.len(),
            c.f.map_or("-".into(), |f| format!("{f:.1}")),
            c.p_value.map_or("-".into(), |p| format!("{p:.1e}")),
            c.max_abs,
            c.max_se,
            if c.identified {
                "yes".to_string()
            } else if c.identifiable {
                format!("NO — {}", c.needs.clone().unwrap_or_default())
            } else {
                format!("NO — needs {}", c.needs.clone().unwrap_or_default())
            }
        );
    }
    for q in &sq {
        let _ = writeln!(
            s,
            "{:<9}  {:+.2} ± {:.2} µrad{}",
            q.name,
            q.value_urad,
            q.se_urad,
            if q.identified {
                ""
            } else if q.identifiable {
                "  (not identified to 2 µrad)"
            } else {
                "  (not identifiable)"
            }
        );
    }
    for w in lead_waves(id) {
        let _ = writeln!(
            s,
            "lead wave: {}{}",
            w.wave.describe(),
            if w.identified {
                ""
            } else {
                "  NOT identified: the plates see it only loosely (a hole pitch that is a whole \
                 number of leads puts every hole of a plate at one phase)"
            }
        );
    }
    let _ = writeln!(s, "resolution: {}", id.resolution.note);
    let v = vouch(id, &sq);
    let _ = writeln!(s, "{}", v.statement);
    for w in &v.widen {
        let _ = writeln!(s, "widen: {w}");
    }
    for (a, h, r) in &id.outliers {
        let _ = writeln!(
            s,
            "outlier: {a} hole {h} repeat {r} (disagrees with its duplicate)"
        );
    }
    if !ver.is_empty() {
        let _ = writeln!(s, "verification   dir  meas_um  res_um  σ_um  efficiency");
        for v in ver {
            let _ = writeln!(
                s,
                "{:<14} {}    {:>6.1}  {:>6.1}  {:>4.1}  {:>6.1} %",
                v.plate,
                v.direction,
                v.meas_um,
                v.res_um,
                v.sigma_um,
                100.0 * v.efficiency
            );
        }
    }
    s
}

/// One verification plate's direction: measured and residual deviation against machine position.
fn plate_svg(v: &DirVerify) -> anyhow::Result<String> {
    let at = |f: fn(&(String, f64, f64)) -> f64| -> Vec<(f64, f64)> {
        v.pos_mm
            .iter()
            .zip(&v.holes)
            .map(|(x, h)| (*x, f(h)))
            .collect()
    };
    let notes = vec![
        format!("largest |Δm| = {:.2} µm", v.meas_um),
        format!("largest |Δm − Δs| = {:.2} µm", v.res_um),
        format!("σ of the residual = {:.2} µm", v.sigma_um),
        format!("efficiency δ = {:.1} %", 100.0 * v.efficiency),
        "rigid pose of the plate fitted out".to_string(),
    ];
    Ok(xy_svg_notes(
        &format!(
            "{} {}: efficiency {:.1} %",
            v.plate,
            v.direction,
            100.0 * v.efficiency
        ),
        &format!("machine position {} / mm", v.direction),
        &format!("deviation e{} / µm", v.direction),
        &[
            Series::markers("measured Δm", at(|h| h.1)),
            Series::markers("residual Δm − Δs (after the model)", at(|h| h.2)),
        ],
        &notes,
    )?)
}

fn plots(dir: &Path, ver: &[DirVerify]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for v in ver {
        let svg = plate_svg(v)?;
        let stem = Path::new(&v.plate)
            .file_name()
            .and_then(|s| s.to_str())
            .unwrap_or("plate")
            .to_string();
        write(&dir.join(format!("{stem}_{}.svg", v.direction)), &svg)?;
    }
    Ok(())
}
