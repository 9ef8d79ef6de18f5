//! Measuring tool for diagnose's CPU time and memory without building the whole `retrocomp`
//! binary: reads a recording CSV and prints the same JSON object as
//! `retrocomp diagnose --recording FILE --json` (the library entry the CLI calls without `--out`,
//! `diagnose_owned`, then `serde_json::to_string_pretty`).
//!
//! ```text
//! MALLOC_ARENA_MAX=1 MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=268435456 \
//!   /usr/bin/time -v target/release/examples/diagnose_json recording.csv > out.json
//! ```
//!
//! (built by `cargo build --release -p retrocomp-analysis --example diagnose_json`). The three
//! glibc variables stand for the CLI's `mallopt` calls (src/cli/diagnose.rs), so the time and RSS
//! are the CLI's. `--no-run` drops the `run` column first (how tests/diagnose/asadullah.rs also
//! runs the Asad Ullah tables); `--skip-bad-rows` reads leniently, as the CLI flag does (the
//! skipped rows are not added to the JSON here). Each stage the diagnosis reports
//! (`diagnose::progress`) is printed on stderr with the wall and CPU seconds since the start
//! (CPU from /proc), so a run shows where its time goes and how much of it ran on both cores.

use retrocomp_analysis::diagnose::{diagnose_owned, select::Options};
use retrocomp_model::recording::Recording;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let no_run = args.iter().any(|a| a == "--no-run");
    let lenient = args.iter().any(|a| a == "--skip-bad-rows");
    let Some(path) = args.iter().find(|a| !a.starts_with("--")) else {
        return Err("usage: diagnose_json [--no-run] [--skip-bad-rows] RECORDING.csv".into());
    };
    let mut rec = if lenient {
        Recording::read_lenient(std::fs::File::open(path)?, path)?.0
    } else {
        Recording::read_path(std::path::Path::new(path))?
    };
    if no_run {
        let cols = rec
            .names()
            .iter()
            .filter(|n| *n != "run")
            .map(|n| (n.clone(), rec.col(n).expect("named").to_vec()))
            .collect();
        rec = Recording::from_columns(cols)?;
    }
    let start = std::time::Instant::now();
    let _stages = retrocomp_analysis::diagnose::progress::observe(move |stage| {
        eprintln!(
            "{:8.2} s wall {:8.2} s cpu  {stage}",
            start.elapsed().as_secs_f64(),
            cpu_s()
        );
    });
    let d = diagnose_owned(rec, &Options::default())?;
    eprintln!(
        "{:8.2} s wall {:8.2} s cpu  done",
        start.elapsed().as_secs_f64(),
        cpu_s()
    );
    let report = serde_json::to_value(&d.report)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

/// The process' CPU time (user + system) so far, from /proc/self/stat (NaN where unreadable).
fn cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the command name's closing parenthesis; utime and stime are the 12th and 13th.
    let after = stat.rsplit_once(')').map_or("", |(_, a)| a);
    let f: Vec<f64> = after
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|v| v.parse().ok())
        .collect();
    // Clock ticks: 100 per second on Linux (USER_HZ).
    f.iter().sum::<f64>() / 100.0
}
