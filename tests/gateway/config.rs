//! Field configs: the shipped ones in deploy/field/ parse and validate; bad input is reported with
//! file, line and key.

use std::path::Path;

use retrocomp_gateway::config::FieldConfig;
use retrocomp_model::ConfigError;

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
    assert!(
        msg.starts_with("field.toml:5:") && msg.contains("cycle_time"),
        "{msg}"
    );
    // Wrong type.
    let msg = parse(&BASE.replace("cycle_ms = 5", "cycle_ms = \"fast\""))
        .unwrap_err()
        .to_string();
    assert!(msg.starts_with("field.toml:4:"), "{msg}");
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

/// An origin-shift sink for BASE's x axis over TCP; `extra` goes into `[sink.origin_shift]`.
fn with_sink(sink_keys: &str, map: &str) -> String {
    format!(
        "{BASE}\n[sink.origin_shift]\ntransport = {{ kind = \"tcp\", address = \"127.0.0.1:5020\" }}\n{sink_keys}\n{map}"
    )
}

const X_REG: &str = "[[sink.origin_shift.map.axis]]\naxis = \"x\"\naddress = 0\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n";

/// The message of a refused config: file, line, key and what was expected.
fn refused(text: &str) -> String {
    parse(text).unwrap_err().to_string()
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

#[test]
fn unsafe_sink_configs_are_refused_with_file_line_and_key() {
    assert!(parse(&with_sink("", X_REG)).is_ok());

    // Zero write period (used to panic the sink task) and absurd periods.
    let text = with_sink("write_period_ms = 0", X_REG);
    let msg = refused(&text);
    let line = line_of(&text, "write_period_ms");
    assert!(
        msg.starts_with(&format!(
            "field.toml:{line}: key `sink.origin_shift.write_period_ms`"
        )) && msg.contains("expected 1..=10000 ms"),
        "{msg}"
    );
    let msg = refused(&with_sink("request_timeout_ms = 0", X_REG));
    assert!(msg.contains("request_timeout_ms"), "{msg}");
    let msg = refused(&with_sink(
        "reconnect_min_ms = 500\nreconnect_max_ms = 100",
        X_REG,
    ));
    assert!(
        msg.contains("reconnect_max_ms") && msg.contains("reconnect_min_ms"),
        "{msg}"
    );

    // The same axis mapped twice: the second entry's line.
    let twice = X_REG.replace("address = 0", "address = 10");
    let text = with_sink("", &format!("{X_REG}{twice}"));
    let msg = refused(&text);
    let second = text
        .match_indices("[[sink.origin_shift.map.axis]]")
        .nth(1)
        .unwrap()
        .0;
    // The line of `axis = "x"` in the second entry (the header is the line before).
    let line = text[..second].lines().count() + 2;
    assert!(
        msg.contains("sink.origin_shift.map.axis[1].axis") && msg.contains("mapped twice"),
        "{msg}"
    );
    assert!(
        msg.starts_with(&format!("field.toml:{line}:")),
        "line {line}: {msg}"
    );

    // An axis not mapped at all.
    let yz = BASE.to_string() + "[[axis]]\nname = \"y\"\nposition_channel = \"y_mm\"\n";
    let text = format!(
        "{yz}\n[sink.origin_shift]\ntransport = {{ kind = \"tcp\", address = \"127.0.0.1:5020\" }}\n{X_REG}"
    );
    let msg = refused(&text);
    assert!(msg.contains("axis y has no entry"), "{msg}");

    // Overlapping registers (strobe inside x's int32).
    let text = with_sink(
        "",
        &format!(
            "{X_REG}[sink.origin_shift.map.handshake]\nstrobe_address = 1\nack_address = 5\ntimeout_ms = 100\n"
        ),
    );
    let msg = refused(&text);
    assert!(msg.contains("overlap"), "{msg}");
    // Handshake with zero timeout.
    let text = with_sink(
        "",
        &format!(
            "{X_REG}[sink.origin_shift.map.handshake]\nstrobe_address = 4\nack_address = 5\ntimeout_ms = 0\n"
        ),
    );
    assert!(refused(&text).contains("handshake.timeout_ms"));
}

#[test]
fn the_client_heartbeat_is_checked_like_the_other_map_addresses() {
    let map = |keys: &str| format!("[sink.origin_shift.map]\n{keys}\n{X_REG}");
    let ok = with_sink(
        "",
        &map("heartbeat_address = 4\nheartbeat_timeout_ms = 500"),
    );
    let cfg = parse(&ok).unwrap();
    let m = &cfg.sink.origin_shift.as_ref().unwrap().map;
    assert_eq!(
        (m.heartbeat_address, m.heartbeat_timeout_ms),
        (Some(4), Some(500))
    );

    // Inside x's int32 (0..2): refused at the heartbeat's line, under its key.
    let text = with_sink(
        "",
        &map("heartbeat_address = 1\nheartbeat_timeout_ms = 500"),
    );
    let msg = refused(&text);
    let line = line_of(&text, "heartbeat_address");
    assert!(
        msg.starts_with(&format!(
            "field.toml:{line}: key `sink.origin_shift.map.heartbeat_address`"
        )) && msg.contains("overlap"),
        "{msg}"
    );
    // The controller's timeout is required, and must leave a live box 3 write periods.
    let msg = refused(&with_sink("", &map("heartbeat_address = 4")));
    assert!(
        msg.contains("`sink.origin_shift.map.heartbeat_timeout_ms`"),
        "{msg}"
    );
    let text = with_sink(
        "write_period_ms = 50",
        &map("heartbeat_address = 4\nheartbeat_timeout_ms = 100"),
    );
    let msg = refused(&text);
    assert!(
        msg.contains("heartbeat_timeout_ms") && msg.contains("expected 150..=60000"),
        "{msg}"
    );

    // The stop policy: ramp out by default, bounded.
    assert_eq!(
        cfg.gateway.on_stop,
        retrocomp_gateway::config::OnStop::RampOut
    );
    let text = ok.replace(
        "[gateway]\n",
        "[gateway]\non_stop = \"hold\"\nstop_ramp_max_s = 0.0\n",
    );
    let msg = refused(&text);
    let line = line_of(&text, "stop_ramp_max_s");
    assert!(
        msg.starts_with(&format!("field.toml:{line}: key `gateway.stop_ramp_max_s`")),
        "{msg}"
    );
    assert!(parse(&ok.replace("[gateway]\n", "[gateway]\non_stop = \"sideways\"\n")).is_err());
}

#[test]
fn absurd_limits_are_refused_with_their_key_and_line() {
    let text = BASE.replace("max_correction_um = 50.0", "max_correction_um = 50000.0");
    let msg = refused(&text);
    let line = line_of(&text, "max_correction_um");
    assert!(
        msg.starts_with(&format!(
            "field.toml:{line}: key `safety.max_correction_um`"
        )) && msg.contains("at most 10000"),
        "{msg}"
    );
    let msg = refused(&BASE.replace(
        "max_change_um_per_cycle = 0.5",
        "max_change_um_per_cycle = 80.0",
    ));
    assert!(
        msg.contains("safety.max_change_um_per_cycle") && msg.contains("at most 50"),
        "{msg}"
    );
    let msg = refused(&BASE.replace("stale_hold_s = 1.0", "stale_hold_s = 1e9"));
    assert!(msg.contains("stale_hold_s"), "{msg}");
    let msg = refused(&BASE.replace("cycle_ms = 5", "cycle_ms = 0"));
    assert!(
        msg.starts_with("field.toml:4: key `gateway.cycle_ms`"),
        "{msg}"
    );
}

#[test]
fn run_refuses_an_axis_without_a_position_source() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field.toml");
    // x has a serial DRO source, y has none.
    let text = format!(
        "{BASE}[[axis]]\nname = \"y\"\nposition_channel = \"y_mm\"\n\
         [[serial.source]]\nname = \"dro\"\ndevice = \"/dev/ttyUSB0\"\nformat = {{ kind = \"nd522\" }}\n\
         channel = [ {{ name = \"x_mm\", key = \"X\" }} ]\n"
    );
    std::fs::write(&path, &text).unwrap();
    assert!(
        FieldConfig::load(&path).is_ok(),
        "parse alone does not require sources"
    );
    let msg = FieldConfig::load_for_run(&path).unwrap_err().to_string();
    let line = line_of(&text, "\"y_mm\"");
    assert!(
        msg.contains(&format!(
            "field.toml:{line}: key `axis[1].position_channel`"
        )) && msg.contains("no source delivers \"y_mm\""),
        "{msg}"
    );
}

#[test]
fn a_model_value_infinite_after_unit_conversion_is_refused() {
    let text = r#"schema = 1
[machine]
name = "huge"
chain = "X F Y Z"
[[tools]]
name = "T"
offset_mm = [0.0, 0.0, 0.0]
[[components]]
name = "EXX"
positions_mm = [0.0, 10.0]
forward_mm = [1.0, 1e306]
"#;
    let err = retrocomp_model::MachineModel::from_toml_str(text, "huge.toml").unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("huge.toml") && msg.contains("forward_mm"),
        "{msg}"
    );
    assert!(msg.contains("finite"), "{msg}");
    assert_eq!(err.issues[0].line, 11, "{msg}");
    // The same value in µm is fine.
    assert!(
        retrocomp_model::MachineModel::from_toml_str(
            &text.replace("forward_mm = [1.0, 1e306]", "forward_mm = [0.001, 0.002]"),
            "ok.toml"
        )
        .is_ok()
    );
}

/// Captures what the config loader logs (the WARN lines of `tracing`).
#[derive(Clone, Default)]
struct Captured(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for Captured {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn an_old_word_order_spelling_loads_with_a_warning_naming_file_and_line() {
    let text = with_sink(
        "write_period_ms = 20",
        &X_REG.replace(
            "kind = \"int32\"\n",
            "kind = \"int32\"\nword_order = \"cdab\"\n",
        ),
    );
    let log = Captured::default();
    let writer = log.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .with_ansi(false)
        .finish();
    let cfg = tracing::subscriber::with_default(subscriber, || parse(&text)).unwrap();
    let axis = &cfg.sink.origin_shift.as_ref().unwrap().map.axes[0];
    assert_eq!(axis.word_order, retrocomp_bus::modbus::WordOrder::LowFirst);
    let log = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    let line = line_of(&text, "word_order = \"cdab\"");
    let want = format!(
        "field.toml:{line}: key `sink.origin_shift.map.axis[0].word_order`: \"cdab\" is a deprecated spelling, write \"low_first\""
    );
    assert!(log.contains("WARN") && log.contains(&want), "{log}");
    // The new spelling loads silently.
    let log2 = Captured::default();
    let writer = log2.clone();
    let subscriber = tracing_subscriber::fmt()
        .with_writer(move || writer.clone())
        .finish();
    let new = text.replace("\"cdab\"", "\"low_first\"");
    tracing::subscriber::with_default(subscriber, || parse(&new)).unwrap();
    assert!(log2.0.lock().unwrap().is_empty());
}

#[test]
fn declared_models_must_load_at_start_and_have_plain_names() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field.toml");
    let geo = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/demo/mill-geometric.toml");
    std::fs::copy(&geo, dir.path().join("geo.toml")).unwrap();
    std::fs::write(dir.path().join("broken.toml"), "schema = 1\n[machine\n").unwrap();
    let source = "[[serial.source]]\nname = \"dro\"\ndevice = \"/dev/ttyUSB0\"\n\
                  format = { kind = \"nd522\" }\nchannel = [ { name = \"x_mm\", key = \"X\" } ]\n";
    // Good: relative to the field config, made absolute at start.
    let text = format!("{BASE}{source}[gateway.models]\ngeo = \"geo.toml\"\n");
    std::fs::write(&path, &text).unwrap();
    let cfg = FieldConfig::load_for_run(&path).unwrap();
    assert_eq!(cfg.gateway.models["geo"], dir.path().join("geo.toml"));
    // A file that does not load (or is missing) is refused with file, line and key.
    for (file, want) in [
        ("broken.toml", "broken.toml"),
        ("missing.toml", "missing.toml"),
    ] {
        let text =
            format!("{BASE}{source}[gateway.models]\ngeo = \"geo.toml\"\nbad = \"{file}\"\n");
        std::fs::write(&path, &text).unwrap();
        let msg = FieldConfig::load_for_run(&path).unwrap_err().to_string();
        let line = line_of(&text, "bad = ");
        assert!(
            msg.contains(&format!("field.toml:{line}: key `gateway.models.bad`"))
                && msg.contains(want),
            "{msg}"
        );
    }
    // A name that could be mistaken for a path is refused by the plain parse already.
    let msg = parse(&format!("{BASE}[gateway.models]\n\"a/b\" = \"geo.toml\"\n"))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("gateway.models.a/b") && msg.contains("letters, digits"),
        "{msg}"
    );
}

/// `[sink.quadrature] state_file` (the held counts, persisted before every step): made absolute
/// against the config's directory at start, and refused with file, line and key when its
/// directory is not writable.
#[test]
fn the_quadrature_state_file_must_be_writable() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field.toml");
    let source = "[[serial.source]]\nname = \"dro\"\ndevice = \"/dev/ttyUSB0\"\n\
                  format = { kind = \"nd522\" }\nchannel = [ { name = \"x_mm\", key = \"X\" } ]\n";
    let quad = |file: &str| {
        format!(
            "{BASE}{source}[sink.quadrature]\nstate_file = \"{file}\"\n[[sink.quadrature.axis]]\n\
             axis = \"x\"\nresolution_um = 0.5\ncount_sign = 1\nmin_edge_gap_ns = 400\n\
             max_inject_rate_hz = 200000.0\n"
        )
    };
    std::fs::write(&path, quad("held.toml")).unwrap();
    let cfg = FieldConfig::load_for_run(&path).unwrap();
    let q = cfg.sink.quadrature.unwrap();
    assert_eq!(q.state_file, Some(dir.path().join("held.toml")));
    let text = quad("no/such/dir/held.toml");
    std::fs::write(&path, &text).unwrap();
    let msg = FieldConfig::load_for_run(&path).unwrap_err().to_string();
    let line = line_of(&text, "state_file = ");
    assert!(
        msg.contains(&format!(
            "field.toml:{line}: key `sink.quadrature.state_file`"
        )) && msg.contains("not writable"),
        "{msg}"
    );
}

/// One channel table per box: every decoder built from a field file resolves its channels to
/// the ids the engine gives them (the file's `channel_table`), so no decoder adds a name and a
/// sample's id means the same channel on every thread.
#[test]
fn decoders_and_the_engine_share_the_field_files_channel_ids() {
    use retrocomp_bus::canopen::CanopenSource;
    use retrocomp_bus::modbus::PollSchedule;
    use retrocomp_bus::serial::LineSource;
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_corpus/field_toml/sensors-can-modbus-serial.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let cfg = FieldConfig::parse(&text, &path).unwrap();
    let table = cfg.channel_table();
    let mut built = table.clone();
    CanopenSource::new(cfg.canopen.clone().unwrap(), &mut built);
    for m in &cfg.modbus.as_ref().unwrap().source {
        PollSchedule::new(m, &mut built);
    }
    for s in &cfg.serial.as_ref().unwrap().source {
        LineSource::new(s.clone(), &mut built);
    }
    assert_eq!(built.len(), table.len(), "a decoder added a name");
    let engine = cfg.engine(&std::collections::BTreeMap::new()).unwrap();
    let names = [
        "x_mm",
        "y_mm",
        "z_mm",
        "T_column_C",
        "T_spindle_C",
        "T_table_C",
        "F_spindle_N",
        "x_dro_mm",
    ];
    for name in names {
        let id = table
            .get(name)
            .unwrap_or_else(|| panic!("{name} not in the table"));
        assert_eq!(engine.channels().get(name), Some(id), "{name}");
        assert_eq!(engine.channels().name(id), name);
    }
    assert_eq!(table.len(), names.len(), "one id per name");
}
