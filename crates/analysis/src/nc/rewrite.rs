//! The rewriter: interprets blocks with their modal state and streams the compensated program.
//!
//! - `commanded = nominal − error/1000` per axis (error in µm, positions in mm). The error is
//!   evaluated in machine coordinates (`machine = program + work offset`); the program is written
//!   back in its own work coordinates. With lathe diameter mode (G7, or `diameter_x` at start) X
//!   words are diameters, so the X correction is doubled in the output; I/K stay radial (LinuxCNC).
//! - The approach direction of each axis is the sign of its motion arriving at the point (on an
//!   arc, the tangent just before the point, so an arc ending on a quadrant point keeps the
//!   direction it arrived with); an axis that does not move keeps its last direction.
//! - G1 moves longer than `split_step_mm` are split into equal pieces (Spaan Ch7: end-point-only
//!   compensation leaves the straightness error along the path), G2/G3 arcs by arc length. G0 is
//!   compensated at its end point only (its path is not controlled). A split never exceeds
//!   `max_pieces_per_move` (clear error), and output is written block by block.
//! - Arcs: both compensated ends move, so the centre is moved onto the perpendicular bisector of
//!   the compensated ends (the point there nearest the nominal centre) and I/J/K or R are
//!   recomputed from it: start and end radius are equal to the output resolution, as a
//!   controller's radius check needs (LinuxCNC refuses > 0.0283 mm).
//! - Incremental (G91) output: each piece is written relative to the previous piece as emitted
//!   (rounded), so rounding never accumulates and moves kept as programmed still end at their
//!   nominal end point.
//! - A move is never guessed from an unknown start: a split or arc move whose start is unknown
//!   (nothing programmed yet, no `start_mm`) is refused; an unsplit line ending where a model axis
//!   is still unknown is kept as programmed and counted.
//! - Blocks without motion (dwells, M codes, comments, G10 L2), `%` tape marks and lines ending
//!   outside the error function's domain are written as programmed (the latter with every axis on
//!   its nominal point); comments of a motion block stay on its first written line.
//! - Subprograms (M97/M98/M99/M198, G65/G66 macro calls, O-words) and `#` parameters are refused
//!   with the line, never passed through uninterpreted. Output resolution is 0.1 µm (4 decimals in mm).
//!   A correction larger than `max_correction_um` or not finite stops the rewrite with the line.

use super::ErrorFunction;
use super::parser::{Block, Word, parse_line};
use crate::import_error::ImportErrors;
use crate::table::Direction;

#[derive(Debug, Clone, PartialEq)]
pub struct RewriteConfig {
    /// X words are diameters at program start (Fanuc lathe, cylindrical grinder); G7/G8 switch.
    pub diameter_x: bool,
    /// Split G1/G2/G3 moves into pieces no longer than this (mm); `None` = end points only.
    pub split_step_mm: Option<f64>,
    /// Most pieces one move may be split into (bounds output size and time).
    pub max_pieces_per_move: usize,
    /// Largest |error| accepted from the model, µm.
    pub max_correction_um: f64,
    /// Where the machine stands when the program starts, in the program's coordinates at start
    /// (G54; X a diameter in diameter mode). `None`: unknown until each axis is programmed.
    pub start_mm: Option<[f64; 3]>,
    /// Work offsets G54, G55 … G59, G59.1, G59.2, G59.3 (index 0 … 8) in mm, X radial, as the
    /// controller holds them. G54 not given = zero (program coordinates are machine coordinates);
    /// any other system not given (nor set by G10 L2 in the program) is refused when selected.
    pub work_offsets_mm: [Option<[f64; 3]>; 9],
}

impl Default for RewriteConfig {
    fn default() -> Self {
        Self {
            diameter_x: false,
            split_step_mm: None,
            max_pieces_per_move: 100_000,
            max_correction_um: 500.0,
            start_mm: None,
            work_offsets_mm: [None; 9],
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
    /// Unsplit lines left as programmed because a model axis position was still unknown.
    pub moves_unknown_start: usize,
    /// Arc pieces whose centre was moved so both compensated ends lie on one circle.
    pub arc_centres_moved: usize,
    /// Largest centre move, µm.
    pub max_centre_shift_um: f64,
    pub max_abs_correction_um: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum RewriteError {
    #[error("line {line}: G{code} is not supported by the rewriter ({why})")]
    Unsupported {
        line: u64,
        code: f64,
        why: &'static str,
    },
    #[error("line {line}: {why}")]
    Refused { line: u64, why: String },
    #[error("line {line}: axis words without a motion mode (G0–G3) in effect")]
    NoMotionMode { line: u64 },
    #[error(
        "line {line}: {why} from an unknown position ({axis} not programmed yet): give the start position (--start X,Y,Z)"
    )]
    UnknownStart {
        line: u64,
        axis: char,
        why: &'static str,
    },
    #[error(
        "line {line}: G{code} selects work offset {name}, which the rewriter was not given: state it (--work-offset {name}=X,Y,Z) or set it in the program with G10 L2"
    )]
    UnknownWorkOffset {
        line: u64,
        code: f64,
        name: &'static str,
    },
    #[error(
        "line {line}: splitting this {length_mm:.3} mm move into pieces of {step_mm} mm needs {pieces} pieces, more than the limit of {limit}: use a larger --split-mm (or raise --max-pieces)"
    )]
    TooManyPieces {
        line: u64,
        length_mm: f64,
        step_mm: f64,
        pieces: f64,
        limit: usize,
    },
    #[error("line {line}: arc: {why}")]
    Arc { line: u64, why: String },
    #[error("line {line}: correction {value_um} µm on {axis} exceeds the limit of {limit_um} µm")]
    Limit {
        line: u64,
        axis: char,
        value_um: f64,
        limit_um: f64,
    },
    #[error(transparent)]
    Parse(#[from] ImportErrors),
    #[error("writing the output: {0}")]
    Io(#[from] std::io::Error),
}

/// One motion point as written: the nominal target (machine coordinates, X radial), the
/// approach directions used, and whether it was compensated. `move_index` counts motion blocks
/// from 0 (one per canonical motion of the original program).
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub line: u64,
    pub move_index: usize,
    pub nominal_mm: [f64; 3],
    pub dirs: [Direction; 3],
    pub compensated: bool,
}

/// Where the rewritten program goes.
pub trait RewriteSink {
    fn line(&mut self, text: &str) -> std::io::Result<()>;
    /// Every motion point written (for checks and plots); ignored by default.
    fn point(&mut self, _p: &Point) -> std::io::Result<()> {
        Ok(())
    }
}

impl RewriteSink for String {
    fn line(&mut self, text: &str) -> std::io::Result<()> {
        self.push_str(text);
        self.push('\n');
        Ok(())
    }
}

/// Header of the points CSV written by `retrocomp nc --points` (`retrocomp eval --path` reads it:
/// nominal machine position in mm, X radial; approach directions +1/−1; compensated 1/0).
pub const POINTS_HEADER: &str = "line,move,x_mm,y_mm,z_mm,dir_x,dir_y,dir_z,compensated";

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Motion {
    Rapid,
    Linear,
    Cw,
    Ccw,
}

/// Names of the work coordinate systems G54 … G59.3 (index 0 … 8).
const WCS_NAMES: [&str; 9] = [
    "G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3",
];

/// Modal state. Positions are machine coordinates (X radial); `None` = not known yet.
pub(super) struct State {
    pub nominal_mm: [Option<f64>; 3],
    /// Commanded position as written (after output rounding), machine coordinates.
    pub commanded_mm: [Option<f64>; 3],
    pub dirs: [Direction; 3],
    pub motion: Option<Motion>,
    pub absolute: bool,
    /// G90.1: I/J/K are absolute centre coordinates.
    pub arc_absolute: bool,
    pub plane: u32,
    pub diameter: bool,
    pub inverse_time: bool,
    pub offsets_mm: [Option<[f64; 3]>; 9],
    pub wcs: usize,
    pub ended: bool,
    pub move_index: usize,
}

impl State {
    pub(crate) fn offset_mm(&self) -> [f64; 3] {
        self.offsets_mm[self.wcs].unwrap_or([0.0; 3])
    }
    /// Program (work) value of axis `k` as written: X doubled in diameter mode.
    pub(crate) fn machine_to_program(&self, k: usize, machine_mm: f64) -> f64 {
        let v = machine_mm - self.offset_mm()[k];
        if k == 0 && self.diameter { 2.0 * v } else { v }
    }
    pub(crate) fn program_to_machine(&self, k: usize, program: f64) -> f64 {
        let v = if k == 0 && self.diameter {
            program / 2.0
        } else {
            program
        };
        v + self.offset_mm()[k]
    }
}

/// The streaming rewriter: feed blocks in order, then take the stats.
pub struct Rewriter<'a> {
    pub(super) model: &'a dyn ErrorFunction,
    pub(super) cfg: RewriteConfig,
    pub(super) st: State,
    pub(super) stats: RewriteStats,
}

// By hand: the error function is a trait object, the modal state is internal.
impl std::fmt::Debug for Rewriter<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rewriter")
            .field("cfg", &self.cfg)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl<'a> Rewriter<'a> {
    pub fn new(model: &'a dyn ErrorFunction, cfg: &RewriteConfig) -> Self {
        let mut offsets = cfg.work_offsets_mm;
        offsets[0].get_or_insert([0.0; 3]);
        let mut st = State {
            nominal_mm: [None; 3],
            commanded_mm: [None; 3],
            dirs: [Direction::Forward; 3],
            motion: None,
            absolute: true,
            arc_absolute: false,
            plane: 17,
            diameter: cfg.diameter_x,
            inverse_time: false,
            offsets_mm: offsets,
            wcs: 0,
            ended: false,
            move_index: 0,
        };
        if let Some(s) = cfg.start_mm {
            let m: [f64; 3] = std::array::from_fn(|k| st.program_to_machine(k, s[k]));
            st.nominal_mm = m.map(Some);
            st.commanded_mm = m.map(Some);
        }
        Self {
            model,
            cfg: cfg.clone(),
            st,
            stats: RewriteStats::default(),
        }
    }

    pub fn stats(&self) -> &RewriteStats {
        &self.stats
    }

    /// Interprets one block and writes its output.
    pub fn block(&mut self, b: &Block, sink: &mut dyn RewriteSink) -> Result<(), RewriteError> {
        self.stats.blocks_in += 1;
        if b.words.is_empty() && b.source == "%" {
            // A tape mark stays alone on its line (LinuxCNC: the program runs between two).
            sink.line("%")?;
            return Ok(());
        }
        if self.st.ended {
            sink.line(&format!("{};", b.source))?;
            return Ok(());
        }
        refuse_subprograms(b)?;
        let has_axis = b.words.iter().any(|w| super::AXES.contains(&w.letter));
        let non_motion = self.modal(b, has_axis)?;
        #[allow(
            clippy::float_cmp,
            reason = "an M word is parsed from decimal text: M30 and M2 read as exactly 30.0 and 2.0"
        )]
        let ends = b
            .get('M')
            .is_some_and(|m| m.value == 30.0 || m.value == 2.0);
        if ends {
            self.st.ended = true;
        }
        if non_motion || !has_axis {
            sink.line(&format!("{};", b.source))?;
            return Ok(());
        }
        let Some(motion) = self.st.motion else {
            return Err(RewriteError::NoMotionMode { line: b.line });
        };
        self.motion_block(b, motion, sink)?;
        self.st.move_index += 1;
        Ok(())
    }

    /// Applies the block's G codes to the modal state; `true` when the axis words of the block
    /// are not a motion (G4 dwell, G10 offsets).
    fn modal(&mut self, b: &Block, has_axis: bool) -> Result<bool, RewriteError> {
        let line = b.line;
        let unsupported =
            |code: f64, why: &'static str| RewriteError::Unsupported { line, code, why };
        let mut non_motion = false;
        for g in b.g_codes() {
            #[allow(
                clippy::cast_possible_truncation,
                reason = "saturating: a code that is not a whole number of tenths (or is past i64) fails the check below"
            )]
            let tenths = (g * 10.0).round() as i64;
            if ((g * 10.0) - tenths as f64).abs() > 1e-6 {
                return Err(unsupported(g, "unknown G code"));
            }
            match tenths {
                0 => self.st.motion = Some(Motion::Rapid),
                10 => self.st.motion = Some(Motion::Linear),
                20 => self.st.motion = Some(Motion::Cw),
                30 => self.st.motion = Some(Motion::Ccw),
                40 => non_motion = true,
                70 => self.st.diameter = true,
                80 => self.st.diameter = false,
                100 => {
                    self.g10(b)?;
                    non_motion = true;
                }
                170 => self.st.plane = 17,
                180 => self.st.plane = 18,
                190 => self.st.plane = 19,
                210 | 400 | 490 | 610 | 611 | 640 | 690 | 950 | 960 | 970 | 980 | 990 => {}
                800 => self.st.motion = None,
                900 => self.st.absolute = true,
                910 => self.st.absolute = false,
                901 => self.st.arc_absolute = true,
                911 => self.st.arc_absolute = false,
                930 => self.st.inverse_time = true,
                940 => self.st.inverse_time = false,
                540 | 550 | 560 | 570 | 580 | 590 | 591 | 592 | 593 => {
                    let i = usize::try_from(if tenths <= 590 {
                        (tenths - 540) / 10
                    } else {
                        tenths - 591 + 6
                    })
                    .expect("the arm's codes are all ≥ 540");
                    if self.st.offsets_mm[i].is_none() {
                        return Err(RewriteError::UnknownWorkOffset {
                            line,
                            code: g,
                            name: WCS_NAMES[i],
                        });
                    }
                    self.st.wcs = i;
                }
                200 => return Err(unsupported(g, "inch programs: convert to mm first")),
                650 | 660 | 661 | 670 => {
                    return Err(unsupported(
                        g,
                        "macro calls are not supported: expand them inline first",
                    ));
                }
                500 | 520 | 530 | 920..=923 => {
                    return Err(unsupported(
                        g,
                        "coordinate-system shifts (G50–G53, G92) move the program by unknown amounts; expand them first",
                    ));
                }
                410..=439 => {
                    return Err(unsupported(
                        g,
                        "tool compensation: expand to tool-centre paths first",
                    ));
                }
                280..=301 => {
                    return Err(unsupported(
                        g,
                        "reference-point returns move through unknown points",
                    ));
                }
                330..=339 | 50..=53 | 380..=385 => {
                    return Err(unsupported(
                        g,
                        "threading, splines and probing moves are not rewritten",
                    ));
                }
                150 | 160 | 510 | 680 | 700..=729 | 730..=899 => {
                    return Err(unsupported(
                        g,
                        "polar coordinates, scaling, rotation and canned cycles must be expanded first",
                    ));
                }
                _ if has_axis => {
                    return Err(unsupported(g, "unknown G code in a block with axis words"));
                }
                _ => {}
            }
        }
        Ok(non_motion)
    }

    /// `G10 L2 P<n> X Y Z`: sets work offset n (P0 = the current one) to the given values.
    fn g10(&mut self, b: &Block) -> Result<(), RewriteError> {
        let line = b.line;
        let refuse = |why: &str| RewriteError::Refused {
            line,
            why: format!("G10: {why}"),
        };
        if b.get('L').map(|w| w.value) != Some(2.0) {
            return Err(refuse(
                "only L2 (work offset values) is interpreted; tool-table and L20 forms are not",
            ));
        }
        if b.get('R').is_some() {
            return Err(refuse("rotated coordinate systems (R) are not supported"));
        }
        let p = b.get('P').map_or(-1.0, |w| w.value);
        let i = match p {
            0.0 => self.st.wcs,
            p if (1.0..=9.0).contains(&p) && p.fract() == 0.0 => crate::numeric::trunc_usize(p) - 1,
            _ => return Err(refuse("P must be 0 … 9")),
        };
        let mut o = self.st.offsets_mm[i].unwrap_or([0.0; 3]);
        for (k, &a) in super::AXES.iter().enumerate() {
            if let Some(w) = b.get(a) {
                // LinuxCNC halves X in diameter mode here too.
                o[k] = if k == 0 && self.st.diameter {
                    w.value / 2.0
                } else {
                    w.value
                };
            }
        }
        // Positions known in machine coordinates stay put; only the program's view changes.
        self.st.offsets_mm[i] = Some(o);
        Ok(())
    }

    /// Value of the axis word in machine mm (X radial): absolute words through the work offset,
    /// incremental words from the nominal position (None when that is unknown).
    pub(super) fn word_target(&self, w: &Word, k: usize) -> Option<f64> {
        if self.st.absolute {
            Some(self.st.program_to_machine(k, w.value))
        } else {
            let v = if k == 0 && self.st.diameter {
                w.value / 2.0
            } else {
                w.value
            };
            self.st.nominal_mm[k].map(|n| n + v)
        }
    }
}

/// Subprogram calls and returns move the program through blocks the rewriter would not have
/// interpreted in that order (a `G91` move after a call would start from the wrong place), so they
/// are refused; the parser refuses O-words and `#` parameters the same way.
fn refuse_subprograms(b: &Block) -> Result<(), RewriteError> {
    for w in b.words.iter().filter(|w| w.letter == 'M') {
        let what = match w.value {
            97.0 => "M97 (local subprogram call)",
            98.0 => "M98 (subprogram call)",
            99.0 => "M99 (subprogram return / program repeat)",
            198.0 => "M198 (external subprogram call)",
            _ => continue,
        };
        return Err(RewriteError::Refused {
            line: b.line,
            why: format!(
                "{what} is not supported by the rewriter: expand the subprogram inline first"
            ),
        });
    }
    Ok(())
}

/// Rewrites parsed `blocks` into a string (small programs, tests).
pub fn rewrite(
    blocks: &[Block],
    model: &dyn ErrorFunction,
    cfg: &RewriteConfig,
) -> Result<(String, RewriteStats), RewriteError> {
    let mut rw = Rewriter::new(model, cfg);
    let mut out = String::new();
    for b in blocks {
        rw.block(b, &mut out)?;
    }
    Ok((out, rw.stats))
}

/// Streams a program from `input` line by line to `sink`: memory does not grow with the
/// program or with the number of pieces.
pub fn rewrite_stream(
    file: &str,
    input: impl std::io::BufRead,
    semicolon_is_eob: bool,
    model: &dyn ErrorFunction,
    cfg: &RewriteConfig,
    sink: &mut dyn RewriteSink,
) -> Result<RewriteStats, RewriteError> {
    let mut rw = Rewriter::new(model, cfg);
    for (i, raw) in input.lines().enumerate() {
        let raw = raw?;
        for b in parse_line(file, i as u64 + 1, &raw, semicolon_is_eob)? {
            rw.block(&b, sink)?;
        }
    }
    Ok(rw.stats)
}
