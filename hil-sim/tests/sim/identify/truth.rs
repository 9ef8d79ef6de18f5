//! Issue 15, point 4 — the artefact identification proven against hil-sim's hidden machine, Spaan's
//! way: identify from six hole plates (or eight ball-bar spheres), verify on five other plates at
//! other places and probe lengths, and compare with what the TRUE model reaches on the same plates.
//! Also: every identifiable component against the truth, and two crippled models (no rotation /
//! Abbe terms; probe length ignored) that must miss the targets.
//!
//! The plans (`hil_sim::artefacts::spaan_plates_for`): the default SIX measurements (one placement
//! per plane, each probed with a 50 and a 300 mm probe: Spaan's "three locations, two probe
//! configurations", two plates per plane); SEVEN (plus a second XZ placement) and TWELVE (two
//! placements per plane, both probes) for what six cannot see. Verification plates: Spaan's five
//! (25 and 400 mm probes), plus, for the unseen combination, two XZ plates at the ends of Y.
//!
//! Deterministic (seeded hil-sim metrology); no timing. Run with `--nocapture` for the tables.

use hil_sim::artefacts::{
    Measured, Metrology, Plan, SpherePlan, measure_plan, measure_plate, measure_spheres, resampled,
    xz_edge_plates,
};
use retrocomp_analysis::identify::Geometry;
use retrocomp_analysis::identify::report::{DirVerify, components, to_spec, verify};
use retrocomp_analysis::identify::{Identification, Options, identify};
use retrocomp_model::{ErrorFunction, MachineModel};

fn load(name: &str) -> MachineModel {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples")
        .join(name);
    MachineModel::from_toml_path(&p).unwrap()
}

/// The truth model without its thermal and load terms: hil-sim's artefacts are probed at the
/// reference state, and the truth's static geometry is what is compared.
fn measure(truth: &MachineModel, seed: u64, plan: Plan) -> Measured {
    measure_plan(truth, &Metrology::default(), seed, plan)
}

/// The two XZ plates at the ends of the Y travel, probed on `truth`.
fn edge_plates(truth: &MachineModel, seed: u64) -> Measured {
    Measured {
        plates: vec![],
        verify: xz_edge_plates()
            .iter()
            .map(|p| measure_plate(truth, p, &Metrology::default(), seed))
            .collect(),
        spheres: vec![],
    }
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
) -> Vec<CompErr> {
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
        let slope = if r.shape == retrocomp_analysis::identify::Shape::Straightness {
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
        out.push(CompErr {
            name: r.name,
            err,
            identifiable: r.identifiable,
            identified: r.identified,
            uncertainty: r.uncertainty,
        });
    }
    out
}

/// One component against the truth, with `identify`'s verdict.
struct CompErr {
    name: String,
    /// Largest deviation from the truth over the range (µm / µrad), as in [`component_errors`].
    err: f64,
    identifiable: bool,
    identified: bool,
    /// `identify`'s expanded uncertainty (3 σ).
    uncertainty: f64,
}

struct Outcome {
    min_eff: f64,
    /// Largest (true model's efficiency − identified model's) over Spaan's five verification
    /// plates and directions.
    shortfall: f64,
    /// The same on the two XZ plates at the ends of the Y travel.
    edge_shortfall: f64,
    errs: Vec<CompErr>,
    /// Squareness angles reported not identifiable.
    unseen_squareness: Vec<&'static str>,
}

impl Outcome {
    fn unseen(&self) -> Vec<&str> {
        self.errs
            .iter()
            .filter(|c| !c.identifiable)
            .map(|c| c.name.as_str())
            .collect()
    }

    /// Every identifiable component within 2 µm / 2 µrad of the truth (issue 15, point 4).
    fn assert_components_within_2(&self, what: &str) {
        for c in &self.errs {
            if c.identifiable {
                assert!(
                    c.err <= 2.0,
                    "{what}: {} off the truth by {:.2} (limit 2)",
                    c.name,
                    c.err
                );
            }
        }
    }

    /// Every component `identify` calls identified (to 2 µm / µrad) is within 2 of the truth.
    fn assert_identified_within_2(&self, what: &str) {
        for c in &self.errs {
            if c.identified {
                assert!(
                    c.err <= 2.0,
                    "{what}: {} called identified (±{:.2}) but off the truth by {:.2}",
                    c.name,
                    c.uncertainty,
                    c.err
                );
            }
        }
    }
}

/// Verification of the identified model against the true model's on `meas.verify`; a model that
/// ignores the probe length ignores it when compensating too.
fn compare(
    label: &str,
    model: &MachineModel,
    truth: &MachineModel,
    meas: &Measured,
    opts: &Options,
) -> (f64, f64) {
    let got = if opts.use_tool_length {
        verify_all(model, meas)
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
        verify_all(model, &m)
    };
    let want = verify_all(truth, meas);
    table(label, &got, &want)
}

fn check_machine(name: &str, plates: bool, seed: u64, opts: &Options, plan: Plan) -> Outcome {
    check_with(name, plates, seed, opts, plan, SpherePlan::Eight)
}

fn check_with(
    name: &str,
    plates: bool,
    seed: u64,
    opts: &Options,
    plan: Plan,
    spheres: SpherePlan,
) -> Outcome {
    let truth = load(name);
    let mut meas = measure(&truth, seed, plan);
    meas.spheres = measure_spheres(&truth, &Metrology::default(), seed, spheres);
    let (id, model) = run(&meas, plates, opts);
    let label = format!(
        "{name} from {} (seed {seed}, rotations {}, probe length {})",
        if plates {
            format!("{} hole-plate measurements", meas.plates.len())
        } else {
            format!("{} ball-bar spheres", meas.spheres.len())
        },
        opts.rotations,
        opts.use_tool_length
    );
    let (min_eff, shortfall) = compare(&label, &model, &truth, &meas, opts);
    let (_, edge_shortfall) = compare(
        "  + XZ plates at the ends of Y",
        &model,
        &truth,
        &edge_plates(&truth, seed),
        opts,
    );
    let errs = component_errors(&id, &model, &truth);
    let line: Vec<String> = errs
        .iter()
        .map(|c| {
            let tag = if !c.identifiable {
                " (n.i.)"
            } else if !c.identified {
                " (loose)"
            } else {
                ""
            };
            format!("{} {:.2} ±{:.2}{tag}", c.name, c.err, c.uncertainty)
        })
        .collect();
    eprintln!("  component error (µm | µrad): {}", line.join(", "));
    eprintln!(
        "  resolution: {} (lack of fit {:.2})",
        id.resolution.note,
        id.resolution.lack_of_fit_ratio.unwrap_or(f64::NAN)
    );
    let (_, sq) = components(&id);
    let unseen_squareness: Vec<&'static str> = sq
        .iter()
        .filter(|s| !s.identifiable)
        .map(|s| s.name)
        .collect();
    eprintln!(
        "  σ = {:.2} µm, rank {} of {}, outliers dropped {}; min efficiency {:.3}, shortfall {:.3} \
         (ends of Y {:.3}); squareness not identifiable {:?}",
        id.solve.sigma_um,
        id.solve.rank,
        id.solve.coef.len(),
        id.outliers.len(),
        min_eff,
        shortfall,
        edge_shortfall,
        unseen_squareness
    );
    Outcome {
        min_eff,
        shortfall,
        edge_shortfall,
        errs,
        unseen_squareness,
    }
}

/// The default plan, Spaan's six measurements: the targets hold on Spaan's five verification
/// plates, every identifiable component is within 2 of the truth, and the report names what six
/// cannot see — ECY/ECZ (no Abbe arm with the tool along Z) and the combination of EAX, EBY and
/// squareness EB0Z that is rigid on both XZ measurements (one placement, two probes). XZ plates
/// at the ends of the Y travel see that combination: there six fall behind the truth.
#[test]
fn six_hole_plates_on_the_old_machine() {
    let o = check_machine(
        "old-mill-3axis.toml",
        true,
        7,
        &Options::default(),
        Plan::Six,
    );
    assert!(
        o.shortfall <= 0.03,
        "efficiency {:.3} below the true model's",
        o.shortfall
    );
    assert!(o.min_eff >= 0.90, "min efficiency {:.3} < 0.90", o.min_eff);
    o.assert_components_within_2("six");
    o.assert_identified_within_2("six");
    assert_eq!(
        o.unseen(),
        ["EAX", "EBY", "ECY", "ECZ"],
        "six: unidentifiable"
    );
    assert_eq!(o.unseen_squareness, ["EB0Z"], "six: squareness");
    // Measured 0.08–0.09 on seeds 7–9: what a seventh measurement buys (next test).
    assert!(
        o.edge_shortfall > 0.03,
        "six measurements cannot see the EAX/EBY/EB0Z combination, yet the XZ plates at the \
         ends of Y are within {:.3} of the truth",
        o.edge_shortfall
    );
}

/// Seven measurements (the six plus a second XZ placement at the back of Y) and the twelve of
/// two placements per plane: every component but ECY/ECZ identified within 2 µm / 2 µrad, and the
/// targets hold on the XZ plates at the ends of Y too.
#[test]
fn seven_or_twelve_hole_plates_identify_everything_but_the_z_rotations() {
    for plan in [Plan::Seven, Plan::Twelve] {
        let o = check_machine("old-mill-3axis.toml", true, 7, &Options::default(), plan);
        let what = format!("{plan:?}");
        assert!(
            o.shortfall <= 0.03 && o.edge_shortfall <= 0.03,
            "{what}: efficiency {:.3} / {:.3} (ends of Y) below the true model's",
            o.shortfall,
            o.edge_shortfall
        );
        assert!(o.min_eff >= 0.90, "{what}: min efficiency {:.3}", o.min_eff);
        o.assert_components_within_2(&what);
        o.assert_identified_within_2(&what);
        assert_eq!(o.unseen(), ["ECY", "ECZ"], "{what}: unidentifiable");
        assert!(o.unseen_squareness.is_empty(), "{what}");
    }
}

/// Spaan's eight spheres (Table 3.1 scaled; 10° rings of 36 points down to 20° below the equator,
/// ~2700 points), identified with knots every 30 mm: on seeds 7–9 every one of Spaan's verification
/// plates and directions within 0.03 of the true model (0.014 / 0.016 / 0.013 measured) and
/// ≥ 80 %. Both halves matter: the rings below the equator read Z at the bottom of the Z travel
/// at 20° rather than grazing (to the equator only: 0.032–0.047), the 30 mm knots follow the
/// 200–300 mm pitch wave of X (the default 50 mm, at most 6: 0.038–0.052).
#[test]
fn eight_ball_bar_spheres_match_the_true_model() {
    // The defaults for spheres only (30 mm, at most 16 per axis), as `retrocomp identify` uses.
    let opts = Options::for_artefacts(0, 8);
    for seed in [7, 8, 9] {
        let o = check_machine("old-mill-3axis.toml", false, seed, &opts, Plan::Six);
        assert!(
            o.shortfall <= 0.03 && o.min_eff >= 0.80,
            "seed {seed}: eight spheres {:.3} behind the true model, min efficiency {:.3}",
            o.shortfall,
            o.min_eff
        );
        o.assert_identified_within_2(&format!("eight spheres, seed {seed}"));
        if seed == 7 {
            // EAX / EBX are 77 / 30 µrad off the truth here, moved by combinations the spheres
            // barely see (standard errors 10 / 4 µrad): identifiable by the null-space test,
            // but not identified to 2 µrad, and `identify` must say so.
            for name in ["EAX", "EBX"] {
                let c = o.errs.iter().find(|c| c.name == name).unwrap();
                assert!(
                    !c.identified,
                    "seed 7: {name} off the truth by {:.1} but called identified (±{:.1})",
                    c.err, c.uncertainty
                );
            }
        }
    }
}

/// The other way to reach the bottom of Z (before the eight spheres' rings went below the
/// equator): ten spheres (two more centred below the Z travel) on a 7.5° × 48 grid to the equator,
/// with candidate knots every 30 mm (at most 16 per axis), reach every one of Spaan's plates
/// within 0.03 of the true model on seeds 7–9 (0.011 / 0.021 / 0.013 measured).
#[test]
fn ten_dense_ball_bar_spheres_match_the_true_model() {
    // The defaults for spheres only (30 mm, at most 16 per axis), as `retrocomp identify` uses.
    let opts = Options::for_artefacts(0, 10);
    for seed in [7, 8, 9] {
        let o = check_with(
            "old-mill-3axis.toml",
            false,
            seed,
            &opts,
            Plan::Six,
            SpherePlan::Ten,
        );
        assert!(
            o.shortfall <= 0.03 && o.min_eff >= 0.80,
            "seed {seed}: ten spheres {:.3} behind the true model, min efficiency {:.3}",
            o.shortfall,
            o.min_eff
        );
    }
}

/// Low-pass of values sampled every `step_mm`: a Gaussian whose response is 1/2 at
/// `wavelength_mm` (σ = λ·√(ln 2 / 2) / π ≈ 0.19 λ), weights renormalised at the ends. Shorter
/// waves are removed (a 21 mm wave through a 120 mm cut keeps e⁻²² of its amplitude), longer ones
/// kept (240 mm: 84 %).
fn low_pass(values: &[f64], step_mm: f64, wavelength_mm: f64) -> Vec<f64> {
    let sigma = wavelength_mm * (std::f64::consts::LN_2 / 2.0).sqrt() / std::f64::consts::PI;
    let half = (3.0 * sigma / step_mm).ceil() as isize;
    let w: Vec<f64> = (-half..=half)
        .map(|k| (-0.5 * (k as f64 * step_mm / sigma).powi(2)).exp())
        .collect();
    let n = values.len() as isize;
    (0..n)
        .map(|i| {
            let (mut s, mut ws) = (0.0, 0.0);
            for (k, wk) in (-half..=half).zip(&w) {
                let j = i + k;
                if (0..n).contains(&j) {
                    s += wk * values[j as usize];
                    ws += wk;
                }
            }
            s / ws
        })
        .collect()
}

/// vmc-3axis' EXX table (100 points, 8.08 mm apart) samples a ±1.2 µm sine of 13/21 mm period:
/// linearly interpolated it is a zigzag at 8 mm scale that the true model follows and no hole
/// plate (pitch ≥ 30 mm) can — Spaan: "the sampling density is limited to the grid size of the
/// plate". A limit of the method, stated by `identify` (its resolution per axis, its lack of fit
/// and the remedy), not hidden. Worse than missing it, the plates alias it: at each hole row they
/// read the zigzag's value there, precisely (80 probings per row), and the fit follows those
/// values. So the identified model is judged against the truth as the identification plates
/// sampled it (`hil_sim::artefacts::resampled`: each component linearly interpolated between its
/// values at the probed positions): within 0.03 on every plate and direction. Separately: X
/// trails the unfiltered truth by more than 0.03, and the identified EXX differs from the true
/// EXX mostly at wavelengths below the reported resolution.
#[test]
fn hole_plates_on_the_small_error_vmc_match_the_truth_as_the_plates_sample_it() {
    let truth = load("vmc-3axis.toml");
    for plan in [Plan::Six, Plan::Seven] {
        let meas = measure(&truth, 11, plan);
        let (id, model) = run(&meas, true, &Options::default());
        let lambda: [f64; 3] =
            std::array::from_fn(|k| id.resolution.axes[k].shortest_wavelength_mm);
        let positions: [Vec<f64>; 3] =
            std::array::from_fn(|k| id.obs.iter().map(|o| o.pos_mm[k]).collect());
        let sampled = resampled(&truth, &positions);
        let got = verify_all(&model, &meas);
        let want = verify_all(&truth, &meas);
        let want_s = verify_all(&sampled, &meas);
        let n = meas.plates.len();
        let (_, gap) = table(
            &format!("vmc-3axis.toml from {n} hole-plate measurements vs the truth"),
            &got,
            &want,
        );
        let (_, gap_s) = table(
            "  vs the truth as the identification plates sample it",
            &got,
            &want_s,
        );
        eprintln!(
            "  shortfall vs truth {gap:.3}, vs sampled truth {gap_s:.3}; lack of fit {:.2}; {}",
            id.resolution.lack_of_fit_ratio.unwrap_or(f64::NAN),
            id.resolution.note
        );
        for (g, b) in got.iter().zip(&want_s) {
            assert!(
                b.efficiency - g.efficiency <= 0.03,
                "{n} measurements, {} {}: {:.3} vs sampled truth {:.3}",
                g.plate,
                g.direction,
                g.efficiency,
                b.efficiency
            );
        }
        // The limit shows: X falls behind the unfiltered truth (0.09–0.24 measured).
        assert!(
            gap > 0.03,
            "{n}: X within {gap:.3} of the unfiltered truth?"
        );
        // Where the identified EXX differs from the truth: mostly below the resolution.
        let (lo, hi) = id.range_mm[0];
        let q: Vec<f64> = (0..=(hi - lo) as usize).map(|i| lo + i as f64).collect();
        let exx = |m: &MachineModel, x: f64| {
            m.spec()
                .components
                .iter()
                .find(|c| c.id.iso_name() == "EXX")
                .map_or(0.0, |c| c.function.eval(x, 0).0)
        };
        let d: Vec<f64> = q.iter().map(|&x| exx(&model, x) - exx(&truth, x)).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let d: Vec<f64> = d.iter().map(|v| v - mean).collect();
        let low = low_pass(&d, 1.0, lambda[0]);
        let e_all: f64 = d.iter().map(|v| v * v).sum();
        let e_high: f64 = d.iter().zip(&low).map(|(v, l)| (v - l).powi(2)).sum();
        eprintln!(
            "  EXX identified − truth: rms {:.2} µm, {:.0} % of its energy below λ = {:.0} mm",
            (e_all / d.len() as f64).sqrt(),
            100.0 * e_high / e_all,
            lambda[0]
        );
        assert!(
            e_high >= 0.5 * e_all,
            "{n}: only {:.0} % of EXX's error below the resolution",
            100.0 * e_high / e_all
        );
        // The residual hardly shows it (lack of fit 1.1 × the repeatability, measured): the fit
        // follows the aliased values at the hole rows. So the report must state the resolution
        // and the remedy whatever the residual says.
        assert!(
            id.resolution.note.contains("X 155 mm") && id.resolution.note.contains("retrocomp fit"),
            "{n}: the report must state the resolution and name the remedy: {}",
            id.resolution.note
        );
    }
}

/// The issue: "a model without the rotation (Abbe) terms, or one that ignores the probe length,
/// must fail these targets". On three seeds the full model from the default six measurements
/// meets both targets (≥ 90 %, within 0.03 of the true model) and each crippled model misses the
/// 0.03.
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
        let full = check_machine(
            "old-mill-3axis.toml",
            true,
            seed,
            &Options::default(),
            Plan::Six,
        );
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
            let o = check_machine("old-mill-3axis.toml", true, seed, opts, Plan::Six);
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
    use retrocomp_analysis::fit::fit_stepwise;
    use retrocomp_model::ComponentSpec;
    let truth = load("old-mill-3axis.toml");
    let meas = measure(&truth, 7, Plan::Six);
    let mut noise = hil_sim::rng::Noise::new(7, "direct");
    let mut spec = truth.spec().clone();
    spec.components = truth
        .spec()
        .components
        .iter()
        .map(|c| {
            let hi = if c.id.axis == retrocomp_model::Axis::X {
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
