//! `retrocomp identify` end to end with the real binaries: `hil-sim artefacts` probes plates and
//! spheres on its hidden machine (deploy/examples/old-mill-3axis.toml), `retrocomp identify` fits
//! them, and the written model is loaded by `check-config` and evaluated by `eval`. Checks the
//! report's content (verification rows, unidentifiable ECZ with its remedy, JSON fields, SVGs).

use crate::hil_sim;
use crate::pixels;

use crate::identify_support as cli;

use std::path::{Path, PathBuf};
use std::process::Command;

use cli::{check_config, csvs, ok, retrocomp};

#[test]
fn identify_from_hil_sim_artefacts_writes_a_loadable_model() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let truth = root.join("deploy/examples/old-mill-3axis.toml");
    let sim = hil_sim::hil_sim_next_to_retrocomp();
    let art = dir.path().join("art");
    let o = Command::new(&sim)
        .args(["artefacts", "--seed", "3", "--truth"])
        .arg(&truth)
        .arg("--out")
        .arg(&art)
        .output()
        .unwrap();
    ok(&o, "hil-sim artefacts");
    let plates = csvs(&art.join("plates"));
    let verify = csvs(&art.join("verify"));
    assert_eq!(
        (plates.len(), verify.len()),
        (6, 5),
        "Spaan's six measurements"
    );
    assert_eq!(csvs(&art.join("ballbar")).len(), 8);
    // Deterministic per seed: a second run writes the same bytes.
    let again = dir.path().join("again");
    ok(
        &Command::new(&sim)
            .args(["artefacts", "--seed", "3", "--truth"])
            .arg(&truth)
            .arg("--out")
            .arg(&again)
            .output()
            .unwrap(),
        "hil-sim artefacts (again)",
    );
    assert_eq!(
        std::fs::read(&plates[0]).unwrap(),
        std::fs::read(again.join("plates").join(plates[0].file_name().unwrap())).unwrap()
    );

    let model = dir.path().join("identified.toml");
    let svg = dir.path().join("svg");
    let mut cmd = retrocomp();
    cmd.args(["identify", "--chain", "X F Y Z", "--hole-plate"])
        .args(&plates)
        .arg("--verify")
        .args(&verify)
        .arg("--out")
        .arg(&model)
        .arg("--svg")
        .arg(&svg)
        .arg("--html")
        .arg(dir.path().join("identify.html"));
    let text = ok(&cmd.output().unwrap(), "retrocomp identify");
    assert!(text.contains("verification"), "{text}");
    assert!(
        text.contains("candidate knots every 50 mm, at most 6 per axis"),
        "hole plates keep Spaan's knots by default:\n{text}"
    );
    assert!(
        text.lines()
            .any(|l| l.starts_with("ECZ") && l.contains("NO") && l.contains("second tool vector")),
        "ECZ must be named as unidentifiable with its remedy:\n{text}"
    );
    assert!(
        text.lines().any(
            |l| l.starts_with("resolution: shortest wavelength identified: X ")
                && l.contains("retrocomp fit")
        ),
        "the resolution and its remedy must be stated:\n{text}"
    );
    assert_eq!(
        std::fs::read_dir(&svg).unwrap().count(),
        10,
        "2 directions × 5 plates"
    );
    // Each plot: deviation against machine position (mm, not the probing index), and the legend
    // box holds no data point: read back from the SVG and on its rendering (figure_support).
    let mut svgs: Vec<PathBuf> = std::fs::read_dir(&svg)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    svgs.sort();
    for p in &svgs {
        let s = std::fs::read_to_string(p).unwrap();
        assert!(
            s.contains("machine position") && s.contains("/ mm"),
            "{}",
            p.display()
        );
        let g = retrocomp_analysis::chart_geometry::parse(&s);
        assert_eq!(g.legend_boxes.len(), 1, "{}", p.display());
        pixels::assert_legend_clear_in_pixels(p, &p.display().to_string());
    }
    let html = std::fs::read_to_string(dir.path().join("identify.html")).unwrap();
    assert_eq!(
        html.matches("<svg").count(),
        10,
        "one figure per plate and direction"
    );
    assert!(html.contains("SHA-256") && html.contains("Verification on held-out plates"));

    check_config(&model);
    let path = dir.path().join("path.csv");
    std::fs::write(
        &path,
        "x_mm,y_mm,z_mm,tool_mm\n300,200,150,120\n500,300,250,120\n",
    )
    .unwrap();
    let ev = ok(
        &retrocomp()
            .args(["eval", "--model"])
            .arg(&model)
            .arg("--path")
            .arg(&path)
            .output()
            .unwrap(),
        "eval on the identified model",
    );
    assert!(ev.lines().count() >= 3 && ev.contains("ex_um"), "{ev}");

    // The command line for ball bars, no knot flags: the defaults for spheres only
    // (30 mm, at most 16 per axis) must give the ball-bar result (≥ 80 % on every
    // verification plate and direction).
    let mut cmd = retrocomp();
    cmd.args(["identify", "--chain", "X F Y Z", "--json", "--ballbar"])
        .args(csvs(&art.join("ballbar")))
        .arg("--verify")
        .args(&verify)
        .arg("--out")
        .arg(dir.path().join("bb.toml"));
    let j: serde_json::Value =
        serde_json::from_str(&ok(&cmd.output().unwrap(), "identify --json")).unwrap();
    assert_eq!(
        (
            j["candidate_knots"]["step_mm"].as_f64(),
            j["candidate_knots"]["max_per_axis"].as_u64()
        ),
        (Some(30.0), Some(16)),
        "spheres only: 30 mm knots, at most 16 per axis"
    );
    for v in j["verification"].as_array().unwrap() {
        let e = v["efficiency"].as_f64().unwrap();
        assert!(
            e >= 0.80,
            "ball bars with the default knots: {} {} at {e:.3}",
            v["plate"],
            v["direction"]
        );
    }
    let comps = j["components"].as_array().unwrap();
    assert_eq!(comps.len(), 18);
    // "Identified" (to 2 µm/µrad) means identifiable with an uncertainty within 2; each one
    // that is not carries its remedy.
    for c in comps {
        let u = c["uncertainty"].as_f64().unwrap();
        let identified = c["identified"].as_bool().unwrap();
        assert_eq!(
            identified,
            c["identifiable"].as_bool().unwrap() && u <= 2.0,
            "{c}"
        );
        assert_eq!(identified, c["needs"].is_null(), "{c}");
    }
    assert_eq!(j["verification"].as_array().unwrap().len(), 10);
    assert_eq!(j["setups"].as_array().unwrap().len(), 8);
    assert!(j["sigma_um"].as_f64().unwrap() > 0.0);
    let axes = j["resolution"]["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 3);
    assert!(
        axes.iter()
            .all(|a| a["shortest_wavelength_mm"].as_f64().unwrap() > 0.0),
        "{axes:?}"
    );
}

#[test]
fn identify_refuses_a_missing_side_file_and_bad_rows() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("P1.csv");
    std::fs::write(&p, "hole,u_mm,v_mm,x_mm,y_mm,z_mm\na,0,0,1,2,zz\n").unwrap();
    let out = retrocomp()
        .args(["identify", "--chain", "X F Y Z", "--hole-plate"])
        .arg(&p)
        .arg("--out")
        .arg(dir.path().join("m.toml"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("side file of") && e.contains("P1.csv"), "{e}");
    std::fs::write(
        dir.path().join("P1.toml"),
        "kind = \"hole_plate\"\nplane = \"xy\"\nalpha_ppm_per_K = 11.5\ncertificate_uncertainty_um = 0.1\n",
    )
    .unwrap();
    let out = retrocomp()
        .args(["identify", "--chain", "X F Y Z", "--hole-plate"])
        .arg(&p)
        .arg("--out")
        .arg(dir.path().join("m.toml"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && e.contains("P1.csv:2: column `z_mm`: `zz`"),
        "{e}"
    );
}
