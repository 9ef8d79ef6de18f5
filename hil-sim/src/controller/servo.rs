//! One axis of the legacy controller's position loop (semi-closed loop: the feedback encoder sits on
//! the motor/screw, so backlash and lead error are outside the loop and reach the tool unseen).
//!
//! velocity command = feedforward·v_setpoint + kv·(target − measured), limited, through a first-order
//! drive lag. `measured = (encoder counts + injected counts) · count`. The quadrature feedback input
//! adds counts to the *measured* position, so the servo moves the slide the other way: injecting
//! +n counts moves the slide by −n·count_um. Positions mm, velocities mm/s.
//!
//! Optional static friction: a standing axis stays put until the velocity command exceeds
//! kv·`stiction_um` (the drive's torque overcomes static friction), and a moving axis sticks again
//! once the command falls below kv·`coulomb_um` and its velocity has reversed or died out.

use crate::config::ServoConfig;

#[derive(Clone, Debug)]
pub(crate) struct AxisServo {
    motor_mm: f64,
    vel_mm_s: f64,
    injected_counts: i64,
    stuck: bool,
}

impl AxisServo {
    pub(crate) fn new(start_mm: f64) -> Self {
        Self {
            motor_mm: start_mm,
            vel_mm_s: 0.0,
            injected_counts: 0,
            stuck: false,
        }
    }

    /// True motor-side (screw) position.
    pub(crate) fn motor_mm(&self) -> f64 {
        self.motor_mm
    }

    /// Raw encoder counts of the motor position (rounded to the nearest count).
    pub(crate) fn encoder_counts(&self, count_um: f64) -> i64 {
        retrocomp_analysis::numeric::round_i64(self.motor_mm * 1000.0 / count_um)
    }

    /// What the controller believes: encoder plus whatever the quadrature input injected.
    pub(crate) fn measured_mm(&self, count_um: f64) -> f64 {
        (self.encoder_counts(count_um) + self.injected_counts) as f64 * count_um / 1000.0
    }

    /// Quadrature feedback input: add `counts` (signed) to the measured position.
    pub(crate) fn inject_counts(&mut self, counts: i64) {
        self.injected_counts += counts;
    }

    pub(crate) fn injected_counts(&self) -> i64 {
        self.injected_counts
    }

    /// Advance one servo tick toward `target_mm`; `v_ff_mm_s` is the set-point velocity.
    pub(crate) fn step(&mut self, p: &ServoConfig, target_mm: f64, v_ff_mm_s: f64, dt_s: f64) {
        if p.ideal {
            // Ideal loop: the injected counts still shift the slide, exactly as a perfect servo would.
            let new = target_mm - self.injected_counts as f64 * p.count_um / 1000.0;
            self.vel_mm_s = (new - self.motor_mm) / dt_s;
            self.motor_mm = new;
            return;
        }
        let err_mm = target_mm - self.measured_mm(p.count_um);
        let vcmd = (p.feedforward * v_ff_mm_s + p.kv_per_s * err_mm)
            .clamp(-p.max_speed_mm_s, p.max_speed_mm_s);
        if p.stiction_um > 0.0 {
            let v_break = p.kv_per_s * p.stiction_um / 1000.0;
            let v_stick = p.kv_per_s * p.coulomb_um / 1000.0;
            if self.stuck {
                if vcmd.abs() <= v_break {
                    self.vel_mm_s = 0.0;
                    return;
                }
                self.stuck = false;
            } else if vcmd.abs() <= v_stick
                && (self.vel_mm_s * vcmd <= 0.0 || self.vel_mm_s.abs() <= v_stick)
            {
                self.stuck = true;
                self.vel_mm_s = 0.0;
                return;
            }
        }
        let a = retrocomp_model::lag::alpha(dt_s, p.velocity_tau_s);
        self.vel_mm_s += (vcmd - self.vel_mm_s) * a;
        self.motor_mm += self.vel_mm_s * dt_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ServoConfig {
        ServoConfig {
            velocity_tau_s: 0.0,
            ..Default::default()
        }
    }

    #[test]
    fn following_error_is_v_over_kv_at_constant_speed() {
        let p = ServoConfig {
            count_um: 0.001,
            ..cfg()
        };
        let mut s = AxisServo::new(0.0);
        let (v, dt) = (10.0, 0.001);
        let mut target = 0.0;
        for _ in 0..3000 {
            target += v * dt;
            s.step(&p, target, v, dt);
        }
        let fe_mm = target - s.motor_mm();
        // Discrete loop: the error is v/kv before the step and one step's travel less after it.
        let expect = v / p.kv_per_s - v * dt;
        assert!(
            (fe_mm - expect).abs() < 1e-3 * expect,
            "following error {fe_mm} mm vs {expect}"
        );
    }

    #[test]
    fn injected_counts_move_the_slide_the_other_way() {
        let p = cfg();
        let mut s = AxisServo::new(5.0);
        s.inject_counts(7);
        for _ in 0..2000 {
            s.step(&p, 5.0, 0.0, 0.001);
        }
        assert_eq!(s.encoder_counts(p.count_um), 5000 - 7);
        assert!((s.measured_mm(p.count_um) - 5.0).abs() < 1e-9);
    }

    #[test]
    fn static_friction_holds_one_count_and_breaks_away_at_two() {
        let p = ServoConfig {
            stiction_um: 1.5,
            coulomb_um: 0.5,
            ..cfg()
        };
        let mut s = AxisServo::new(0.0);
        for _ in 0..10 {
            s.step(&p, 0.0, 0.0, 0.001); // settle and stick at the target
        }
        for _ in 0..500 {
            s.step(&p, 0.001, 0.0, 0.001);
        }
        assert_eq!(
            s.motor_mm(),
            0.0,
            "1 µm error: torque below static friction"
        );
        for _ in 0..500 {
            s.step(&p, 0.002, 0.0, 0.001);
        }
        assert_eq!(
            s.encoder_counts(p.count_um),
            2,
            "2 µm error breaks away and reaches the target"
        );
    }
}
