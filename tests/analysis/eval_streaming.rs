//! `retrocomp eval` streams (issue 14.5): memory stays bounded whatever the recording's length, and
//! the streamed output is the model's evaluation row by row.
//!
//! The recording is the real FL_THERMAL file (`tests/data/fl_thermal/`, MIT) tiled with time
//! continuing, evaluated by the fixed thermal model of the pandas side by side
//! (`benches/data/eval_thermal_model.toml`: a ΔT polynomial plus a first-order lag, both on EZZ).
//! Peak memory is the child's own `ru_maxrss` from `wait4`: it does not depend on how fast this
//! machine is. Holding every row, as `eval` did, took ≈ 865 bytes a row (865 MB for 10⁶).

use std::io::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};

use retrocomp_model::MachineModel;

const MODEL: &str = "benches/data/eval_thermal_model.toml";
const SOURCE: &str = "tests/data/fl_thermal/fl_thermal_dev.csv";

/// `rows` rows of the FL recording repeated, `t_s` continuing at its 15 s step.
fn tiled_recording(path: &Path, rows: usize) {
    let text = std::fs::read_to_string(SOURCE).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let body: Vec<&str> = lines.collect();
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    writeln!(out, "{header}").unwrap();
    for i in 0..rows {
        let line = body[i % body.len()];
        let rest = &line[line.find(',').unwrap()..];
        writeln!(out, "{}{rest}", i * 15).unwrap();
    }
    out.flush().unwrap();
}

/// Run `retrocomp eval` with stdout into `out`; return its exit status and peak RSS in MiB.
fn eval_peak_rss_mib(input: &Path, out: &Path) -> (i32, f64) {
    let child = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["eval", "--model", MODEL, "--path"])
        .arg(input)
        .stdout(Stdio::from(std::fs::File::create(out).unwrap()))
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: plain FFI; `usage` is a valid out-pointer and the child is ours (std will not reap it:
    // `child` is dropped without wait, which neither waits nor kills).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let got = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(got, pid, "wait4: {}", std::io::Error::last_os_error());
    drop(child);
    let code = if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        -1
    };
    (code, usage.ru_maxrss as f64 / 1024.0)
}

#[test]
fn eval_of_200k_rows_streams_in_bounded_memory_and_matches_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("rec.csv"), dir.path().join("out.csv"));
    let rows = 200_000;
    tiled_recording(&input, rows);
    let (code, rss_mib) = eval_peak_rss_mib(&input, &out);
    assert_eq!(code, 0, "retrocomp eval failed");
    println!("eval of {rows} rows: peak RSS {rss_mib:.1} MiB");
    // Holding the rows would need ≈ 165 MiB here; streaming needs the binary and a few buffers.
    assert!(
        rss_mib < 64.0,
        "peak RSS {rss_mib:.1} MiB for {rows} rows: eval is not streaming"
    );

    assert_is_the_model_run_forward(&out, &input, rows);
}

/// `out` holds every row of `input`, in order, its passed-through columns as the csv crate reads
/// them, and `ez_um` equal to the library's evaluation run forward in time (the lag state carries
/// from row to row, so each row checks every row before it).
fn assert_is_the_model_run_forward(out: &Path, input: &Path, rows: usize) {
    let model = MachineModel::from_toml_path(Path::new(MODEL)).unwrap();
    let mut rdr = csv::Reader::from_path(out).unwrap();
    let mut inp = csv::Reader::from_path(input).unwrap();
    let h = rdr.headers().unwrap().clone();
    let passed = inp.headers().unwrap().len();
    assert_eq!(
        &h.iter().take(passed).collect::<Vec<_>>(),
        &inp.headers().unwrap().iter().collect::<Vec<_>>()
    );
    let col = |n: &str| h.iter().position(|c| c == n).unwrap();
    let (ez, t, flags) = (col("ez_um"), col("t_s"), col("flags"));
    let temps: Vec<usize> = model.sensor_columns().iter().map(|n| col(n)).collect();
    let mut state = model.new_state();
    let mut bd = model.new_breakdown();
    let mut input_row = model.new_input();
    let mut n = 0usize;
    let mut worst = 0.0f64;
    for (rec, given) in rdr.records().zip(inp.records()) {
        let (rec, given) = (rec.unwrap(), given.unwrap());
        assert_eq!(
            rec.iter().take(passed).collect::<Vec<_>>(),
            given.iter().collect::<Vec<_>>(),
            "row {n}: the passed-through columns"
        );
        input_row.t_s = rec[t].parse().unwrap();
        for (i, c) in temps.iter().enumerate() {
            input_row.temps_c[i] = rec[*c].parse().unwrap();
        }
        model.evaluate(&input_row, &mut state, &mut bd);
        let streamed: f64 = rec[ez].parse().unwrap();
        worst = worst.max((streamed - bd.total_um[2]).abs());
        assert_eq!(&rec[flags], "", "no flag on a complete row");
        n += 1;
    }
    assert_eq!(n, rows, "every input row is in the output");
    assert!(
        worst <= 5e-7,
        "streamed ez_um differs from the model by {worst} µm"
    );
}

#[test]
fn rows_across_batches_and_the_csv_hand_over_come_out_in_order() {
    // 3.5 batches of rows (4096 each) read and evaluated on two threads; from row 6000 on, a
    // passed-through cell is quoted, so the plain-line reader hands the rest to the csv crate in
    // the middle of a batch, and the quoted cell is written back unquoted (nothing needs quoting).
    let dir = tempfile::tempdir().unwrap();
    let (plain, input, out) = (
        dir.path().join("plain.csv"),
        dir.path().join("rec.csv"),
        dir.path().join("out.csv"),
    );
    let rows = 14_500;
    tiled_recording(&plain, rows);
    let text = std::fs::read_to_string(&plain).unwrap();
    let mut quoted = String::with_capacity(text.len() + rows * 2);
    for (i, line) in text.lines().enumerate() {
        match line.rsplit_once(',') {
            // The last column (a displacement the model does not read) quoted, CRLF endings.
            Some((head, last)) if i > 6000 => quoted.push_str(&format!("{head},\"{last}\"\r\n")),
            _ => quoted.push_str(&format!("{line}\n")),
        }
    }
    std::fs::write(&input, quoted).unwrap();
    let (code, _) = eval_peak_rss_mib(&input, &out);
    assert_eq!(code, 0, "retrocomp eval failed");
    assert_is_the_model_run_forward(&out, &input, rows);
}

#[test]
fn a_bad_row_deep_in_the_file_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("rec.csv");
    tiled_recording(&input, 20_000);
    // Spoil one temperature on line 15 001 (row 15 000 after the header).
    let text = std::fs::read_to_string(&input).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let cells: Vec<&str> = lines[15_000].split(',').collect();
    let mut cells: Vec<String> = cells.into_iter().map(String::from).collect();
    cells[5] = "warm".into(); // T_4_C, read by the model
    lines[15_000] = cells.join(",");
    std::fs::write(&input, lines.join("\n") + "\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["eval", "--model", MODEL, "--path"])
        .arg(&input)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(o.stdout.is_empty(), "nothing is written when a row is bad");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(":15001: column T_4_C: expected a finite number, found \"warm\""),
        "{err}"
    );
}

/// A recording whose line 15 001 holds a temperature the model reads that is not a number.
fn recording_with_a_bad_row(path: &Path) {
    tiled_recording(path, 20_000);
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut cells: Vec<String> = lines[15_000].split(',').map(String::from).collect();
    cells[5] = "warm".into(); // T_4_C, read by the model
    lines[15_000] = cells.join(",");
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn into_a_file_a_bad_row_leaves_the_file_as_it_was() {
    // stdout a regular file positioned at its end: rows go straight into it (≈ 4 MB before the bad
    // row, far past one write chunk), then are taken back, and what was there before stays.
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("rec.csv"), dir.path().join("out.csv"));
    recording_with_a_bad_row(&input);
    let before = b"an earlier result\n";
    let mut f = std::fs::File::create(&out).unwrap();
    f.write_all(before).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["eval", "--model", MODEL, "--path"])
        .arg(&input)
        .stdout(Stdio::from(f))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(":15001: column T_4_C: expected a finite number"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "the file holds what it held"
    );
}

#[test]
fn into_a_pipe_the_output_is_the_same_as_into_a_file() {
    // 20 000 rows ≈ 5.8 MB: past the spool's 4 MiB in memory, so it goes through its temporary file.
    let dir = tempfile::tempdir().unwrap();
    let (input, out) = (dir.path().join("rec.csv"), dir.path().join("out.csv"));
    tiled_recording(&input, 20_000);
    let (code, _) = eval_peak_rss_mib(&input, &out);
    assert_eq!(code, 0);
    let piped = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["eval", "--model", MODEL, "--path"])
        .arg(&input)
        .output()
        .unwrap();
    assert!(piped.status.success());
    let filed = std::fs::read(&out).unwrap();
    assert!(filed.len() > 5 << 20, "{} bytes", filed.len());
    assert!(piped.stdout == filed, "piped and filed outputs differ");
}
