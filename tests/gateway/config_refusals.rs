//! Configs that cannot be safe are refused at start with file:line, the key and what was expected
//! (issue 33.5): a direction latch with a negative deadband or a NaN blend, a correction register
//! that cannot hold its clamp (client and server), a served register image with a controller
//! timeout of 0 or without held registers (with and without a write marker), a model table value
//! of 1e300 µm, a `forward_mm` table whose numbers are µm, and a model input no source delivers.

use std::path::{Path, PathBuf};

use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::config::check_field;
use retrocomp_model::MachineModel;

use crate::base_field;
use base_field::BASE;

/// BASE with `from` replaced by `to` (which must occur), plus `extra`.
fn edited(from: &str, to: &str, extra: &str) -> String {
    assert!(BASE.contains(from), "{from}");
    format!("{}{extra}", BASE.replacen(from, to, 1))
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines()
        .position(|l| l.contains(needle))
        .unwrap_or_else(|| panic!("{needle} not in {text}"))
        + 1
}

/// Asserts `text` is refused at the line of `needle` under `key`, mentioning `expected`.
fn assert_refused(text: &str, needle: &str, key: &str, expected: &str) {
    let msg = match FieldConfig::parse(text, Path::new("field.toml")) {
        Ok(_) => panic!("accepted, expected a refusal at {key}:\n{text}"),
        Err(e) => e.to_string(),
    };
    let want = format!("field.toml:{}: key `{key}`: ", line_of(text, needle));
    assert!(msg.starts_with(&want), "want {want:?}, got {msg}");
    assert!(msg.contains(expected), "want {expected:?} in {msg}");
}

#[test]
fn direction_latch_settings_must_be_real() {
    assert!(FieldConfig::parse(BASE, Path::new("field.toml")).is_ok());
    let t = edited("deadband_mm = 0.005", "deadband_mm = -1", "");
    assert_refused(
        &t,
        "deadband_mm",
        "direction.deadband_mm",
        "expected 0 ≤ mm ≤ 1",
    );
    let t = edited("switch_time_s = 0.1", "switch_time_s = nan", "");
    assert_refused(&t, "switch_time_s", "direction.switch_time_s", "got NaN");
    let t = edited("switch_time_s = 0.1", "switch_time_s = inf", "");
    assert_refused(&t, "switch_time_s", "direction.switch_time_s", "got inf");
}

const CLIENT: &str = "[sink.origin_shift]\ntransport = { kind = \"tcp\", address = \"127.0.0.1:5020\" }\n\
[[sink.origin_shift.map.axis]]\naxis = \"x\"\naddress = 0\nkind = \"int16\"\nlsb_um = 0.1\nsign = 1\n";

#[test]
fn a_client_register_must_hold_the_clamp() {
    // 50 µm in int16 at 0.1 µm: fine.
    assert!(FieldConfig::parse(&edited("", "", CLIENT), Path::new("f.toml")).is_ok());
    let t = edited(
        "max_correction_um = 50.0",
        "max_correction_um = 5000.0",
        CLIENT,
    );
    assert_refused(
        &t,
        "kind = \"int16\"",
        "sink.origin_shift.map.axis[0].kind",
        "int16 at lsb_um = 0.1 holds at most ±3276.7 µm, but axis x's clamp max_correction_um is 5000 µm",
    );
    // The same clamp fits an int32, or int16 at 1 µm per count.
    let t32 = t.replace("kind = \"int16\"", "kind = \"int32\"");
    assert!(FieldConfig::parse(&t32, Path::new("f.toml")).is_ok());
    let coarse = t.replace("lsb_um = 0.1", "lsb_um = 1.0");
    assert!(FieldConfig::parse(&coarse, Path::new("f.toml")).is_ok());
}

/// A served image for x: int16 at 0.1 µm, position and held registers, `extra` keys in the sink.
fn server(extra: &str, held: &str) -> String {
    format!(
        "[sink.origin_shift_server]\ntransport = {{ kind = \"tcp\", listen = \"127.0.0.1:1502\" }}\n{extra}\n\
[sink.origin_shift_server.map]\nheartbeat_address = 1\n\
axis = [ {{ axis = \"x\", address = 0, kind = \"int16\", lsb_um = 0.1, sign = 1 }} ]\n\
position = [ {{ channel = \"x_mm\", address = 10, kind = \"int16\", lsb_um = 10.0 }} ]\n{held}"
    )
}

const HELD: &str = "held = [ { axis = \"x\", address = 11 } ]\n";
const MARKER: &str = "write_marker = { address = 12, value = 21930 }\n";

#[test]
fn a_served_image_must_hold_the_clamp_notice_the_controller_and_know_what_it_holds() {
    let ok = edited("", "", &server("", &format!("{HELD}{MARKER}")));
    assert!(FieldConfig::parse(&ok, Path::new("f.toml")).is_ok());

    let t = edited(
        "max_correction_um = 50.0",
        "max_correction_um = 5000.0",
        &server("", &format!("{HELD}{MARKER}")),
    );
    assert_refused(
        &t,
        "axis = [",
        "sink.origin_shift_server.map.axis[0].kind",
        "holds at most ±3276.7 µm",
    );

    let t = edited(
        "",
        "",
        &server("controller_timeout_ms = 0", &format!("{HELD}{MARKER}")),
    );
    assert_refused(
        &t,
        "controller_timeout_ms",
        "sink.origin_shift_server.controller_timeout_ms",
        "expected 20..=60000 ms",
    );

    // Without held registers, with and without a write marker: the line of `[…map]`.
    for held in [MARKER, ""] {
        let t = edited("", "", &server("", held));
        assert_refused(
            &t,
            "[sink.origin_shift_server.map]",
            "sink.origin_shift_server.map.held",
            "a restarted box serves from 0 whatever the controller holds",
        );
    }
}

const MODEL: &str = r#"schema = 1
[machine]
name = "m"
chain = "X F Y Z"
[[tools]]
name = "T"
offset_mm = [0.0, 0.0, 0.0]
[[components]]
name = "EXX"
positions_mm = [0.0, 100.0, 200.0]
forward_um = [0.0, 4.0, 7.5]
"#;

/// The message of a refused model, after asserting its first issue is at `needle`'s line.
fn model_refused(text: &str, needle: &str, key: &str) -> String {
    let e = MachineModel::from_toml_str(text, "m.toml").unwrap_err();
    let msg = e.to_string();
    let want = format!("m.toml:{}:", line_of(text, needle));
    assert!(msg.starts_with(&want), "want {want}, got {msg}");
    assert!(msg.contains(&format!("key `{key}`")), "{msg}");
    msg
}

#[test]
fn table_values_are_checked_against_their_unit() {
    assert!(MachineModel::from_toml_str(MODEL, "m.toml").is_ok());
    let huge = MODEL.replace("[0.0, 4.0, 7.5]", "[0.0, 1e300, 7.5]");
    let msg = model_refused(&huge, "forward_um", "components[0].forward_um");
    assert!(msg.contains("expected |value| ≤ 10000 µm"), "{msg}");
    // µm numbers under `_mm`: 7.5 mm of geometric error is refused, naming the fix.
    let mm = MODEL.replace("forward_um", "forward_mm");
    let msg = model_refused(&mm, "forward_mm", "components[0].forward_mm");
    assert!(
        msg.contains("value [2] is 7.5 mm") && msg.contains("write forward_um"),
        "{msg}"
    );
    // A plausible `_mm` table (Studer S-36 style, 0.0075 mm) loads.
    let plausible = MODEL.replace(
        "forward_um = [0.0, 4.0, 7.5]",
        "forward_mm = [0.0, 0.004, 0.0075]",
    );
    assert!(MachineModel::from_toml_str(&plausible, "m.toml").is_ok());
    // A reverse table and a rotation in rad where µrad was meant.
    let rev = MODEL.replace("7.5]\n", "7.5]\nreverse_mm = [0.0, 4.0, 2.0]\n");
    model_refused(&rev, "reverse_mm", "components[0].reverse_mm");
    let rot = format!(
        "{MODEL}[[components]]\nname = \"EAX\"\npositions_mm = [0.0, 200.0]\nforward_rad = [0.0, 12.0]\n"
    );
    let msg = model_refused(&rot, "forward_rad", "components[1].forward_rad");
    assert!(msg.contains("µrad"), "{msg}");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// A field file for BASE's x axis whose serial DRO delivers `channels`, naming `model`.
fn field_with(channels: &str, model: &str) -> String {
    format!(
        "{BASE}[model]\npath = \"{model}\"\n[[serial.source]]\nname = \"dro\"\ndevice = \"/dev/null\"\nformat = {{ kind = \"nd522\" }}\nchannel = [ {channels} ]\n"
    )
}

#[test]
fn a_model_input_no_source_delivers_is_refused_at_the_model_key() {
    let dir = tempfile::tempdir().unwrap();
    let thermal = format!(
        "{MODEL}[[sensors]]\nname = \"spindle\"\nreference_C = 20.0\n[[thermal]]\nname = \"grow\"\ntarget = \"EXX\"\nkind = \"expansion\"\nsensor = \"spindle\"\nalpha_ppm_per_K = 11.5\norigin_mm = 0.0\n"
    );
    write(dir.path(), "model.toml", &thermal);
    let text = field_with("{ name = \"x_mm\" }", "model.toml");
    let f = write(dir.path(), "field.toml", &text);
    let msg = check_field(&f, None).unwrap_err().to_string();
    let want = format!(
        "{}:{}: key `model.path`: ",
        f.display(),
        line_of(&text, "path =")
    );
    assert!(msg.starts_with(&want), "want {want}, got {msg}");
    assert!(
        msg.contains("needs T_spindle_C but no source delivers it"),
        "{msg}"
    );
    // Delivered by the DRO line: accepted, with the model ready.
    let text = field_with(
        "{ name = \"x_mm\" }, { name = \"T_spindle_C\" }",
        "model.toml",
    );
    let f = write(dir.path(), "field.toml", &text);
    let c = check_field(&f, None).unwrap_or_else(|e| panic!("{e}"));
    assert!(c.optional_missing.is_empty());

    // A missing model names the field file, line and key, then the path it tried.
    let text = field_with("{ name = \"x_mm\" }", "nowhere.toml");
    let f = write(dir.path(), "field.toml", &text);
    let msg = check_field(&f, None).unwrap_err().to_string();
    let want = format!(
        "{}:{}: key `model.path`: expected a machine model TOML; ",
        f.display(),
        line_of(&text, "path =")
    );
    assert!(
        msg.starts_with(&want) && msg.contains("nowhere.toml: cannot read"),
        "{msg}"
    );
}

/// The issue's case: the shipped 16-sensor VMC model with a field file that delivers positions
/// only was accepted and compensated nothing (0 µm forever); now it is refused, every missing
/// sensor named.
#[test]
fn the_vmc_model_without_temperature_sources_is_refused() {
    let root = env!("CARGO_MANIFEST_DIR");
    let dir = tempfile::tempdir().unwrap();
    let text = field_with(
        "{ name = \"x_mm\" }",
        &format!("{root}/deploy/examples/vmc-3axis.toml"),
    );
    let f = write(dir.path(), "field.toml", &text);
    let msg = check_field(&f, None).unwrap_err().to_string();
    assert!(msg.contains("key `model.path`"), "{msg}");
    let names = msg.matches("T_").count();
    assert!(names >= 16, "every missing sensor named ({names}): {msg}");
}
