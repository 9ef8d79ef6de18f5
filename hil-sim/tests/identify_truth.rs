//! Issue 15, point 4 — the artefact identification proven against hil-sim's hidden machine, Spaan's
//! way: identify from six hole plates (or eight ball-bar spheres), verify on five other plates at
//! other places and probe lengths, and compare with what the TRUE model reaches on the same plates.
//! Also: every identifiable component against the truth, and two crippled models (no rotation /
//! Abbe terms; probe length ignored) that must miss the targets.
//!
//! The plan (`hil_sim::artefacts::spaan_plates`): six placements, two per plane, each probed with
//! two probes (50 and 300 mm); verification plates with 25 and 400 mm probes.
//!
//! Deterministic (seeded hil-sim metrology); no timing. Run with `--nocapture` for the tables.

use hil_sim::artefacts::{Measured, Metrology, measure_all};
use retrocomp::analysis::identify::design::Geometry;
use retrocomp::analysis::identify::report::{DirVerify, components, to_spec, verify};
use retrocomp::analysis::identify::{Identification, Options, identify};
use retrocomp::models::{ErrorFunction, MachineModel};

fn load(name: &str) -> MachineModel {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples")
        .join(name);
    MachineModel::from_toml_path(&p).unwrap()
}

/// The truth model without its thermal and load terms: hil-sim's artefacts are probed at the
/// reference state, and the truth's static geometry is what is compared.
fn measure(truth: &MachineModel, seed: u64) -> Measured {
    measure_all(truth, &Metrology::default(), seed)
}

fn run(meas: &Measured, plates: bool, opts: &Options) -> (Identification, MachineModel) {
    let geo = Geometry::from_chain("X F Y Z").unwrap();
    let (p, b) = if plates {
        (&meas.plates[..], &[][..])
    } else {
        (&[][..], &meas.spheres[..])
    };
    let id = identify(&geo, p, b, opts).unwrap();
    let text = MachineModel::from_spec(to_spec(&id, "identified")).to_toml_string();
    let model = MachineModel::from_toml_str(&text, "identified").expect("written model loads");
    (id, model)
}

fn verify_all(model: &MachineModel, meas: &Measured) -> Vec<DirVerify> {
    meas.verify.iter().flat_map(|p| verify(model, p)).collect()
}

/// Prints Spaan's table and returns (min efficiency, max shortfall against truth).
fn table(label: &str, got: &[DirVerify], truth: &[DirVerify]) -> (f64, f64) {
    eprintln!("{label}: plate dir | meas µm | res/σ/eff identified | res/σ/eff true model");
    let mut min_eff: f64 = 1.0;
    let mut worst: f64 = f64::NEG_INFINITY;
    for (g, t) in got.iter().zip(truth) {
        eprintln!(
            "  {:<11} {} | {:5.1} | {:4.1}/{:3.1}/{:5.1} % | {:4.1}/{:3.1}/{:5.1} %",
            g.plate,
            g.direction,
            g.meas_um,
            g.res_um,
            g.sigma_um,
            100.0 * g.efficiency,
            t.res_um,
            t.sigma_um,
            100.0 * t.efficiency
        );
        min_eff = min_eff.min(g.efficiency);
        worst = worst.max(t.efficiency - g.efficiency);
    }
    (min_eff, worst)
}

/// Largest difference (µm / µrad) between identified and true component over the identified
/// range, modulo what artefacts cannot see: a constant (all), and a line for straightness.
fn component_errors(
    id: &Identification,
    model: &MachineModel,
    truth: &MachineModel,
) -> Vec<(String, f64, bool)> {
    let (rep, _) = components(id);
    let mut out = Vec::new();
    for r in rep {
        let eval = |m: &MachineModel, q: f64| -> f64 {
            m.spec()
                .components
                .iter()
                .find(|c| c.id.iso_name() == r.name)
                .map_or(0.0, |c| c.function.eval(q, 0).0)
        };
        let qs: Vec<f64> = (0..=60)
            .map(|k| r.range_mm.0 + (r.range_mm.1 - r.range_mm.0) * f64::from(k) / 60.0)
            .collect();
        let d: Vec<f64> = qs
            .iter()
            .map(|&q| eval(model, q) - eval(truth, q))
            .collect();
        let n = d.len() as f64;
        let mq = qs.iter().sum::<f64>() / n;
        let md = d.iter().sum::<f64>() / n;
        let slope = if r.shape == retrocomp::analysis::identify::design::Shape::Straightness {
            qs.iter()
                .zip(&d)
                .map(|(q, d)| (q - mq) * (d - md))
                .sum::<f64>()
                / qs.iter().map(|q| (q - mq).powi(2)).sum::<f64>()
        } else {
            0.0
        };
        let err = qs
            .iter()
            .zip(&d)
            .map(|(q, d)| (d - md - slope * (q - mq)).abs())
            .fold(0.0, f64::max);
        out.push((r.name, err, r.identifiable));
    }
    out
}

struct Outcome {
    min_eff: f64,
    /// Largest (true model's efficiency − identified model's) over plates and directions.
    shortfall: f64,
    errs: Vec<(String, f64, bool)>,
}

fn check_machine(name: &str, plates: bool, seed: u64, opts: &Options) -> Outcome {
    let truth = load(name);
    let meas = measure(&truth, seed);
    let (id, model) = run(&meas, plates, opts);
    // A model that ignores the probe length ignores it when compensating too.
    let got = if opts.use_tool_length {
        verify_all(&model, &meas)
    } else {
        let mut m = Measured {
            plates: vec![],
            verify: meas.verify.clone(),
            spheres: vec![],
        };
        for p in &mut m.verify {
            for h in &mut p.probes {
                h.tool_mm = 0.0;
            }
        }
        verify_all(&model, &m)
    };
    let want = verify_all(&truth, &meas);
    let label = format!(
        "{name} from {} (seed {seed}, rotations {}, probe length {})",
        if plates {
            "12 hole-plate measurements"
        } else {
            "8 ball-bar spheres"
        },
        opts.rotations,
        opts.use_tool_length
    );
    let (min_eff, shortfall) = table(&label, &got, &want);
    let errs = component_errors(&id, &model, &truth);
    let line: Vec<String> = errs
        .iter()
        .map(|(n, e, ok)| format!("{n} {e:.2}{}", if *ok { "" } else { " (n.i.)" }))
        .collect();
    eprintln!("  component error (µm | µrad): {}", line.join(", "));
    eprintln!(
        "  σ = {:.2} µm, rank {} of {}, outliers dropped {}; min efficiency {:.3}, shortfall {:.3}",
        id.solve.sigma_um,
        id.solve.rank,
        id.solve.coef.len(),
        id.outliers.len(),
        min_eff,
        shortfall
    );
    Outcome {
        min_eff,
        shortfall,
        errs,
    }
}

#[test]
fn hole_plates_on_the_old_machine() {
    let o = check_machine("old-mill-3axis.toml", true, 7, &Options::default());
    assert!(
        o.shortfall <= 0.03,
        "efficiency {:.3} below the true model's",
        o.shortfall
    );
    assert!(o.min_eff >= 0.90, "min efficiency {:.3} < 0.90", o.min_eff);
    // Every identifiable component within 2 µm / 2 µrad of the truth (measured ≤ 0.6; the Z roll
    // EAZ 0.5 µrad, 3.6 before every placement was probed with both probes).
    for (n, e, ok) in &o.errs {
        if *ok {
            assert!(*e <= 2.0, "{n} off the truth by {e:.2} (limit 2)");
        }
    }
    // ECY and ECZ have no Abbe arm with the tool along Z: named, not guessed. Everything else —
    // including table roll EAX, Y pitch EBY and Z pitch EBZ, which one probe per placement left to
    // a combination the plates could not see — is identified.
    let unseen: Vec<&str> = o
        .errs
        .iter()
        .filter(|(_, _, ok)| !ok)
        .map(|(n, _, _)| n.as_str())
        .collect();
    assert_eq!(unseen, ["ECY", "ECZ"], "components reported unidentifiable");
}

#[test]
fn ball_bars_on_the_old_machine() {
    let o = check_machine("old-mill-3axis.toml", false, 7, &Options::default());
    assert!(o.min_eff >= 0.80, "min efficiency {:.3} < 0.80", o.min_eff);
}

#[test]
fn hole_plates_on_the_small_error_vmc_match_the_true_model_across_x() {
    // vmc-3axis' EXX carries a ±1 µm ripple of ≈ 16 mm period (its 100-point table alternates);
    // 40–60 mm hole pitches alias it, so no smooth model from plates follows it in X while the
    // true model does: X directions are reported, Y and Z must match the truth within 0.03.
    let truth = load("vmc-3axis.toml");
    let meas = measure(&truth, 11);
    let (_, model) = run(&meas, true, &Options::default());
    let got = verify_all(&model, &meas);
    let want = verify_all(&truth, &meas);
    table(
        "vmc-3axis.toml from 12 hole-plate measurements",
        &got,
        &want,
    );
    for (g, t) in got.iter().zip(&want) {
        if g.direction != 'x' {
            assert!(
                t.efficiency - g.efficiency <= 0.03,
                "{} {}: {:.3} vs true {:.3}",
                g.plate,
                g.direction,
                g.efficiency,
                t.efficiency
            );
        }
    }
}

/// The issue: "a model without the rotation (Abbe) terms, or one that ignores the probe length,
/// must fail these targets". On three seeds the full model meets both targets (≥ 90 %, within
/// 0.03 of the true model) and each crippled model misses the 0.03 (measured on seeds 1–12: full
/// 0.003–0.007, without rotations 0.051–0.069, probe length ignored 0.042–0.055).
#[test]
fn without_abbe_terms_or_probe_length_the_models_fail_the_targets() {
    let no_rot = Options {
        rotations: false,
        ..Options::default()
    };
    let no_tool = Options {
        use_tool_length: false,
        ..Options::default()
    };
    for seed in [7, 8, 9] {
        let full = check_machine("old-mill-3axis.toml", true, seed, &Options::default());
        assert!(
            full.shortfall <= 0.03 && full.min_eff >= 0.90,
            "seed {seed}: the full model must meet the targets: shortfall {:.3}, min {:.3}",
            full.shortfall,
            full.min_eff
        );
        for (what, opts) in [
            ("without rotations", &no_rot),
            ("ignoring the probe length", &no_tool),
        ] {
            let o = check_machine("old-mill-3axis.toml", true, seed, opts);
            assert!(
                o.shortfall > 0.03,
                "seed {seed}: a model {what} must miss the target: shortfall {:.3} (full {:.3})",
                o.shortfall,
                full.shortfall
            );
        }
    }
}

/// Spaan's direct method on the same machine: each component read every 10 mm over the travel
/// (laser 0.3 µm, levels 0.5 µrad noise), fitted with the toolkit's stepwise piecewise quadratics,
/// squareness from a square (±2 µrad); verified on the same five plates.
#[test]
fn direct_method_on_the_old_machine() {
    use retrocomp::analysis::fit::piecewise::fit_stepwise;
    use retrocomp::models::spec::ComponentSpec;
    let truth = load("old-mill-3axis.toml");
    let meas = measure(&truth, 7);
    let mut noise = hil_sim::rng::Noise::new(7, "direct");
    let mut spec = truth.spec().clone();
    spec.components = truth
        .spec()
        .components
        .iter()
        .map(|c| {
            let hi = if c.id.axis == retrocomp::models::Axis::X {
                800.0
            } else {
                500.0
            };
            let xs: Vec<f64> = (0..=(hi as usize / 10)).map(|k| k as f64 * 10.0).collect();
            let sd = if c.id.is_rotation() { 0.5 } else { 0.3 };
            let ys: Vec<f64> = xs
                .iter()
                .map(|&q| c.function.eval(q, 0).0 + noise.gauss(sd))
                .collect();
            let cands: Vec<f64> = (1..(hi as usize / 50)).map(|k| k as f64 * 50.0).collect();
            let p = fit_stepwise(&xs, &ys, &cands, 1e-4).unwrap();
            let cc = p.centre_mm;
            let [b0, b1, b2] = p.poly;
            ComponentSpec {
                id: c.id,
                function: ErrorFunction::PiecewiseQuadratic {
                    base: [b0 - b1 * cc + b2 * cc * cc, b1 - 2.0 * b2 * cc, b2],
                    knots_mm: p.knots_mm.clone(),
                    knot_coefficients: p.gammas.clone(),
                    range_mm: Some((0.0, hi)),
                },
            }
        })
        .collect();
    for s in &mut spec.squareness {
        s.value_urad += noise.gauss(2.0);
    }
    let model = MachineModel::from_spec(spec);
    let got = verify_all(&model, &meas);
    let want = verify_all(&truth, &meas);
    let (min_eff, _) = table("old-mill-3axis.toml, direct method", &got, &want);
    // Measured 66–84 % (Spaan's direct column: 43–96 %): the ±2 µrad squareness and the angular
    // noise times the probe arms dominate. It must still halve the error on every plate.
    assert!(min_eff >= 0.5, "direct method min efficiency {min_eff:.3}");
}
