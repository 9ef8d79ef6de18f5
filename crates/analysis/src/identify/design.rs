//! The design matrix of the joint artefact fit ΔP = Xβ + γ (Spaan Ch3).
//!
//! β: per component, a C¹ piecewise quadratic in its own axis position q, measured from the low
//! end `lo` of the identified range (so every component is 0 at `lo`, the gauge artefacts cannot
//! see): `a1·(q−lo) + a2·(q−lo)² + Σ c_i (q−t_i)₊²`; with `--lead-mm L` a positioning component
//! also carries a lead wave `s·(sin ωq − sin ωlo) + c·(cos ωq − cos ωlo)`, ω = 2π/L, q from the
//! axis' 0 (`fit::lead`), two more linear columns between the quadratic and the knots; straightness components have no linear term,
//! their slope is a squareness (EC0Y ≡ slope of EXY, EB0Z of EXZ, EA0Z of EYZ; the slopes of EYX,
//! EZX, EZY are a rotation of the artefact and fixed at 0). Then the three squareness angles.
//! γ: per hole plate its in-plane translation (2, µm) and rotation (1, µrad), per ball-bar sphere
//! its centre (3, µm).
//!
//! Each observation is one number y = n·e(r) + γ-terms, e the first-order tool-tip error
//! (actual − nominal, µm) of the chain at the machine position r: Σ δ_K + ε_K × arm_K + squareness
//! (the same closed form as `models::kinematics`). Translations in µm, rotations in µrad, µrad·mm =
//! 1e-3 µm.

use retrocomp_model::kinematics::{Elem, arms, cross};
use retrocomp_model::{Axis, ComponentId, MachineModel, ModelSpec, Motion};

/// Which kind of basis a component gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    /// EXX, EYY, EZZ: linear + quadratic + knots.
    Positioning,
    /// Translation across the axis: quadratic + knots (slope = squareness or artefact rotation).
    Straightness,
    /// Rotations: linear + quadratic + knots (the constant is a rigid rotation of the artefact).
    Rotation,
}

/// The basis of one component.
#[derive(Debug, Clone, PartialEq)]
pub struct CompBasis {
    pub id: ComponentId,
    pub shape: Shape,
    /// Identified range of the axis, mm.
    pub lo_mm: f64,
    pub hi_mm: f64,
    pub knots_mm: Vec<f64>,
    /// Lead of a ball-screw wave fitted as a sin/cos pair (positioning components only), mm.
    pub lead_mm: Option<f64>,
}

impl CompBasis {
    /// Terms before the knots: linear (not straightness), quadratic, the lead pair.
    fn n_smooth(&self) -> usize {
        let lin = usize::from(self.shape != Shape::Straightness);
        lin + 1 + if self.lead_mm.is_some() { 2 } else { 0 }
    }

    pub fn n_terms(&self) -> usize {
        self.n_smooth() + self.knots_mm.len()
    }

    /// Index of the lead wave's sin coefficient within this component's terms (cos follows).
    pub fn lead_term(&self) -> Option<usize> {
        self.lead_mm.map(|_| self.n_smooth() - 2)
    }

    /// Basis values at q (µm or µrad per unit coefficient), appended to `out`.
    pub fn values(&self, q_mm: f64, out: &mut Vec<f64>) {
        let q = q_mm.clamp(self.lo_mm, self.hi_mm);
        let d = q - self.lo_mm;
        if self.shape != Shape::Straightness {
            out.push(d);
        }
        out.push(d * d);
        if let Some(lead) = self.lead_mm {
            let [s0, c0] = crate::fit::lead::columns(lead, self.lo_mm);
            let [s, c] = crate::fit::lead::columns(lead, q);
            out.extend([s - s0, c - c0]);
        }
        for &t in &self.knots_mm {
            let k = (q - t).max(0.0);
            out.push(k * k);
        }
    }

    /// Term names for reports: `lin`, `quad`, `sin@L`, `cos@L`, `knot@t`.
    pub fn term_names(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.shape != Shape::Straightness {
            v.push("lin".to_string());
        }
        v.push("quad".to_string());
        if let Some(l) = self.lead_mm {
            v.extend([format!("sin@{l}"), format!("cos@{l}")]);
        }
        v.extend(self.knots_mm.iter().map(|t| format!("knot@{t:.0}")));
        v
    }

    /// Value of the component for coefficients `c` at q.
    pub fn eval(&self, c: &[f64], q_mm: f64) -> f64 {
        let mut b = Vec::with_capacity(c.len());
        self.values(q_mm, &mut b);
        b.iter().zip(c).map(|(b, c)| b * c).sum()
    }
}

/// The squareness angles in β's order.
pub(super) const SQUARENESS: [retrocomp_model::Squareness; 3] = [
    retrocomp_model::Squareness::EC0Y,
    retrocomp_model::Squareness::EB0Z,
    retrocomp_model::Squareness::EA0Z,
];

/// The chain as the fit sees it: elements in chain order, the tool direction.
#[derive(Debug, Clone)]
pub struct Geometry {
    pub spec: ModelSpec,
    elems: Vec<Elem>,
    /// Unit vector along which `tool_mm` points from the spindle to the tip (mill: −z).
    pub tool_dir: [f64; 3],
}

#[derive(Debug, thiserror::Error)]
pub enum ChainError {
    #[error("--chain `{0}`: {1}")]
    Bad(String, String),
}

impl Geometry {
    /// From a chain such as `X F Y Z` (three linear axes); the tool points along −(last axis).
    pub fn from_chain(chain: &str) -> Result<Geometry, ChainError> {
        let toks: Vec<&str> = chain.split_whitespace().collect();
        let last = toks
            .iter()
            .rev()
            .find(|t| **t != "F")
            .map(|t| t.to_lowercase())
            .unwrap_or_else(|| "z".into());
        let text = format!(
            "schema = 1\n[machine]\nname = \"identified\"\nchain = \"{chain}\"\ntool_axis = \"-{last}\"\n\
             [[tools]]\nname = \"probe\"\noffset_mm = [0.0, 0.0, 0.0]\n"
        );
        let model = MachineModel::from_toml_str(&text, "--chain")
            .map_err(|e| ChainError::Bad(chain.into(), e.to_string()))?;
        let spec = model.spec().clone();
        if spec.axes.len() != 3 {
            return Err(ChainError::Bad(
                chain.into(),
                "artefact identification needs the three axes X, Y, Z".into(),
            ));
        }
        let elems = spec.axes.iter().map(Elem::untilted).collect();
        let mut tool_dir = [0.0; 3];
        tool_dir[spec.tool_axis.0.index()] = spec.tool_axis.1;
        Ok(Geometry {
            spec,
            elems,
            tool_dir,
        })
    }

    /// Abbe arm (mm) of each machine axis (indexed x, y, z) at r with a probe `tool_mm` long.
    pub fn arms_by_axis(&self, pos_mm: [f64; 3], tool_mm: f64) -> [[f64; 3]; 3] {
        let q: [f64; 3] = std::array::from_fn(|j| pos_mm[self.elems[j].axis.index()]);
        let t = self.tool_dir.map(|d| d * tool_mm);
        let mut out = [[0.0; 3]; 3];
        arms(&self.elems, &q, t, &mut out);
        let mut by_axis = [[0.0; 3]; 3];
        for (j, e) in self.elems.iter().enumerate() {
            by_axis[e.axis.index()] = out[j];
        }
        by_axis
    }
}

/// The 18 components with their bases over the identified ranges; candidate knots every
/// `knot_step_mm` (at most `max_knots` per axis, evenly spread); positioning components carry a
/// lead wave at `lead_mm` when given.
pub(super) fn component_bases(
    range_mm: [(f64, f64); 3],
    knot_step_mm: f64,
    max_knots: usize,
    lead_mm: Option<f64>,
) -> Vec<CompBasis> {
    let mut v = Vec::new();
    for axis in Axis::ALL {
        let (lo, hi) = range_mm[axis.index()];
        let n = crate::numeric::ceil_usize((hi - lo) / knot_step_mm)
            .saturating_sub(1)
            .min(max_knots);
        let knots: Vec<f64> = (1..=n)
            .map(|k| lo + (hi - lo) * k as f64 / (n + 1) as f64)
            .collect();
        for slot in 0..6 {
            let d = Axis::ALL[slot % 3];
            let (motion, shape) = if slot < 3 {
                let s = if d == axis {
                    Shape::Positioning
                } else {
                    Shape::Straightness
                };
                (Motion::Translation(d), s)
            } else {
                (Motion::Rotation(d), Shape::Rotation)
            };
            v.push(CompBasis {
                id: ComponentId { axis, motion },
                shape,
                lo_mm: lo,
                hi_mm: hi,
                knots_mm: knots.clone(),
                lead_mm: lead_mm.filter(|_| shape == Shape::Positioning),
            });
        }
    }
    v
}

/// Error (µm) per unit of each squareness angle (µrad) at r (model convention, docs/model.md).
pub(super) fn squareness_rows(pos_mm: [f64; 3]) -> [[f64; 3]; 3] {
    let [_, y, z] = pos_mm;
    [
        [-y * 1e-3, 0.0, 0.0], // EC0Y on y: ex = −S·y
        [z * 1e-3, 0.0, 0.0],  // EB0Z on z: ex = +S·z
        [0.0, -z * 1e-3, 0.0], // EA0Z on z: ey = −S·z
    ]
}

/// One observation: y = n·e(r) + Σ setup terms.
#[derive(Debug, Clone, PartialEq)]
pub struct Obs {
    pub pos_mm: [f64; 3],
    pub tool_mm: f64,
    pub n: [f64; 3],
    pub y_um: f64,
    /// (column within γ, coefficient).
    pub setup: Vec<(usize, f64)>,
    /// Which artefact (index into the fit's set-up list) and which probing (for outliers).
    pub artefact: usize,
    pub key: String,
    pub repeat: u32,
    /// Machine axis of a hole-plate row (None for ball-bar rows).
    pub dir: Option<usize>,
}

/// Fills one design row: β columns of `bases` (in order), 3 squareness, then γ at `beta_len + 3`.
pub(super) fn fill_row(geo: &Geometry, bases: &[CompBasis], o: &Obs, row: &mut [f64]) {
    row.fill(0.0);
    let arms = geo.arms_by_axis(o.pos_mm, o.tool_mm);
    let mut col = 0;
    let mut b = Vec::with_capacity(16);
    for c in bases {
        b.clear();
        c.values(o.pos_mm[c.id.axis.index()], &mut b);
        let g = match c.id.motion {
            Motion::Translation(d) => o.n[d.index()],
            Motion::Rotation(d) => {
                let mut e = [0.0; 3];
                e[d.index()] = 1e-3;
                let v = cross(e, arms[c.id.axis.index()]);
                o.n[0] * v[0] + o.n[1] * v[1] + o.n[2] * v[2]
            }
        };
        for v in &b {
            row[col] = g * v;
            col += 1;
        }
    }
    for s in squareness_rows(o.pos_mm) {
        row[col] = o.n[0] * s[0] + o.n[1] * s[1] + o.n[2] * s[2];
        col += 1;
    }
    for &(k, v) in &o.setup {
        row[col + k] = v;
    }
}
