//! ISSUE 12 TARGETS ON THE HARD FAMILIES — the score of `retrocomp diagnose` (what `retrocomp
//! diagnose-bench` reports per family), not the generator's properties (those are
//! `cases_hard_families.rs`). On every hard family, at effect/noise ≥ 1 (all effect cases of these
//! families): recall ≥ 0.9, FPR on nulls ≤ 0.05, median relative parameter error ≤ 15 %.
//!
//! Written before the algorithm that is meant to pass it (forward validation, autocorrelation-aware
//! criteria, rpm as a heat driver): with diagnose as of commit c8d149a it failed on five of six
//! families. Four now meet every target and are asserted in CI; the two random-walk families stay
//! `#[ignore]`d — see the per-family table it prints and docs/diagnose.md "Hard families".

use hil_sim::cases::{Family, generate_family_case};
use retrocomp_analysis::diagnose::scoring::{families_markdown, score_case, summarize_by_family};
use retrocomp_analysis::diagnose::{diagnose, select::Options};

/// Cases per family: indices 0–19 (6 nulls, 14 effect cases: every effect id once in the families
/// that cycle through them).
const PER_FAMILY: usize = 20;

/// Diagnose cases 0..PER_FAMILY of seed 2026 in `families`; print the per-family table and return
/// the families that miss a target, with their figures.
fn failing_targets(families: &[Family]) -> Vec<String> {
    let mut scores = vec![];
    for &fam in families {
        for i in 0..PER_FAMILY {
            let (rec, m) = generate_family_case(fam, 2026, i);
            let d = diagnose(&rec, &Options::default())
                .unwrap_or_else(|e| panic!("{}: diagnose failed: {e:#}", m.case));
            scores.push(score_case(&m, &rec, &d.report));
        }
    }
    let fams = summarize_by_family(&scores);
    eprintln!("{}", families_markdown(&fams));
    assert_eq!(fams.len(), families.len());
    for (f, s) in &fams {
        assert_eq!(s.nulls, 6, "{f}");
        assert_eq!(s.effects_scored, 14, "{f}");
    }
    fams.iter()
        .filter(|(_, s)| !s.meets_targets())
        .map(|(f, s)| {
            format!(
                "{f}: recall {:.3} (≥ 0.9), FPR {:.3} (≤ 0.05), median param error {:.3} (≤ 0.15)",
                s.recall, s.fpr, s.median_param_error
            )
        })
        .collect()
}

/// The four hard families that meet every target (since session 11, `regime` too) are held to
/// them in CI.
#[test]
fn issue_12_targets_on_ar099_rpm_heat_ambient_drift_and_regime() {
    let failing = failing_targets(&[
        Family::Ar099,
        Family::RpmHeat,
        Family::AmbientDrift,
        Family::Regime,
    ]);
    assert!(
        failing.is_empty(),
        "issue 12 targets not met:\n{}",
        failing.join("\n")
    );
}

#[test]
#[ignore = "issue 12 (open): random_walk (recall 0.71) and rw_decoy (0.79) miss the 0.9 target; their slow-effect misses are below the best-case GLS evidence (scripts/rw_gls_bound.py, docs/diagnose.md); run with --ignored to see the current figures"]
fn issue_12_targets_on_the_random_walk_families() {
    let failing = failing_targets(&[Family::RandomWalk, Family::RwDecoy]);
    assert!(
        failing.is_empty(),
        "issue 12 targets not met:\n{}",
        failing.join("\n")
    );
}

/// Development aid: the hard families named in `HARD_FAMILIES` (comma-separated, default all),
/// cases `HARD_FROM`..`HARD_TO` (default 0..20) of seed `HARD_SEED` (default 2026), one line per
/// case (verdict, what was recalled, false alarm, spurious findings) and the per-family table.
/// Asserts only that every case was diagnosed: the targets are asserted by the tests above.
#[test]
#[ignore = "development aid: HARD_FAMILIES=random_walk,ar099 cargo test -p hil-sim --test sim cases::hard_benchmark::subset -- --ignored --nocapture"]
fn subset() {
    let want = std::env::var("HARD_FAMILIES").unwrap_or_default();
    let num = |k: &str, d: usize| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let (from, to) = (num("HARD_FROM", 0), num("HARD_TO", PER_FAMILY));
    let seed = num("HARD_SEED", 2026) as u64;
    let mut scores = vec![];
    for fam in Family::HARD {
        if !want.is_empty() && !want.split(',').any(|w| w == fam.name()) {
            continue;
        }
        for i in from..to {
            let (rec, m) = generate_family_case(fam, seed, i);
            let d = diagnose(&rec, &Options::default())
                .unwrap_or_else(|e| panic!("{}: diagnose failed: {e:#}", m.case));
            let s = score_case(&m, &rec, &d.report);
            let found: Vec<String> = d
                .report
                .findings
                .iter()
                .map(|f| format!("{}/{}", f.effect, f.axis))
                .collect();
            eprintln!(
                "{} {} snr {:.2} verdict {} recalled {}/{} fp {} spurious {} found {:?}",
                m.case,
                s.class,
                s.snr,
                s.verdict,
                s.recalled,
                s.n_hidden,
                s.false_positive,
                s.spurious,
                found
            );
            scores.push(s);
        }
    }
    assert!(!scores.is_empty(), "no family matched HARD_FAMILIES={want}");
    eprintln!("{}", families_markdown(&summarize_by_family(&scores)));
}
