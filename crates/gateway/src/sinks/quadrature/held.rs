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
use super::counts::CountError;

/// Why the held counts could not be read, saved or handed out.
#[derive(Debug, thiserror::Error)]
pub enum HeldError {
    /// The store's file could not be read, written or renamed (`what` says which and where).
    #[error("{what}")]
    Io {
        what: String,
        #[source]
        source: std::io::Error,
    },
    /// The file is not `axis = count` lines.
    #[error(
        "{path} is corrupt (expected `axis = count` lines); fix or, after homing the controller, \
         delete it"
    )]
    Corrupt {
        path: String,
        #[source]
        source: toml::de::Error,
    },
    /// Another store's own failure (the harness's, a test's).
    #[error("{0}")]
    Store(String),
    /// The correction has no count (the quantizer refused it).
    #[error(transparent)]
    Count(#[from] CountError),
}

fn io(what: String) -> impl FnOnce(std::io::Error) -> HeldError {
    move |source| HeldError::Io { what, source }
}

/// Where the held counts live.
pub trait HeldCounts {
    /// Every axis's persisted count; `Ok(None)` = nothing persisted (first start: all 0).
    fn load(&mut self) -> Result<Option<BTreeMap<String, i64>>, HeldError>;
    /// Persist `axis`'s count (the others unchanged); returns only once it is durable.
    fn save(&mut self, axis: &str, count: i64) -> Result<(), HeldError>;
}

/// The count delta for `correction_um`, persisted ahead: when the target count changes it is saved
/// first, and only then handed out. A failed save hands out nothing (the quantizer stays at what is
/// persisted), so the controller never holds a count the store does not know.
pub(crate) fn write_ahead(
    store: &mut dyn HeldCounts,
    axis: &str,
    quant: &mut CountQuantizer,
    correction_um: f64,
) -> Result<i64, HeldError> {
    let target = quant.target_counts(correction_um)?;
    if target != quant.emitted_counts() {
        store.save(axis, target)?;
    }
    Ok(quant.delta_counts(correction_um)?)
}

/// The gateway's store: one TOML file per sink (`x = -6`), replaced atomically on every change.
#[derive(Debug)]
pub(crate) struct FileHeldCounts {
    path: PathBuf,
    counts: BTreeMap<String, i64>,
}

impl FileHeldCounts {
    pub(crate) fn new(path: PathBuf) -> Self {
        Self {
            path,
            counts: BTreeMap::new(),
        }
    }
}

impl HeldCounts for FileHeldCounts {
    fn load(&mut self) -> Result<Option<BTreeMap<String, i64>>, HeldError> {
        let text = match std::fs::read_to_string(&self.path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(io(format!("reading {}", self.path.display()))(e)),
        };
        let counts: BTreeMap<String, i64> =
            toml::from_str(&text).map_err(|source| HeldError::Corrupt {
                path: self.path.display().to_string(),
                source,
            })?;
        self.counts = counts.clone();
        Ok(Some(counts))
    }

    fn save(&mut self, axis: &str, count: i64) -> Result<(), HeldError> {
        use std::io::Write as _;
        self.counts.insert(axis.to_string(), count);
        let text = toml::to_string(&self.counts).map_err(|e| HeldError::Store(e.to_string()))?;
        let tmp = self.path.with_extension("tmp");
        let writing = || io(format!("writing {}", tmp.display()));
        let mut f = std::fs::File::create(&tmp).map_err(writing())?;
        f.write_all(text.as_bytes()).map_err(writing())?;
        // Durable before the edges go out: the count must survive a power cut, not only a crash.
        f.sync_all().map_err(writing())?;
        std::fs::rename(&tmp, &self.path).map_err(io(format!(
            "renaming {} to {}",
            tmp.display(),
            self.path.display()
        )))?;
        Ok(())
    }
}

/// Refuse a state file whose directory this process cannot write (checked at start).
pub(crate) fn check_writable(path: &Path) -> Result<(), String> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let probe = dir.join(format!(".retrocomp-write-probe-{}", std::process::id()));
    std::fs::File::create(&probe)
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| {
            format!(
                "a file in a writable directory; {} is not writable: {e}",
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
        fn load(&mut self) -> Result<Option<BTreeMap<String, i64>>, HeldError> {
            Ok(None)
        }
        fn save(&mut self, axis: &str, count: i64) -> Result<(), HeldError> {
            if self.saved.len() >= self.ok {
                return Err(HeldError::Store("disk full".into()));
            }
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
