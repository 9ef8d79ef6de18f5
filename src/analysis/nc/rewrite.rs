//! The rewriter: interprets parsed blocks with their modal state and emits the compensated program.
//!
//! - `commanded = nominal − error/1000` per axis (error in µm, positions in mm); on a lathe with
//!   diameter programming the X word is a diameter, so the X correction is doubled in the output.
//! - The approach direction of each axis is the sign of its motion in the move; an axis that does
//!   not move keeps its last direction (the overshoot moves before a measurement exist to set it).
//! - G1 moves longer than `split_step_mm` are split into equal pieces (Spaan Ch7: end-point-only
//!   compensation leaves the straightness error along the path); G2/G3 arcs are split by arc
//!   length into sub-arcs whose I/J/K point from the compensated start to the nominal centre;
//!   G0 is compensated at its end point only (its path is not controlled).
//! - Blocks without motion (dwells `G4`, M codes, comments) and moves ending outside the error
//!   function's domain (e.g. overshoot moves beyond the measured travel) are emitted verbatim.
//! - Output resolution is 0.1 µm (4 decimals in mm). A correction larger than
//!   `max_correction_um` or not finite stops the rewrite with the line number: a program is never
//!   written with a jump the model cannot justify.

use std::fmt::Write as _;

use super::parser::{Block, Word};
use super::{AXES, ErrorFunction};
use crate::analysis::table::Direction;

#[derive(Debug, Clone, PartialEq)]
pub struct RewriteConfig {
    /// X words are diameters (lathe / cylindrical grinder).
    pub diameter_x: bool,
    /// Split G1/G2/G3 moves into pieces no longer than this (mm); `None` = end points only.
    pub split_step_mm: Option<f64>,
    /// Largest |error| accepted from the model, µm.
    pub max_correction_um: f64,
    /// Accept G54–G59 and treat the program as if in machine coordinates (the offset is zero).
    pub allow_work_offsets: bool,
}

impl Default for RewriteConfig {
    fn default() -> Self {
        Self {
            diameter_x: false,
            split_step_mm: None,
            max_correction_um: 500.0,
            allow_work_offsets: false,
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RewriteStats {
    pub blocks_in: usize,
    pub moves_compensated: usize,
    pub points_emitted: usize,
    /// Moves left as programmed because their end point is outside the model's domain.
    pub moves_outside_domain: usize,
    pub max_abs_correction_um: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RewriteError {
    #[error("line {line}: G{code} is not supported by the rewriter ({why})")]
    Unsupported {
        line: u64,
        code: f64,
        why: &'static str,
    },
    #[error("line {line}: axis words without a motion mode (G0–G3) in effect")]
    NoMotionMode { line: u64 },
    #[error("line {line}: arc: {why}")]
    Arc { line: u64, why: String },
    #[error("line {line}: correction {value_um} µm on {axis} exceeds the limit of {limit_um} µm")]
    Limit {
        line: u64,
        axis: char,
        value_um: f64,
        limit_um: f64,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Motion {
    Rapid,
    Linear,
    Cw,
    Ccw,
}

/// Plane of G2/G3 as (first, second) axis indices, right-handed about the plane normal.
fn plane_axes(g: u32) -> (usize, usize) {
    match g {
        18 => (2, 0), // G18: Z, X (normal +Y)
        19 => (1, 2), // G19: Y, Z (normal +X)
        _ => (0, 1),  // G17: X, Y (normal +Z)
    }
}

struct State {
    nominal_mm: [Option<f64>; 3],
    commanded_mm: [f64; 3],
    dirs: [Direction; 3],
    motion: Option<Motion>,
    absolute: bool,
    plane: u32,
    ended: bool,
}

/// Rewrites `blocks` against `model`.
pub fn rewrite(
    blocks: &[Block],
    model: &dyn ErrorFunction,
    cfg: &RewriteConfig,
) -> Result<(String, RewriteStats), RewriteError> {
    let mut st = State {
        nominal_mm: [None; 3],
        commanded_mm: [0.0; 3],
        dirs: [Direction::Forward; 3],
        motion: None,
        absolute: true,
        plane: 17,
        ended: false,
    };
    let mut out = String::new();
    let mut stats = RewriteStats {
        blocks_in: blocks.len(),
        ..Default::default()
    };
    for b in blocks {
        if st.ended {
            let _ = writeln!(out, "{};", b.source);
            continue;
        }
        let has_axis = b.words.iter().any(|w| AXES.contains(&w.letter));
        let mut dwell = false;
        for g in b.g_codes() {
            let gi = g.round() as u32;
            if (g - f64::from(gi)).abs() > 1e-9 {
                return Err(RewriteError::Unsupported {
                    line: b.line,
                    code: g,
                    why: "fractional G codes are not interpreted",
                });
            }
            match gi {
                0 => st.motion = Some(Motion::Rapid),
                1 => st.motion = Some(Motion::Linear),
                2 => st.motion = Some(Motion::Cw),
                3 => st.motion = Some(Motion::Ccw),
                4 => dwell = true,
                17..=19 => st.plane = gi,
                90 => st.absolute = true,
                91 => st.absolute = false,
                21 | 40 | 49 | 61 | 64 | 80 | 94 | 95 | 96 | 97 => {}
                20 => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "inch programs: convert to mm first",
                    });
                }
                54..=59 if cfg.allow_work_offsets => {}
                54..=59 | 52 | 53 | 92 | 50 => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "coordinate systems: the rewriter needs machine coordinates; expand the offset first",
                    });
                }
                41..=44 => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "tool compensation: expand to tool-centre paths first",
                    });
                }
                28..=30 => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "reference-point returns move through unknown points",
                    });
                }
                51 | 68 | 73..=89 | 70..=72 => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "scaling, rotation and canned cycles must be expanded first",
                    });
                }
                _ if has_axis => {
                    return Err(RewriteError::Unsupported {
                        line: b.line,
                        code: g,
                        why: "unknown G code in a block with axis words",
                    });
                }
                _ => {}
            }
        }
        if b.get('M')
            .is_some_and(|m| m.value == 30.0 || m.value == 2.0)
        {
            st.ended = true;
        }
        if dwell || !has_axis {
            let _ = writeln!(out, "{};", b.source);
            continue;
        }
        let Some(motion) = st.motion else {
            return Err(RewriteError::NoMotionMode { line: b.line });
        };
        emit_move(&mut out, &mut stats, &mut st, b, motion, model, cfg)?;
    }
    Ok((out, stats))
}

/// Value of the axis word in internal (radial) mm.
fn word_mm(w: &Word, k: usize, cfg: &RewriteConfig) -> f64 {
    if k == 0 && cfg.diameter_x {
        w.value / 2.0
    } else {
        w.value
    }
}

fn emit_move(
    out: &mut String,
    stats: &mut RewriteStats,
    st: &mut State,
    b: &Block,
    motion: Motion,
    model: &dyn ErrorFunction,
    cfg: &RewriteConfig,
) -> Result<(), RewriteError> {
    let start: [f64; 3] = std::array::from_fn(|k| st.nominal_mm[k].unwrap_or(0.0));
    let mut end = start;
    let mut present = [false; 3];
    for (k, &a) in AXES.iter().enumerate() {
        if let Some(w) = b.get(a) {
            let v = word_mm(w, k, cfg);
            end[k] = if st.absolute { v } else { start[k] + v };
            present[k] = true;
        }
    }
    // Sub-points (end of each piece) with the direction of motion arriving there, and for arcs the
    // centre.
    let mut pieces: Vec<([f64; 3], [Option<Direction>; 3])> = Vec::new();
    let mut centre: Option<[f64; 3]> = None;
    let sign_dir = |d: f64| {
        if d.abs() < 1e-9 {
            None
        } else if d > 0.0 {
            Some(Direction::Forward)
        } else {
            Some(Direction::Reverse)
        }
    };
    match motion {
        Motion::Rapid | Motion::Linear => {
            let len = (0..3)
                .map(|k| (end[k] - start[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            let n = match (motion, cfg.split_step_mm) {
                (Motion::Linear, Some(step)) if step > 0.0 => (len / step).ceil().max(1.0) as usize,
                _ => 1,
            };
            let d: [Option<Direction>; 3] = std::array::from_fn(|k| sign_dir(end[k] - start[k]));
            for i in 1..=n {
                let f = i as f64 / n as f64;
                pieces.push((
                    std::array::from_fn(|k| start[k] + f * (end[k] - start[k])),
                    d,
                ));
            }
        }
        Motion::Cw | Motion::Ccw => {
            let (a, bb) = plane_axes(st.plane);
            let c = arc_centre(b, start, end, (a, bb), motion)?;
            let r0 = ((start[a] - c[a]).powi(2) + (start[bb] - c[bb]).powi(2)).sqrt();
            let th0 = (start[bb] - c[bb]).atan2(start[a] - c[a]);
            let mut th1 = (end[bb] - c[bb]).atan2(end[a] - c[a]);
            let ccw = motion == Motion::Ccw;
            if ccw {
                while th1 <= th0 + 1e-12 {
                    th1 += std::f64::consts::TAU;
                }
            } else {
                while th1 >= th0 - 1e-12 {
                    th1 -= std::f64::consts::TAU;
                }
            }
            let sweep = th1 - th0;
            let n = match cfg.split_step_mm {
                Some(step) if step > 0.0 => ((sweep.abs() * r0) / step).ceil().max(1.0) as usize,
                _ => 1,
            };
            for i in 1..=n {
                let f = i as f64 / n as f64;
                let th = th0 + f * sweep;
                let mut p: [f64; 3] = std::array::from_fn(|k| start[k] + f * (end[k] - start[k])); // helix axis linear
                if i == n {
                    p[a] = end[a];
                    p[bb] = end[bb];
                } else {
                    p[a] = c[a] + r0 * th.cos();
                    p[bb] = c[bb] + r0 * th.sin();
                }
                // Tangent of the motion at this point.
                let s = if ccw { 1.0 } else { -1.0 };
                let mut d: [Option<Direction>; 3] =
                    std::array::from_fn(|k| sign_dir(end[k] - start[k]));
                d[a] = sign_dir(-s * th.sin());
                d[bb] = sign_dir(s * th.cos());
                pieces.push((p, d));
            }
            centre = Some(c);
        }
    }
    // Evaluate all pieces first: the whole move is either compensated or (end outside the domain)
    // left verbatim.
    let mut comp: Vec<[f64; 3]> = Vec::with_capacity(pieces.len());
    let mut dirs = st.dirs;
    let mut outside = false;
    for (p, d) in &pieces {
        for k in 0..3 {
            if let Some(dk) = d[k] {
                dirs[k] = dk;
            }
        }
        match model.error_um(*p, dirs) {
            Some(e) => {
                let mut c = *p;
                for k in 0..3 {
                    if !e[k].is_finite() || e[k].abs() > cfg.max_correction_um {
                        return Err(RewriteError::Limit {
                            line: b.line,
                            axis: AXES[k],
                            value_um: e[k],
                            limit_um: cfg.max_correction_um,
                        });
                    }
                    c[k] = p[k] - e[k] / 1000.0;
                    stats.max_abs_correction_um = stats.max_abs_correction_um.max(e[k].abs());
                }
                comp.push(c);
            }
            None => {
                outside = true;
                comp.push(*p);
            }
        }
    }
    st.dirs = dirs;
    for k in 0..3 {
        if present[k] {
            st.nominal_mm[k] = Some(end[k]);
        }
    }
    let end_outside = model.error_um(end, dirs).is_none();
    if outside && end_outside && pieces.len() == 1 {
        stats.moves_outside_domain += 1;
        let _ = writeln!(out, "{};", b.source);
        st.commanded_mm = end;
        stats.points_emitted += 1;
        return Ok(());
    }
    stats.moves_compensated += 1;
    let known: [bool; 3] = std::array::from_fn(|k| st.nominal_mm[k].is_some());
    let (pa, pb) = plane_axes(st.plane);
    for (i, c) in comp.iter().enumerate() {
        let mut line = String::new();
        if i == 0 {
            for w in b.words.iter().filter(|w| matches!(w.letter, 'N' | 'G')) {
                let _ = write!(line, "{}{} ", w.letter, w.text);
            }
        }
        for k in 0..3 {
            if !known[k] {
                continue;
            }
            let v = if st.absolute {
                c[k]
            } else {
                c[k] - st.commanded_mm[k]
            };
            let v = if k == 0 && cfg.diameter_x { 2.0 * v } else { v };
            let _ = write!(line, "{}{} ", AXES[k], fmt_mm(v));
        }
        if let Some(ctr) = centre {
            // I/J/K from the compensated start of this piece to the nominal centre.
            let from = if i == 0 { st.commanded_mm } else { comp[i - 1] };
            for k in [pa, pb] {
                let letter = ['I', 'J', 'K'][k];
                let _ = write!(line, "{letter}{} ", fmt_mm(ctr[k] - from[k]));
            }
        }
        if i == 0 {
            for w in b.words.iter().filter(|w| {
                !matches!(
                    w.letter,
                    'N' | 'G' | 'X' | 'Y' | 'Z' | 'I' | 'J' | 'K' | 'R'
                )
            }) {
                let _ = write!(line, "{}{} ", w.letter, w.text);
            }
        }
        let _ = writeln!(out, "{};", line.trim_end());
        stats.points_emitted += 1;
    }
    st.commanded_mm = *comp.last().expect("at least one piece");
    Ok(())
}

/// Arc centre from R (perpendicular bisector) or I/J/K (incremental from the start; on a lathe I
/// is a radius value, like the internal X).
fn arc_centre(
    b: &Block,
    start: [f64; 3],
    end: [f64; 3],
    (a, bb): (usize, usize),
    motion: Motion,
) -> Result<[f64; 3], RewriteError> {
    let ijk = ['I', 'J', 'K'];
    let mut c = start;
    if let Some(r) = b.get('R') {
        // Centre on the perpendicular bisector; R < 0 selects the arc longer than 180°.
        let (dx, dy) = (end[a] - start[a], end[bb] - start[bb]);
        let d = (dx * dx + dy * dy).sqrt();
        let rr = r.value.abs();
        if d < 1e-12 || d > 2.0 * rr + 1e-9 {
            return Err(RewriteError::Arc {
                line: b.line,
                why: format!("radius {} cannot join points {d:.4} mm apart", r.value),
            });
        }
        let h = (rr * rr - d * d / 4.0).max(0.0).sqrt();
        let (mx, my) = (start[a] + dx / 2.0, start[bb] + dy / 2.0);
        let (ux, uy) = (-dy / d, dx / d); // left normal of the chord
        let left = (motion == Motion::Ccw) == (r.value > 0.0);
        let s = if left { 1.0 } else { -1.0 };
        c[a] = mx + s * h * ux;
        c[bb] = my + s * h * uy;
        return Ok(c);
    }
    let mut any = false;
    for k in [a, bb] {
        if let Some(w) = b.get(ijk[k]) {
            c[k] = start[k] + w.value;
            any = true;
        }
    }
    if !any {
        return Err(RewriteError::Arc {
            line: b.line,
            why: "needs I/J/K or R".to_string(),
        });
    }
    let r0 = ((start[a] - c[a]).powi(2) + (start[bb] - c[bb]).powi(2)).sqrt();
    let r1 = ((end[a] - c[a]).powi(2) + (end[bb] - c[bb]).powi(2)).sqrt();
    if (r0 - r1).abs() > 1e-3 {
        return Err(RewriteError::Arc {
            line: b.line,
            why: format!("start radius {r0:.4} and end radius {r1:.4} differ"),
        });
    }
    Ok(c)
}

/// mm with 4 decimals (0.1 µm), `-0.0000` printed as `0.0000`.
pub fn fmt_mm(v: f64) -> String {
    let s = format!("{v:.4}");
    if s == "-0.0000" {
        "0.0000".to_string()
    } else {
        s
    }
}
