//! The gateway's field config for the demo, as text (the same TOML a field install would use, see
//! deploy/field/): CiA 406 encoders 1..3 and the CiA 404 temperature node 10 on the socketcand hub,
//! origin shifts into hil-sim's PLC window over Modbus TCP (int32 high word first, LSB 0.5 µm,
//! registers 0..5, strobe 10 / ack 11), the cutting force F_cut_N from weighing lines on hil-sim's
//! serial pty. Register = correction = −error (sign +1).

use std::net::SocketAddr;
use std::path::Path;

/// Field config for one run. `thermal_period_s` is short because the demo's warm-up is accelerated.
pub(crate) fn field_toml(
    name: &str,
    hub: SocketAddr,
    plc: SocketAddr,
    weighing_pty: &Path,
) -> String {
    let pty = weighing_pty.display();
    let (hub_port, plc_addr) = (hub.port(), plc);
    format!(
        r#"
[gateway]
name = "{name}"
cycle_ms = 5
thermal_period_s = 0.1
status_listen = "127.0.0.1:0"

[safety]
max_correction_um = 200.0
max_change_um_per_cycle = 1.0
ramp_um_per_s = 400.0
stale_hold_s = 0.5

[direction]
deadband_mm = 0.005
switch_time_s = 0.05

[[axis]]
name = "x"
position_channel = "x_mm"

[[axis]]
name = "y"
position_channel = "y_mm"

[[axis]]
name = "z"
position_channel = "z_mm"

[can]
backend = "socketcand"
host = "127.0.0.1"
port = {hub_port}
channel = "can0"

[canopen]
pdo_timeout_s = 0.2
encoder = [
  {{ channel = "x_mm", node_id = 1, counts_per_mm = 1000.0 }},
  {{ channel = "y_mm", node_id = 2, counts_per_mm = 1000.0 }},
  {{ channel = "z_mm", node_id = 3, counts_per_mm = 1000.0 }},
]
analog = [
  {{ channel = "T_spindle_C", node_id = 10, type = "int16", byte_offset = 0, decimal_digits = 1 }},
  {{ channel = "T_xscrew_C", node_id = 10, type = "int16", byte_offset = 2, decimal_digits = 1 }},
]

# The cutting force: weighing-indicator lines on hil-sim's pty.
[serial]
[[serial.source]]
name = "scale"
device = "{pty}"
baud = 9600
format = {{ kind = "weighing", unit = "N" }}
channel = [ {{ name = "F_cut_N" }} ]

[sink.origin_shift]
transport = {{ kind = "tcp", address = "{plc_addr}" }}
write_period_ms = 10

[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "x"
address = 0
kind = "int32"
lsb_um = 0.5
sign = 1
[[sink.origin_shift.map.axis]]
axis = "y"
address = 2
kind = "int32"
lsb_um = 0.5
sign = 1
[[sink.origin_shift.map.axis]]
axis = "z"
address = 4
kind = "int32"
lsb_um = 0.5
sign = 1
[sink.origin_shift.map.handshake]
strobe_address = 10
ack_address = 11
timeout_ms = 200
"#
    )
}

/// `field` (from [`field_toml`]) with the gateway's cycle, sink and source readers under
/// `SCHED_FIFO` at `priority` (`[gateway] realtime_priority`). `None`: unchanged.
pub(crate) fn with_realtime_priority(field: &str, priority: Option<u8>) -> String {
    match priority {
        Some(p) => field.replacen(
            "[gateway]\n",
            &format!("[gateway]\nrealtime_priority = {p}\n"),
            1,
        ),
        None => field.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_gateway::config::FieldConfig;

    #[test]
    fn field_config_parses_and_has_a_sink() {
        let a: SocketAddr = "127.0.0.1:29536".parse().unwrap();
        let text = field_toml("demo-full", a, a, Path::new("/dev/pts/9"));
        let cfg = FieldConfig::parse(&text, Path::new("demo.toml")).unwrap();
        assert_eq!(cfg.axes.len(), 3);
        retrocomp_gateway::run::require_sink(&cfg).unwrap();
        assert!(cfg.serial.is_some(), "the force source is configured");
        let rt = with_realtime_priority(&text, Some(20));
        let cfg = FieldConfig::parse(&rt, Path::new("demo.toml")).unwrap();
        assert_eq!(cfg.gateway.realtime_priority, Some(20));
    }
}
