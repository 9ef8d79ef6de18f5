//! What the controller holds from this box, persisted across restarts (pulses have no read-back).
//!
//! Per axis the *held count* is the total of injected counts the controller's receiver has taken
//! (or is about to: the count is written **ahead** of the edges of a step, so after a crash the
//! controller holds the persisted count to within that one step, which the per-write cap bounds).
//! Its phase (`count mod 4`, see [`super::gray::levels_of_phase`]) gives the A/B levels a new box
//! must drive at takeover so the receiver sees no edge. Units: counts (one A/B edge); the held
//! correction in µm is `−count × resolution_um × count_sign` ([`CountQuantizer::correction_um_of`]).
//!
//! The store is a trait so the core stays sans-IO: [`FileHeldCounts`] is the gateway's (one small
//! TOML file per sink, `axis = count`, atomic write + rename), the hil-sim harness keeps it in
//! memory across its simulated restarts.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::CountQuantizer;

/// Where the held counts live.
pub trait HeldCounts {
    /// Every axis's persisted count; `Ok(None)` = nothing persisted (first start: all 0).
    fn load(&mut self) -> anyhow::Result<Option<BTreeMap<String, i64>>>;
    /// Persist `axis`'s count (the others unchanged); returns only once it is durable.
    fn save(&mut self, axis: &str, count: i64) -> anyhow::Result<()>;
}

/// The count delta for `correction_um`, persisted ahead: when the target count changes it is saved
/// first, and only then handed out. A failed save hands out nothing (the quantizer stays at what is
/// persisted), so the controller never holds a count the store does not know.
pub fn write_ahead(
    store: &mut dyn HeldCounts,
    axis: &str,
    quant: &mut CountQuantizer,
    correction_um: f64,
) -> anyhow::Result<i64> {
    let target = quant.target_counts(correction_um)?;
    if target != quant.emitted_counts() {
        store.save(axis, target)?;
    }
    Ok(quant.delta_counts(correction_um)?)
}

/// The gateway's store: one TOML file per sink (`x = -6`), replaced atomically on every change.
pub struct FileHeldCounts {
    path: PathBuf,
    counts: BTreeMap<String, i64>,
}

impl FileHeldCounts {
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            counts: BTreeMap::new(),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl HeldCounts for FileHeldCounts {
    fn load(&mut self) -> anyhow::Result<Option<BTreeMap<String, i64>>> {
        use anyhow::Context as _;
        let text = match std::fs::read_to_string(&self.path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("reading {}", self.path.display())),
        };
        let counts: BTreeMap<String, i64> = toml::from_str(&text).with_context(|| {
            format!(
                "{} is corrupt (expected `axis = count` lines); fix or, after homing the \
                 controller, delete it",
                self.path.display()
            )
        })?;
        self.counts = counts.clone();
        Ok(Some(counts))
    }

    fn save(&mut self, axis: &str, count: i64) -> anyhow::Result<()> {
        use anyhow::Context as _;
        use std::io::Write as _;
        self.counts.insert(axis.to_string(), count);
        let text = toml::to_string(&self.counts)?;
        let tmp = self.path.with_extension("tmp");
        let mut f =
            std::fs::File::create(&tmp).with_context(|| format!("writing {}", tmp.display()))?;
        f.write_all(text.as_bytes())?;
        // Durable before the edges go out: the count must survive a power cut, not only a crash.
        f.sync_all()?;
        std::fs::rename(&tmp, &self.path)
            .with_context(|| format!("renaming {} to {}", tmp.display(), self.path.display()))?;
        Ok(())
    }
}

/// Refuse a state file whose directory this process cannot write (checked at start).
pub fn check_writable(path: &Path) -> Result<(), String> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let probe = dir.join(format!(".retrocomp-write-probe-{}", std::process::id()));
    std::fs::File::create(&probe)
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| {
            format!(
                "a file in a writable directory (the held counts are persisted there); {} is not \
                 writable: {e}",
                dir.display()
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_round_trips_and_a_missing_file_is_a_first_start() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("held.toml");
        let mut s = FileHeldCounts::new(path.clone());
        assert_eq!(s.load().unwrap(), None);
        s.save("x", -6).unwrap();
        s.save("z", 3).unwrap();
        s.save("x", -7).unwrap();
        let mut again = FileHeldCounts::new(path.clone());
        let got = again.load().unwrap().unwrap();
        assert_eq!(got, BTreeMap::from([("x".into(), -7), ("z".into(), 3)]));
        assert!(!path.with_extension("tmp").exists());
        check_writable(&path).unwrap();
        let e = check_writable(&dir.path().join("no/such/dir/held.toml")).unwrap_err();
        assert!(e.contains("not writable"), "{e}");
    }

    #[test]
    fn a_corrupt_file_is_an_error_not_a_first_start() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("held.toml");
        std::fs::write(&path, "x = \"minus six\"\n").unwrap();
        let e = FileHeldCounts::new(path).load().unwrap_err();
        assert!(format!("{e:#}").contains("corrupt"), "{e:#}");
    }

    /// A store whose saves fail after `ok` of them.
    struct Failing {
        ok: usize,
        saved: Vec<(String, i64)>,
    }
    impl HeldCounts for Failing {
        fn load(&mut self) -> anyhow::Result<Option<BTreeMap<String, i64>>> {
            Ok(None)
        }
        fn save(&mut self, axis: &str, count: i64) -> anyhow::Result<()> {
            anyhow::ensure!(self.saved.len() < self.ok, "disk full");
            self.saved.push((axis.into(), count));
            Ok(())
        }
    }

    #[test]
    fn writes_ahead_only_on_a_change_and_hands_out_nothing_unsaved() {
        let mut store = Failing {
            ok: 2,
            saved: Vec::new(),
        };
        let mut q = CountQuantizer::new(1.0, 1).unwrap();
        assert_eq!(write_ahead(&mut store, "x", &mut q, 2.0).unwrap(), -2);
        assert_eq!(write_ahead(&mut store, "x", &mut q, 2.2).unwrap(), 0);
        assert_eq!(write_ahead(&mut store, "x", &mut q, 3.0).unwrap(), -1);
        assert_eq!(store.saved, [("x".into(), -2), ("x".into(), -3)]);
        assert!(write_ahead(&mut store, "x", &mut q, 4.0).is_err());
        assert_eq!(
            q.emitted_counts(),
            -3,
            "nothing handed out beyond what is saved"
        );
    }
}
