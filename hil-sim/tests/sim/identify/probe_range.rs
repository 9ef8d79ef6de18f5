//! Issue 37 point 5 — does `identify` extrapolate the Abbe arm? Six identification measurements
//! with 100 and 250 mm probes (one placement per plane, both probes), verification plates at six
//! places each probed with 30, 50, 100, 175, 250 and 350 mm probes, on the old mill
//! (`deploy/examples/old-mill-3axis.toml`, 0.5 µm probing noise). Per plate and direction the
//! identified model's efficiency δ is compared with the TRUE model's on the same readings.
//!
//! Deterministic (seeded hil-sim metrology); no timing. `--nocapture` prints the table that
//! docs/identify-results.md quotes.

use hil_sim::artefacts::{Metrology, PlatePlacement, measure_plate};
use retrocomp_analysis::identify::Geometry;
use retrocomp_analysis::identify::contracts::{HolePlate, Plane};
use retrocomp_analysis::identify::report::{DirVerify, components, to_spec, verify};
use retrocomp_analysis::identify::vouch::{Vouch, vouch};
use retrocomp_analysis::identify::{Identification, Options, identify};
use retrocomp_model::MachineModel;

const ID_PROBES_MM: [f64; 2] = [100.0, 250.0];
const VERIFY_PROBES_MM: [f64; 6] = [30.0, 50.0, 100.0, 175.0, 250.0, 350.0];
const SEED: u64 = 7;

fn truth() -> MachineModel {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples/old-mill-3axis.toml");
    MachineModel::from_toml_path(&p).unwrap()
}

fn place(
    name: &str,
    plane: Plane,
    o: [f64; 3],
    n: [usize; 2],
    pitch: [f64; 2],
    tool: f64,
) -> PlatePlacement {
    PlatePlacement {
        name: format!("{name}_t{tool:.0}"),
        placement: name.into(),
        plane,
        origin_mm: o,
        tool_mm: tool,
        n,
        pitch_mm: pitch,
    }
}

/// The six identification measurements: one placement per plane (as `Plan::Six`), both probes.
fn identification(extra_xz_y_mm: Option<f64>) -> Vec<PlatePlacement> {
    let mut out: Vec<PlatePlacement> = [
        ("id_xy", Plane::Xy, [130.0, 50.0, 150.0], [60.0, 40.0]),
        ("id_xz", Plane::Xz, [130.0, 225.0, 50.0], [60.0, 40.0]),
        ("id_yz", Plane::Yz, [375.0, 50.0, 50.0], [40.0, 40.0]),
    ]
    .iter()
    .flat_map(|&(n, pl, o, pitch)| ID_PROBES_MM.map(|t| place(n, pl, o, [10, 10], pitch, t)))
    .collect();
    if let Some(y) = extra_xz_y_mm {
        out.push(place(
            "id_xz_back",
            Plane::Xz,
            [130.0, y, 50.0],
            [10, 10],
            [60.0, 40.0],
            ID_PROBES_MM[1],
        ));
    }
    out
}

/// A place: name, plane, origin (mm), holes, pitch (mm).
type Place = (&'static str, Plane, [f64; 3], [usize; 2], [f64; 2]);

/// Six verification places (Spaan's five and the XZ plate at y = 330 mm), every probe.
fn verification() -> Vec<PlatePlacement> {
    let places: [Place; 6] = [
        (
            "v_xy",
            Plane::Xy,
            [220.0, 50.0, 150.0],
            [10, 10],
            [40.0, 40.0],
        ),
        (
            "v_xz_short",
            Plane::Xz,
            [300.0, 250.0, 120.0],
            [10, 10],
            [30.0, 30.0],
        ),
        (
            "v_xz_long",
            Plane::Xz,
            [150.0, 200.0, 50.0],
            [10, 10],
            [55.0, 40.0],
        ),
        (
            "v_xz_y330",
            Plane::Xz,
            [150.0, 330.0, 50.0],
            [10, 10],
            [55.0, 40.0],
        ),
        (
            "v_yz_left",
            Plane::Yz,
            [250.0, 50.0, 50.0],
            [10, 10],
            [40.0, 40.0],
        ),
        (
            "v_yz_right",
            Plane::Yz,
            [650.0, 50.0, 50.0],
            [10, 10],
            [40.0, 40.0],
        ),
    ];
    places
        .iter()
        .flat_map(|&(n, pl, o, holes, pitch)| {
            VERIFY_PROBES_MM.map(|t| place(n, pl, o, holes, pitch, t))
        })
        .collect()
}

fn measure(truth: &MachineModel, plates: &[PlatePlacement]) -> Vec<HolePlate> {
    plates
        .iter()
        .map(|p| measure_plate(truth, p, &Metrology::default(), SEED))
        .collect()
}

fn identified(plates: &[HolePlate]) -> (Identification, MachineModel) {
    let geo = Geometry::from_chain("X F Y Z").unwrap();
    let id = identify(&geo, plates, &[], &Options::default()).unwrap();
    let text = MachineModel::from_spec(to_spec(&id, "identified")).to_toml_string();
    (
        id,
        MachineModel::from_toml_str(&text, "identified").unwrap(),
    )
}

/// One row per verification plate and direction: (placement, identified, truth).
fn rows<'a>(
    model: &MachineModel,
    truth: &MachineModel,
    places: &'a [PlatePlacement],
    ver: &[HolePlate],
) -> Vec<(&'a PlatePlacement, DirVerify, DirVerify)> {
    places
        .iter()
        .zip(ver)
        .flat_map(|(pl, p)| {
            verify(model, p)
                .into_iter()
                .zip(verify(truth, p))
                .map(move |(g, t)| (pl, g, t))
        })
        .collect()
}

/// Does `v` vouch for a plate at `pl`: probe inside its range, and for a limited plane at a
/// measured position across it (±5 mm; the placement's offset is ±2 mm)?
fn vouched(v: &Vouch, pl: &PlatePlacement) -> bool {
    let (lo, hi) = v.probe_mm.unwrap();
    let [a, b] = pl.plane.axes();
    let c = 3 - a - b;
    let probe_ok = pl.tool_mm >= lo - 1e-9 && pl.tool_mm <= hi + 1e-9;
    let plane = pl.plane.as_str();
    let across_ok = v
        .limited_planes
        .iter()
        .filter(|l| l.plane == plane)
        .all(|l| l.at_mm.iter().any(|y| (y - pl.origin_mm[c]).abs() <= 5.0));
    probe_ok && across_ok
}

/// Prints the markdown table; returns the largest shortfall (truth δ − identified δ) on the
/// plates `v` vouches for and on all plates.
fn table(label: &str, v: &Vouch, rows: &[(&PlatePlacement, DirVerify, DirVerify)]) -> (f64, f64) {
    eprintln!("\n{label}\n{}", v.statement);
    eprintln!(
        "| plate | probe / mm | dir | meas / µm | δ identified | δ true model | shortfall | vouched |"
    );
    eprintln!("|---|---|---|---|---|---|---|---|");
    let (mut inside, mut all) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    for (pl, g, t) in rows {
        let short = t.efficiency - g.efficiency;
        let ok = vouched(v, pl);
        all = all.max(short);
        if ok {
            inside = inside.max(short);
        }
        eprintln!(
            "| {} | {:.0} | {} | {:.1} | {:.3} | {:.3} | {:.3} | {} |",
            pl.placement,
            pl.tool_mm,
            g.direction,
            g.meas_um,
            g.efficiency,
            t.efficiency,
            short,
            if ok { "yes" } else { "no" }
        );
    }
    eprintln!("largest shortfall: vouched plates {inside:.3}, all plates {all:.3}");
    (inside, all)
}

fn vouch_of(id: &Identification) -> Vouch {
    vouch(id, &components(id).1)
}

#[test]
fn six_plates_with_100_and_250_mm_probes_against_probes_of_30_to_350_mm() {
    let truth = truth();
    let places = verification();
    let ver = measure(&truth, &places);
    let (id6, m6) = identified(&measure(&truth, &identification(None)));
    let v6 = vouch_of(&id6);
    let (in6, all6) = table(
        "six measurements (probes 100 / 250 mm)",
        &v6,
        &rows(&m6, &truth, &places, &ver),
    );
    let (id7, m7) = identified(&measure(&truth, &identification(Some(400.0))));
    let v7 = vouch_of(&id7);
    let (in7, all7) = table(
        "seven measurements (+ XZ at y = 400 mm, 250 mm probe)",
        &v7,
        &rows(&m7, &truth, &places, &ver),
    );
    // identify names the probe range it vouches for, and the XZ position six measurements pin …
    assert_eq!(v6.probe_mm, Some((100.0, 250.0)));
    assert!(v6.statement.contains("100–250 mm"), "{}", v6.statement);
    let xz: Vec<_> = v6
        .limited_planes
        .iter()
        .map(|l| (l.plane.as_str(), l.at_mm.clone()))
        .collect();
    assert_eq!(xz, [("xz", vec![225.0])], "{}", v6.statement);
    assert!(
        v6.widen.iter().any(|w| w.contains("one more xz plate")),
        "{:?}",
        v6.widen
    );
    assert!(v7.limited_planes.is_empty(), "{}", v7.statement);
    // … within which the model is as good as the truth to 0.03 on every plate and direction.
    assert!(
        in6 <= 0.03,
        "six: vouched plates fall {in6:.3} behind the truth"
    );
    assert!(
        in7 <= 0.03,
        "seven: vouched plates fall {in7:.3} behind the truth"
    );
    // The Abbe arm itself extrapolates: with seven measurements every plate, probes 30–350 mm,
    // is within 0.03 of the truth (what six miss is the XZ plate away from y = 225 mm at every
    // probe length, the unseen EAX/EBY/EB0Z combination, not the probe).
    assert!(
        all7 <= 0.03,
        "seven: some plate falls {all7:.3} behind the truth"
    );
    eprintln!("all plates: six {all6:.3}, seven {all7:.3}");
}
