//! The gateway's OPC UA server (issue 16 point 4) against a third-party client: the real
//! `hil-sim serve` (the demo mill, real time) and the real `retrocomp run` binary with `[opcua]`
//! on loopback, and Python `asyncua` (pinned in scripts/setup-peers.sh) as the plant's client:
//! it browses `Objects/Machines/<box>`, checks each axis' `Correction` against `/status`, reads
//! the EngineeringUnits (µm = UNECE "4H", °C = "CEL"), receives ≥ 3 data changes on a
//! subscription, and has an anonymous write refused (tests/peers/asyncua_client.py); a silenced
//! sensor's stale fault arrives as an AlarmConditionType event raised and cleared
//! (tests/peers/asyncua_quality.py).

use crate::configs;
use crate::hil_sim;
use crate::peers;
use crate::run;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// The venv's python (RETROCOMP_PYTHON overrides), failing with how to install asyncua.
fn python_with_asyncua() -> PathBuf {
    let py = std::env::var_os("RETROCOMP_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(peers::python);
    let ok = Command::new(&py)
        .args(["-c", "import asyncua"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "{} cannot import asyncua: {}",
        py.display(),
        peers::INSTALL
    );
    py
}

/// The value after `prefix` on the first log line that has it (≤ 60 s).
fn from_log(log: &Path, prefix: &str, gw: &mut std::process::Child) -> String {
    let t = Instant::now();
    loop {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        if let Some(rest) = text
            .lines()
            .find_map(|l| l.split_once(prefix).map(|(_, r)| r))
        {
            return rest.split_whitespace().next().unwrap_or("").to_string();
        }
        if let Some(st) = gw.try_wait().unwrap() {
            panic!("the gateway exited ({st}):\n{text}");
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no {prefix:?} in the gateway log:\n{text}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn asyncua_browses_reads_and_subscribes_to_the_gateway() {
    let _turn = crate::turn::take(file!());
    let py = python_with_asyncua();
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let dir = run::run_dir("gateway_opcua");
    let dir = dir.as_path();
    let (_rt, hub) = run::loopback_hub();
    let truth = run::demo_truth_model();
    let port = hub.local_addr().port();
    let sim_cfg = dir.join("sim.toml");
    let pty_link = dir.join("weighing-pty");
    // Twenty out-and-back strokes (to the sim's 60 s cap): the axes move while the client reads
    // (it compares until it has caught them moving; the sim is stopped when the client is done).
    // The temperature node (10) falls silent from 15 s to 21 s of the sim's clock: its channels go
    // stale and come back while asyncua_quality.py holds a subscription to one of them.
    let silent = format!(
        "\n[[io.faults]]\nkind = \"can_node_silent\"\nnode = 10\nfrom_s = {}\nto_s = {}\n",
        TEMPS_SILENT_S.0, TEMPS_SILENT_S.1
    );
    let sim = configs::sim_machine_toml(20, &truth)
        + &configs::sim_io_toml(port, &pty_link, None)
        + &silent;
    std::fs::write(&sim_cfg, sim).unwrap();
    let mut sim = run::Sim::spawn(&hil_sim, &sim_cfg, &dir.join("out"));
    let [plc, pty] = <[String; 2]>::try_from(
        sim.wait_for(&["hil-sim: modbus tcp on ", "hil-sim: weighing lines on "]),
    )
    .unwrap();
    let field = dir.join("field.toml");
    let text = configs::field_toml(port, &plc, Path::new(&pty))
        + "\n[opcua]\nlisten = \"127.0.0.1:0\"\n"
        + configs::OPCUA_IDENT;
    std::fs::write(&field, text).unwrap();
    // Its own TMPDIR: whatever the server puts in the temporary folder is seen (and must be gone).
    let tmp = dir.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let (mut gw, log) =
        run::start_gateway_with(dir, "gateway.log", &field, &truth, &[("TMPDIR", &tmp)]);
    let opc_url = from_log(&log, "OPC UA endpoint ", &mut gw);
    let status_addr = from_log(&log, "bound=", &mut gw);
    assert!(opc_url.starts_with("opc.tcp://127.0.0.1:"), "{opc_url}");
    let quality = Command::new(&py)
        .arg(peers::repo().join("tests/peers/asyncua_quality.py"))
        .args([opc_url.as_str(), QUALITY_CHANNEL])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("running asyncua_quality.py");

    let out = Command::new(&py)
        .arg(peers::repo().join("tests/peers/asyncua_client.py"))
        .arg(&opc_url)
        .arg(format!("http://{status_addr}/status"))
        .output()
        .expect("running the asyncua client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let quality = quality.wait_with_output().unwrap();
    std::fs::write(dir.join("asyncua_quality.out"), &quality.stdout).unwrap();
    std::fs::write(dir.join("asyncua_quality.err"), &quality.stderr).unwrap();
    let alive = gw.try_wait().unwrap().is_none();
    run::stop_gateway(&mut gw, &log);
    let _ = sim.child.kill();
    let _ = sim.child.wait();
    assert!(alive, "the gateway died during the client's session");
    assert!(
        out.status.success(),
        "asyncua client failed ({}):\n{stdout}\n{stderr}\ngateway log: {}",
        out.status,
        log.display()
    );
    let summary: serde_json::Value = serde_json::from_str(
        stdout
            .lines()
            .last()
            .unwrap_or_else(|| panic!("no summary from the client:\n{stderr}")),
    )
    .unwrap_or_else(|e| panic!("{e}: {stdout}"));
    eprintln!("asyncua summary: {summary}");

    assert_eq!(summary["box"], "faults-hil", "{summary}");
    // OPC 40501-1 / 40001-1: found by its type in Machinery's Machines folder, typed components,
    // the mandatory nameplate from [opcua.identification].
    let c = &summary["companion"];
    let mt = c["machine_tool_ns"].as_u64().unwrap();
    assert_eq!(c["type_definition"], format!("ns={mt};i=13"), "{c}");
    assert_eq!(c["identification_type"], 11, "{c}");
    assert_eq!(
        c["components"],
        serde_json::json!({"Monitoring": 14, "Notification": 7, "Production": 21}),
        "{c}"
    );
    assert_eq!(
        c["nameplate"],
        serde_json::json!({
            "Manufacturer": "retrocomp test rig",
            "SerialNumber": "faults-hil-1",
            "ProductInstanceUri": "urn:retrocomp:test:faults-hil-1",
        }),
        "{c}"
    );
    assert_eq!(summary["axes"], serde_json::json!(["X", "Y", "Z"]));
    let ident = &summary["identification"];
    assert_eq!(ident["ModelName"].as_str().map(str::is_empty), Some(false));
    let hash = ident["ModelSha256"].as_str().unwrap();
    assert!(
        hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit()),
        "{hash}"
    );
    assert!(summary["matched"].as_u64() >= Some(3), "{summary}");
    // The machine moves: some correction differs from zero while the values were compared.
    assert!(
        summary["max_abs_correction_um"].as_f64() >= Some(0.1),
        "{summary}"
    );
    let units = summary["units"].as_object().unwrap();
    assert_eq!(units["Monitoring/Axes/X/Correction"]["unit_id"], 13384);
    assert_eq!(units["Monitoring/Axes/X/Correction"]["symbol"], "µm");
    let celsius = units
        .iter()
        .filter(|(k, _)| k.starts_with("Monitoring/Sensors/T_"))
        .collect::<Vec<_>>();
    assert!(!celsius.is_empty(), "no temperature channel: {summary}");
    for (k, u) in celsius {
        assert_eq!(u["unit_id"], 4408652, "{k}");
        assert_eq!(u["symbol"], "°C", "{k}");
    }
    assert!(summary["cycle_changes"].as_u64() >= Some(3), "{summary}");
    assert!(summary["write_refused"].as_str().is_some(), "{summary}");
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(log_text.contains("(read-only)"), "{log_text}");
    check_quality(&quality, &log_text);
    check_alarms(&quality);
    // An anonymous server needs no certificate: no ERROR about one, no certificate folder left.
    let false_error = log_text
        .lines()
        .find(|l| l.contains("ERROR") && (l.contains("opcua") || l.contains("certificate")));
    assert_eq!(false_error, None, "{log_text}");
    let left: Vec<_> = std::fs::read_dir(&tmp)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().contains("opcua"))
        .collect();
    assert!(left.is_empty(), "left in TMPDIR: {left:?}");
}

/// hil-sim's temperature node is silent over this window of its clock, s.
const TEMPS_SILENT_S: (f64, f64) = (15.0, 21.0);
/// The channel asyncua_quality.py watches (on the temperature node; no neighbour estimate).
const QUALITY_CHANNEL: &str = "T_xscrew_C";

/// asyncua_quality.py's verdict: Good, then UncertainLastUsableValue while the channel is stale
/// (the last reading's value, with that reading's SourceTimestamp: older than its ServerTimestamp),
/// then Good again with a reading taken after the silence; every ServerTimestamp is the time the
/// server took the value (before the client got it, within the session: not 9999 or 1601);
/// BuildInfo names this build.
fn check_quality(out: &std::process::Output, log_text: &str) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let q: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap_or(""))
        .unwrap_or_else(|e| panic!("asyncua_quality.py: {e}\n{stdout}\n{stderr}"));
    assert_eq!(q["error"], serde_json::Value::Null, "{q}");
    assert!(q["recovered"].as_bool().unwrap(), "{q}\n{log_text}");
    let seen = q["notifications"].as_array().unwrap();
    let f = |n: &serde_json::Value, k: &str| n[k].as_f64().unwrap();
    let first_uncertain = seen
        .iter()
        .position(|n| n["status"] == "UncertainLastUsableValue")
        .unwrap();
    assert!(first_uncertain > 0, "{q}");
    let (before, stale) = (&seen[first_uncertain - 1], &seen[first_uncertain]);
    assert_eq!(before["status"], "Good", "{before}");
    assert_eq!(
        stale["value"], before["value"],
        "the last usable value: {stale}"
    );
    assert!(
        f(stale, "source_s") >= f(before, "source_s"),
        "{before} {stale}"
    );
    assert!(f(stale, "source_s") < f(stale, "server_s"), "{stale}");
    let back = seen[first_uncertain..]
        .iter()
        .find(|n| n["status"] == "Good")
        .unwrap();
    // hil-sim's silence lasts 6 s: the reading that recovers is well after the last one before.
    assert!(
        f(back, "source_s") - f(stale, "source_s") > 1.0,
        "{stale} {back}"
    );
    for n in seen {
        let (srv, arrived, src) = (f(n, "server_s"), f(n, "arrived_s"), f(n, "source_s"));
        // Taken by the server before it reached the client (1 s for clock rounding), and
        // within this test's minute.
        assert!(
            srv <= arrived + 1.0 && arrived - srv < 60.0,
            "ServerTimestamp: {n}"
        );
        // The reading happened before the client had it (one host clock, 1 ms for rounding).
        // Not `src <= srv`: the gateway sets both with src ≤ srv, but async-opcua 0.19 moves the
        // SourceTimestamp of a value that comes inside the item's sampling interval forward to
        // the next sampling slot (the previous notification's SourceTimestamp + the interval;
        // `MonitoredItem::notify_data_value`) and sends it at that slot, keeping its
        // ServerTimestamp: under load two updates bunch up and the shifted source passes the
        // server time (seen: 1.5 ms). It is never later than when the client gets it.
        assert!(
            src <= arrived + 1e-3,
            "SourceTimestamp after the notification arrived: {n}"
        );
    }
    let bi = &q["build_info"];
    assert_eq!(bi["software_version"], env!("CARGO_PKG_VERSION"), "{bi}");
    for k in ["product_name", "product_uri", "manufacturer"] {
        assert!(
            !bi[k].as_str().unwrap_or("").is_empty(),
            "BuildInfo.{k}: {bi}"
        );
    }
    // A build date after 2024 and not in the future.
    let built = bi["build_date_s"].as_f64().unwrap();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    assert!(built > 1.7e9 && built <= now, "BuildInfo.BuildDate: {bi}");
}

/// asyncua_quality.py's alarm events (subscribed on `Server`, type AlarmConditionType): the machine
/// object is an event notifier under `Server`; the watched
/// channel's `stale` fault raised (ActiveState/Id and Retain true) and then cleared (both false)
/// while hil-sim silenced it, each with the standard fields: EventType AlarmConditionType,
/// SourceNode the machine object, SourceName the channel, a Message naming the fault, a Severity
/// in 1..=1000, its own EventId, and the clear after the start.
fn check_alarms(out: &std::process::Output) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let q: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap_or("")).unwrap();
    let machine = q["machine_node"].as_str().unwrap();
    // An event notifier, found from Server by HasNotifier (Part 3's event hierarchy).
    assert_eq!(
        q["machine_event_notifier"],
        serde_json::json!(["SubscribeToEvents"]),
        "{q}"
    );
    assert_eq!(q["server_notifiers"], serde_json::json!([machine]), "{q}");
    let alarms = q["alarms"].as_array().unwrap();
    let condition = format!("{QUALITY_CHANNEL}/stale");
    let mine: Vec<_> = alarms
        .iter()
        .filter(|e| e["condition_name"] == condition.as_str())
        .collect();
    // The last start before the last clear: the silence (an episode at start-up may precede it).
    let clear = mine
        .iter()
        .rposition(|e| e["active"] == false)
        .unwrap_or_else(|| panic!("no clear of {condition}: {alarms:#?}"));
    let start = mine[..clear]
        .iter()
        .rposition(|e| e["active"] == true)
        .unwrap_or_else(|| panic!("no start of {condition} before its clear: {alarms:#?}"));
    let (start, clear) = (mine[start], mine[clear]);
    for (e, active, word) in [(start, true, "stale"), (clear, false, "cleared")] {
        assert_eq!(e["event_type"], "i=2915", "AlarmConditionType: {e}");
        assert_eq!(e["source_node"], machine, "{e}");
        assert_eq!(e["source_name"], QUALITY_CHANNEL, "{e}");
        assert_eq!(e["active"], active, "ActiveState/Id: {e}");
        assert_eq!(e["retain"], active, "Retain: {e}");
        let msg = e["message"].as_str().unwrap();
        assert!(msg.contains(QUALITY_CHANNEL) && msg.contains(word), "{e}");
        let severity = e["severity"].as_u64().unwrap();
        assert!((1..=1000).contains(&severity), "{e}");
    }
    assert_ne!(start["event_id"], clear["event_id"]);
    // hil-sim's silence lasts 6 s: the fault held for more than 1 s of it.
    let held_s = clear["time_s"].as_f64().unwrap() - start["time_s"].as_f64().unwrap();
    assert!(held_s > 1.0, "{start} {clear}");
}

/// `[opcua]` with a user: anonymous stays on the unencrypted endpoint (`anonymous = true`), the
/// password only on Basic256Sha256/SignAndEncrypt with the server's self-signed certificate created
/// in `pki_dir` at start. No machine is needed for this: the gateway runs `--dry-run` on an empty
/// CAN hub (its inputs are stale, the address space is there all the same).
#[test]
fn a_user_reads_over_the_encrypted_endpoint_and_a_wrong_password_is_refused() {
    let _turn = crate::turn::take(file!());
    let py = python_with_asyncua();
    let dir = run::run_dir("gateway_opcua_users");
    let dir = dir.as_path();
    let (_rt, hub) = run::loopback_hub();
    let password = "opcua-test-password-1";
    std::fs::write(dir.join("mes.pw"), format!("{password}\n")).unwrap();
    let opcua = "\n[opcua]\nlisten = \"127.0.0.1:0\"\nanonymous = true\npki_dir = \"pki\"\n\
           trust_client_certs = true\nusers = [ { name = \"mes\", password_file = \"mes.pw\" } ]\n";
    let (mut gw, log) = start_dry_run(dir, hub.local_addr().port(), opcua);
    let opc_url = from_log(&log, "OPC UA endpoint ", &mut gw);
    let out = Command::new(&py)
        .arg(peers::repo().join("tests/peers/asyncua_users.py"))
        .args([opc_url.as_str(), "mes", password])
        .arg(dir)
        .output()
        .expect("running the asyncua client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    run::stop_gateway(&mut gw, &log);
    assert!(
        out.status.success(),
        "asyncua client failed ({}):\n{stdout}\n{stderr}\ngateway log: {}",
        out.status,
        log.display()
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    eprintln!("asyncua summary: {summary}");
    // asyncua spells MessageSecurityMode.None as `None_` (None is a Python keyword).
    assert_eq!(
        summary["endpoints"],
        serde_json::json!([
            ["Basic256Sha256", "SignAndEncrypt", "Anonymous,UserName"],
            ["None", "None_", "Anonymous"]
        ]),
        "{summary}"
    );
    assert!(summary["user_read_um"].as_f64().is_some(), "{summary}");
    assert!(summary["user_write_refused"].as_str().is_some());
    assert!(
        dir.join("pki/own/cert.der").is_file(),
        "no server certificate"
    );
    // The password is not in the log.
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(!log_text.contains(password), "{log_text}");
}

/// `retrocomp run --dry-run` with the test field config plus the `[opcua]` TOML `opcua`, on an empty
/// CAN hub (its inputs are stale, the address space is there all the same); (child, log).
fn start_dry_run(dir: &Path, hub_port: u16, opcua: &str) -> (std::process::Child, PathBuf) {
    let field = dir.join("field.toml");
    let full = configs::field_toml(hub_port, "127.0.0.1:9", Path::new("-"));
    // Without the serial source (there is no pty to open); the sink goes with --dry-run.
    // Section headers at the start of a line (the shared fixture's comments name them too).
    let (head, tail) = full.split_once("\n[serial]\n").unwrap();
    let text = head.to_string()
        + &tail[tail.find("\n[sink.origin_shift]\n").unwrap()..]
        + opcua
        + configs::OPCUA_IDENT;
    std::fs::write(&field, text).unwrap();
    let log = dir.join("gateway.log");
    let gw = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["run", "--dry-run", "--config"])
        .arg(&field)
        .arg("--model")
        .arg(run::demo_truth_model())
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .expect("starting retrocomp run");
    (gw, log)
}

/// `[[opcua.cert_users]]`: a user logs in with an X.509 certificate (X509IdentityToken) generated
/// by the test with asyncua's own helper; another certificate, or the declared one signed with
/// another key, is refused (tests/peers/asyncua_certs.py).
#[test]
fn a_certificate_user_reads_and_another_certificate_is_refused() {
    let _turn = crate::turn::take(file!());
    let py = python_with_asyncua();
    let dir = run::run_dir("gateway_opcua_certs");
    let dir = dir.as_path();
    let script = peers::repo().join("tests/peers/asyncua_certs.py");
    let made = Command::new(&py)
        .arg(&script)
        .arg("gen")
        .arg(dir)
        .output()
        .unwrap();
    assert!(made.status.success(), "generating certificates: {made:?}");
    let (_rt, hub) = run::loopback_hub();
    let opcua = "\n[opcua]\nlisten = \"127.0.0.1:0\"\npki_dir = \"pki\"\ntrust_client_certs = true\n\
                 cert_users = [ { name = \"mes\", certificate = \"user-good.der\" } ]\n";
    let (mut gw, log) = start_dry_run(dir, hub.local_addr().port(), opcua);
    let opc_url = from_log(&log, "OPC UA endpoint ", &mut gw);
    let out = Command::new(&py)
        .arg(&script)
        .args(["check", opc_url.as_str()])
        .arg(dir)
        .output()
        .expect("running the asyncua client");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    run::stop_gateway(&mut gw, &log);
    assert!(
        out.status.success(),
        "asyncua client failed ({}):\n{stdout}\n{stderr}\ngateway log: {}",
        out.status,
        log.display()
    );
    let summary: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    eprintln!("asyncua summary: {summary}");
    // Certificates only: no anonymous endpoint, no password token.
    assert_eq!(
        summary["endpoints"],
        serde_json::json!([["Basic256Sha256", "SignAndEncrypt", "Certificate"]]),
        "{summary}"
    );
    assert!(summary["cert_user_read_um"].is_number(), "{summary}");
    assert!(summary["other_certificate"].as_str().is_some(), "{summary}");
    assert!(summary["wrong_key"].as_str().is_some(), "{summary}");
}
