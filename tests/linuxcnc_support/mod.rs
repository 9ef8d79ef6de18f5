//! LinuxCNC 2.9 as an outside judge for the tests: `rs274` (the standalone interpreter) reads
//! NC programs into canonical machining calls ([`rs274`], [`CanonMotion`]); [`headless`] starts a
//! real LinuxCNC (uspace, no X, no realtime kernel) as an unprivileged user with a Python display
//! script. Missing LinuxCNC fails the test with how to install it — never a silent skip.
//! Positions are in mm; canonical positions are converted to machine coordinates (work offset
//! added; X is the radius in lathe diameter mode, as the interpreter holds it).

pub(crate) mod headless;
pub(crate) mod nobody;

use std::path::Path;
use std::process::Command;

pub(crate) const INSTALL_HINT: &str = "LinuxCNC 2.9 is not installed: run scripts/setup-linuxcnc.sh (apt-get install --no-install-recommends linuxcnc-uspace)";

/// Fails the test (with the install hint) when `prog` is not on PATH.
pub(crate) fn require(prog: &str) {
    let found = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).any(|d| d.join(prog).is_file()))
        .unwrap_or(false);
    assert!(found, "`{prog}` not found. {INSTALL_HINT}");
}

/// One canonical motion: end point (machine coordinates, X Y Z) and, for arcs, the centre in the
/// plane `(first, second)` axis indices and the rotation (+ counter-clockwise).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CanonMotion {
    pub end_mm: [f64; 3],
    pub arc: Option<CanonArc>,
    pub rapid: bool,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CanonArc {
    pub plane: (usize, usize),
    /// Centre, machine coordinates (only the plane components are meaningful).
    pub centre_mm: [f64; 3],
    pub rotation: i32,
}

/// Runs `rs274 -g program` and returns its canonical motions, or the interpreter's error text.
pub(crate) fn rs274(program: &Path) -> Result<Vec<CanonMotion>, String> {
    require("rs274");
    // Two rs274 at once crash (SIGBUS, seen on 2.9.0~pre1): one at a time per test binary.
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _guard = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let canon = program.with_extension("canon");
    let out = Command::new("rs274")
        .arg("-g")
        .arg(program)
        .arg(&canon)
        .output()
        .expect("run rs274");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&canon).unwrap_or_default();
    // rs274 prints the failing block after its message and exits non-zero.
    if !out.status.success()
        || log
            .lines()
            .any(|l| l.trim() != "executing" && !l.trim().is_empty())
    {
        return Err(format!(
            "rs274 {}: {}\n{log}",
            program.display(),
            out.status
        ));
    }
    Ok(parse_canon(&text))
}

fn args_of(line: &str) -> Option<(&str, Vec<&str>)> {
    let body = line
        .split_once("N..... ")
        .map(|x| x.1)
        .unwrap_or(line)
        .trim();
    let (name, rest) = body.split_once('(')?;
    let inner = rest.strip_suffix(')')?;
    Some((name, inner.split(',').map(str::trim).collect()))
}

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("canon number `{s}`"))
}

pub(crate) fn parse_canon(text: &str) -> Vec<CanonMotion> {
    let mut plane = (0, 1);
    let mut off = [0.0; 3];
    let mut g92 = [0.0; 3];
    let mut out = Vec::new();
    for line in text.lines() {
        let Some((name, a)) = args_of(line) else {
            continue;
        };
        match name {
            "SET_G5X_OFFSET" => off = [num(a[1]), num(a[2]), num(a[3])],
            "SET_G92_OFFSET" => g92 = [num(a[0]), num(a[1]), num(a[2])],
            "SELECT_PLANE" => {
                plane = match a[0] {
                    "CANON_PLANE_XZ" => (2, 0),
                    "CANON_PLANE_YZ" => (1, 2),
                    _ => (0, 1),
                }
            }
            "STRAIGHT_TRAVERSE" | "STRAIGHT_FEED" => out.push(CanonMotion {
                end_mm: std::array::from_fn(|k| num(a[k]) + off[k] + g92[k]),
                arc: None,
                rapid: name == "STRAIGHT_TRAVERSE",
            }),
            "ARC_FEED" => {
                let (p, q) = plane;
                let h = 3 - p - q;
                let mut end = [0.0; 3];
                let mut centre = [0.0; 3];
                end[p] = num(a[0]);
                end[q] = num(a[1]);
                centre[p] = num(a[2]);
                centre[q] = num(a[3]);
                end[h] = num(a[5]);
                for k in 0..3 {
                    end[k] += off[k] + g92[k];
                    centre[k] += off[k] + g92[k];
                }
                out.push(CanonMotion {
                    end_mm: end,
                    arc: Some(CanonArc {
                        plane,
                        centre_mm: centre,
                        rotation: a[4].parse().expect("rotation"),
                    }),
                    rapid: false,
                });
            }
            _ => {}
        }
    }
    out
}
