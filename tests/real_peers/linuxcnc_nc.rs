//! `retrocomp nc` judged by LinuxCNC 2.9's own interpreter (`rs274`): every program of the NC
//! corpus (tests/data/nc: mill and lathe, G90/G91, arcs in I/J/K and R, dwells, work offsets,
//! diameter mode, split and unsplit) is rewritten, read by rs274 without error, and every
//! canonical end point of the rewritten program equals the nominal point minus
//! `retrocomp eval`'s error there (machine coordinates; target = nominal − error) within 0.1 µm.
//! The nominal points come from `retrocomp nc --points` and are checked to lie on the original
//! program's path as rs274 reads it; the approach directions are computed here from rs274's
//! geometry, not taken from the rewriter. Plus one regression test per bug of issue 13.

use crate::linuxcnc_support;

use std::path::{Path, PathBuf};
use std::process::Command;

use linuxcnc_support::{CanonMotion, rs274};

const TOL_UM: f64 = 0.1 + 1e-6;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/nc")
        .join(name)
}

fn tmpdir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("retrocomp-lcnc-nc-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn retrocomp(args: &[&str], cwd: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run retrocomp")
}

/// Axes the model TOML defines (`[axes.x]` …).
fn model_axes(model: &Path) -> [bool; 3] {
    let t = std::fs::read_to_string(model).unwrap();
    ["[axes.x]", "[axes.y]", "[axes.z]"].map(|h| t.contains(h))
}

struct Row {
    move_index: usize,
    nominal: [f64; 3],
    dirs: [i32; 3],
    compensated: bool,
}

fn read_points(p: &Path) -> Vec<Row> {
    let t = std::fs::read_to_string(p).unwrap();
    t.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            Row {
                move_index: c[1].parse().unwrap(),
                nominal: [c[2], c[3], c[4]].map(|v| v.parse().unwrap()),
                dirs: [c[5], c[6], c[7]].map(|v| v.parse().unwrap()),
                compensated: c[8] == "1",
            }
        })
        .collect()
}

/// Approach directions computed from rs274's reading of the original program: per point, the
/// sign of the motion arriving there (arcs: a point 1e-4 rad before it on the canonical arc);
/// an axis that does not move keeps its direction; before the first motion nothing is known.
fn directions(orig: &[CanonMotion], rows: &[Row], start_known: bool) -> Vec<[i32; 3]> {
    let mut dirs = [1; 3];
    let mut prev: Option<[f64; 3]> = None;
    let mut out = Vec::new();
    for r in rows {
        let m = &orig[r.move_index];
        let before: Option<[f64; 3]> = match &m.arc {
            Some(a) => {
                let (p, q) = a.plane;
                let rot = f64::from(a.rotation.signum());
                let th = (r.nominal[q] - a.centre_mm[q]).atan2(r.nominal[p] - a.centre_mm[p]);
                let rad = (r.nominal[q] - a.centre_mm[q]).hypot(r.nominal[p] - a.centre_mm[p]);
                let thb = th - rot * 1e-4;
                let mut b = prev.unwrap();
                b[p] = a.centre_mm[p] + rad * thb.cos();
                b[q] = a.centre_mm[q] + rad * thb.sin();
                Some(b)
            }
            None if r.move_index == 0 && !start_known && prev.is_none() => None,
            None => prev,
        };
        if let Some(b) = before {
            for k in 0..3 {
                let d = r.nominal[k] - b[k];
                if d.abs() > 1e-12 {
                    dirs[k] = if d > 0.0 { 1 } else { -1 };
                }
            }
        }
        out.push(dirs);
        prev = Some(r.nominal);
    }
    out
}

/// Is `p` on original motion `m` starting at `s`? (lines: on the segment; arcs: on the circle.)
fn on_path(s: [f64; 3], m: &CanonMotion, p: [f64; 3]) -> bool {
    match &m.arc {
        None => {
            let d: [f64; 3] = std::array::from_fn(|k| m.end_mm[k] - s[k]);
            let l2: f64 = d.iter().map(|v| v * v).sum();
            let t = if l2 == 0.0 {
                0.0
            } else {
                (0..3).map(|k| (p[k] - s[k]) * d[k]).sum::<f64>() / l2
            };
            (-1e-9..=1.0 + 1e-9).contains(&t)
                && (0..3).all(|k| (s[k] + t * d[k] - p[k]).abs() < 1e-6)
        }
        Some(a) => {
            let (u, v) = a.plane;
            let r = |q: [f64; 3]| (q[u] - a.centre_mm[u]).hypot(q[v] - a.centre_mm[v]);
            let (r0, r1) = (r(s), r(m.end_mm));
            (r(p) - r0).abs() <= (r1 - r0).abs() + 1e-6
        }
    }
}

/// Errors (µm) and flags from `retrocomp eval` at the given points and directions.
fn eval(model: &Path, pts: &[[f64; 3]], dirs: &[[i32; 3]], dir: &Path) -> Vec<([f64; 3], String)> {
    let csv = dir.join("eval_in.csv");
    let mut t = String::from("x_mm,y_mm,z_mm,dir_x,dir_y,dir_z\n");
    for (p, d) in pts.iter().zip(dirs) {
        t.push_str(&format!(
            "{:.9},{:.9},{:.9},{},{},{}\n",
            p[0], p[1], p[2], d[0], d[1], d[2]
        ));
    }
    std::fs::write(&csv, t).unwrap();
    let out = retrocomp(
        &[
            "eval",
            "--model",
            model.to_str().unwrap(),
            "--path",
            csv.to_str().unwrap(),
        ],
        dir,
    );
    assert!(
        out.status.success(),
        "eval: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| head.iter().position(|h| *h == n).unwrap();
    let (ex, ey, ez, fl) = (col("ex_um"), col("ey_um"), col("ez_um"), col("flags"));
    lines
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (
                [ex, ey, ez].map(|i| c[i].parse::<f64>().unwrap()),
                c[fl].to_string(),
            )
        })
        .collect()
}

#[derive(Debug, Default)]
struct Report {
    points: usize,
    compensated: usize,
    max_dev_um: f64,
    max_corr_um: f64,
    stdout: String,
}

/// Rewrites `program` with `args` (run in tests/data/nc) and checks it through rs274 and eval.
fn check(program: &Path, args: &[&str], tag: &str) -> Report {
    let dir = tmpdir(tag);
    let orig_copy = dir.join("orig.ngc");
    std::fs::copy(program, &orig_copy).unwrap();
    let orig = rs274(&orig_copy).unwrap_or_else(|e| panic!("original program: {e}"));
    let out = dir.join("rewritten.ngc");
    let points = dir.join("points.csv");
    let mut a: Vec<&str> = vec!["nc", program.to_str().unwrap()];
    a.extend_from_slice(args);
    a.extend_from_slice(&[
        "--out",
        out.to_str().unwrap(),
        "--points",
        points.to_str().unwrap(),
    ]);
    let run = retrocomp(&a, &data(""));
    assert!(
        run.status.success(),
        "{tag}: retrocomp nc failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let rew = rs274(&out).unwrap_or_else(|e| {
        panic!(
            "{tag}: LinuxCNC refuses the rewritten program: {e}\n{}",
            std::fs::read_to_string(&out).unwrap()
        )
    });
    let rows = read_points(&points);
    assert_eq!(
        rows.len(),
        rew.len(),
        "{tag}: one canonical motion per written point"
    );
    let moves: std::collections::BTreeSet<usize> = rows.iter().map(|r| r.move_index).collect();
    assert_eq!(
        moves,
        (0..orig.len()).collect(),
        "{tag}: every original motion is in the rewrite, in order"
    );
    // Nominal points on the original path; the last piece of each move on its end point.
    for (i, r) in rows.iter().enumerate() {
        let m = &orig[r.move_index];
        let s = if r.move_index == 0 {
            [0.0; 3]
        } else {
            orig[r.move_index - 1].end_mm
        };
        if r.move_index > 0 {
            assert!(
                on_path(s, m, r.nominal),
                "{tag}: point {i} {:?} not on motion {}",
                r.nominal,
                r.move_index
            );
        }
        let last = rows.get(i + 1).is_none_or(|n| n.move_index != r.move_index);
        if last {
            let d = (0..3)
                .map(|k| (r.nominal[k] - m.end_mm[k]).abs())
                .fold(0.0, f64::max);
            assert!(
                d < 1e-6,
                "{tag}: move {} ends at {:?}, rs274 says {:?}",
                r.move_index,
                r.nominal,
                m.end_mm
            );
        }
    }
    let start_known = args.contains(&"--start");
    let dirs = directions(&orig, &rows, start_known);
    for (r, d) in rows.iter().zip(&dirs) {
        assert_eq!(&r.dirs, d, "{tag}: approach direction at {:?}", r.nominal);
    }
    let model = data(args[args.iter().position(|a| *a == "--model").unwrap() + 1]);
    let axes = model_axes(&model);
    let nominal: Vec<[f64; 3]> = rows.iter().map(|r| r.nominal).collect();
    let errs = eval(&model, &nominal, &dirs, &dir);
    let mut rep = Report {
        points: rows.len(),
        stdout: String::from_utf8_lossy(&run.stdout).into(),
        ..Default::default()
    };
    for (i, ((r, (e, flags)), m)) in rows.iter().zip(&errs).zip(&rew).enumerate() {
        if r.compensated {
            rep.compensated += 1;
        } else {
            assert!(
                !flags.is_empty(),
                "{tag}: point {i} kept as programmed although eval has a value there"
            );
        }
        for k in 0..3 {
            let corr = if r.compensated && axes[k] {
                e[k] / 1000.0
            } else {
                0.0
            };
            let want = r.nominal[k] - corr;
            let dev = (m.end_mm[k] - want).abs() * 1000.0;
            rep.max_corr_um = rep.max_corr_um.max(corr.abs() * 1000.0);
            rep.max_dev_um = rep.max_dev_um.max(dev);
            assert!(
                dev <= TOL_UM,
                "{tag}: point {i} axis {k}: rs274 {:.5} vs nominal {:.5} − error {:.3} µm: {dev:.3} µm apart",
                m.end_mm[k],
                r.nominal[k],
                e[k]
            );
        }
    }
    rep
}

/// Options of a corpus program: its first line `(args: …)`.
fn corpus_args(p: &Path) -> Vec<String> {
    let t = std::fs::read_to_string(p).unwrap();
    let first = t.lines().next().unwrap();
    let inner = first
        .strip_prefix("(args:")
        .and_then(|s| s.strip_suffix(')'))
        .unwrap_or_else(|| panic!("{}: first line must be (args: …)", p.display()));
    inner.split_whitespace().map(String::from).collect()
}

#[test]
fn corpus_rewritten_programs_are_read_by_rs274_and_end_at_nominal_minus_error() {
    let _turn = crate::turn::take(file!());
    let mut files: Vec<PathBuf> = std::fs::read_dir(data(""))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ngc"))
        .collect();
    files.sort();
    assert!(files.len() >= 6, "corpus present");
    let (mut total, mut worst) = (0, 0.0f64);
    for f in &files {
        let args = corpus_args(f);
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let tag = f.file_stem().unwrap().to_str().unwrap();
        let rep = check(f, &a, tag);
        eprintln!(
            "{tag}: {} points ({} compensated), max |correction| {:.2} µm, max |rs274 − (nominal − error)| {:.3} µm",
            rep.points, rep.compensated, rep.max_corr_um, rep.max_dev_um
        );
        assert!(
            rep.compensated > 0 && rep.max_corr_um > 1.0,
            "{tag}: the model corrects something"
        );
        total += rep.points;
        worst = worst.max(rep.max_dev_um);
    }
    eprintln!(
        "corpus: {} programs, {total} points, worst {worst:.3} µm",
        files.len()
    );
}

fn write_prog(tag: &str, text: &str) -> PathBuf {
    let d = tmpdir(&format!("{tag}-src"));
    let p = d.join(format!("{tag}.ngc"));
    std::fs::write(&p, text).unwrap();
    p
}

const MILL: &str = "worn-mill.toml";

/// Issue 13 (1): a G91 split move is written incrementally piece by piece: rs274 ends at the
/// nominal end minus the error, not at the sum of distances from the block start.
#[test]
fn g91_split_pieces_are_incremental() {
    let _turn = crate::turn::take(file!());
    let p = write_prog(
        "g91",
        "G21 G90 G17\nG0 X100 Y100 Z20\nG91 G1 X60 Y30 F500\nG1 X-20 Y-10\nM2\n",
    );
    let rep = check(
        &p,
        &["--model", MILL, "--semicolon-comment", "--split-mm", "20"],
        "g91",
    );
    assert_eq!(rep.points, 1 + 4 + 2, "67 mm in 4 pieces, 22 mm in 2");
}

/// Issue 13 (2): a split feed move from an unknown start is refused (naming --start); with
/// --start it is split from the stated position.
#[test]
fn unknown_start_is_refused_or_taken_from_start_option() {
    let _turn = crate::turn::take(file!());
    let p = write_prog("start", "G21 G90 G17\nG1 X60 Y30 Z10 F500\nM2\n");
    let out = retrocomp(
        &[
            "nc",
            p.to_str().unwrap(),
            "--model",
            MILL,
            "--semicolon-comment",
            "--split-mm",
            "10",
        ],
        &data(""),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("--start") && err.contains("line 2"),
        "{err}"
    );
    let rep = check(
        &p,
        &[
            "--model",
            MILL,
            "--semicolon-comment",
            "--split-mm",
            "10",
            "--start",
            "0,0,0",
        ],
        "start",
    );
    assert_eq!(rep.points, 7, "68.3 mm from the stated start in 7 pieces");
}

/// Issue 13 (3): an unsplit arc ending on a quadrant point uses the direction it arrives with
/// (Y forward here, after a −Y move): rs274 ends at 130 − EYY_forward, 35 µm from the reverse.
#[test]
fn arc_ending_on_a_quadrant_point_uses_the_arriving_direction() {
    let _turn = crate::turn::take(file!());
    let p = write_prog(
        "quad",
        "G21 G90 G17\nG0 X120 Y100 Z5\nG1 Y90 F500\nG2 X160 Y130 I40 J0\nM2\n",
    );
    let rep = check(&p, &["--model", MILL, "--semicolon-comment"], "quad");
    assert_eq!(rep.points, 3);
}

/// Issue 13 (4): on a worn machine (40/35 µm reversal) the ends of an arc move by different
/// amounts: X and Y arrive at the start of this 180° arc forward and at its end in reverse, so with
/// the nominal centre the radii differ by ≈ 56 µm and LinuxCNC refuses the program (measured with
/// the old rewriter). The centre is moved, LinuxCNC accepts, and the summary says so.
#[test]
fn worn_arcs_get_a_moved_centre_linuxcnc_accepts() {
    let _turn = crate::turn::take(file!());
    let p = write_prog(
        "worn",
        "G21 G90 G17\nG0 X100 Y28.7868 Z5\nG1 X151.2132 F500\nG3 X108.7868 Y71.2132 I-21.2132 J21.2132\nG0 X100 Y50\nG1 X160 F500\nG3 X100 Y50 R30\nM2\n",
    );
    let rep = check(&p, &["--model", MILL, "--semicolon-comment"], "worn");
    assert!(rep.stdout.contains("2 arc centres moved"), "{}", rep.stdout);
    assert!(rep.max_corr_um > 35.0, "{rep:?}");
}

/// Issue 13 (5): `(a; b)` is a comment under --semicolon-comment, `;` to the end of line too.
#[test]
fn semicolon_inside_a_comment_is_accepted() {
    let _turn = crate::turn::take(file!());
    let p = write_prog(
        "semi",
        "G21 G90 G17 (setup; mm)\nG0 X10 Y10 Z10 ; rapid (x\nG1 X50 F300 (cut; slow)\nM2\n",
    );
    check(&p, &["--model", MILL, "--semicolon-comment"], "semi");
}

/// Issue 13 (6): a G91 move kept as programmed past the travel end is written so it ends on
/// its nominal point; the next move's correction is counted once.
#[test]
fn g91_move_past_the_travel_end_does_not_double_the_next_correction() {
    let _turn = crate::turn::take(file!());
    let rep = check(
        &data("mill_outside_g91.ngc"),
        &["--model", MILL, "--semicolon-comment"],
        "outside",
    );
    assert!(
        rep.stdout.contains("1 moves outside the model"),
        "{}",
        rep.stdout
    );
}

/// Issue 33 (6): a G90 move past the travel end naming X only ends with Y and Z on their nominal
/// points (they carried the previous move's correction: Y stayed 3.5 µm off).
#[test]
fn g90_move_past_the_travel_end_puts_every_axis_on_its_nominal_point() {
    let _turn = crate::turn::take(file!());
    let rep = check(
        &data("mill_outside_g90.ngc"),
        &["--model", MILL, "--semicolon-comment"],
        "outside90",
    );
    assert!(
        rep.stdout.contains("1 moves outside the model"),
        "{}",
        rep.stdout
    );
}

/// Issue 33 (6): `%` tape marks and comments, `(MSG, …)` in the middle of a motion block
/// included, are kept where they were; rs274 reads the rewrite.
#[test]
fn tape_marks_and_comments_are_kept() {
    let _turn = crate::turn::take(file!());
    let p = write_prog(
        "keep",
        "%\n(header)\nG21 G90 G17\nG0 X10 Y10 (MSG, rapid in) Z10 ; tail\nG1 X50 F300 (MSG, cutting)\nM2\n%\n",
    );
    let rep = check(&p, &["--model", MILL, "--semicolon-comment"], "keep");
    assert!(rep.stdout.contains("2 moves compensated"), "{}", rep.stdout);
    let out = std::env::temp_dir()
        .join(format!("retrocomp-lcnc-nc-{}-keep", std::process::id()))
        .join("rewritten.ngc");
    let out = std::fs::read_to_string(out).unwrap();
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!((lines[0], *lines.last().unwrap()), ("%", "%"), "{out}");
    let with = |s: &str| lines.iter().find(|l| l.contains(s)).copied().unwrap_or("");
    assert!(with("(header)").starts_with("(header)"), "{out}");
    assert!(
        with("(MSG, rapid in)").starts_with("G0 X") && with("; tail").contains("(MSG, rapid in)"),
        "{out}"
    );
    assert!(with("(MSG, cutting)").starts_with("G1 X"), "{out}");
}

/// Issue 33 (6): subprograms (M98 … O1000 … M99, o-word subs), `#` parameters and expressions
/// are refused naming the line and saying they are not supported, never passed uninterpreted.
#[test]
fn subprograms_and_parameters_are_refused_naming_the_line() {
    let _turn = crate::turn::take(file!());
    for (prog, line, what) in [
        (
            "G21 G90\nG0 X10 Y10 Z10\nM98 P1000\nG91 G1 X5 F300\nM30\nO1000\nG91 G1 Y5\nM99\n",
            "line 3",
            "M98 (subprogram call) is not supported",
        ),
        (
            "G21 G90\no100 sub\nG1 X5 F300\no100 endsub\no100 call\nM2\n",
            ":2:",
            "O-words (subprograms, program numbers, o-word control flow) are not supported",
        ),
        (
            "G21 G90\n#1 = 5\nG1 X#1 F300\nM2\n",
            ":2:",
            "`#` parameters (variables) are not supported",
        ),
        (
            "G21 G90\nG0 X[1+2] Y0 Z0\nM2\n",
            ":2:",
            "expressions are not supported",
        ),
        (
            "G21 G90\nG65 P9010 A1\nM2\n",
            "line 2",
            "macro calls are not supported",
        ),
    ] {
        let p = write_prog("sub", prog);
        let out = retrocomp(&["nc", p.to_str().unwrap(), "--model", MILL], &data(""));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains(line) && err.contains(what),
            "{prog}: {err}"
        );
    }
}

/// Issue 13 (7): the CAM header with G54, G61.1, G90.1 and every work system G54–G59.3.
#[test]
fn work_offsets_g54_to_g59_3_and_cam_header() {
    let _turn = crate::turn::take(file!());
    let mut prog = String::from("G17 G21 G40 G49 G54 G80 G90 G94\nG61.1\nG0 X0 Y0 Z30\n");
    let mut args = vec!["--model", MILL, "--semicolon-comment"];
    let names = [
        "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
    ];
    let offs: Vec<String> = (0..9)
        .map(|i| format!("{}={},{},{}", names[i], 10 * i, 5 * i, -(i as i32)))
        .collect();
    for (i, n) in names.iter().enumerate() {
        prog.push_str(&format!(
            "G10 L2 P{} X{} Y{} Z{}\n{n} G1 X{} Y{} Z20 F400\n",
            i + 1,
            10 * i,
            5 * i,
            -(i as i32),
            20 + 15 * i,
            40 + 7 * i
        ));
        args.push("--work-offset");
    }
    prog.push_str("G90.1 G2 X120 Y116 I140 J116\nG91.1\nM2\n");
    // The offsets are also given on the command line (what the controller holds).
    let mut a: Vec<&str> = Vec::new();
    for (i, s) in args.iter().enumerate() {
        a.push(s);
        if *s == "--work-offset" {
            a.push(&offs[i - 3]);
        }
    }
    let p = write_prog("wcs", &prog);
    let rep = check(&p, &a, "wcs");
    assert_eq!(rep.points, 1 + 9 + 1);
    // Without the offset stated, selecting G55 is refused with the option to give.
    let p = write_prog("wcs2", "G21 G90\nG55 G0 X1 Y1 Z1\nM2\n");
    let out = retrocomp(&["nc", p.to_str().unwrap(), "--model", MILL], &data(""));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--work-offset G55=X,Y,Z"), "{err}");
}

/// Issue 18 (6): the split is bounded with a clear error (no unbounded allocation), and a
/// refused program leaves no output file behind.
#[test]
fn split_is_bounded_with_a_clear_error() {
    let _turn = crate::turn::take(file!());
    let p = write_prog("bound", "G21 G90\nG0 X0 Y0 Z0\nG1 X400 Y400 F500\nM2\n");
    let d = tmpdir("bound");
    let out_file = d.join("out.ngc");
    let out = retrocomp(
        &[
            "nc",
            p.to_str().unwrap(),
            "--model",
            MILL,
            "--split-mm",
            "0.00001",
            "--out",
            out_file.to_str().unwrap(),
        ],
        &data(""),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("line 3") && err.contains("more than the limit of 100000"),
        "{err}"
    );
    assert!(!out_file.exists() && std::fs::read_dir(&d).unwrap().next().is_none());
}
