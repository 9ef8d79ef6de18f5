//! `hil-sim gen-cases --seed N --count K --out DIR`: writes one recording + one manifest per case;
//! every recording reads back strictly (docs/recording-csv.md) and every manifest parses with the truth types.

use std::process::Command;

use retrocomp_analysis::diagnose::scoring::read_manifest;
use retrocomp_model::recording::Recording;

#[test]
fn gen_cases_writes_readable_recordings_and_manifests() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cases");
    let o = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["gen-cases", "--seed", "9", "--count", "4", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for i in 0..4 {
        let rec = Recording::read_path(&out.join(format!("case_{i:04}.csv"))).unwrap();
        assert!(rec.n_rows() > 1000);
        let m = read_manifest(&out.join(format!("case_{i:04}.json"))).unwrap();
        assert_eq!(m.seed, 9);
        // Cases 0–2 are nulls (no hidden effect, snr null); case 3 hides one effect.
        assert_eq!(m.hidden.is_empty(), i < 3, "{m:?}");
        assert_eq!(m.snr.is_none(), i < 3);
    }
}
