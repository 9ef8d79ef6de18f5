//! `retrocomp check-config` on field files, as the real binary (issue 40.5): a field file is
//! checked with the model it names and nothing is opened (its sources point at a serial device
//! and a Modbus host that do not exist); `FILE` and `--field FILE` both work; a missing model
//! names the field file, line and key; an unclosed `[` is reported on its own line; a recording
//! with bad rows names `--skip-bad-rows`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::base_field;
use base_field::BASE;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

fn root(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

/// A field file whose sources cannot be opened here (a serial device and a Modbus host that do
/// not exist): check-config must not try.
fn field(model: &str) -> String {
    format!(
        r#"{BASE}[model]
path = "{model}"
[[axis]]
name = "z"
position_channel = "z_mm"
[[serial.source]]
name = "dro"
device = "/dev/retrocomp-no-such-tty"
format = {{ kind = "nd522" }}
channel = [ {{ name = "x_mm" }}, {{ name = "z_mm" }} ]
[[modbus.source]]
name = "pt100"
transport = "tcp"
host = "192.0.2.1"
channel = [
  {{ channel = "T_spindle_C", kind = "input", address = 0, type = "int16", scale = 0.1 }},
  {{ channel = "T_bed_C", kind = "input", address = 1, type = "int16", scale = 0.1 }},
  {{ channel = "T_carriage_C", kind = "input", address = 2, type = "int16", scale = 0.1 }},
]
"#
    )
}

#[test]
fn a_field_file_is_checked_with_its_model_offline_both_spellings() {
    let dir = tempfile::tempdir().unwrap();
    let model = root("deploy/field/lathe-machine.toml");
    let f = dir.path().join("field.toml");
    std::fs::write(&f, field(model.to_str().unwrap())).unwrap();
    for args in [vec!["check-config"], vec!["check-config", "--field"]] {
        let o = bin().args(&args).arg(&f).output().unwrap();
        let (out, err) = text(&o);
        assert!(o.status.success(), "{args:?}: {err}");
        assert!(
            out.contains("field config") && out.contains(": OK"),
            "{args:?}: {out}"
        );
        assert!(
            out.contains("sources deliver: T_spindle_C, T_bed_C, T_carriage_C, x_mm, z_mm"),
            "{out}"
        );
        assert!(
            out.contains("model \"excello-921\"") && out.contains("sensor T_bed_C"),
            "{out}"
        );
    }
    // A model file still checks as before.
    let o = bin().arg("check-config").arg(&model).output().unwrap();
    assert!(o.status.success() && text(&o).0.starts_with("model \"excello-921\""));
    // The shipped RTU lathe checks too (its model beside it). (mill-quadrature.toml names a
    // state_file under /var/lib/retrocomp, whose writability is the box's, checked there.)
    let o = bin()
        .arg("check-config")
        .arg(root("deploy/field/lathe-origin-shift-rtu.toml"))
        .output()
        .unwrap();
    let (out, err) = text(&o);
    assert!(o.status.success() && out.contains(": OK"), "{err}{out}");
}

#[test]
fn a_missing_model_or_input_names_the_field_file_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("field.toml");
    let t = field("no-such-model.toml");
    std::fs::write(&f, &t).unwrap();
    let o = bin().arg("check-config").arg(&f).output().unwrap();
    let (_, err) = text(&o);
    assert!(!o.status.success());
    let want = format!(
        "{}:{}: key `model.path`",
        f.display(),
        line_of(&t, "path =")
    );
    assert!(err.contains(&want), "want {want}: {err}");
    assert!(err.contains("no-such-model.toml: cannot read"), "{err}");

    // The model asks for a sensor the field file does not deliver.
    let t = field(root("deploy/field/lathe-machine.toml").to_str().unwrap())
        .replace("T_carriage_C", "T_saddle_C");
    std::fs::write(&f, &t).unwrap();
    let o = bin().arg("check-config").arg(&f).output().unwrap();
    let (_, err) = text(&o);
    assert!(!o.status.success());
    assert!(
        err.contains(&want) && err.contains("needs T_carriage_C but no source delivers it"),
        "{err}"
    );
}

#[test]
fn an_unclosed_bracket_is_reported_on_its_own_line() {
    let dir = tempfile::tempdir().unwrap();
    let model = root("deploy/field/lathe-machine.toml");
    // Field file: `channel = [` left open; the next table header starts two lines later.
    let t = field(model.to_str().unwrap()).replace(
        "channel = [ { name = \"x_mm\" }, { name = \"z_mm\" } ]",
        "channel = [ { name = \"x_mm\" }, { name = \"z_mm\" }\n",
    );
    let f = dir.path().join("field.toml");
    std::fs::write(&f, &t).unwrap();
    let o = bin().arg("check-config").arg(&f).output().unwrap();
    let (_, err) = text(&o);
    let open = line_of(&t, "channel = [ { name");
    assert!(!o.status.success());
    assert!(
        err.contains(&format!("field.toml:{open}:")) && err.contains("is not closed"),
        "line {open}: {err}"
    );
    // Model file: the same mistake in a table row.
    let m = std::fs::read_to_string(&model).unwrap();
    let bad = m.replacen(
        "reference_C = 20.0\ntau_s = 240.0",
        "reference_C = 20.0\ntau_s = [240.0\n",
        1,
    );
    assert_ne!(bad, m);
    let p = dir.path().join("model.toml");
    std::fs::write(&p, &bad).unwrap();
    let o = bin().arg("check-config").arg(&p).output().unwrap();
    let (_, err) = text(&o);
    let open = line_of(&bad, "tau_s = [240.0");
    assert!(
        err.contains(&format!("model.toml:{open}:")) && err.contains("is not closed"),
        "line {open}: {err}"
    );
}

#[test]
fn bad_recording_rows_name_the_flag_that_skips_them() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let mut s = String::from("t_s,x_mm,T_a_C,ex_um\n");
    for i in 0..50 {
        s.push_str(&format!(
            "{},{},{},{}\n",
            i * 10,
            i % 5,
            20.0 + f64::from(i) * 0.1,
            0.5
        ));
    }
    s.push_str("500,1,oops,0.5\n");
    std::fs::write(&rec, s).unwrap();
    let o = bin()
        .args(["diagnose", "--recording"])
        .arg(&rec)
        .output()
        .unwrap();
    let (_, err) = text(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("line 52") && err.contains("--skip-bad-rows"),
        "{err}"
    );
}
