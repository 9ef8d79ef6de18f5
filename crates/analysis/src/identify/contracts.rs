//! The artefact input contracts of `retrocomp identify` (docs/identify.md): one CSV per hole-plate
//! placement or ball-bar set-up, and a side TOML file with the same stem. Sans-IO: the readers
//! take the texts and a file name for messages; every problem is reported as `file:line: …`, all
//! problems of a file at once. The writers produce the same contract (hil-sim uses them).
//!
//! Units as named: positions mm, deviations µm, temperatures °C, expansion ppm/K. Certified hole
//! centres (`u_mm`, `v_mm`) and bar lengths are at 20 °C.

use std::fmt::Write as _;

/// Reference temperature of certificates and scales, °C.
pub const REFERENCE_C: f64 = 20.0;

/// The plane a hole plate lies in; `u`, `v` of the plate map onto its two machine axes in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Plane {
    Xy,
    Xz,
    Yz,
}

impl Plane {
    /// Machine axis indices (0 = x) that `u` and `v` map onto.
    pub fn axes(self) -> [usize; 2] {
        match self {
            Plane::Xy => [0, 1],
            Plane::Xz => [0, 2],
            Plane::Yz => [1, 2],
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Plane::Xy => "xy",
            Plane::Xz => "xz",
            Plane::Yz => "yz",
        }
    }

    fn parse(s: &str) -> Option<Plane> {
        match s {
            "xy" => Some(Plane::Xy),
            "xz" => Some(Plane::Xz),
            "yz" => Some(Plane::Yz),
            _ => None,
        }
    }
}

/// One probing of one hole.
#[derive(Debug, Clone, PartialEq)]
pub struct HoleProbe {
    pub hole: String,
    /// Certified centre in the plate frame at 20 °C, mm.
    pub uv_mm: [f64; 2],
    /// Machine scale readings at the probed centre, mm.
    pub pos_mm: [f64; 3],
    /// Probe length along the tool axis (the Abbe arm), mm.
    pub tool_mm: f64,
    /// 0 for the first probing of a hole, 1, 2, … for repeats.
    pub repeat: u32,
    pub t_plate_c: Option<f64>,
    /// `T_scale_x_C`, `T_scale_y_C`, `T_scale_z_C`.
    pub t_scale_c: [Option<f64>; 3],
    /// CSV line (1 = header).
    pub line: usize,
}

/// One hole-plate placement.
#[derive(Debug, Clone, PartialEq)]
pub struct HolePlate {
    pub name: String,
    pub plane: Plane,
    pub alpha_ppm_per_k: f64,
    pub certificate_uncertainty_um: f64,
    /// Expansion of the machine's scales, needed when `T_scale_*_C` columns are given.
    pub scale_alpha_ppm_per_k: Option<f64>,
    pub probes: Vec<HoleProbe>,
}

/// One point on a static ball-bar sphere.
#[derive(Debug, Clone, PartialEq)]
pub struct BallPoint {
    pub point: String,
    /// Machine position (the ball at the tool tip), mm.
    pub pos_mm: [f64; 3],
    /// Bar length minus nominal, µm.
    pub dr_um: f64,
    pub tool_mm: f64,
    pub t_bar_c: Option<f64>,
    pub t_scale_c: [Option<f64>; 3],
    pub line: usize,
}

/// One static ball-bar set-up (one sphere).
#[derive(Debug, Clone, PartialEq)]
pub struct BallBar {
    pub name: String,
    pub r_nom_mm: f64,
    /// Nominal centre; the true centre is estimated.
    pub centre_mm: [f64; 3],
    pub alpha_ppm_per_k: f64,
    pub scale_alpha_ppm_per_k: Option<f64>,
    pub points: Vec<BallPoint>,
}

/// All problems of one file, each `file:line: message`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}", .0.join("\n"))]
pub struct ContractError(pub Vec<String>);

struct Issues {
    file: String,
    list: Vec<String>,
}

impl Issues {
    fn new(file: &str) -> Self {
        Self {
            file: file.to_string(),
            list: Vec::new(),
        }
    }
    fn at(&mut self, line: usize, msg: impl std::fmt::Display) {
        self.list.push(format!("{}:{line}: {msg}", self.file));
    }
    fn finish<T>(self, v: T) -> Result<T, ContractError> {
        if self.list.is_empty() {
            Ok(v)
        } else {
            Err(ContractError(self.list))
        }
    }
}

/// The side file's keys, read with line numbers.
struct Side {
    table: toml::Table,
    text: String,
}

impl Side {
    fn parse(text: &str, iss: &mut Issues) -> Option<Side> {
        match text.parse::<toml::Table>() {
            Ok(table) => Some(Side {
                table,
                text: text.to_string(),
            }),
            Err(e) => {
                let line = e
                    .span()
                    .map(|s| 1 + text[..s.start].matches('\n').count())
                    .unwrap_or(1);
                iss.at(line, format!("not valid TOML: {}", e.message()));
                None
            }
        }
    }
    /// Line of `key = …` (1 when absent).
    fn line(&self, key: &str) -> usize {
        self.text
            .lines()
            .position(|l| {
                l.trim_start()
                    .strip_prefix(key)
                    .is_some_and(|r| r.trim_start().starts_with('='))
            })
            .map_or(1, |i| i + 1)
    }
    fn num(&self, key: &str, required: bool, iss: &mut Issues) -> Option<f64> {
        match self.table.get(key) {
            Some(toml::Value::Float(f)) => Some(*f),
            Some(toml::Value::Integer(i)) => Some(*i as f64),
            Some(_) => {
                iss.at(self.line(key), format!("key `{key}`: expected a number"));
                None
            }
            None => {
                if required {
                    iss.at(1, format!("key `{key}` missing: expected a number"));
                }
                None
            }
        }
    }
    fn check_keys(&self, allowed: &[&str], iss: &mut Issues) {
        for k in self.table.keys() {
            if !allowed.contains(&k.as_str()) {
                iss.at(
                    self.line(k),
                    format!("unknown key `{k}`: expected one of {}", allowed.join(", ")),
                );
            }
        }
    }
    fn kind(&self, want: &str, iss: &mut Issues) {
        match self.table.get("kind").and_then(|v| v.as_str()) {
            Some(k) if k == want => {}
            Some(k) => iss.at(
                self.line("kind"),
                format!("key `kind`: is \"{k}\", expected \"{want}\""),
            ),
            None => iss.at(1, format!("key `kind` missing: expected \"{want}\"")),
        }
    }
}

/// A CSV's rows with column lookup and per-cell errors.
struct Rows {
    header: Vec<String>,
    rows: Vec<(usize, Vec<String>)>,
}

impl Rows {
    fn parse(text: &str, iss: &mut Issues) -> Option<Rows> {
        let mut rdr = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .comment(Some(b'#'))
            .from_reader(text.as_bytes());
        let header: Vec<String> = match rdr.headers() {
            Ok(h) => h.iter().map(str::to_string).collect(),
            Err(e) => {
                iss.at(1, format!("header: {e}"));
                return None;
            }
        };
        let mut rows = Vec::new();
        for rec in rdr.records() {
            match rec {
                Ok(r) => {
                    let line = r
                        .position()
                        .map_or(0, |p| usize::try_from(p.line()).unwrap_or(usize::MAX));
                    rows.push((line, r.iter().map(str::to_string).collect()));
                }
                Err(e) => {
                    let line = e
                        .position()
                        .map_or(0, |p| usize::try_from(p.line()).unwrap_or(usize::MAX));
                    iss.at(line, e);
                }
            }
        }
        Some(Rows { header, rows })
    }
    fn col(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }
    fn require(&self, names: &[&str], iss: &mut Issues) -> bool {
        let missing: Vec<&str> = names
            .iter()
            .copied()
            .filter(|n| self.col(n).is_none())
            .collect();
        if !missing.is_empty() {
            iss.at(
                1,
                format!(
                    "header: missing column(s) {}; found {}",
                    missing.join(", "),
                    self.header.join(",")
                ),
            );
        }
        missing.is_empty()
    }
}

fn cell_f64(
    row: &[String],
    col: Option<usize>,
    name: &str,
    line: usize,
    iss: &mut Issues,
) -> Option<f64> {
    let s = row.get(col?)?;
    if s.is_empty() {
        return None;
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Some(v),
        _ => {
            iss.at(
                line,
                format!("column `{name}`: `{s}` is not a finite number"),
            );
            None
        }
    }
}

const SCALE_COLS: [&str; 3] = ["T_scale_x_C", "T_scale_y_C", "T_scale_z_C"];

/// The hole-plate side file's keys: plane, expansion, certificate uncertainty and the scales'
/// expansion, each problem reported in `iss` (the defaults stand in for what is missing).
fn hole_plate_side(s: &Side, iss: &mut Issues) -> (Plane, f64, f64, Option<f64>) {
    let mut plane = Plane::Xy;
    s.check_keys(
        &[
            "kind",
            "plane",
            "alpha_ppm_per_K",
            "certificate_uncertainty_um",
            "scale_alpha_ppm_per_K",
        ],
        iss,
    );
    s.kind("hole_plate", iss);
    match s.table.get("plane").and_then(|v| v.as_str()) {
        Some(p) => match Plane::parse(p) {
            Some(p) => plane = p,
            None => iss.at(
                s.line("plane"),
                format!("key `plane`: \"{p}\", expected \"xy\", \"xz\" or \"yz\""),
            ),
        },
        None => iss.at(1, "key `plane` missing: expected \"xy\", \"xz\" or \"yz\""),
    }
    let alpha = s.num("alpha_ppm_per_K", true, iss).unwrap_or(0.0);
    let unc = s
        .num("certificate_uncertainty_um", true, iss)
        .unwrap_or(0.0);
    let scale_alpha = s.num("scale_alpha_ppm_per_K", false, iss);
    (plane, alpha, unc, scale_alpha)
}

/// Reads one hole-plate placement: CSV text and side-file text, `name` for messages (the stem).
pub fn read_hole_plate(name: &str, csv: &str, side: &str) -> Result<HolePlate, ContractError> {
    let mut iss = Issues::new(&format!("{name}.toml"));
    let s = Side::parse(side, &mut iss);
    let (plane, alpha, unc, scale_alpha) = match &s {
        Some(s) => hole_plate_side(s, &mut iss),
        None => (Plane::Xy, 0.0, 0.0, None),
    };
    let side_issues = iss.list;
    let mut iss = Issues::new(&format!("{name}.csv"));
    iss.list = side_issues;
    let mut probes = Vec::new();
    if let Some(rows) = Rows::parse(csv, &mut iss)
        && rows.require(&["hole", "u_mm", "v_mm", "x_mm", "y_mm", "z_mm"], &mut iss)
    {
        let c = |n: &str| rows.col(n);
        let scale_cols = SCALE_COLS.map(c);
        for (line, r) in &rows.rows {
            let line = *line;
            let req = |n: &str, iss: &mut Issues| {
                let v = cell_f64(r, c(n), n, line, iss);
                if v.is_none() && r.get(c(n).unwrap()).is_some_and(String::is_empty) {
                    iss.at(line, format!("column `{n}`: empty, expected a number"));
                }
                v
            };
            let (u, v) = (req("u_mm", &mut iss), req("v_mm", &mut iss));
            let (x, y, z) = (
                req("x_mm", &mut iss),
                req("y_mm", &mut iss),
                req("z_mm", &mut iss),
            );
            let tool = cell_f64(r, c("tool_mm"), "tool_mm", line, &mut iss).unwrap_or(0.0);
            let repeat = match c("repeat").and_then(|i| r.get(i)).filter(|s| !s.is_empty()) {
                None => 0,
                Some(s) => s.parse::<u32>().unwrap_or_else(|_| {
                    iss.at(
                        line,
                        format!("column `repeat`: `{s}` is not a count 0, 1, 2…"),
                    );
                    0
                }),
            };
            let t_plate = cell_f64(r, c("T_plate_C"), "T_plate_C", line, &mut iss);
            let t_scale =
                std::array::from_fn(|k| cell_f64(r, scale_cols[k], SCALE_COLS[k], line, &mut iss));
            let hole = r[c("hole").unwrap()].clone();
            if hole.is_empty() {
                iss.at(line, "column `hole`: empty, expected a hole name");
            }
            if t_scale.iter().any(Option::is_some) && scale_alpha.is_none() {
                iss.at(
                    line,
                    "scale temperature given: the side file needs `scale_alpha_ppm_per_K`",
                );
            }
            if let (Some(u), Some(v), Some(x), Some(y), Some(z)) = (u, v, x, y, z) {
                probes.push(HoleProbe {
                    hole,
                    uv_mm: [u, v],
                    pos_mm: [x, y, z],
                    tool_mm: tool,
                    repeat,
                    t_plate_c: t_plate,
                    t_scale_c: t_scale,
                    line,
                });
            }
        }
        if rows.rows.len() < 3 {
            iss.at(1, "fewer than 3 probings: a plate's pose needs 3");
        }
    }
    iss.finish(HolePlate {
        name: name.to_string(),
        plane,
        alpha_ppm_per_k: alpha,
        certificate_uncertainty_um: unc,
        scale_alpha_ppm_per_k: scale_alpha,
        probes,
    })
}

/// Reads one ball-bar set-up.
pub fn read_ballbar(name: &str, csv: &str, side: &str) -> Result<BallBar, ContractError> {
    let mut iss = Issues::new(&format!("{name}.toml"));
    let s = Side::parse(side, &mut iss);
    let (mut r_nom, mut centre, mut alpha, mut scale_alpha) = (0.0, [0.0; 3], 0.0, None);
    if let Some(s) = &s {
        s.check_keys(
            &[
                "kind",
                "r_nom_mm",
                "centre_mm",
                "alpha_ppm_per_K",
                "scale_alpha_ppm_per_K",
            ],
            &mut iss,
        );
        s.kind("ballbar", &mut iss);
        r_nom = s.num("r_nom_mm", true, &mut iss).unwrap_or(0.0);
        if s.table.contains_key("r_nom_mm") && r_nom <= 0.0 {
            iss.at(s.line("r_nom_mm"), "key `r_nom_mm`: expected > 0");
        }
        let arr: Option<Vec<f64>> = s.table.get("centre_mm").and_then(|v| {
            v.as_array()?
                .iter()
                .map(|x| x.as_float().or(x.as_integer().map(|i| i as f64)))
                .collect()
        });
        match arr {
            Some(a) if a.len() == 3 => centre = [a[0], a[1], a[2]],
            _ => iss.at(
                s.line("centre_mm"),
                "key `centre_mm`: expected [x, y, z] numbers",
            ),
        }
        alpha = s.num("alpha_ppm_per_K", true, &mut iss).unwrap_or(0.0);
        scale_alpha = s.num("scale_alpha_ppm_per_K", false, &mut iss);
    }
    let side_issues = iss.list;
    let mut iss = Issues::new(&format!("{name}.csv"));
    iss.list = side_issues;
    let mut points = Vec::new();
    if let Some(rows) = Rows::parse(csv, &mut iss)
        && rows.require(&["point", "x_mm", "y_mm", "z_mm", "dr_um"], &mut iss)
    {
        let c = |n: &str| rows.col(n);
        let scale_cols = SCALE_COLS.map(c);
        for (line, r) in &rows.rows {
            let line = *line;
            let req = |n: &str, iss: &mut Issues| {
                let v = cell_f64(r, c(n), n, line, iss);
                if v.is_none() && r.get(c(n).unwrap()).is_some_and(String::is_empty) {
                    iss.at(line, format!("column `{n}`: empty, expected a number"));
                }
                v
            };
            let (x, y, z, dr) = (
                req("x_mm", &mut iss),
                req("y_mm", &mut iss),
                req("z_mm", &mut iss),
                req("dr_um", &mut iss),
            );
            let tool = cell_f64(r, c("tool_mm"), "tool_mm", line, &mut iss).unwrap_or(0.0);
            let t_bar = cell_f64(r, c("T_bar_C"), "T_bar_C", line, &mut iss);
            let t_scale =
                std::array::from_fn(|k| cell_f64(r, scale_cols[k], SCALE_COLS[k], line, &mut iss));
            if t_scale.iter().any(Option::is_some) && scale_alpha.is_none() {
                iss.at(
                    line,
                    "scale temperature given: the side file needs `scale_alpha_ppm_per_K`",
                );
            }
            if let (Some(x), Some(y), Some(z), Some(dr)) = (x, y, z, dr) {
                points.push(BallPoint {
                    point: r[c("point").unwrap()].clone(),
                    pos_mm: [x, y, z],
                    dr_um: dr,
                    tool_mm: tool,
                    t_bar_c: t_bar,
                    t_scale_c: t_scale,
                    line,
                });
            }
        }
        if rows.rows.len() < 4 {
            iss.at(
                1,
                "fewer than 4 points: a sphere's centre needs 3 and one more",
            );
        }
    }
    iss.finish(BallBar {
        name: name.to_string(),
        r_nom_mm: r_nom,
        centre_mm: centre,
        alpha_ppm_per_k: alpha,
        scale_alpha_ppm_per_k: scale_alpha,
        points,
    })
}

/// Scale readings corrected to 20 °C: actual = reading·(1 + α·ΔT) per axis with a temperature.
pub fn scale_corrected(
    pos_mm: [f64; 3],
    t_scale_c: [Option<f64>; 3],
    alpha: Option<f64>,
) -> [f64; 3] {
    std::array::from_fn(|k| match (t_scale_c[k], alpha) {
        (Some(t), Some(a)) => pos_mm[k] * (1.0 + a * 1e-6 * (t - REFERENCE_C)),
        _ => pos_mm[k],
    })
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.3}")).unwrap_or_default()
}

impl HolePlate {
    /// The CSV and side-file texts of this placement (the contract's writer).
    pub fn to_texts(&self) -> (String, String) {
        let mut csv = String::from(
            "hole,u_mm,v_mm,x_mm,y_mm,z_mm,tool_mm,repeat,T_plate_C,T_scale_x_C,T_scale_y_C,T_scale_z_C\n",
        );
        for p in &self.probes {
            let _ = writeln!(
                csv,
                "{},{:.4},{:.4},{:.5},{:.5},{:.5},{:.3},{},{},{},{},{}",
                p.hole,
                p.uv_mm[0],
                p.uv_mm[1],
                p.pos_mm[0],
                p.pos_mm[1],
                p.pos_mm[2],
                p.tool_mm,
                p.repeat,
                opt(p.t_plate_c),
                opt(p.t_scale_c[0]),
                opt(p.t_scale_c[1]),
                opt(p.t_scale_c[2])
            );
        }
        let mut side = format!(
            "kind = \"hole_plate\"\nplane = \"{}\"\nalpha_ppm_per_K = {}\ncertificate_uncertainty_um = {}\n",
            self.plane.as_str(),
            self.alpha_ppm_per_k,
            self.certificate_uncertainty_um
        );
        if let Some(a) = self.scale_alpha_ppm_per_k {
            let _ = writeln!(side, "scale_alpha_ppm_per_K = {a}");
        }
        (csv, side)
    }
}

impl BallBar {
    pub fn to_texts(&self) -> (String, String) {
        let mut csv = String::from(
            "point,x_mm,y_mm,z_mm,dr_um,tool_mm,T_bar_C,T_scale_x_C,T_scale_y_C,T_scale_z_C\n",
        );
        for p in &self.points {
            let _ = writeln!(
                csv,
                "{},{:.5},{:.5},{:.5},{:.4},{:.3},{},{},{},{}",
                p.point,
                p.pos_mm[0],
                p.pos_mm[1],
                p.pos_mm[2],
                p.dr_um,
                p.tool_mm,
                opt(p.t_bar_c),
                opt(p.t_scale_c[0]),
                opt(p.t_scale_c[1]),
                opt(p.t_scale_c[2])
            );
        }
        let [cx, cy, cz] = self.centre_mm;
        let mut side = format!(
            "kind = \"ballbar\"\nr_nom_mm = {}\ncentre_mm = [{cx}, {cy}, {cz}]\nalpha_ppm_per_K = {}\n",
            self.r_nom_mm, self.alpha_ppm_per_k
        );
        if let Some(a) = self.scale_alpha_ppm_per_k {
            let _ = writeln!(side, "scale_alpha_ppm_per_K = {a}");
        }
        (csv, side)
    }
}
