//! The property each fuzz target checks, one function per target, shared by the cargo-fuzz targets
//! (`fuzz/fuzz_targets/*.rs` include this file) and the normal suite (`tests/gateway/fuzz_regressions.rs`
//! runs every input kept in `tests/fuzz_corpus/<target>/` through the same function). Each takes
//! raw bytes and panics only on a real fault: a parser panic, or a writer whose output does not read
//! back. Errors for bad input are the expected outcome, not a failure. The targets fed from the
//! network (Modbus server and client, Sparkplug, fleet host) are in `net.rs`.

pub(crate) mod net;
pub(crate) use net::{
    fleet_view, modbus_client_reply, modbus_server, recording_chunks, sparkplug_commands,
};

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpStream};
use std::path::Path;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use retrocomp_analysis::circular::parse_traces;
use retrocomp_analysis::circular::{CircleSetup, analyse};
use retrocomp_analysis::export::fanuc::{read_tape, write_tape};
use retrocomp_analysis::export::isg::{read_isg, write_isg};
use retrocomp_analysis::export::linuxcnc::{CompFileType, read_comp, write_comp};
use retrocomp_analysis::iso230_2::evaluate;
use retrocomp_analysis::laser_import::{parse_readings, parse_table_columns, remove_linear_drift};
use retrocomp_analysis::nc::ErrorFunction;
use retrocomp_analysis::nc::parser::parse_program;
use retrocomp_analysis::nc::rewrite::{RewriteConfig, rewrite};
use retrocomp_analysis::plane_model::ZxPlaneModel;
use retrocomp_analysis::plane_model::parse_plane_model;
use retrocomp_analysis::table::Direction;
use retrocomp_gateway::StatusSnapshot;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::northbound::http::serve_status;
use retrocomp_model::MachineModel;
use retrocomp_model::recording::Recording;

/// A target's check: panics on a fault, returns on anything else.
pub(crate) type Check = fn(&[u8]);

/// Every target, by the name of its fuzz target and corpus folder.
pub(crate) const TARGETS: [(&str, Check); 15] = [
    ("field_toml", field_toml),
    ("gateway_config", gateway_config),
    ("model_toml", model_toml),
    ("nc_program", nc_program),
    ("recording_csv", recording_csv),
    ("laser_iso230_2", laser_iso230_2),
    ("controller_tables", controller_tables),
    ("circle_traces", circle_traces),
    ("plane_model", plane_model),
    ("http_request", http_request),
    ("modbus_server", modbus_server),
    ("modbus_client_reply", modbus_client_reply),
    ("sparkplug_commands", sparkplug_commands),
    ("fleet_view", fleet_view),
    ("recording_chunks", recording_chunks),
];

/// The bus layer's field TOML loader.
pub(crate) fn field_toml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = retrocomp_bus::config::parse(text, "fuzz.toml");
    }
}

/// The whole field config (`retrocomp run --config`).
pub(crate) fn gateway_config(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = FieldConfig::parse(text, Path::new("fuzz.toml"));
    }
}

/// The machine model TOML and its writer: whatever reads must write, read back as the same spec,
/// and write the same text again (the round trip `fit` and `diagnose` rely on).
pub(crate) fn model_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(m) = MachineModel::from_toml_str(text, "fuzz.toml") else {
        return;
    };
    let written = m.to_toml_string();
    let back = MachineModel::from_toml_str(&written, "written")
        .unwrap_or_else(|e| panic!("written model does not read back: {e}\n{written}"));
    assert_eq!(
        back.spec(),
        m.spec(),
        "spec changed in the round trip\n{written}"
    );
    assert_eq!(back.to_toml_string(), written, "writing is not stable");
}

/// 20 ppm scale on every axis plus ±2 µm reversal: smooth and finite everywhere.
struct Ppm;
impl ErrorFunction for Ppm {
    fn error_um(&self, p: [f64; 3], d: [Direction; 3]) -> Option<[f64; 3]> {
        let r = |i: usize| {
            if d[i] == Direction::Forward {
                2.0
            } else {
                -2.0
            }
        };
        Some([0.02 * p[0] + r(0), 0.02 * p[1] + r(1), 0.02 * p[2] + r(2)])
    }
}

/// NC programs: the parser under both `;` rules (first byte's bit 0), the rewriter (bits 1, 2:
/// diameter X, work offsets; bit 3: split moves, `--split-mm`, into pieces of 0.5, 1, 2.5 or 20 mm
/// by bits 4–5) against [`Ppm`]; a rewritten program must parse again. Splitting is capped at 1000
/// pieces a move (`--max-pieces`; a longer move is refused with `TooManyPieces`, which this also
/// reaches) so one input cannot write millions of lines.
pub(crate) fn nc_program(data: &[u8]) {
    let Some((&flags, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let semicolon_is_eob = flags & 1 != 0;
    let Ok(blocks) = parse_program("fuzz.nc", text, semicolon_is_eob) else {
        return;
    };
    let cfg = RewriteConfig {
        diameter_x: flags & 2 != 0,
        // Every work offset given (G55…G59.3 selectable) or only the implicit G54.
        work_offsets_mm: if flags & 4 != 0 {
            [Some([1.0, -2.0, 3.0]); 9]
        } else {
            [None; 9]
        },
        split_step_mm: (flags & 8 != 0)
            .then(|| [0.5, 1.0, 2.5, 20.0][usize::from((flags >> 4) & 3)]),
        max_pieces_per_move: 1000,
        ..RewriteConfig::default()
    };
    if let Ok((out, _)) = rewrite(&blocks, &Ppm, &cfg)
        && let Err(e) = parse_program("rewritten.nc", &out, semicolon_is_eob)
    {
        panic!("the rewritten program does not parse: {e}\n--- in\n{text}\n--- out\n{out}");
    }
}

/// Recording CSV (docs/recording-csv.md), strict and lenient.
pub(crate) fn recording_csv(data: &[u8]) {
    let _ = Recording::read_strict(data, "fuzz.csv");
    if let Ok((rec, _bad)) = Recording::read_lenient(data, "fuzz.csv") {
        let _ = rec.load_channels();
    }
}

/// Laser runs (both layouts) and the ISO 230-2 evaluation of what they give; the table CSV reader.
pub(crate) fn laser_iso230_2(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(mut readings) = parse_readings("fuzz.csv", text) {
        let _ = evaluate(&readings);
        let _ = remove_linear_drift(&mut readings);
        let _ = evaluate(&readings);
    }
    let _ = parse_table_columns(
        "fuzz.csv",
        text,
        "position_mm",
        "forward_um",
        "reverse_um",
        1.0,
    );
}

/// Controller tables: Fanuc pitch tape, ISG CSV, LinuxCNC comp files of both kinds; where a reader
/// succeeds, its writer's output must read back.
pub(crate) fn controller_tables(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(axes) = read_tape("fuzz.tape", text) {
        let out = write_tape(&axes);
        if let Err(e) = read_tape("written.tape", &out) {
            panic!("written tape does not read back: {e}\n{out}");
        }
    }
    if let Ok(m) = read_isg("fuzz.csv", text) {
        let out = write_isg(&m);
        if let Err(e) = read_isg("written.csv", &out) {
            panic!("written ISG table does not read back: {e}\n{out}");
        }
    }
    for kind in [CompFileType::Actual, CompFileType::Offset] {
        if let Ok(t) = read_comp("fuzz.comp", text, kind)
            && let Ok(out) = write_comp(&t, kind)
            && let Err(e) = read_comp("written.comp", &out, kind)
        {
            panic!("written comp file does not read back: {e}\n{out}");
        }
    }
}

/// Circular-test traces and the ISO 230-4 analysis of whatever the reader accepts.
pub(crate) fn circle_traces(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(traces) = parse_traces("fuzz.csv", text) else {
        return;
    };
    let setup = CircleSetup {
        radius_mm: 100.0,
        feed_mm_per_min: 1000.0,
        cyclic_period_x_mm: Some(5.0),
        cyclic_period_y_mm: None,
    };
    let _ = analyse(&traces, &setup);
}

/// Input of the plane-model target: `TOML \n%%\n a.csv \n%%\n b.csv`, parsed by
/// `parse_plane_model` (what `load_plane_model` runs after reading the files); the TOML's table
/// files `a.csv` and `b.csv` are served from memory (any other name is a missing file), so no file
/// is written per input. None where the input is refused.
pub(crate) fn plane_model_parse(data: &[u8]) -> Option<ZxPlaneModel> {
    let text = std::str::from_utf8(data).ok()?;
    let mut parts = text.splitn(3, "\n%%\n");
    let (toml, a, b) = (
        parts.next().unwrap_or(""),
        parts.next().unwrap_or(""),
        parts.next().unwrap_or(""),
    );
    let dir = Path::new("fuzz");
    let mut files = |p: &Path| -> std::io::Result<String> {
        if p == dir.join("a.csv") {
            Ok(a.to_string())
        } else if p == dir.join("b.csv") {
            Ok(b.to_string())
        } else {
            Err(std::io::ErrorKind::NotFound.into())
        }
    };
    parse_plane_model(&dir.join("plane.toml"), toml, &mut files).ok()
}

/// The Z–X plane model (`retrocomp nc --plane-model`) through the command's own parser, evaluated
/// across and beyond its tables. Input: see [`plane_model_parse`].
pub(crate) fn plane_model(data: &[u8]) {
    let Some(m) = plane_model_parse(data) else {
        return;
    };
    for z in [-1e3, 0.0, 50.0, 170.0, 1e6] {
        for x in [-1e3, 0.0, 20.0, 85.0, 1e6] {
            for dir in [Direction::Forward, Direction::Reverse] {
                let _ = m.error_um([x, 0.0, z], [dir; 3]);
            }
        }
    }
}

fn status_server() -> SocketAddr {
    static ADDR: OnceLock<SocketAddr> = OnceLock::new();
    *ADDR.get_or_init(|| {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .enable_all()
                .build()
                .unwrap();
            rt.block_on(async move {
                let snap = StatusSnapshot {
                    t_s: 1.0,
                    cycles: 1,
                    enabled: true,
                    axes: vec![],
                    ..Default::default()
                };
                let (keep, wrx) = tokio::sync::watch::channel(Some(Arc::new(snap)));
                let (addr, task) = serve_status("127.0.0.1:0".parse().unwrap(), wrx)
                    .await
                    .unwrap();
                tx.send(addr).unwrap();
                let _ = task.await;
                drop(keep);
            });
        });
        rx.recv().unwrap()
    })
}

/// `data` without the empty lines before a request line, which a server ignores (RFC 9112 §2.2;
/// hyper's parser skips any run of `\r\n` and `\n`): only blank lines are not a request, and a
/// server rightly leaves them unanswered.
pub(crate) fn skip_empty_lines(mut data: &[u8]) -> &[u8] {
    loop {
        if let Some(rest) = data.strip_prefix(b"\r\n") {
            data = rest;
        } else if let Some(rest) = data.strip_prefix(b"\n") {
            data = rest;
        } else {
            return data;
        }
    }
}

/// The status endpoint (crates/gateway/src/northbound/http.rs) through the real server on an ephemeral loopback
/// port: any bytes as a request give no answer (head never completed) or a well-formed HTTP/1.1
/// answer with a known code and an exact Content-Length, and never take the server down (every
/// input connects to the same server).
pub(crate) fn http_request(data: &[u8]) {
    let mut s = TcpStream::connect(status_server()).expect("the status server is down");
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    // The server may answer and close before reading everything (a 405): a failed write is fine.
    let _ = s.write_all(data);
    let _ = s.shutdown(Shutdown::Write);
    let mut resp = Vec::new();
    if s.read_to_end(&mut resp).is_err() {
        return; // reset by the server after an early answer
    }
    if resp.is_empty() {
        assert!(
            !skip_empty_lines(data).windows(4).any(|w| w == b"\r\n\r\n"),
            "a complete request head got no answer"
        );
        return;
    }
    let text = String::from_utf8(resp).expect("answer is UTF-8");
    let (head, body) = text.split_once("\r\n\r\n").expect("answer has a head");
    // HTTP/1.0 requests are answered in 1.0 (hyper); header names are case-insensitive.
    let code = head
        .strip_prefix("HTTP/1.1 ")
        .or_else(|| head.strip_prefix("HTTP/1.0 "))
        .expect("HTTP/1.x status line");
    assert!(
        [
            "200 ", "400 ", "401 ", "403 ", "404 ", "405 ", "408 ", "413 ", "415 ", "422 ", "431 ",
            "503 ",
        ]
        .iter()
        .any(|c| code.starts_with(c)),
        "unexpected status line {head:?}"
    );
    let len: usize = head
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case("content-length").then(|| v.trim())
        })
        .expect("Content-Length")
        .parse()
        .unwrap();
    assert_eq!(len, body.len(), "Content-Length");
}
