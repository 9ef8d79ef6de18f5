//! What an identification from hole plates can vouch for on plates it was not given, and the
//! set-up that would widen it (issue 37 point 5):
//! - probe lengths (Abbe arms along the tool): the identification's shortest to longest probe. The
//!   model's rotation terms act linearly in the probe length, so beyond that range it extrapolates
//!   them; with a probe range of 150 mm it is not asked to vouch for 30 or 350 mm;
//! - for a plane whose squareness sits in an unseen combination ([`super::report::components`]:
//!   rigid on every plate of that plane measured so far), plates of that plane only at the
//!   positions across the plane that were measured: elsewhere the combination shows.
//!
//! Positions and probe lengths in mm.

use serde::Serialize;

use super::Identification;
use super::design::SQUARENESS;
use super::report::SquarenessReport;

/// A plane whose plates are vouched for only where they were measured.
#[derive(Debug, Clone, Serialize)]
pub struct LimitedPlane {
    /// "xz"
    pub plane: String,
    /// The axis across the plane ('y' for xz).
    pub across: char,
    /// Positions along `across` of the identification plates in that plane, mm (rounded to 1 mm).
    pub at_mm: Vec<f64>,
    pub squareness: &'static str,
}

#[derive(Debug, Clone, Serialize)]
pub struct Vouch {
    /// Shortest and longest probe of the identification plates, mm (None: no plates).
    pub probe_mm: Option<(f64, f64)>,
    pub limited_planes: Vec<LimitedPlane>,
    /// One sentence each: what is vouched for, and what would widen it.
    pub statement: String,
    pub widen: Vec<String>,
}

/// Per hole-plate set-up: its in-plane axes, its mean position across the plane, its probe.
fn plates(id: &Identification) -> Vec<([usize; 2], f64, f64)> {
    let mut out = vec![];
    for (k, s) in id.setups.iter().enumerate() {
        if s.kind != "hole_plate" {
            continue;
        }
        let obs: Vec<_> = id.obs.iter().filter(|o| o.artefact == k).collect();
        let mut dirs: Vec<usize> = obs.iter().filter_map(|o| o.dir).collect();
        dirs.sort_unstable();
        dirs.dedup();
        if dirs.len() != 2 || obs.is_empty() {
            continue;
        }
        let c = 3 - dirs[0] - dirs[1];
        let n = obs.len() as f64;
        let across = obs.iter().map(|o| o.pos_mm[c]).sum::<f64>() / n;
        let tool = obs.iter().map(|o| o.tool_mm).sum::<f64>() / n;
        out.push(([dirs[0], dirs[1]], across, tool));
    }
    out
}

/// What `id` vouches for, given its squareness verdicts.
pub fn vouch(id: &Identification, sq: &[SquarenessReport]) -> Vouch {
    let ps = plates(id);
    let probe_mm = ps
        .iter()
        .map(|p| p.2)
        .fold(None, |r: Option<(f64, f64)>, t| {
            Some(r.map_or((t, t), |(a, b)| (a.min(t), b.max(t))))
        });
    let mut limited_planes = vec![];
    for (q, rep) in SQUARENESS.iter().zip(sq) {
        if rep.identifiable {
            continue;
        }
        let (a, b, across) = q.axes();
        let mut ab = [a.index(), b.index()];
        ab.sort_unstable();
        let mut at_mm: Vec<f64> = ps
            .iter()
            .filter(|p| p.0 == ab)
            .map(|p| p.1.round())
            .collect();
        at_mm.sort_by(f64::total_cmp);
        at_mm.dedup();
        limited_planes.push(LimitedPlane {
            plane: format!("{}{}", a.lower(), b.lower()),
            across: across.lower(),
            at_mm,
            squareness: rep.name,
        });
    }
    let mut statement = match probe_mm {
        Some((lo, hi)) => format!(
            "vouched for: plates probed with probes of {lo:.0}–{hi:.0} mm (the identification's); \
             beyond, the Abbe terms are extrapolated linearly in the probe length"
        ),
        None => "vouched for: no hole plates, so no probe range".to_string(),
    };
    let mut widen = vec![];
    if let Some((lo, hi)) = probe_mm {
        widen.push(format!(
            "to vouch for shorter or longer probes, probe one placement per plane also with the \
             shortest and the longest probe to be used (below {lo:.0} mm, above {hi:.0} mm)"
        ));
    }
    for l in &limited_planes {
        let at: Vec<String> = l.at_mm.iter().map(|v| format!("{v:.0}")).collect();
        statement.push_str(&format!(
            "; {} plates only at {} = {} mm (the {} squareness is in a combination no {} plate so \
             far sees)",
            l.plane,
            l.across,
            at.join(", "),
            l.squareness,
            l.plane
        ));
        widen.push(format!(
            "for {} plates at other {} positions: one more {} plate at another {} (e.g. the far \
             end of its travel)",
            l.plane, l.across, l.plane, l.across
        ));
    }
    Vouch {
        probe_mm,
        limited_planes,
        statement,
        widen,
    }
}
