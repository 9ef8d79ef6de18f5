//! One report per job, printed as a customer gets it: `retrocomp iso230-2`, `circle`, `fit axis`
//! and `demo` write their figure SVGs and an HTML report; the SVGs are checked from their own geometry (no data
//! point in the legend box), the HTML is printed to A4 PDF by headless Chromium (the peer of
//! tests/real_peers/gateway_web_browser.rs), and poppler's pdfinfo/pdftoppm/pdftotext check the page count,
//! the page size and that the figures' numbers are in the PDF's text.
//! Peers: chromium and poppler-utils (scripts/setup-peers.sh).

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use retrocomp_analysis::chart_geometry;

use crate::hil_sim;
use crate::pixels;
use crate::runs;

fn retrocomp() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

fn ok(out: Output, what: &str) -> String {
    assert!(
        out.status.success(),
        "{what} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn tool(name: &str, env: &str, package: &str) -> PathBuf {
    let p = PathBuf::from(std::env::var(env).unwrap_or(format!("/usr/bin/{name}")));
    assert!(
        p.exists(),
        "{} missing: bash scripts/setup-peers.sh (apt package {package}) or set {env}",
        p.display()
    );
    p
}

/// Runs `cmd`, killing it if it hangs (a guard against a stuck browser, not a speed check).
fn run_guarded(mut cmd: Command, what: &str) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(300) {
            child.kill().unwrap();
            panic!("{what} did not finish in 300 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().unwrap()
}

/// Prints `html` to `pdf` with headless Chromium; returns (pages, pdfinfo text, pdftotext text).
fn print_pdf(html: &Path, pdf: &Path, tmp: &Path) -> (usize, String, String) {
    let chromium = tool("chromium", "RETROCOMP_CHROMIUM", "chromium");
    let profile = tmp.join("chromium-profile");
    let mut cmd = Command::new(chromium);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-pdf-header-footer",
    ])
    .arg(format!("--user-data-dir={}", profile.display()))
    .arg(format!("--print-to-pdf={}", pdf.display()))
    .arg(format!("file://{}", html.display()));
    let out = run_guarded(cmd, "chromium --print-to-pdf");
    assert!(
        pdf.exists(),
        "chromium wrote no PDF: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let pdfinfo = tool("pdfinfo", "RETROCOMP_PDFINFO", "poppler-utils");
    let info = ok(Command::new(pdfinfo).arg(pdf).output().unwrap(), "pdfinfo");
    let pages: usize = info
        .lines()
        .find_map(|l| l.strip_prefix("Pages:"))
        .unwrap_or_else(|| panic!("no page count in {info}"))
        .trim()
        .parse()
        .unwrap();
    // Every page renders (pdftoppm writes one PNG per page).
    let pdftoppm = tool("pdftoppm", "RETROCOMP_PDFTOPPM", "poppler-utils");
    let prefix = tmp.join("page");
    ok(
        Command::new(pdftoppm)
            .args(["-r", "40", "-png"])
            .arg(pdf)
            .arg(&prefix)
            .output()
            .unwrap(),
        "pdftoppm",
    );
    let pngs = std::fs::read_dir(tmp)
        .unwrap()
        .filter(|e| {
            let n = e.as_ref().unwrap().file_name();
            let n = n.to_string_lossy();
            n.starts_with("page") && n.ends_with(".png")
        })
        .count();
    assert_eq!(pngs, pages, "pdftoppm rendered every page");
    let pdftotext = tool("pdftotext", "RETROCOMP_PDFTOTEXT", "poppler-utils");
    let text = ok(
        Command::new(pdftotext).arg(pdf).arg("-").output().unwrap(),
        "pdftotext",
    );
    (pages, info, text)
}

/// The SVG's legend box holds no data point and lies right of every data point; rendered to PNG,
/// it holds no pixel of a series colour (figure_support/pixels.rs).
fn assert_legend_clear(path: &Path, what: &str) {
    pixels::assert_legend_clear_in_pixels(path, what);
    let g = chart_geometry::parse(&std::fs::read_to_string(path).unwrap());
    assert_eq!(g.legend_boxes.len(), 1, "{what}: one legend box");
    assert!(g.data_points.len() > 10, "{what}: data drawn");
    assert!(
        g.covered().is_empty(),
        "{what}: legend covers {:?}",
        g.covered()
    );
    let right = g.data_points.iter().map(|p| p.0).fold(f64::MIN, f64::max);
    assert!(
        right < g.legend_boxes[0][0],
        "{what}: legend outside the data"
    );
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/analysis")
        .join(name)
}

#[test]
fn iso230_2_report_of_asad_ullahs_x_axis_prints_to_a4_with_the_figures_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let csv = fixture("asadullah_x_iso230_2.csv");
    let (svg, html, pdf) = (
        dir.path().join("x.svg"),
        dir.path().join("x.html"),
        dir.path().join("x.pdf"),
    );
    let json: serde_json::Value = serde_json::from_str(&ok(
        retrocomp()
            .arg("iso230-2")
            .arg(&csv)
            .args(["--json", "--title", "Asad Ullah 2013 X axis", "--svg"])
            .arg(&svg)
            .arg("--html")
            .arg(&html)
            .args(["--machine", "thesis mill", "--report-axis", "X"])
            .output()
            .unwrap(),
        "retrocomp iso230-2",
    ))
    .unwrap();
    let svg_text = std::fs::read_to_string(&svg).unwrap();
    assert_legend_clear(&svg, "iso230-2");
    // The pixel check is not blind: a marker put into the legend box is found.
    pixels::assert_an_injected_overlap_is_seen(&svg);
    // Asad Ullah's X: the forward and reverse means cross between 145 and 160 mm (Bi changes
    // sign), the place the old opaque legend hid.
    let bi = |t: f64| {
        json["targets"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["target_mm"].as_f64() == Some(t))
            .unwrap()["B_i_um"]
            .as_f64()
            .unwrap()
    };
    let crossing = (140..=170)
        .step_by(5)
        .map(f64::from)
        .filter(|t| {
            json["targets"]
                .as_array()
                .unwrap()
                .iter()
                .any(|x| x["target_mm"].as_f64() == Some(*t))
        })
        .collect::<Vec<_>>();
    assert!(
        crossing
            .windows(2)
            .any(|w| bi(w[0]).signum() != bi(w[1]).signum()),
        "Bi changes sign around 145–160 mm: {crossing:?}"
    );
    let e = json["axis"]["E_um"].as_f64().unwrap();
    let m = json["axis"]["M_um"].as_f64().unwrap();
    let b = json["axis"]["B_um"].as_f64().unwrap();
    let numbers = [
        format!("E = {e:.2} µm"),
        format!("M = {m:.2} µm"),
        format!("B = {b:.2} µm"),
        "R: n/a".to_string(),
        "A: n/a".to_string(),
    ];
    for n in &numbers {
        assert!(svg_text.contains(n.as_str()), "figure lacks {n}");
    }
    for label in ["target position / mm", "deviation (actual − target) / µm"] {
        assert!(svg_text.contains(label), "axis label {label}");
    }
    let (pages, info, text) = print_pdf(&html, &pdf, dir.path());
    assert!((1..=3).contains(&pages), "{pages} pages:\n{info}");
    assert!(info.contains("(A4)"), "A4 pages:\n{info}");
    for n in numbers
        .iter()
        .chain([&"thesis mill".to_string(), &"SHA-256".to_string()])
    {
        assert!(text.contains(n.as_str()), "PDF text lacks {n}:\n{text}");
    }
}

/// Two runs of a 150 mm circle: CCW and CW differ by a backlash-like step, so H > 0.
fn circle_csv(path: &Path) {
    let mut s = String::from("angle_deg,dr_um,direction\n");
    for dir in ["ccw", "cw"] {
        for i in 0..360 {
            let a = f64::from(if dir == "ccw" { i } else { 360 - i });
            let r = a.to_radians();
            let rev = if dir == "ccw" { 1.0 } else { -1.0 };
            let dr = 3.0 * r.cos() + 1.5 * (2.0 * r).sin() + rev * 2.0 * r.sin().signum();
            s.push_str(&format!("{a},{dr:.3},{dir}\n"));
        }
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn circle_report_has_the_polar_plot_and_prints_its_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("circle.csv");
    circle_csv(&csv);
    let (polar, angle, html, pdf) = (
        dir.path().join("polar.svg"),
        dir.path().join("angle.svg"),
        dir.path().join("c.html"),
        dir.path().join("c.pdf"),
    );
    let json: serde_json::Value = serde_json::from_str(&ok(
        retrocomp()
            .arg("circle")
            .arg(&csv)
            .args([
                "--radius-mm",
                "150",
                "--feed-mm-min",
                "1000",
                "--json",
                "--svg",
            ])
            .arg(&polar)
            .arg("--svg-angle")
            .arg(&angle)
            .arg("--html")
            .arg(&html)
            .output()
            .unwrap(),
        "retrocomp circle",
    ))
    .unwrap();
    let polar_text = std::fs::read_to_string(&polar).unwrap();
    assert_legend_clear(&polar, "polar");
    assert_legend_clear(&angle, "angle");
    let g_b = json["iso230_4"]["g_bidirectional_um"].as_f64().unwrap();
    let numbers = [
        format!("G(b) = {g_b:.2} µm"),
        "R = 150 mm, F = 1000 mm/min".to_string(),
        "H (circular hysteresis) =".to_string(),
        "magnification ×".to_string(),
    ];
    for n in &numbers {
        assert!(polar_text.contains(n.as_str()), "polar plot lacks {n}");
    }
    // The step of ±2 µm in sin θ's sign makes CCW and CW differ by up to 4 µm.
    assert!(
        polar_text.contains("H (circular hysteresis) = 4.00 µm"),
        "H"
    );
    let (pages, info, text) = print_pdf(&html, &pdf, dir.path());
    assert!((1..=4).contains(&pages), "{pages} pages:\n{info}");
    for n in numbers.iter().take(2) {
        assert!(text.contains(n.as_str()), "PDF text lacks {n}:\n{text}");
    }
}

#[test]
fn fit_axis_report_prints_the_fit_table_figure_and_model() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs.csv");
    runs::bowed_runs_csv(&runs);
    let (svg, html, pdf, model) = (
        dir.path().join("fit.svg"),
        dir.path().join("fit.html"),
        dir.path().join("fit.pdf"),
        dir.path().join("m.toml"),
    );
    let json: serde_json::Value = serde_json::from_str(&ok(
        retrocomp()
            .args(["fit", "axis"])
            .arg(&runs)
            .args([
                "--component",
                "EXX",
                "--holdout-run",
                "3",
                "--json",
                "--out",
            ])
            .arg(&model)
            .arg("--svg")
            .arg(&svg)
            .arg("--html")
            .arg(&html)
            .args(["--machine", "bench mill", "--instrument", "XL-80 laser"])
            .output()
            .unwrap(),
        "retrocomp fit axis",
    ))
    .unwrap();
    let svg_text = std::fs::read_to_string(&svg).unwrap();
    assert_legend_clear(&svg, "fit axis");
    let fit = &json["fit"];
    let numbers = [
        format!("fit rms = {:.3} µm", fit["fit_rms_um"].as_f64().unwrap()),
        format!(
            "held-out δ = {:.1} %",
            100.0 * fit["heldout"]["delta"].as_f64().unwrap()
        ),
        format!(
            "max residual = {:.2} µm",
            fit["heldout"]["max_residual_um"].as_f64().unwrap()
        ),
    ];
    for n in &numbers {
        assert!(svg_text.contains(n.as_str()), "figure lacks {n}");
    }
    let html_text = std::fs::read_to_string(&html).unwrap();
    let toml = std::fs::read_to_string(&model).unwrap();
    let first_model_line = toml.lines().find(|l| !l.trim().is_empty()).unwrap();
    assert!(
        html_text.contains(first_model_line),
        "the report holds the model written"
    );
    let (pages, info, text) = print_pdf(&html, &pdf, dir.path());
    assert!((1..=4).contains(&pages), "{pages} pages:\n{info}");
    assert!(info.contains("(A4)"), "A4 pages:\n{info}");
    for n in numbers.iter().map(String::as_str).chain([
        "bench mill",
        "XL-80 laser",
        "SHA-256",
        "What was assumed",
    ]) {
        assert!(text.contains(n), "PDF text lacks {n}:\n{text}");
    }
}

#[test]
fn demo_report_prints_the_four_runs_table_and_figures() {
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let dir = tempfile::tempdir().unwrap();
    let (out, html, pdf) = (
        dir.path().join("demo"),
        dir.path().join("demo.html"),
        dir.path().join("demo.pdf"),
    );
    let stdout = ok(
        run_guarded(
            {
                let mut c = retrocomp();
                c.args(["demo", "--json", "--seconds", "0", "--out"])
                    .arg(&out)
                    .arg("--html")
                    .arg(&html)
                    .env("HIL_SIM_BIN", &hil_sim);
                c
            },
            "retrocomp demo",
        ),
        "retrocomp demo",
    );
    let v: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    let mut numbers = vec![];
    for mode in ["uncompensated", "geometric", "full", "fitted"] {
        let vol = v[mode]["volumetric_max_um"].as_f64().unwrap();
        numbers.push(format!("{mode} {vol:.2} µm"));
    }
    let vol_svg = std::fs::read_to_string(out.join("volumetric.svg")).unwrap();
    for f in [
        "error_x.svg",
        "error_y.svg",
        "error_z.svg",
        "volumetric.svg",
    ] {
        assert_legend_clear(&out.join(f), f);
    }
    for n in &numbers {
        assert!(vol_svg.contains(n.as_str()), "volumetric figure lacks {n}");
    }
    let (pages, info, text) = print_pdf(&html, &pdf, dir.path());
    assert!((2..=8).contains(&pages), "{pages} pages:\n{info}");
    assert!(info.contains("(A4)"), "A4 pages:\n{info}");
    for n in numbers
        .iter()
        .map(String::as_str)
        // pdftotext may break the path at its hyphen ("mill-fitted" reads "millfitted").
        .chain(["fitted.toml SHA-256", "What was assumed"])
    {
        assert!(text.contains(n), "PDF text lacks {n}:\n{text}");
    }
}
