//! Checks of the targets whose bytes come from the network (a Modbus peer, an MQTT broker), one
//! function per target as in `mod.rs`. Inputs that carry several messages are cut by a length
//! byte (Modbus PDUs) or a 16-bit length (Sparkplug payloads), or split at 0xFF (JSON chunks: the
//! byte never occurs in UTF-8), so one input can drive a sequence through the same state.

use std::sync::OnceLock;

use prost::Message as _;
use retrocomp_bus::ChannelTable;
use retrocomp_bus::modbus::{
    DataType, RegisterBank, RegisterService, RegisterTable, WordOrder, decode_raw, read_registers,
};
use retrocomp_fleet::FleetView;
use retrocomp_gateway::northbound::telemetry::recordings::{Collector, Took};
use retrocomp_gateway::northbound::telemetry::sparkplug::{self, EdgeNode, Payload};
use retrocomp_gateway::sinks::guard::AxisLimits;
use retrocomp_gateway::sinks::origin_shift::{ServerCore, ServerMap};
use tokio::io::{AsyncReadExt as _, AsyncWriteExt as _};
use tokio_modbus::bytes::Bytes;
use tokio_modbus::prelude::{Request, Response, SlaveRequest};
use tokio_modbus::server::Service as _;

/// A three-axis server map in the kit's layout (deploy/linuxcnc/sim/retrocomp-sim.toml: int16 X,
/// positions, held values, write marker), with the int32 kinds and both word orders added.
const SERVER_MAP: &str = r#"
heartbeat_address = 1
axis = [
  { axis = "x", address = 0, kind = "int16", lsb_um = 0.1, sign = 1 },
  { axis = "y", address = 2, kind = "int32", word_order = "low_first", lsb_um = 0.1, sign = -1 },
  { axis = "z", address = 4, kind = "int32", lsb_um = 0.01, sign = 1 },
]
position = [
  { channel = "x_mm", address = 10, kind = "int16", lsb_um = 10.0 },
  { channel = "y_mm", address = 11, kind = "int32", lsb_um = 1.0 },
  { channel = "z_mm", address = 13, kind = "int32", word_order = "low_first", lsb_um = 1.0 },
]
held = [ { axis = "x", address = 15 }, { axis = "y", address = 16 }, { axis = "z", address = 18 } ]
write_marker = { address = 20, value = 21930 }
"#;

/// Registers the check compares before and after each request (every mapped one and beyond).
const IMAGE_WORDS: u16 = 24;

fn image(bank: &RegisterBank) -> Vec<Option<u16>> {
    (0..IMAGE_WORDS)
        .map(|a| bank.holding(a, 1).map(|w| w[0]))
        .collect()
}

/// The Modbus server's request path, as the origin-shift server runs it: each PDU (length byte,
/// then the PDU) through tokio-modbus's request decoder, the register service over the bank the
/// server map allows writes to, and after each accepted write the core's controller-write
/// handling. A read answers exactly the count asked; a write answers what it wrote, changes only
/// writable registers and, refused, changes nothing; decoded positions and held values are finite.
pub(crate) fn modbus_server(data: &[u8]) {
    let map: ServerMap = toml::from_str(SERVER_MAP).expect("the harness's map parses");
    map.validate(&["x", "y", "z"])
        .expect("the harness's map is valid");
    let bank = RegisterBank::new();
    let writable: Vec<(u16, u16)> = map.writable();
    for &(a, n) in &writable {
        bank.allow_writes(a, n);
    }
    let may_write = |a: u16| writable.iter().any(|&(s, n)| a >= s && a - s < n);
    let limits: Vec<AxisLimits> = ["x", "y", "z"]
        .map(|a| AxisLimits {
            axis: a.to_string(),
            max_correction_um: 50.0,
            max_change_um_per_write: 1.0,
        })
        .into();
    let mut core = ServerCore::new(map, &limits, &mut ChannelTable::default());
    let service = RegisterService {
        bank: bank.clone(),
        slave: None,
    };
    let mut rest = data;
    while let Some((&len, tail)) = rest.split_first() {
        let (pdu, tail) = tail.split_at(usize::from(len).min(tail.len()));
        rest = tail;
        if panics_tokio_modbus(pdu) {
            continue;
        }
        let Ok(request) = Request::try_from(Bytes::copy_from_slice(pdu)) else {
            continue;
        };
        let before = image(&bank);
        let answer = service
            .call(SlaveRequest {
                slave: 1,
                request: request.clone(),
            })
            .into_inner();
        let after = image(&bank);
        let wrote = match (&request, answer) {
            (Request::ReadHoldingRegisters(_, n), Ok(Some(Response::ReadHoldingRegisters(w))))
            | (Request::ReadInputRegisters(_, n), Ok(Some(Response::ReadInputRegisters(w)))) => {
                assert_eq!(w.len(), usize::from(*n), "{request:?}");
                false
            }
            (Request::WriteSingleRegister(a, v), Ok(Some(r))) => {
                assert_eq!(r, Response::WriteSingleRegister(*a, *v));
                true
            }
            (Request::WriteMultipleRegisters(a, ws), Ok(Some(r))) => {
                assert_eq!(r, Response::WriteMultipleRegisters(*a, ws.len() as u16));
                true
            }
            (_, Ok(r)) => panic!("{request:?} answered {r:?}"),
            (_, Err(_)) => false,
        };
        for (a, (b, f)) in before.iter().zip(&after).enumerate() {
            let a = a as u16;
            assert!(
                b == f || (wrote && may_write(a)),
                "{request:?} changed register {a} ({b:?} -> {f:?})"
            );
        }
        if wrote {
            let positions = core.handle_controller_write(|a, n| bank.holding(a, n));
            for (channel, mm) in positions {
                assert!(mm.is_finite(), "{channel} = {mm} mm");
            }
            for (axis, um) in core.held_um() {
                assert!(um.is_finite(), "held {axis} = {um} µm");
            }
        }
    }
}

/// A PDU that panics tokio-modbus 0.17's request decoder (`Request::try_from`), found by this
/// target; the check skips them to go on fuzzing what follows:
/// - FC16 (or FC23) with a register count of 0x8000 or more: the count is checked as `quantity * 2`
///   in u16, which panics where overflow is checked (debug builds, this fuzz build's `-a`) and wraps
///   in a release build (the request is then refused as too short). Kept as
///   `crash-fc16-quantity-0xaa05`.
/// - FC15 (write multiple coils) with more coils than its data bytes hold: the coils are unpacked
///   by indexing past the bytes, a panic in every build. Kept as `crash-fc15-coils-beyond-bytes`.
///
/// The panic ends the task that decodes: on TCP only that peer's connection (tokio-modbus spawns
/// one task per connection), on RTU the whole serving task. `tests/gateway/fuzz_regressions.rs` fails once
/// a tokio-modbus release stops panicking on either, so the skip can go.
pub(crate) fn panics_tokio_modbus(pdu: &[u8]) -> bool {
    let be = |at: usize| {
        pdu.get(at..at + 2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
    };
    match pdu.first() {
        Some(0x10) => be(3).is_some_and(|q| q >= 0x8000),
        Some(0x17) => be(7).is_some_and(|q| q >= 0x8000),
        Some(0x0F) => match (be(3), pdu.get(5)) {
            (Some(coils), Some(&bytes)) => coils.div_ceil(8) > u16::from(bytes),
            _ => false,
        },
        _ => false,
    }
}

fn runtime() -> &'static tokio::runtime::Runtime {
    static RT: OnceLock<tokio::runtime::Runtime> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    })
}

/// A Modbus client's read (the poller's and the client sink's [`read_registers`]) against a peer
/// that answers with the input. First byte: bit 0 the table (holding, input), bits 1–3 the count
/// less one, bit 4 wraps the rest in a TCP header that echoes the request's transaction and unit
/// (so the fuzzer reaches the PDU decoder); the rest is the reply, after which the peer closes.
/// tokio-modbus frames and decodes the reply; words come back only as many as were asked for,
/// and decode as every register type.
pub(crate) fn modbus_client_reply(data: &[u8]) {
    let Some((&flags, reply)) = data.split_first() else {
        return;
    };
    let table = if flags & 1 == 0 {
        RegisterTable::Holding
    } else {
        RegisterTable::Input
    };
    let count = u16::from((flags >> 1) & 7) + 1;
    let framed = flags & 0x10 != 0;
    let reply = reply.to_vec();
    let got = runtime().block_on(async move {
        let (ours, mut peer) = tokio::io::duplex(1 << 16);
        let mut ctx = tokio_modbus::client::tcp::attach(ours);
        let answer = async move {
            // MBAP header (7 bytes) + function, address, count (5 bytes).
            let mut req = [0u8; 12];
            peer.read_exact(&mut req).await.expect("a read request");
            let out = if framed {
                let len = u16::try_from(reply.len() + 1).unwrap_or(u16::MAX);
                let mut out = req[..4].to_vec();
                out.extend(len.to_be_bytes());
                out.push(req[6]);
                out.extend(&reply);
                out
            } else {
                reply
            };
            let _ = peer.write_all(&out).await;
        };
        let (got, ()) = tokio::join!(read_registers(&mut ctx, table, 7, count), answer);
        got
    });
    let Ok(Ok(words)) = got else {
        return;
    };
    assert_eq!(
        words.len(),
        usize::from(count),
        "a read answered with another count"
    );
    for t in [
        DataType::Int16,
        DataType::Uint16,
        DataType::Int32,
        DataType::Uint32,
        DataType::Float32,
    ] {
        for wo in [WordOrder::HighFirst, WordOrder::LowFirst] {
            let _ = decode_raw(&words, t, wo);
        }
    }
}

/// What the edge node reads from the broker: an NCMD payload (rebirth request) and a host's STATE
/// message. A payload that decodes encodes to bytes that decode to the same encoding; a rebirth
/// request gives a birth that decodes with seq 0.
pub(crate) fn sparkplug_commands(data: &[u8]) {
    let online = sparkplug::host_online(data);
    let rebirth = sparkplug::is_rebirth_request(data);
    match Payload::decode(data) {
        Ok(p) => {
            let bytes = p.encode_to_vec();
            let again = Payload::decode(bytes.as_slice()).expect("a re-encoded payload decodes");
            assert_eq!(again.encode_to_vec(), bytes, "encoding is not stable");
        }
        Err(_) => assert!(!rebirth, "a rebirth request from bytes that do not decode"),
    }
    if online.is_some() {
        assert!(serde_json::from_slice::<serde_json::Value>(data).is_ok());
    }
    if rebirth {
        let mut edge = EdgeNode::new(0);
        edge.next_connect();
        let birth = Payload::decode(edge.birth(&[], 1).as_slice()).expect("a birth decodes");
        assert_eq!(birth.seq, Some(0));
    }
}

/// The fleet host's Sparkplug view: messages of `[kind][node][len: u16 BE][payload]` (kind % 4:
/// NBIRTH, NDATA, NDEATH, or a topic it ignores; node % 2: one of two edge nodes) into one
/// [`FleetView`] at 1 ms apart; counts follow the messages taken, every outgoing message is an
/// NCMD rebirth request to a node seen, and the table has a line per node.
pub(crate) fn fleet_view(data: &[u8]) {
    let mut view = FleetView::default();
    let mut rest = data;
    let mut now_ms = 0;
    while let [kind, node, l0, l1, tail @ ..] = rest {
        now_ms += 1;
        let len = usize::from(u16::from_be_bytes([*l0, *l1])).min(tail.len());
        let (payload, tail) = tail.split_at(len);
        rest = tail;
        let kind = ["NBIRTH", "NDATA", "NDEATH", "NCMD"][usize::from(kind % 4)];
        let topic = format!("spBv1.0/shop/{kind}/mill-{}", node % 2);
        let before: u64 = view.nodes.values().map(|n| n.births + n.ndata).sum();
        view.handle_message(&topic, payload, now_ms);
        while let Some((t, p)) = view.poll_transmit(now_ms) {
            assert!(t.starts_with("spBv1.0/shop/NCMD/mill-"), "{t}");
            assert!(sparkplug::is_rebirth_request(&p));
        }
        let after: u64 = view.nodes.values().map(|n| n.births + n.ndata).sum();
        let taken = matches!(kind, "NBIRTH" | "NDATA") && Payload::decode(payload).is_ok();
        assert_eq!(after, before + u64::from(taken), "{topic}");
        for n in view.nodes.values() {
            let _ = n.verdict();
            assert!(n.seq_gaps <= n.ndata);
        }
    }
    assert_eq!(view.table(now_ms).lines().count(), view.nodes.len() + 1);
}

/// The fleet host's recording collector: chunks (JSON, split at 0xFF) into a fresh directory. Every
/// chunk is taken without an I/O error; a completed recording is a file under the directory that
/// starts with its chunk 0's header line.
pub(crate) fn recording_chunks(data: &[u8]) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut col = Collector::new(dir.path().to_path_buf());
    let mut headers = std::collections::HashMap::new();
    for payload in data.split(|&b| b == 0xFF) {
        let chunk = retrocomp_gateway::northbound::telemetry::recordings::Chunk::decode(payload);
        let took = col
            .handle_payload(payload)
            .unwrap_or_else(|e| panic!("I/O error on {:?}: {e}", String::from_utf8_lossy(payload)));
        if let Some(c) = &chunk
            && c.index == 0
            && !matches!(took, Took::Refused(_) | Took::Duplicate)
        {
            let header = c.csv.split_once('\n').map_or(c.csv.as_str(), |h| h.0);
            headers.insert(
                (c.group.clone(), c.edge_node.clone(), c.name.clone()),
                header.to_string(),
            );
        }
        if let Took::Written(Some(path)) = took {
            assert!(path.starts_with(dir.path()), "{} outside", path.display());
            let text = std::fs::read_to_string(&path).expect("the completed recording");
            let c = chunk.expect("only a chunk completes a recording");
            let header = &headers[&(c.group, c.edge_node, c.name)];
            assert!(
                text.starts_with(&format!("{header}\n")),
                "{} does not start with {header:?}",
                path.display()
            );
        }
    }
}
