//! Item 4: the simulator on real transports — Modbus TCP (origin shift with the PMC-style handshake,
//! PT100 and force input registers), Modbus RTU on a pty, CiA 406/404 on the in-memory CAN bus and
//! through a socketcand hub, weighing-indicator lines on a pty. Loopback and ptys only.

use hil_sim::SimConfig;
use hil_sim::io::serve::start;
use retrocomp_bus::can::{CanBus, Hub, MemBus, SocketcandBus};
use retrocomp_bus::canopen::{AnalogChannel, AnalogType, EncoderChannel, PositionDecoder};
use std::time::Duration;
use tokio::time::timeout;
use tokio_modbus::prelude::*;

const T: Duration = Duration::from_secs(10);

/// x moves 50 → `x_end` mm between 0.2 s and `move_end_s`, then holds 0.5 s; two temperature
/// sensors; in cut (force) from 0.2 s on.
fn config(io: &str, move_end_s: f64, realtime: bool, x_end: f64) -> SimConfig {
    let hold_end_s = move_end_s + 0.5;
    let toml = format!(
        r#"
[clock]
realtime = {realtime}
[program]
script = [
  {{ t_s = 0.0, x_mm = 50.0, y_mm = 20.0, z_mm = 1.0, rpm = 2000.0 }},
  {{ t_s = 0.2, x_mm = 50.0, y_mm = 20.0, z_mm = -1.0, rpm = 2000.0 }},
  {{ t_s = {move_end_s}, x_mm = {x_end}, y_mm = 20.0, z_mm = -1.0, rpm = 2000.0 }},
  {{ t_s = {hold_end_s}, x_mm = {x_end}, y_mm = 20.0, z_mm = -1.0, rpm = 2000.0 }},
]
[plc]
scan_s = 0.010
word = "int32"
lsb_um = 1.0
first_register = 0
handshake = {{ strobe_register = 6, ack_register = 7 }}
[hidden.thermal]
ambient_C = 21.5
nodes = [{{ name = "spindle", tau_s = 100.0, start_C = 23.4 }}]
sensors = [{{ name = "spindle", node = "spindle" }}, {{ name = "room", node = "ambient" }}]
[hidden.cutting]
stock_top_z_mm = 0.0
gauges = [{{ name = "column", ue_per_N = 0.1 }}]
{io}
"#
    );
    SimConfig::from_toml_str(&toml, None).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn modbus_tcp_serves_temperatures_and_takes_origin_shift_with_handshake() {
    let io = "[io.modbus]\ntcp_bind = \"127.0.0.1:0\"\ntemps_first_input = 10\nforce_first_input = 20\nstrain_first_input = 30\n";
    let running = start(config(io, 3.0, true, 53.0), None, None)
        .await
        .unwrap();
    let mut status = running.status.clone();
    let mut ctx = tcp::connect_slave(running.modbus_tcp.unwrap(), Slave(1))
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    let t = timeout(T, ctx.read_input_registers(10, 2))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(
        t,
        vec![234, 215],
        "PT100 int16 in 0.1 °C: spindle 23.4, room 21.5"
    );
    let f = timeout(T, ctx.read_input_registers(20, 2))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let force_n = f64::from(((u32::from(f[0]) << 16) | u32::from(f[1])) as i32) * 0.1;
    assert!(
        force_n > 10.0,
        "in cut the force register carries the load: {force_n} N"
    );
    // The strain gauge reads 0.1 µε/N (the force is constant at constant feed and depth).
    let st = timeout(T, ctx.read_input_registers(30, 2))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let int32 = |hi: u16, lo: u16| f64::from(((u32::from(hi) << 16) | u32::from(lo)) as i32);
    let (f, strain) = (force_n, int32(st[0], st[1]) * 0.01);
    assert!(
        (strain - 0.1 * f).abs() < 0.02,
        "strain {strain} µε vs force {f} N"
    );
    // The ack register belongs to the PLC.
    let r = timeout(T, ctx.write_single_register(7, 1))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(r, Err(ExceptionCode::IllegalDataAddress));
    // Following error is constant at constant feed, so encoder − set-point moves only by the shift.
    let offset =
        |s: &hil_sim::io::serve::Status| s.encoder_counts[0] as f64 - s.setpoint_mm[0] * 1000.0;
    let before = offset(&status.borrow());
    // −25 µm on X: int32 hi-lo at 0/1, then strobe, wait for ack, drop strobe (PMC window protocol).
    let words = [((-25i32 as u32) >> 16) as u16, -25i32 as u32 as u16];
    timeout(T, ctx.write_multiple_registers(0, &words))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(
        status.borrow().shift_counts[0],
        0,
        "no strobe yet: the PLC must not latch"
    );
    timeout(T, ctx.write_single_register(6, 1))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    let ack = timeout(T, async {
        loop {
            let a = ctx.read_holding_registers(7, 1).await.unwrap().unwrap();
            if a[0] == 1 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await;
    assert!(ack.is_ok(), "PLC acknowledged within a scan");
    timeout(T, ctx.write_single_register(6, 0))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    timeout(T, status.wait_for(|s| s.shift_counts[0] == -25))
        .await
        .unwrap()
        .unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    let after = offset(&status.borrow());
    assert!(
        (after - before + 25.0).abs() <= 2.0,
        "slide moved by the shift: {before} → {after} counts"
    );
    running.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn modbus_rtu_on_a_pty_serves_the_same_registers() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("rtu");
    let io = format!(
        "[io.modbus]\nrtu_pty_link = \"{}\"\nrtu_slave = 7\n",
        link.display()
    );
    let running = start(config(&io, 2.0, true, 50.0), None, None)
        .await
        .unwrap();
    let dev = running.rtu_pty.clone().unwrap();
    assert_eq!(std::fs::read_link(&link).unwrap(), dev);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let port =
        tokio_serial::SerialStream::open(&tokio_serial::new(dev.to_string_lossy(), 19200)).unwrap();
    let mut ctx = rtu::attach_slave(port, Slave(7));
    let t = timeout(T, ctx.read_input_registers(0, 2))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(t, vec![234, 215]);
    let shift = timeout(T, ctx.read_holding_registers(0, 2))
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(shift, vec![0, 0]);
    running.abort();
}

fn encoder(node: u8) -> EncoderChannel {
    let toml = format!("channel = \"x_mm\"\nnode_id = {node}\ncounts_per_mm = 1000.0\n");
    toml::from_str(&toml).unwrap()
}

/// Collect frames until the simulation ends, decode x and the temperatures.
async fn check_can_frames(mut rx: impl CanBus, mut done: impl FnMut() -> bool) {
    let mut table = retrocomp_bus::ChannelTable::default();
    let mut dec = PositionDecoder::new(encoder(1), &mut table);
    let t_id = table.resolve("T");
    let temp = |i: usize| AnalogChannel {
        channel: "T".into(),
        node_id: 10,
        tpdo: 1,
        byte_offset: 2 * i as u8,
        data_type: AnalogType::Int16,
        decimal_digits: 1,
        min: None,
        max: None,
    };
    let (mut last_x, mut temps, mut heartbeats, mut n) = (None, None, 0, 0);
    while let Ok(Ok(f)) = timeout(Duration::from_millis(500), rx.recv()).await {
        n += 1;
        if let Some(s) = dec.decode(&f, 0.0) {
            last_x = Some(s.value);
        }
        if let (Some(a), Some(b)) = (temp(0).decode(t_id, &f, 0.0), temp(1).decode(t_id, &f, 0.0)) {
            temps = Some((a.value, b.value));
        }
        if f.raw_id() == 0x701 {
            heartbeats += 1;
        }
        if done() && last_x.is_some_and(|x: f64| (x - 60.0).abs() < 0.01) {
            break;
        }
    }
    assert!(n > 100, "{n} frames");
    assert!(
        (last_x.unwrap() - 60.0).abs() < 0.01,
        "x from CiA 406 TPDOs: {last_x:?}"
    );
    assert_eq!(temps, Some((23.4, 21.5)), "CiA 404 INT16 temperatures");
    assert!(heartbeats > 0, "heartbeats");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn can_tpdos_on_the_memory_bus() {
    let bus = MemBus::new(1 << 16);
    let rx = bus.endpoint();
    let io = "[io.can]\nbackend = \"mem\"\ntemp_node = 10\nheartbeat_period_s = 0.1\n";
    let running = start(config(io, 0.6, false, 60.0), Some(bus), None)
        .await
        .unwrap();
    let status = running.status.clone();
    check_can_frames(rx, || status.borrow().done).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn can_tpdos_through_a_socketcand_hub() {
    let hub = Hub::start_loopback().await.unwrap();
    let port = hub.local_addr().port();
    let rx = SocketcandBus::connect(("127.0.0.1", port), "vcan0")
        .await
        .unwrap();
    let io = format!(
        "[io.can]\nbackend = \"socketcand\"\nhost = \"127.0.0.1\"\nport = {port}\nchannel = \"vcan0\"\ntemp_node = 10\nheartbeat_period_s = 0.1\nencoder_period_s = 0.01\n"
    );
    let running = start(config(&io, 0.5, true, 60.0), None, None)
        .await
        .unwrap();
    let status = running.status.clone();
    check_can_frames(rx, || status.borrow().done).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn weighing_lines_on_a_pty() {
    use tokio::io::AsyncReadExt;
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("scale");
    let io = format!(
        "[io.weighing]\npty_link = \"{}\"\nperiod_s = 0.05\n",
        link.display()
    );
    let running = start(config(&io, 1.0, true, 53.0), None, None)
        .await
        .unwrap();
    let mut port = tokio_serial::SerialStream::open(&tokio_serial::new(
        running.weighing_pty.clone().unwrap().to_string_lossy(),
        9600,
    ))
    .unwrap();
    let mut buf = Vec::new();
    let _ = timeout(Duration::from_millis(900), async {
        let mut b = [0u8; 256];
        while let Ok(n) = port.read(&mut b).await {
            buf.extend_from_slice(&b[..n]);
        }
    })
    .await;
    let text = String::from_utf8(buf).unwrap();
    let lines: Vec<&str> = text
        .split("\r\n")
        .filter(|l| l.starts_with("ST,GS,"))
        .collect();
    assert!(lines.len() >= 5, "{text:?}");
    let last: f64 = lines.last().unwrap()["ST,GS,".len()..]
        .trim_end_matches('N')
        .parse()
        .unwrap();
    assert!(last > 10.0, "in cut: {last} N");
    running.abort();
}

/// One CiA 404 node has TPDO1–4, 4 temperatures each: a 17th sensor would go out on TPDO4's COB-ID
/// and overwrite the 13th–16th in every receiver, so such a config is refused when it loads.
#[test]
fn more_temperatures_than_one_cia404_node_sends_are_refused() {
    let toml = |n: usize| {
        let sensors: Vec<String> = (0..n)
            .map(|i| format!(r#"{{ name = "s{i}", node = "spindle" }}"#))
            .collect();
        format!(
            r#"
[program]
script = [{{ t_s = 0.0, x_mm = 0.0, y_mm = 0.0, z_mm = 0.0 }}, {{ t_s = 1.0, x_mm = 1.0, y_mm = 0.0, z_mm = 0.0 }}]
[hidden.thermal]
ambient_C = 20.0
nodes = [{{ name = "spindle", tau_s = 100.0 }}]
sensors = [{}]
[io.can]
backend = "mem"
temp_node = 10
"#,
            sensors.join(", ")
        )
    };
    SimConfig::from_toml_str(&toml(16), None).expect("16 sensors fit TPDO1–4");
    let e = SimConfig::from_toml_str(&toml(17), None)
        .expect_err("a 17th sensor has no TPDO")
        .to_string();
    assert!(
        e.contains("io.can.temp_node") && e.contains("17 sensors") && e.contains("at most 16"),
        "{e}"
    );
}
