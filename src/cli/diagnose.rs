//! `retrocomp diagnose` and `retrocomp diagnose-bench`: thin shells over [`retrocomp_analysis::diagnose`].

use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail};

use retrocomp_analysis::diagnose::scoring::{self, CaseScore};
use retrocomp_analysis::diagnose::{self, output, select::Options};
use retrocomp_model::recording::{BadRow, Recording};

#[derive(clap::Args, Debug)]
pub(crate) struct DiagnoseArgs {
    /// Recording CSV (docs/recording-csv.md).
    #[arg(long)]
    pub recording: PathBuf,
    /// Machine model TOML to evaluate as the simulation (instead of the `sim_e*_um` columns).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Directory for report.json, model.toml (the machine model with the found terms added),
    /// found_terms.toml and SVG plots.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the docs/diagnose-json.md JSON object instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// Keep going past bad rows (each listed on stderr, and under `skipped_rows` in the JSON and
    /// report.json), instead of refusing the file.
    #[arg(long)]
    pub skip_bad_rows: bool,
    /// With --out: also write the joint refit's constant offset into model.toml (for a simulation
    /// fitted on this same recording, whose intercept was fitted without the found terms).
    #[arg(long)]
    pub fit_offset: bool,
    #[command(flatten)]
    pub report: super::report_args::ReportArgs,
}

/// Read a recording; `lenient` (`--skip-bad-rows`) keeps going past bad rows, prints every one on
/// stderr (file, line, column, why) and returns them for the JSON output.
pub(crate) fn read_recording(
    path: &Path,
    lenient: bool,
) -> anyhow::Result<(Recording, Vec<BadRow>)> {
    if !lenient {
        return match Recording::read_path(path) {
            Ok(rec) => Ok((rec, vec![])),
            Err(e @ retrocomp_model::recording::RecordingError::BadRows { .. }) => {
                Err(anyhow::anyhow!(
                    "{e}to skip these rows and use the rest, run again with --skip-bad-rows (each skipped row is listed)"
                ))
            }
            Err(e) => Err(e.into()),
        };
    }
    let f = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let (rec, bad) = Recording::read_lenient(f, &path.display().to_string())?;
    for b in &bad {
        eprintln!("{}: skipped {b}", path.display());
    }
    Ok((rec, bad))
}

/// The skipped rows as a JSON list (`[{"line", "column", "reason"}]`), the `skipped_rows` key that
/// `--skip-bad-rows` adds to the JSON object (docs/diagnose-json.md's keys are unchanged).
pub(crate) fn skipped_rows_json(bad: &[BadRow]) -> serde_json::Value {
    bad.iter()
        .map(|b| serde_json::json!({ "line": b.line, "column": b.column, "reason": b.reason }))
        .collect()
}

pub(crate) fn run_diagnose(a: &DiagnoseArgs) -> anyhow::Result<()> {
    tune_malloc();
    let progress = super::term::Progress::spinner("diagnose: reading the recording");
    let (rec, bad) = read_recording(&a.recording, a.skip_bad_rows)?;
    progress.stage("diagnose: finding what simulation and recording disagree on");
    // The analysis names each stage it enters (signal, selection step, exchange, refit).
    let set = progress.stage_setter();
    let observing = diagnose::progress::observe(move |what| set(&format!("diagnose: {what}")));
    let base = match &a.model {
        Some(m) => Some(
            retrocomp_model::MachineModel::from_toml_path(m).map_err(|e| anyhow::anyhow!("{e}"))?,
        ),
        None => None,
    };
    // Without --out nothing needs the recording afterwards: diagnose takes it and drops the
    // error and sim columns once it has the residuals (the 1M-row memory bound).
    let mut rec = Some(rec);
    let d = match (&base, &a.model) {
        (Some(model), Some(m)) => {
            let rec = rec.as_ref().expect("kept");
            let sims = diagnose::model_sim::simulate(model, rec)
                .with_context(|| m.display().to_string())?;
            let inputs = diagnose::model_sim::regressors(model, rec);
            diagnose::diagnose_with_model_sim(rec, &sims, &inputs, &Options::default())
        }
        _ if a.out.is_none() => {
            diagnose::diagnose_owned(rec.take().expect("not taken yet"), &Options::default())
        }
        _ => diagnose::diagnose(rec.as_ref().expect("kept"), &Options::default()),
    }
    .with_context(|| a.recording.display().to_string())?;
    drop(observing);
    progress.finish();
    let mut report = serde_json::to_value(&d.report)?;
    if a.skip_bad_rows {
        report["skipped_rows"] = skipped_rows_json(&bad);
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", d.report.to_text());
    }
    if let Some(dir) = &a.out {
        let rec = rec.as_ref().expect("kept with --out");
        let (files, m) = output::write_outputs_opts(&d, rec, base.as_ref(), dir, a.fit_offset)?;
        if a.skip_bad_rows {
            // report.json (files[0]) carries the skipped rows too.
            std::fs::write(&files[0], serde_json::to_string_pretty(&report)?)?;
        }
        // Nothing the model cannot hold is dropped silently: with --json it goes to stderr.
        let mut text = format!("\nmachine model {}: {}\n", files[1].display(), m.base);
        for l in &m.added {
            text.push_str(&format!("  added: {l}\n"));
        }
        for l in &m.not_in_model {
            text.push_str(&format!("  NOT in the model: {l}\n"));
        }
        if a.json {
            eprint!("{text}");
        } else {
            print!("{text}");
            println!("wrote {} files to {}", files.len(), dir.display());
        }
    }
    let mut inputs = vec![a.recording.as_path()];
    inputs.extend(a.model.as_deref());
    a.report.write("Diagnosis of a recording", &inputs, || {
        super::diagnose_report::sections(&d)
    })
}

#[derive(clap::Args, Debug)]
pub(crate) struct BenchArgs {
    /// Directory written by `hil-sim gen-cases` (case_NNNN.csv + case_NNNN.json).
    #[arg(long)]
    pub cases: PathBuf,
    /// Also print one line per case.
    #[arg(long)]
    pub verbose: bool,
    /// Print one JSON object (overall summary, per-family summaries, per-case scores, time)
    /// instead of the tables.
    #[arg(long)]
    pub json: bool,
}

/// Diagnose one case file pair and score it against its manifest.
pub(crate) fn score_file(csv: &Path) -> anyhow::Result<CaseScore> {
    let m = scoring::read_manifest(&csv.with_extension("json"))?;
    let rec = Recording::read_path(csv)?;
    let d = diagnose::diagnose(&rec, &Options::default())?;
    Ok(scoring::score_case(&m, &rec, &d.report))
}

pub(crate) fn run_bench(a: &BenchArgs) -> anyhow::Result<()> {
    let mut csvs: Vec<PathBuf> = std::fs::read_dir(&a.cases)
        .with_context(|| a.cases.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "csv") && p.with_extension("json").exists())
        .collect();
    csvs.sort();
    if csvs.is_empty() {
        bail!(
            "{}: no case CSV + JSON pairs (run `hil-sim gen-cases --out DIR` first)",
            a.cases.display()
        );
    }
    let start = std::time::Instant::now();
    let mut scores = vec![];
    let progress = super::term::Progress::bar(csvs.len() as u64, "diagnose-bench: cases");
    for c in &csvs {
        let s = score_file(c)?;
        progress.inc(1);
        if a.verbose && !a.json {
            progress.suspend(|| println!(
                "{} {:<13} {:<10} snr {:>6.2} verdict {:<9} recalled {}/{} spurious {} perr {:?} heldout {:?} forward {:?}",
                s.case,
                s.family,
                s.class,
                s.snr,
                s.verdict,
                s.recalled,
                s.n_hidden,
                s.spurious,
                s.param_errors,
                s.heldout_gain_ratio,
                s.forward_gain_ratio
            ));
        }
        scores.push(s);
    }
    progress.finish();
    let sum = scoring::summarize(&scores);
    let fams = scoring::summarize_by_family(&scores);
    let elapsed_s = start.elapsed().as_secs_f64();
    if a.json {
        let families: Vec<serde_json::Value> = fams
            .iter()
            .map(|(f, s)| {
                let mut v = serde_json::to_value(s).expect("serialisable");
                v["family"] = f.as_str().into();
                v["meets_targets"] = s.meets_targets().into();
                v
            })
            .collect();
        let out = serde_json::json!({
            "overall": sum,
            "families": families,
            "cases": scores,
            "diagnose_time_s": elapsed_s,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("{}", sum.to_markdown());
    println!("{}", scoring::families_markdown(&fams));
    println!("diagnose time: {elapsed_s:.2} s for {} cases", csvs.len());
    Ok(())
}

/// One glibc malloc arena for the whole process, and freed columns kept in it for the next one.
/// The screening's rayon threads each allocate and free recording-length columns (8 MB at 10⁶
/// rows); with an arena per thread glibc keeps each thread's freed columns for that thread, which
/// cost ≈ 90 MB of peak RSS on the 1M-row mill recording (618 → 525 MB, the same JSON, +1 s of
/// system time: `docs/performance.md`). glibc's defaults also serve a block that large by mmap,
/// or give the heap's freed top back to the kernel, so nearly every fresh column was first-touch
/// page faults: 3.9 million on that recording, ≈ 7.5 s of system time. With blocks up to 32 MB
/// (the ceiling of glibc's own sliding mmap threshold) taken from the heap, and its top trimmed
/// only beyond 256 MB free: 0.27 million faults, 0.7 s (part of the saving returns as user time:
/// calloc zeroes a reused block itself), the same peak RSS (448 → 446 MB) and the same JSON (the
/// allocator places buffers, it computes nothing).
fn tune_malloc() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter; it is called before any thread of ours
    // exists and its result (0 on failure) only means the default stays.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
}
