//! Field configs: the shipped ones in deploy/field/ parse and validate; bad input is reported with
//! file, line and key.

use std::path::Path;

use retrocomp::gateway::config::{ConfigError, FieldConfig};

fn field(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("deploy/field")
        .join(name)
}

#[test]
fn shipped_field_configs_are_valid() {
    let lathe = FieldConfig::load(&field("lathe-origin-shift-rtu.toml")).unwrap();
    let os = lathe
        .sink
        .origin_shift
        .as_ref()
        .expect("lathe uses origin shift");
    assert_eq!(os.map.axes.len(), 2);
    assert!(os.map.handshake.is_some());
    assert_eq!(lathe.recoveries[0].target, "T_spindle_C");

    let mill = FieldConfig::load(&field("mill-quadrature.toml")).unwrap();
    let q = mill.sink.quadrature.as_ref().expect("mill uses quadrature");
    assert_eq!(q.axes[0].min_edge_gap_ns, 400);

    let sensors = FieldConfig::load(&field("sensors-can-modbus-serial.toml")).unwrap();
    assert!(sensors.can.is_some() && sensors.modbus.is_some() && sensors.serial.is_some());
    assert_eq!(
        sensors.canopen.as_ref().unwrap().encoder.len(),
        3,
        "three CiA 406 encoders"
    );
}

fn parse(text: &str) -> Result<FieldConfig, ConfigError> {
    FieldConfig::parse(text, Path::new("field.toml"))
}

const BASE: &str = r#"
[gateway]
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

#[test]
fn errors_name_file_line_and_key() {
    assert!(parse(BASE).is_ok());
    // Typo in a key: the message names the file, the line and the unknown key.
    let bad = BASE.replace("cycle_ms = 5", "cycle_ms = 5\ncycle_time = 3");
    let msg = parse(&bad).unwrap_err().to_string();
    assert!(msg.starts_with("field.toml:"), "{msg}");
    assert!(
        msg.contains("line 5") && msg.contains("cycle_time"),
        "{msg}"
    );
    // Wrong type.
    let msg = parse(&BASE.replace("cycle_ms = 5", "cycle_ms = \"fast\""))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("line 4"), "{msg}");
    // Semantic errors carry the key path.
    let msg = parse(&BASE.replace("\"x_mm\"", "\"x_um\""))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("axis[0].position_channel") && msg.contains("_mm"),
        "{msg}"
    );
    let msg = parse(&BASE.replace("ramp_um_per_s = 10.0", "ramp_um_per_s = -1.0"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("ramp_um_per_s"), "{msg}");
    let chan = format!(
        "{BASE}\n[[channel]]\nname = \"T_C\"\nmin = 1.0\nmax = 2.0\nstale_after_s = 1.0\nmax_rate = 3.0\n"
    );
    let msg = parse(&chan).unwrap_err().to_string();
    assert!(
        msg.contains("max_rate"),
        "unknown channel key must be rejected: {msg}"
    );
}
