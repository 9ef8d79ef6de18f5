//! Motion blocks for the rewriter: pieces of lines and arcs (machine coordinates, X radial),
//! their approach directions, compensation (`target = nominal − error/1000`), and the words
//! written for each piece (program coordinates, 4 decimals, G91 relative to the previous piece as
//! written). Arc centres are moved so both compensated ends lie on one circle (see rewrite.rs).

use super::AXES;
use super::parser::Block;
use super::rewrite::{Motion, Point, RewriteError, RewriteSink, Rewriter};
use crate::table::Direction;

/// Radius mismatch of a nominal arc the controller accepts (LinuxCNC 2.9: 0.0283 mm and 0.1 %);
/// a program beyond it is refused as the controller would.
const ARC_RADIUS_TOL_MM: f64 = 0.0283;
const ARC_RADIUS_TOL_REL: f64 = 0.001;

/// Plane of G2/G3 as (first, second) axis indices, right-handed about the plane normal.
fn plane_axes(g: u32) -> (usize, usize) {
    match g {
        18 => (2, 0), // G18: Z, X (normal +Y)
        19 => (1, 2), // G19: Y, Z (normal +X)
        _ => (0, 1),  // G17: X, Y (normal +Z)
    }
}

fn sign_dir(d: f64, tol: f64) -> Option<Direction> {
    if d.abs() <= tol {
        None
    } else if d > 0.0 {
        Some(Direction::Forward)
    } else {
        Some(Direction::Reverse)
    }
}

/// Rounds to the output resolution (0.1 µm).
fn round4(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

/// mm with 4 decimals (0.1 µm), `-0.0000` printed as `0.0000`.
fn fmt_mm(v: f64) -> String {
    let s = format!("{v:.4}");
    if s == "-0.0000" {
        "0.0000".to_string()
    } else {
        s
    }
}

/// The arc a piece belongs to, for its centre words.
struct ArcPiece {
    plane: (usize, usize),
    centre_mm: [f64; 3],
    /// Sweep of this piece, rad (sign: + CCW).
    sweep: f64,
    r_format: bool,
}

/// One point to write.
struct Piece<'p> {
    nominal: [f64; 3],
    known: [bool; 3],
    dirs: [Option<Direction>; 3],
    first: bool,
    compensate: bool,
    arc: Option<&'p ArcPiece>,
}

impl Rewriter<'_> {
    fn pieces_for(&self, line: u64, length_mm: f64) -> Result<usize, RewriteError> {
        let Some(step) = self.cfg.split_step_mm else {
            return Ok(1);
        };
        let n = (length_mm / step).ceil().max(1.0);
        if n > self.cfg.max_pieces_per_move as f64 || !n.is_finite() {
            return Err(RewriteError::TooManyPieces {
                line,
                length_mm,
                step_mm: step,
                pieces: n,
                limit: self.cfg.max_pieces_per_move,
            });
        }
        Ok(crate::numeric::trunc_usize(n))
    }

    pub(super) fn motion_block(
        &mut self,
        b: &Block,
        motion: Motion,
        sink: &mut dyn RewriteSink,
    ) -> Result<(), RewriteError> {
        let start = self.st.nominal_mm;
        let mut end = start;
        let mut present = [false; 3];
        for (k, &a) in AXES.iter().enumerate() {
            if let Some(w) = b.get(a) {
                present[k] = true;
                end[k] = self.word_target(w, k);
            }
        }
        let model_axes = self.model.axes();
        let split = motion == Motion::Linear && self.cfg.split_step_mm.is_some();
        if self.st.inverse_time && split {
            return Err(RewriteError::Refused {
                line: b.line,
                why: "G93 inverse-time feed: splitting would change every piece's duration; rewrite without --split-mm".into(),
            });
        }
        if matches!(motion, Motion::Cw | Motion::Ccw) {
            return self.arc_block(b, motion, start, end, present, sink);
        }
        let needs_start = |k: usize| model_axes[k] || present[k];
        if split && let Some(k) = (0..3).find(|&k| needs_start(k) && start[k].is_none()) {
            return Err(RewriteError::UnknownStart {
                line: b.line,
                axis: AXES[k],
                why: "a split feed move",
            });
        }
        let known: [bool; 3] = std::array::from_fn(|k| end[k].is_some());
        let s = start.map(|v| v.unwrap_or(0.0));
        let e = end.map(|v| v.unwrap_or(0.0));
        if (0..3).any(|k| model_axes[k] && !known[k]) {
            // Unsplit line ending where the model cannot be evaluated: never guess a position.
            self.stats.moves_unknown_start += 1;
            return self.keep_line(b, e, known, present, sink);
        }
        let len = (0..3)
            .filter(|&k| start[k].is_some() && known[k])
            .map(|k| (e[k] - s[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let n = if split {
            self.pieces_for(b.line, len)?
        } else {
            1
        };
        let dirs: [Option<Direction>; 3] = std::array::from_fn(|k| {
            if start[k].is_some() && known[k] {
                sign_dir(e[k] - s[k], 1e-9)
            } else {
                None
            }
        });
        if n == 1 && self.st.absolute && self.model.error_um(e, self.dirs_with(dirs)).is_none() {
            self.stats.moves_outside_domain += 1;
            self.st.dirs = self.dirs_with(dirs);
            return self.keep_line(b, e, known, present, sink);
        }
        let mut outside = false;
        for i in 1..=n {
            let f = i as f64 / n as f64;
            let p: [f64; 3] = std::array::from_fn(|k| {
                if i == n {
                    e[k]
                } else {
                    s[k] + f * (e[k] - s[k])
                }
            });
            let piece = Piece {
                nominal: p,
                known,
                dirs,
                first: i == 1,
                compensate: true,
                arc: None,
            };
            outside = !self.emit_piece(b, &piece, present, sink)?;
        }
        if outside {
            self.stats.moves_outside_domain += 1;
        } else {
            self.stats.moves_compensated += 1;
        }
        Ok(())
    }

    fn dirs_with(&self, d: [Option<Direction>; 3]) -> [Direction; 3] {
        std::array::from_fn(|k| d[k].unwrap_or(self.st.dirs[k]))
    }

    /// A line written so it ends on its nominal end point (as programmed): the source itself in
    /// G90 when every known axis already stands on its nominal position, else (G91, or an axis
    /// the block does not name still carrying the previous point's correction) every known axis
    /// written at its nominal position.
    fn keep_line(
        &mut self,
        b: &Block,
        e: [f64; 3],
        known: [bool; 3],
        present: [bool; 3],
        sink: &mut dyn RewriteSink,
    ) -> Result<(), RewriteError> {
        let off_nominal = (0..3).any(|k| {
            known[k]
                && !present[k]
                && self.st.commanded_mm[k]
                    .is_some_and(|c| (round4(c) - round4(e[k])).abs() > 0.5e-4)
        });
        if self.st.absolute && !off_nominal {
            sink.line(&format!("{};", b.source))?;
            for k in (0..3).filter(|&k| present[k]) {
                self.st.nominal_mm[k] = Some(e[k]);
                self.st.commanded_mm[k] = Some(e[k]);
            }
            self.stats.points_emitted += 1;
            sink.point(&Point {
                line: b.line,
                move_index: self.st.move_index,
                nominal_mm: e,
                dirs: self.st.dirs,
                compensated: false,
            })?;
            return Ok(());
        }
        let piece = Piece {
            nominal: e,
            known,
            dirs: [None; 3],
            first: true,
            compensate: false,
            arc: None,
        };
        self.emit_piece(b, &piece, present, sink)?;
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    #[allow(
        clippy::float_cmp,
        reason = "a P word is parsed from decimal text: P1 reads as exactly 1.0"
    )]
    fn arc_block(
        &mut self,
        b: &Block,
        motion: Motion,
        start: [Option<f64>; 3],
        end: [Option<f64>; 3],
        present: [bool; 3],
        sink: &mut dyn RewriteSink,
    ) -> Result<(), RewriteError> {
        let line = b.line;
        let model_axes = self.model.axes();
        let (a, bb) = plane_axes(self.st.plane);
        let h = 3 - a - bb;
        if let Some(k) = (0..3)
            .find(|&k| (k == a || k == bb || model_axes[k] || present[k]) && start[k].is_none())
        {
            return Err(RewriteError::UnknownStart {
                line,
                axis: AXES[k],
                why: "an arc",
            });
        }
        if b.get('P').is_some_and(|p| p.value != 1.0) {
            return Err(RewriteError::Arc {
                line,
                why: "multi-turn arcs (P) are not rewritten".into(),
            });
        }
        let s = start.map(|v| v.unwrap_or(0.0));
        let e = end.map(|v| v.unwrap_or(0.0));
        let known: [bool; 3] = std::array::from_fn(|k| end[k].is_some());
        let ccw = motion == Motion::Ccw;
        let c = self.arc_centre(b, s, e, (a, bb), ccw)?;
        let r0 = (s[a] - c[a]).hypot(s[bb] - c[bb]);
        let r1 = (e[a] - c[a]).hypot(e[bb] - c[bb]);
        let th0 = (s[bb] - c[bb]).atan2(s[a] - c[a]);
        let mut th1 = (e[bb] - c[bb]).atan2(e[a] - c[a]);
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
        let mut n = self.pieces_for(line, sweep.abs() * r0.max(r1))?;
        let full_circle = (e[a] - s[a]).hypot(e[bb] - s[bb]) < 1e-9;
        if full_circle {
            // Two compensated ends of a full circle need not coincide: write it in halves.
            n = n.max(2);
        }
        let rot = if ccw { 1.0 } else { -1.0 };
        let arc = ArcPiece {
            plane: (a, bb),
            centre_mm: c,
            sweep: sweep / n as f64,
            r_format: b.get('R').is_some(),
        };
        let delta = (sweep.abs() / n as f64 / 2.0).min(1e-6);
        let mut outside = false;
        for i in 1..=n {
            let f = i as f64 / n as f64;
            let th = th0 + f * sweep;
            let r = r0 + f * (r1 - r0);
            let mut p: [f64; 3] = std::array::from_fn(|k| s[k] + f * (e[k] - s[k]));
            if i == n {
                p = e;
            } else {
                p[a] = c[a] + r * th.cos();
                p[bb] = c[bb] + r * th.sin();
            }
            // Direction arriving at the point: the tangent just before it.
            let thb = th - rot * delta;
            let mut dirs: [Option<Direction>; 3] = [None; 3];
            dirs[a] = sign_dir(-rot * thb.sin(), 1e-12);
            dirs[bb] = sign_dir(rot * thb.cos(), 1e-12);
            dirs[h] = sign_dir(e[h] - s[h], 1e-9);
            let piece = Piece {
                nominal: p,
                known,
                dirs,
                first: i == 1,
                compensate: true,
                arc: Some(&arc),
            };
            outside = !self.emit_piece(b, &piece, present, sink)?;
        }
        if outside {
            self.stats.moves_outside_domain += 1;
        } else {
            self.stats.moves_compensated += 1;
        }
        Ok(())
    }

    /// Arc centre (machine coordinates) from R (perpendicular bisector) or I/J/K (relative to
    /// the start, or absolute in G90.1; radial on a lathe, as LinuxCNC reads them).
    fn arc_centre(
        &self,
        b: &Block,
        s: [f64; 3],
        e: [f64; 3],
        (a, bb): (usize, usize),
        ccw: bool,
    ) -> Result<[f64; 3], RewriteError> {
        let line = b.line;
        let mut c = s;
        if let Some(r) = b.get('R') {
            // Centre on the perpendicular bisector; R < 0 selects the arc longer than 180°.
            let (dx, dy) = (e[a] - s[a], e[bb] - s[bb]);
            let d = dx.hypot(dy);
            let rr = r.value.abs();
            if d < 1e-12 || d > 2.0 * rr + 1e-9 {
                return Err(RewriteError::Arc {
                    line,
                    why: format!("radius {} cannot join points {d:.4} mm apart", r.value),
                });
            }
            let hgt = (rr * rr - d * d / 4.0).max(0.0).sqrt();
            let (mx, my) = (s[a] + dx / 2.0, s[bb] + dy / 2.0);
            let (ux, uy) = (-dy / d, dx / d); // left normal of the chord
            let side = if ccw == (r.value > 0.0) { 1.0 } else { -1.0 };
            c[a] = mx + side * hgt * ux;
            c[bb] = my + side * hgt * uy;
            return Ok(c);
        }
        let mut any = false;
        let off = self.st.offset_mm();
        for k in [a, bb] {
            if let Some(w) = b.get(['I', 'J', 'K'][k]) {
                c[k] = if self.st.arc_absolute {
                    w.value + off[k]
                } else {
                    s[k] + w.value
                };
                any = true;
            } else if self.st.arc_absolute {
                return Err(RewriteError::Arc {
                    line,
                    why: "G90.1 needs both centre words of the plane".into(),
                });
            }
        }
        if !any {
            return Err(RewriteError::Arc {
                line,
                why: "needs I/J/K or R".into(),
            });
        }
        let r0 = (s[a] - c[a]).hypot(s[bb] - c[bb]);
        let r1 = (e[a] - c[a]).hypot(e[bb] - c[bb]);
        if (r0 - r1).abs() > ARC_RADIUS_TOL_MM && (r0 - r1).abs() > ARC_RADIUS_TOL_REL * r0 {
            return Err(RewriteError::Arc {
                line,
                why: format!(
                    "start radius {r0:.4} and end radius {r1:.4} differ (the controller refuses it too)"
                ),
            });
        }
        Ok(c)
    }

    /// Compensates and writes one point; `false` when it lies outside the model's domain (then
    /// its nominal position is written).
    fn emit_piece(
        &mut self,
        b: &Block,
        pc: &Piece<'_>,
        present: [bool; 3],
        sink: &mut dyn RewriteSink,
    ) -> Result<bool, RewriteError> {
        let dirs = self.dirs_with(pc.dirs);
        self.st.dirs = dirs;
        let model_axes = self.model.axes();
        let err = if pc.compensate {
            self.model.error_um(pc.nominal, dirs)
        } else {
            None
        };
        let mut target = pc.nominal;
        if let Some(e) = err {
            for k in (0..3).filter(|&k| model_axes[k] && pc.known[k]) {
                if !e[k].is_finite() || e[k].abs() > self.cfg.max_correction_um {
                    return Err(RewriteError::Limit {
                        line: b.line,
                        axis: AXES[k],
                        value_um: e[k],
                        limit_um: self.cfg.max_correction_um,
                    });
                }
                target[k] -= e[k] / 1000.0;
                self.stats.max_abs_correction_um = self.stats.max_abs_correction_um.max(e[k].abs());
            }
        }
        let mut text = String::new();
        let word_text = |text: &mut String, l: char, t: &str| {
            text.push(l);
            text.push_str(t);
            text.push(' ');
        };
        if pc.first {
            for w in b.words.iter().filter(|w| matches!(w.letter, 'N' | 'G')) {
                word_text(&mut text, w.letter, &w.text);
            }
        }
        let before = self.st.commanded_mm;
        for k in 0..3 {
            if !pc.known[k] {
                if pc.first && present[k] {
                    word_text(&mut text, AXES[k], &b.get(AXES[k]).expect("present").text);
                }
                continue;
            }
            let w_abs = round4(self.st.machine_to_program(k, target[k]));
            let v = match (self.st.absolute, before[k]) {
                (true, _) | (false, None) => w_abs,
                (false, Some(prev)) => w_abs - round4(self.st.machine_to_program(k, prev)),
            };
            word_text(&mut text, AXES[k], &fmt_mm(v));
            self.st.commanded_mm[k] = Some(self.st.program_to_machine(k, w_abs));
            self.st.nominal_mm[k] = Some(pc.nominal[k]);
        }
        if let Some(arc) = pc.arc {
            self.arc_words(&mut text, arc, before);
        }
        if pc.first {
            for w in b.words.iter().filter(|w| {
                !matches!(
                    w.letter,
                    'N' | 'G' | 'X' | 'Y' | 'Z' | 'I' | 'J' | 'K' | 'R'
                )
            }) {
                word_text(&mut text, w.letter, &w.text);
            }
            text.push_str(&super::parser::comments(&b.source));
        }
        sink.line(&format!("{};", text.trim_end()))?;
        self.stats.points_emitted += 1;
        sink.point(&Point {
            line: b.line,
            move_index: self.st.move_index,
            nominal_mm: pc.nominal,
            dirs,
            compensated: err.is_some(),
        })?;
        Ok(err.is_some() || !pc.compensate)
    }

    /// I/J/K (or R) of an arc piece from the written start to the moved centre: the point of
    /// the perpendicular bisector of the written ends nearest the nominal centre.
    fn arc_words(&mut self, text: &mut String, arc: &ArcPiece, before: [Option<f64>; 3]) {
        let (a, bb) = arc.plane;
        let p0 = [before[a].unwrap_or(0.0), before[bb].unwrap_or(0.0)];
        let p1 = [
            self.st.commanded_mm[a].unwrap_or(0.0),
            self.st.commanded_mm[bb].unwrap_or(0.0),
        ];
        let c = [arc.centre_mm[a], arc.centre_mm[bb]];
        let d = [p1[0] - p0[0], p1[1] - p0[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        let mut cm = c;
        if len2 > 1e-18 {
            let m = [(p0[0] + p1[0]) / 2.0, (p0[1] + p1[1]) / 2.0];
            let t = ((c[0] - m[0]) * d[0] + (c[1] - m[1]) * d[1]) / len2;
            cm = [c[0] - t * d[0], c[1] - t * d[1]];
        }
        let shift_um = (cm[0] - c[0]).hypot(cm[1] - c[1]) * 1000.0;
        if shift_um > 0.05 {
            self.stats.arc_centres_moved += 1;
            self.stats.max_centre_shift_um = self.stats.max_centre_shift_um.max(shift_um);
        }
        if arc.r_format {
            let r = (p0[0] - cm[0]).hypot(p0[1] - cm[1]);
            // Never below the half chord after rounding (the controller would refuse it).
            let r = ((r.max(len2.sqrt() / 2.0)) * 1e4).ceil() / 1e4;
            let r = if arc.sweep.abs() > std::f64::consts::PI {
                -r
            } else {
                r
            };
            text.push_str(&format!("R{} ", fmt_mm(r)));
            return;
        }
        let off = self.st.offset_mm();
        for (i, k) in [a, bb].into_iter().enumerate() {
            let v = if self.st.arc_absolute {
                cm[i] - off[k]
            } else {
                cm[i] - p0[i]
            };
            text.push_str(&format!("{}{} ", ['I', 'J', 'K'][k], fmt_mm(v)));
        }
    }
}
