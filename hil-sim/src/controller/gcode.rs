//! Parser for the legacy controller's G-code subset: G0/G1/G2/G3 (XY plane, `I J` centre offsets or
//! `R`), G4 dwell (`P` in seconds, RS274NGC style), G90/G91, G21 (mm only; G20 is refused), F (mm/min),
//! S (rpm), M3/M5, M30. Comments `( … )` and `; …`, and `N` line numbers, are ignored.
//!
//! Output is a list of [`Block`]s in absolute machine coordinates (mm). Every error names the line.

/// Motion kind of a block.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    Rapid,
    Linear,
    /// Arc clockwise (G2) / counter-clockwise (G3) in the XY plane, Z interpolated linearly (helix).
    Arc {
        center_xy_mm: [f64; 2],
        clockwise: bool,
    },
}

/// One executable step of the part program.
#[derive(Clone, Debug, PartialEq)]
pub enum Block {
    Move {
        motion: Motion,
        from_mm: [f64; 3],
        to_mm: [f64; 3],
        feed_mm_min: f64,
        line: usize,
    },
    Dwell {
        s: f64,
        line: usize,
    },
    Spindle {
        rpm: f64,
        line: usize,
    },
    End {
        line: usize,
    },
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("G-code line {line}: {msg}")]
pub struct GcodeError {
    pub line: usize,
    pub msg: String,
}

/// Parse a program starting at `start_mm`. `rapid_mm_min` is the feed used for G0 blocks.
pub fn parse(text: &str, start_mm: [f64; 3], rapid_mm_min: f64) -> Result<Vec<Block>, GcodeError> {
    let mut p = Parser::new(start_mm, rapid_mm_min);
    let mut blocks = Vec::new();
    for (idx, raw) in text.lines().enumerate() {
        if p.line(raw, idx + 1, &mut blocks)? {
            break;
        }
    }
    Ok(blocks)
}

/// The parser one line at a time, for a program that arrives as it runs (DNC): the modal state
/// is carried between calls.
#[derive(Debug)]
pub struct Parser {
    st: Modal,
    rapid_mm_min: f64,
}

impl Parser {
    pub fn new(start_mm: [f64; 3], rapid_mm_min: f64) -> Self {
        Self {
            st: Modal {
                pos: start_mm,
                absolute: true,
                motion: None,
                feed: 0.0,
                rpm: 0.0,
                spindle_on: false,
            },
            rapid_mm_min,
        }
    }

    /// Parse line number `line` and append its blocks to `blocks`; true if it ends the program
    /// (M2/M30).
    pub fn line(
        &mut self,
        raw: &str,
        line: usize,
        blocks: &mut Vec<Block>,
    ) -> Result<bool, GcodeError> {
        let st = &mut self.st;
        let err = |msg: String| GcodeError { line, msg };
        let words = tokenize(raw).map_err(err)?;
        let w = read_words(words, st, line)?;
        if let Some(s) = w.s_word {
            st.rpm = s;
            if st.spindle_on {
                blocks.push(Block::Spindle { rpm: st.rpm, line });
            }
        }
        if let Some(on) = w.new_spindle {
            st.spindle_on = on;
            blocks.push(Block::Spindle {
                rpm: if on { st.rpm } else { 0.0 },
                line,
            });
        }
        if w.dwell {
            let s = w.p.ok_or_else(|| err("G4 needs P<seconds>".into()))?;
            if s < 0.0 {
                return Err(err(format!("G4 P{s}: dwell must be >= 0 s")));
            }
            blocks.push(Block::Dwell { s, line });
        }
        if w.motion.is_some() {
            st.motion = w.motion;
        }
        if w.axes.iter().any(Option::is_some) {
            blocks.push(move_block(&w, st, self.rapid_mm_min, line)?);
        }
        if w.end {
            blocks.push(Block::End { line });
        }
        Ok(w.end)
    }
}

/// The modal state carried from line to line.
#[derive(Debug)]
struct Modal {
    pos: [f64; 3],
    absolute: bool,
    /// Last motion code (G0–G3), for axis words without one.
    motion: Option<u32>,
    feed: f64,
    rpm: f64,
    spindle_on: bool,
}

/// What one line asks for, once its words are read (G90/G91 and F are modal and go straight into
/// [`Modal`]).
struct LineWords {
    motion: Option<u32>,
    dwell: bool,
    axes: [Option<f64>; 3],
    i: Option<f64>,
    j: Option<f64>,
    r: Option<f64>,
    p: Option<f64>,
    new_spindle: Option<bool>,
    end: bool,
    s_word: Option<f64>,
}

/// Read the words of line `line` in order, refusing codes and words outside the subset.
fn read_words(
    words: Vec<(char, f64)>,
    st: &mut Modal,
    line: usize,
) -> Result<LineWords, GcodeError> {
    let err = |msg: String| GcodeError { line, msg };
    let mut w = LineWords {
        motion: None,
        dwell: false,
        axes: [None; 3],
        i: None,
        j: None,
        r: None,
        p: None,
        new_spindle: None,
        end: false,
        s_word: None,
    };
    for (letter, value) in words {
        match letter {
            'G' => match value_code(value)
                .ok_or_else(|| err(format!("G{value} is not an integer code")))?
            {
                c @ 0..=3 => w.motion = Some(c),
                4 => w.dwell = true,
                17 | 21 | 40 | 49 | 80 | 94 => {}
                20 => {
                    return Err(err(
                        "G20 (inch) is not supported: the simulator works in mm".into(),
                    ));
                }
                90 => st.absolute = true,
                91 => st.absolute = false,
                c => {
                    return Err(err(format!(
                        "G{c} is not in the supported subset (G0-G4, G17, G21, G90, G91)"
                    )));
                }
            },
            'M' => match value_code(value)
                .ok_or_else(|| err(format!("M{value} is not an integer code")))?
            {
                3 => w.new_spindle = Some(true),
                5 => w.new_spindle = Some(false),
                30 | 2 => w.end = true,
                c => {
                    return Err(err(format!(
                        "M{c} is not in the supported subset (M2, M3, M5, M30)"
                    )));
                }
            },
            'X' => w.axes[0] = Some(value),
            'Y' => w.axes[1] = Some(value),
            'Z' => w.axes[2] = Some(value),
            'I' => w.i = Some(value),
            'J' => w.j = Some(value),
            'R' => w.r = Some(value),
            'P' => w.p = Some(value),
            'F' => {
                if value <= 0.0 {
                    return Err(err(format!("F{value}: feed must be > 0 mm/min")));
                }
                st.feed = value;
            }
            'S' => {
                if value < 0.0 {
                    return Err(err(format!("S{value}: spindle speed must be >= 0 rpm")));
                }
                w.s_word = Some(value);
            }
            'N' => {}
            other => return Err(err(format!("word '{other}' is not supported"))),
        }
    }
    Ok(w)
}

/// The move of a line with axis words, in the modal motion mode; advances `st.pos` to its end.
fn move_block(
    w: &LineWords,
    st: &mut Modal,
    rapid_mm_min: f64,
    line: usize,
) -> Result<Block, GcodeError> {
    let err = |msg: String| GcodeError { line, msg };
    let pos = st.pos;
    let code = st
        .motion
        .ok_or_else(|| err("axis words without a motion mode (G0/G1/G2/G3)".into()))?;
    let mut to = pos;
    for k in 0..3 {
        if let Some(v) = w.axes[k] {
            to[k] = if st.absolute { v } else { pos[k] + v };
        }
    }
    let motion = match code {
        0 => Motion::Rapid,
        1 => Motion::Linear,
        _ => arc_motion(pos, to, code == 2, (w.i, w.j, w.r), line)?,
    };
    let feed_mm_min = if motion == Motion::Rapid {
        rapid_mm_min
    } else if st.feed > 0.0 {
        st.feed
    } else {
        return Err(err("feed move before any F word".into()));
    };
    st.pos = to;
    Ok(Block::Move {
        motion,
        from_mm: pos,
        to_mm: to,
        feed_mm_min,
        line,
    })
}

/// A G2/G3 arc from `pos` to `to`, its centre from `I J` offsets or from `R`; refuses a zero
/// radius and an end point off the circle.
fn arc_motion(
    pos: [f64; 3],
    to: [f64; 3],
    clockwise: bool,
    (i, j, r): (Option<f64>, Option<f64>, Option<f64>),
    line: usize,
) -> Result<Motion, GcodeError> {
    let err = |msg: String| GcodeError { line, msg };
    let center = match (i, j, r) {
        (_, _, Some(r)) => arc_center_from_radius(pos, to, r, clockwise).map_err(err)?,
        (None, None, None) => return Err(err("G2/G3 needs I/J or R".into())),
        _ => [pos[0] + i.unwrap_or(0.0), pos[1] + j.unwrap_or(0.0)],
    };
    let r0 = (pos[0] - center[0]).hypot(pos[1] - center[1]);
    let r1 = (to[0] - center[0]).hypot(to[1] - center[1]);
    if r0 < 1e-9 {
        return Err(err("arc radius is zero".into()));
    }
    if (r0 - r1).abs() > 1e-3 * r0.max(1.0) {
        return Err(err(format!(
            "arc end point is not on the circle (radius {r0:.4} vs {r1:.4} mm)"
        )));
    }
    Ok(Motion::Arc {
        center_xy_mm: center,
        clockwise,
    })
}

#[allow(
    clippy::float_cmp,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "a whole number in 0 … 999 is checked before the cast"
)]
fn value_code(v: f64) -> Option<u32> {
    (v >= 0.0 && v.fract() == 0.0 && v < 1000.0).then_some(v as u32)
}

/// Words of one line, read by the workspace's one G-code lexer (retrocomp's NC parser, issue 14.3)
/// with LinuxCNC's rule for `;`: a comment to the end of the line, except inside `( … )`.
fn tokenize(raw: &str) -> Result<Vec<(char, f64)>, String> {
    let blocks =
        retrocomp_analysis::nc::parser::parse_line("program", 0, raw, false).map_err(|e| {
            e.0.iter()
                .map(|x| x.message.clone())
                .collect::<Vec<_>>()
                .join("; ")
        })?;
    Ok(blocks
        .into_iter()
        .flat_map(|b| b.words)
        .map(|w| (w.letter, w.value))
        .collect())
}

/// Centre of an XY arc given its signed radius (R > 0: the short arc, R < 0: the long arc).
fn arc_center_from_radius(
    from: [f64; 3],
    to: [f64; 3],
    r: f64,
    clockwise: bool,
) -> Result<[f64; 2], String> {
    let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
    let d = dx.hypot(dy);
    if d < 1e-12 || d > 2.0 * r.abs() + 1e-9 {
        return Err(format!(
            "R{r} cannot join the arc end points ({d:.4} mm apart)"
        ));
    }
    let h = (r * r - d * d / 4.0).max(0.0).sqrt();
    let (mx, my) = (from[0] + dx / 2.0, from[1] + dy / 2.0);
    // Left normal of the chord; a clockwise short arc has its centre on the right.
    let (nx, ny) = (-dy / d, dx / d);
    let side = if clockwise == (r > 0.0) { -1.0 } else { 1.0 };
    Ok([mx + side * h * nx, my + side * h * ny])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_modal_moves_incremental_and_spindle() {
        let p = "G90 G0 X10 Y5\nS1200 M3\nG1 F600 X20 ; cut\nG91 Y-5 (incremental)\nG4 P0.5\nM5\nM30\nG0 X99";
        let b = parse(p, [0.0; 3], 6000.0).unwrap();
        assert_eq!(
            b[0],
            Block::Move {
                motion: Motion::Rapid,
                from_mm: [0.0; 3],
                to_mm: [10.0, 5.0, 0.0],
                feed_mm_min: 6000.0,
                line: 1
            }
        );
        assert_eq!(
            b[1],
            Block::Spindle {
                rpm: 1200.0,
                line: 2
            }
        );
        assert!(matches!(
            b[2],
            Block::Move {
                motion: Motion::Linear,
                to_mm: [20.0, 5.0, 0.0],
                feed_mm_min: 600.0,
                ..
            }
        ));
        assert!(matches!(
            b[3],
            Block::Move {
                to_mm: [20.0, 0.0, 0.0],
                ..
            }
        ));
        assert_eq!(b[4], Block::Dwell { s: 0.5, line: 5 });
        assert_eq!(b[5], Block::Spindle { rpm: 0.0, line: 6 });
        assert_eq!(b[6], Block::End { line: 7 });
        assert_eq!(b.len(), 7, "nothing after M30");
    }

    #[test]
    fn arc_by_ij_and_by_r_agree() {
        let ij = parse("G1 F100 X10\nG2 X20 Y0 I5 J0", [0.0; 3], 1.0).unwrap();
        let r = parse("G1 F100 X10\nG2 X20 Y0 R5", [0.0; 3], 1.0).unwrap();
        let c = |b: &Block| match b {
            Block::Move {
                motion:
                    Motion::Arc {
                        center_xy_mm,
                        clockwise,
                    },
                ..
            } => (*center_xy_mm, *clockwise),
            _ => panic!("not an arc"),
        };
        let (a, cw) = c(&ij[1]);
        let (b, _) = c(&r[1]);
        assert!(cw);
        assert!((a[0] - 15.0).abs() < 1e-12 && a[1].abs() < 1e-12);
        assert!(
            (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9,
            "{a:?} vs {b:?}"
        );
    }

    #[test]
    fn errors_name_the_line() {
        assert_eq!(
            parse("G0 X1\nG1 X2", [0.0; 3], 1.0).unwrap_err().line,
            2,
            "feed missing"
        );
        let e = parse("G0 X1\n\nG20", [0.0; 3], 1.0).unwrap_err();
        assert_eq!(e.line, 3);
        assert!(e.msg.contains("G20"));
        assert!(
            parse("G1 F10 Xabc", [0.0; 3], 1.0)
                .unwrap_err()
                .msg
                .contains("`X`")
        );
        assert!(
            parse("G2 F10 X10 I1", [0.0; 3], 1.0)
                .unwrap_err()
                .msg
                .contains("not on the circle")
        );
        assert!(parse("T1", [0.0; 3], 1.0).unwrap_err().msg.contains("'T'"));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(5000))]
        #[test]
        fn never_panics_and_moves_stay_finite(text in "[GXYZIJRFPSMN0-9 .\\-+();\n]{0,120}") {
            if let Ok(blocks) = parse(&text, [0.0; 3], 6000.0) {
                for b in blocks {
                    if let Block::Move { to_mm, feed_mm_min, .. } = b {
                        proptest::prop_assert!(to_mm.iter().all(|v| v.is_finite()) && feed_mm_min > 0.0);
                    }
                }
            }
        }
    }
}
