//! Laser runs for the `fit axis` tests: three runs of a bowed X axis (0–500 mm every 25 mm) with a
//! 3 µm reversal and a 0.05 µm run-to-run wobble, in the ISO 230-2 long CSV form.

/// Writes the runs to `path`.
pub(crate) fn bowed_runs_csv(path: &std::path::Path) {
    let mut s = String::from("target_mm,run,direction,deviation_um\n");
    for run in 1..=3 {
        for i in 0..=20 {
            let x = 25.0 * f64::from(i);
            let e = 0.03 * x - 4e-5 * x * x + 0.05 * f64::from(run % 2);
            s.push_str(&format!(
                "{x},{run},+,{:.3}\n{x},{run},-,{:.3}\n",
                e + 1.5,
                e - 1.5
            ));
        }
    }
    std::fs::write(path, s).unwrap();
}
