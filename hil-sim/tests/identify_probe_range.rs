//! Issue 37 point 5 — does `identify` extrapolate the Abbe arm? Six identification measurements
//! with 100 and 250 mm probes (one placement per plane, both probes), verification plates at six
//! places each probed with 30, 50, 100, 175, 250 and 350 mm probes, on the old mill
//! (`deploy/examples/old-mill-3axis.toml`, 0.5 µm probing noise). Per plate and direction the
//! identified model's efficiency δ is compared with the TRUE model's on the same readings.
//!
//! Deterministic (seeded hil-sim metrology); no timing. `--nocapture` prints the table that
//! docs/identify-results.md quotes.

use hil_sim::artefacts::{Metrology, PlatePlacement, measure_plate};
use retrocomp::analysis::identify::contracts::{HolePlate, Plane};
use retrocomp::analysis::identify::design::Geometry;
use retrocomp::analysis::identify::report::{DirVerify, to_spec, verify};
use retrocomp::analysis::identify::{Identification, Options, identify};
use retrocomp::models::MachineModel;

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

/// Six verification places (Spaan's five and the XZ plate at y = 330 mm), every probe.
fn verification() -> Vec<PlatePlacement> {
    let places: [(&str, Plane, [f64; 3], [usize; 2], [f64; 2]); 6] = [
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

/// One row per verification plate and direction: (identified, truth).
fn rows(
    model: &MachineModel,
    truth: &MachineModel,
    ver: &[HolePlate],
) -> Vec<(DirVerify, DirVerify)> {
    let got = ver.iter().flat_map(|p| verify(model, p));
    let want = ver.iter().flat_map(|p| verify(truth, p));
    got.zip(want).collect()
}

/// Prints the markdown table; returns the largest shortfall (truth δ − identified δ).
fn table(label: &str, rows: &[(DirVerify, DirVerify)]) -> f64 {
    eprintln!(
        "\n{label}\n| plate | probe / mm | dir | meas / µm | δ identified | δ true model | shortfall |"
    );
    eprintln!("|---|---|---|---|---|---|---|");
    let mut worst = f64::NEG_INFINITY;
    for (g, t) in rows {
        let (plate, probe) = g.plate.rsplit_once("_t").unwrap();
        let short = t.efficiency - g.efficiency;
        worst = worst.max(short);
        eprintln!(
            "| {plate} | {probe} | {} | {:.1} | {:.3} | {:.3} | {:.3} |",
            g.direction, g.meas_um, g.efficiency, t.efficiency, short
        );
    }
    eprintln!("largest shortfall {worst:.3}");
    worst
}

#[test]
fn six_plates_with_100_and_250_mm_probes_against_probes_of_30_to_350_mm() {
    let truth = truth();
    let ver = measure(&truth, &verification());
    let (_id6, m6) = identified(&measure(&truth, &identification(None)));
    let worst6 = table(
        "six measurements (probes 100 / 250 mm)",
        &rows(&m6, &truth, &ver),
    );
    let (_, m7) = identified(&measure(&truth, &identification(Some(400.0))));
    let worst7 = table(
        "seven measurements (+ XZ at y = 400 mm, 250 mm probe)",
        &rows(&m7, &truth, &ver),
    );
    assert!(worst6.is_finite() && worst7.is_finite());
}
