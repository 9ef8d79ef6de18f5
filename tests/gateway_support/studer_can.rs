//! The Studer S-36 grinder (seed 004's model) as the binary-level gateway tests see it: z and x
//! read from CiA 406 encoders (nodes 1 and 2, 1000 counts/mm) through a socketcand hub on loopback.

use retrocomp_bus::canopen::EncoderChannel;

/// `[direction]`, `[model]`, the two `[[axis]]` and `[can]` + `[canopen]` of a field file whose
/// CAN is the hub on 127.0.0.1:`hub_port`.
pub(crate) fn machine_on_can(hub_port: u16) -> String {
    let root = env!("CARGO_MANIFEST_DIR");
    format!(
        r#"[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[model]
path = "{root}/deploy/examples/studer-s36.toml"
[[axis]]
name = "z"
position_channel = "z_mm"
[[axis]]
name = "x"
position_channel = "x_mm"
[can]
backend = "socketcand"
host = "127.0.0.1"
port = {hub_port}
channel = "can0"
[canopen]
pdo_timeout_s = 0.1
encoder = [
  {{ channel = "z_mm", node_id = 1, counts_per_mm = 1000.0 }},
  {{ channel = "x_mm", node_id = 2, counts_per_mm = 1000.0 }},
]
"#
    )
}

/// The encoder of `channel` on `node` (1000 counts/mm), to send its TPDOs.
pub(crate) fn encoder(channel: &str, node: u8) -> EncoderChannel {
    toml::from_str(&format!(
        "channel = \"{channel}\"\nnode_id = {node}\ncounts_per_mm = 1000.0\n"
    ))
    .unwrap()
}
