//! The controller's interpolator: turns the part program (or a scripted trajectory) into one set-point
//! per servo tick. Feed is constant along each block (no acceleration planning: the position loop's
//! lag is the legacy controller's smoothing). Block time is carried across ticks exactly, so a program
//! takes the same simulated time whatever the servo rate.
//!
//! Positions are machine coordinates in mm, *before* the origin shift (the "nominal" position).

use super::gcode::{Block, Motion};
use crate::config::ScriptPoint;
use std::f64::consts::TAU;

/// What the interpolator commands at one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Setpoint {
    pub pos_mm: [f64; 3],
    pub rpm: f64,
    /// A feed move (G1/G2/G3) is being executed: cutting can happen.
    pub feeding: bool,
    pub feed_mm_min: f64,
    pub done: bool,
}

/// Runs G-code blocks. A streaming runner (DNC) is open: out of blocks it holds the set-point and
/// waits for more instead of ending.
#[derive(Clone, Debug)]
pub struct ProgramRunner {
    blocks: Vec<Block>,
    idx: usize,
    t_in_block_s: f64,
    sp: Setpoint,
    open: bool,
}

impl ProgramRunner {
    pub fn new(blocks: Vec<Block>, start_mm: [f64; 3]) -> Self {
        Self {
            blocks,
            idx: 0,
            t_in_block_s: 0.0,
            sp: Setpoint {
                pos_mm: start_mm,
                ..Default::default()
            },
            open: false,
        }
    }

    /// A runner whose blocks arrive while it runs ([`Self::push`]).
    pub fn streaming(start_mm: [f64; 3]) -> Self {
        Self {
            open: true,
            ..Self::new(Vec::new(), start_mm)
        }
    }

    /// Append blocks to a streaming runner.
    pub fn push(&mut self, blocks: &mut Vec<Block>) {
        self.blocks.append(blocks);
    }

    /// Every block received has been executed (a streaming runner waits for the next one).
    pub fn starved(&self) -> bool {
        self.idx >= self.blocks.len()
    }

    /// The line of the dwell in progress if it ends within the next `dt_s`: this step is the last
    /// one whole inside it (the slide is settled at the block's end point). The test is the one
    /// [`Self::advance`] ends the dwell by, so each dwell is reported exactly once.
    pub fn dwell_ending(&self, dt_s: f64) -> Option<usize> {
        match self.blocks.get(self.idx) {
            Some(Block::Dwell { s, line }) if self.t_in_block_s + dt_s >= *s => Some(*line),
            _ => None,
        }
    }

    /// Advance by `dt_s` and return the set-point at the end of the step.
    pub fn advance(&mut self, dt_s: f64) -> Setpoint {
        let mut rem = dt_s;
        self.sp.feeding = false;
        while let Some(block) = self.blocks.get(self.idx) {
            match *block {
                Block::Spindle { rpm, .. } => {
                    self.sp.rpm = rpm;
                    self.next_block();
                }
                Block::End { .. } => {
                    self.sp.done = true;
                    self.sp.rpm = 0.0;
                    return self.sp;
                }
                Block::Dwell { s, .. } => {
                    if self.t_in_block_s + rem >= s {
                        rem -= s - self.t_in_block_s;
                        self.next_block();
                    } else {
                        self.t_in_block_s += rem;
                        return self.sp;
                    }
                }
                Block::Move {
                    motion,
                    from_mm,
                    to_mm,
                    feed_mm_min,
                    ..
                } => {
                    let len = path_length_mm(motion, from_mm, to_mm);
                    let dur = len / (feed_mm_min / 60.0);
                    self.sp.feed_mm_min = feed_mm_min;
                    self.sp.feeding = motion != Motion::Rapid;
                    if self.t_in_block_s + rem >= dur {
                        rem -= dur - self.t_in_block_s;
                        self.sp.pos_mm = to_mm;
                        self.next_block();
                        if rem <= 0.0 {
                            return self.sp;
                        }
                    } else {
                        self.t_in_block_s += rem;
                        self.sp.pos_mm = point_on(motion, from_mm, to_mm, self.t_in_block_s / dur);
                        return self.sp;
                    }
                }
            }
        }
        self.sp.done = !self.open;
        self.sp
    }

    fn next_block(&mut self) {
        self.idx += 1;
        self.t_in_block_s = 0.0;
    }
}

fn arc_geometry(
    center: [f64; 2],
    clockwise: bool,
    from: [f64; 3],
    to: [f64; 3],
) -> (f64, f64, f64) {
    let r = (from[0] - center[0]).hypot(from[1] - center[1]);
    let a0 = (from[1] - center[1]).atan2(from[0] - center[0]);
    let a1 = (to[1] - center[1]).atan2(to[0] - center[0]);
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(TAU);
    if sweep < 1e-12 {
        sweep = TAU; // same start and end: a full circle
    }
    (r, a0, sweep)
}

fn path_length_mm(motion: Motion, from: [f64; 3], to: [f64; 3]) -> f64 {
    match motion {
        Motion::Rapid | Motion::Linear => {
            ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2) + (to[2] - from[2]).powi(2))
                .sqrt()
        }
        Motion::Arc {
            center_xy_mm,
            clockwise,
        } => {
            let (r, _, sweep) = arc_geometry(center_xy_mm, clockwise, from, to);
            (r * sweep).hypot(to[2] - from[2])
        }
    }
}

fn point_on(motion: Motion, from: [f64; 3], to: [f64; 3], u: f64) -> [f64; 3] {
    match motion {
        Motion::Rapid | Motion::Linear => std::array::from_fn(|k| from[k] + (to[k] - from[k]) * u),
        Motion::Arc {
            center_xy_mm: c,
            clockwise,
        } => {
            let (r, a0, sweep) = arc_geometry(c, clockwise, from, to);
            let a = if clockwise {
                a0 - u * sweep
            } else {
                a0 + u * sweep
            };
            [
                c[0] + r * a.cos(),
                c[1] + r * a.sin(),
                from[2] + (to[2] - from[2]) * u,
            ]
        }
    }
}

/// Scripted trajectory: piecewise-linear in time.
#[derive(Clone, Debug)]
pub(crate) struct ScriptRunner {
    points: Vec<ScriptPoint>,
    t_s: f64,
}

impl ScriptRunner {
    pub(crate) fn new(points: Vec<ScriptPoint>) -> Self {
        Self { points, t_s: 0.0 }
    }

    pub(crate) fn advance(&mut self, dt_s: f64) -> Setpoint {
        self.t_s += dt_s;
        let pts = &self.points;
        let last = pts.len() - 1;
        let i = pts.partition_point(|p| p.t_s <= self.t_s);
        let (pos, rpm, moving) = if i == 0 {
            ([pts[0].x_mm, pts[0].y_mm, pts[0].z_mm], pts[0].rpm, false)
        } else if i > last {
            (
                [pts[last].x_mm, pts[last].y_mm, pts[last].z_mm],
                pts[last].rpm,
                false,
            )
        } else {
            let (a, b) = (&pts[i - 1], &pts[i]);
            let u = (self.t_s - a.t_s) / (b.t_s - a.t_s);
            let lerp = |p: f64, q: f64| p + (q - p) * u;
            #[allow(clippy::float_cmp, reason = "the same set-point: not moving")]
            let moving = a.x_mm != b.x_mm || a.y_mm != b.y_mm || a.z_mm != b.z_mm;
            (
                [
                    lerp(a.x_mm, b.x_mm),
                    lerp(a.y_mm, b.y_mm),
                    lerp(a.z_mm, b.z_mm),
                ],
                a.rpm,
                moving,
            )
        };
        let feed = if i > 0 && i <= last {
            let (a, b) = (&pts[i - 1], &pts[i]);
            let d =
                ((b.x_mm - a.x_mm).powi(2) + (b.y_mm - a.y_mm).powi(2) + (b.z_mm - a.z_mm).powi(2))
                    .sqrt();
            d / (b.t_s - a.t_s) * 60.0
        } else {
            0.0
        };
        Setpoint {
            pos_mm: pos,
            rpm,
            feeding: moving,
            feed_mm_min: feed,
            done: self.t_s > pts[last].t_s,
        }
    }
}

/// Either kind of trajectory source.
#[derive(Clone, Debug)]
pub(crate) enum Trajectory {
    Program(ProgramRunner),
    Script(ScriptRunner),
}

impl Trajectory {
    pub(crate) fn advance(&mut self, dt_s: f64) -> Setpoint {
        match self {
            Trajectory::Program(p) => p.advance(dt_s),
            Trajectory::Script(s) => s.advance(dt_s),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::controller::gcode::parse;

    #[test]
    fn linear_move_takes_length_over_feed_and_ends_exactly() {
        // 10 mm at 600 mm/min = 1 s, then a 0.5 s dwell, then M30.
        let b = parse("G1 F600 X10\nG4 P0.5\nM30", [0.0; 3], 6000.0).unwrap();
        let mut r = ProgramRunner::new(b, [0.0; 3]);
        let dt = 0.001;
        let mut t = 0.0;
        let mut sp = r.advance(dt);
        while !sp.done {
            t += dt;
            if (t - 0.5).abs() < 1e-9 {
                assert!(
                    (sp.pos_mm[0] - 5.0).abs() < 1e-6,
                    "half way at 0.5 s: {}",
                    sp.pos_mm[0]
                );
            }
            sp = r.advance(dt);
        }
        assert_eq!(sp.pos_mm, [10.0, 0.0, 0.0]);
        assert!((t - 1.5).abs() < 2e-3, "program time {t}");
    }

    #[test]
    fn arc_stays_on_circle_and_sweeps_the_right_way() {
        // CCW quarter circle from (10,0) to (0,10) around the origin.
        let b = parse("G1 F6000 X10\nG3 X0 Y10 I-10 J0\nM30", [0.0; 3], 6000.0).unwrap();
        let mut r = ProgramRunner::new(b, [0.0; 3]);
        let mut saw_first_quadrant = false;
        loop {
            let sp = r.advance(0.001);
            let [x, y, _] = sp.pos_mm;
            if x > 0.5 && y > 0.5 {
                saw_first_quadrant = true;
                assert!((x.hypot(y) - 10.0).abs() < 1e-9);
            }
            assert!(y >= -1e-12, "CCW from (10,0) never goes below y=0");
            if sp.done {
                assert!((x).abs() < 1e-9 && (y - 10.0).abs() < 1e-9);
                break;
            }
        }
        assert!(saw_first_quadrant);
    }

    #[test]
    fn script_interpolates_in_time() {
        let pts = vec![
            ScriptPoint {
                t_s: 0.0,
                x_mm: 0.0,
                y_mm: 0.0,
                z_mm: 0.0,
                rpm: 0.0,
            },
            ScriptPoint {
                t_s: 2.0,
                x_mm: 4.0,
                y_mm: 0.0,
                z_mm: -2.0,
                rpm: 100.0,
            },
        ];
        let mut s = ScriptRunner::new(pts);
        let sp = s.advance(0.5);
        assert!((sp.pos_mm[0] - 1.0).abs() < 1e-12 && (sp.pos_mm[2] + 0.5).abs() < 1e-12);
        assert!((sp.feed_mm_min - 20f64.sqrt() / 2.0 * 60.0).abs() < 1e-9);
        assert!(!s.advance(1.4).done);
        assert!(s.advance(0.2).done);
    }
}
