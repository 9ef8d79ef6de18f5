//! The corpus of broken model files (`tests/fixtures/models/*.toml`): each must be refused with an
//! error that names the file, the line of the mistake (marked `# ERROR-HERE` in the fixture), the
//! key, and what was expected (the fixture's `# key:` and `# message:` header lines).

use std::path::Path;

use retrocomp_model::MachineModel;

fn header<'a>(text: &'a str, field: &str) -> &'a str {
    let tag = format!("# {field}: ");
    text.lines()
        .find_map(|l| l.strip_prefix(&tag))
        .unwrap_or_else(|| panic!("fixture lacks `{tag}`"))
}

#[test]
fn every_broken_fixture_is_refused_with_file_line_key_and_expectation() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/models");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(
        files.len() >= 15,
        "the issue asks for at least 15 broken files, found {}",
        files.len()
    );
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let (key, message) = (header(&text, "key"), header(&text, "message"));
        let marker = text
            .lines()
            .position(|l| l.contains("# ERROR-HERE"))
            .map(|i| i + 1);
        let err = match MachineModel::from_toml_path(&path) {
            Ok(_) => panic!("{} loaded although it is broken", path.display()),
            Err(e) => e,
        };
        let shown = err.to_string();
        let file_name = path.display().to_string();
        let issue = err
            .issues
            .iter()
            .find(|i| i.key == key && i.message.contains(message))
            .unwrap_or_else(|| panic!("{}: no issue with key `{key}` and message containing {message:?}; got:\n{shown}", path.display()));
        assert_eq!(issue.file, file_name);
        assert!(
            shown.contains(&format!("{file_name}:{}:", issue.line)),
            "the message names file and line: {shown}"
        );
        if let Some(line) = marker {
            // A syntax error may surface on the line after the mistake (where the parser notices).
            let ok = issue.line == line || (key.is_empty() && issue.line == line + 1);
            assert!(
                ok,
                "{}: reported line {} but the mistake is on line {line}\n{shown}",
                path.display(),
                issue.line
            );
        }
        assert_eq!(
            err.issues.len(),
            1,
            "{}: one mistake gives one message, no follow-on noise:\n{shown}",
            path.display()
        );
    }
}

#[test]
fn several_problems_are_all_reported_in_file_order() {
    let text = r#"schema = 1
[machine]
name = "many"
chain = "X F Y Z"
[[tools]]
name = "T"
offset_mm = [0.0, 0.0]
[[components]]
name = "EXX"
positions_mm = [0.0, 10.0]
forward_um = [1.0, "two"]
[[sensors]]
name = "s"
tau_s = 0.0
"#;
    let err = MachineModel::from_toml_str(text, "many.toml").unwrap_err();
    let lines: Vec<usize> = err.issues.iter().map(|i| i.line).collect();
    assert_eq!(lines, vec![7, 11, 14], "{err}");
    assert!(err.issues[0].message.contains("expected 3 numbers"));
    assert_eq!(err.issues[1].key, "components[0].forward_um[1]");
    assert!(err.issues[2].message.contains("> 0"));
}

#[test]
fn a_missing_file_is_a_clear_error() {
    let err = MachineModel::from_toml_path(Path::new("/nonexistent/machine.toml")).unwrap_err();
    assert!(
        err.to_string()
            .starts_with("/nonexistent/machine.toml: cannot read"),
        "{err}"
    );
}
