//! Every test against real peers, real processes and real time: python-can, pymodbus, pyserial,
//! socat, mbpoll, Mosquitto and Sparkplug hosts, asyncua, Chromium, LinuxCNC, the DNC drip-feed,
//! and the gateway's hil-sim runs over loopback sockets and ptys.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate).
//! Each test takes its file's turn first (`turn.rs`), so tests of different files never overlap,
//! as when they were separate binaries run one after another. A test is named
//! `<file>::<test>`, e.g. `cargo test --test real_peers dnc_peers::`.

#[path = "../gateway_support/base_field.rs"]
mod base_field;
#[path = "../gateway_support/faults_hil_configs.rs"]
mod configs;
#[path = "../peers/fleet_processes.rs"]
mod fleet_processes;
#[path = "../peers/gateway.rs"]
mod gateway;
#[path = "../gateway_support/hil_sim.rs"]
mod hil_sim;
#[path = "../linuxcnc_support/kit.rs"]
mod kit;
#[path = "../linuxcnc_support/mod.rs"]
mod linuxcnc_support;
#[path = "../peers/mosquitto.rs"]
mod mosquitto;
#[path = "../gateway_support/faults_hil_observe.rs"]
mod observe;
#[path = "../peers/mod.rs"]
mod peers;
#[path = "../gateway_support/plc.rs"]
mod plc;
#[path = "../gateway_support/process.rs"]
mod process;
#[path = "../gateway_support/faults_rtu_configs.rs"]
mod rtu_configs;
#[path = "../gateway_support/faults_hil_run.rs"]
mod run;
#[path = "../gateway_support/scale_model.rs"]
mod scale_model;
#[path = "../peers/snapshot.rs"]
mod snapshot;
#[path = "../peers/spb_lines.rs"]
mod spb_lines;
#[path = "../gateway_support/studer_can.rs"]
mod studer_can;
mod turn;
#[path = "../gateway_support/web_rig.rs"]
mod web_rig;

mod bus_can_peers;
mod bus_can_recovery;
mod bus_modbus_faults;
mod bus_modbus_peers;
mod bus_modbus_server;
mod bus_serial_peers;
mod bus_supervision;
mod dnc_peers;
mod fleet_bridge;
mod fleet_bridge_rebirth;
mod fleet_workers;
mod gateway_cli;
mod gateway_closed_loop;
mod gateway_demo;
mod gateway_demo_serve;
mod gateway_faults_hil;
mod gateway_faults_rtu_hil;
mod gateway_http_flood;
mod gateway_late_peripherals;
mod gateway_modbus_server;
mod gateway_model_switch;
mod gateway_opcua;
mod gateway_origin_shift;
mod gateway_prometheus;
mod gateway_server_guard;
mod gateway_sources;
mod gateway_watchdog_hil;
mod gateway_web_actions;
mod gateway_web_browser;
mod linuxcnc_closed_loop;
mod linuxcnc_comp;
mod linuxcnc_edge_trace;
mod linuxcnc_nc;
mod listener_allow_writes;
mod listener_flood;
mod telemetry_fleet_drift;
mod telemetry_fleet_host;
mod telemetry_mqtt;
mod telemetry_stock_host;
mod walkthrough;
