//! The head of a field file shared by the config tests: `[gateway]`, `[safety]`, `[direction]` and
//! one `[[axis]]` x on `x_mm`. Valid on its own (no source, no sink).

pub(crate) const BASE: &str = r#"[gateway]
name = "t"
cycle_ms = 5
[safety]
max_correction_um = 50.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 10.0
stale_hold_s = 1.0
[direction]
deadband_mm = 0.005
switch_time_s = 0.1
[[axis]]
name = "x"
position_channel = "x_mm"
"#;
