//! The edge trace: every level the injector threads put on the A/B lines, written as CSV so a
//! counter outside the project (LinuxCNC's HAL `encoder`, `tests/real_peers/linuxcnc_edge_trace.rs`) can count
//! what the box drove.
//!
//! Real-time side: [`EdgeTrace::record`] is a `try_send` into a bounded channel whose buffer is
//! allocated at start (`buffer_edges` entries, std's array-backed `sync_channel`): no allocation, no
//! lock, no wait. The writer thread drains it by polling (it never parks on the channel, so a sender
//! never has to wake it); a full buffer drops the entry and counts it ([`TraceWriter::dropped`]),
//! which the sink reports as a `sink.quadrature.trace` fault — a trace with a hole is never silent.
//!
//! File: `t_ns,axis,a,b,source` per row. `t_ns`: ns on the sink's injector clock (one epoch for all
//! axes, taken when the sink opened its lines), read just before the pin write; `a`, `b`: the levels
//! after the write (0/1); `source`: `start` (the levels the thread drove at takeover), `native` or
//! `injected`. Bounded: when a row would take the file past `max_bytes` it is renamed to
//! `<path>.1` (replacing the previous one) and a new file with the header is started, so at most
//! 2 × `max_bytes` are on disk. An existing trace is rotated the same way at start.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::scheduler::Source;

/// The CSV header, also the column order.
pub const HEADER: &str = "t_ns,axis,a,b,source";

/// How long the writer sleeps when the buffer is empty (the buffer must hold this long's edges).
const DRAIN_PERIOD: Duration = Duration::from_millis(10);

/// Limits of the config keys (checked at start with file and line, `config/check.rs`).
pub const MAX_BYTES_RANGE: std::ops::RangeInclusive<u64> = 4_096..=1_000_000_000;
pub const BUFFER_EDGES_RANGE: std::ops::RangeInclusive<usize> = 64..=4_194_304;

/// `[sink.quadrature.trace]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TraceConfig {
    /// The CSV file (relative: to the config file's directory); the rotated one is `<path>.1`.
    pub path: PathBuf,
    /// Size at which the file is rotated, bytes.
    #[serde(default = "default_max_bytes")]
    pub max_bytes: u64,
    /// Edges the buffer between the injector threads and the writer holds (each 24 bytes).
    #[serde(default = "default_buffer_edges")]
    pub buffer_edges: usize,
}

fn default_max_bytes() -> u64 {
    10_000_000
}

fn default_buffer_edges() -> usize {
    65_536
}

/// Where a traced level came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceSource {
    /// The levels the injector drove when it took the lines.
    Start,
    Native,
    Injected,
}

impl From<Source> for TraceSource {
    fn from(s: Source) -> Self {
        match s {
            Source::Native => Self::Native,
            Source::Injected => Self::Injected,
        }
    }
}

impl TraceSource {
    fn name(self) -> &'static str {
        match self {
            Self::Start => "start",
            Self::Native => "native",
            Self::Injected => "injected",
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Entry {
    t_ns: u64,
    axis: u16,
    a: bool,
    b: bool,
    source: TraceSource,
}

/// One axis's end of the trace, held by its injector thread.
#[derive(Clone, Debug)]
pub struct EdgeTrace {
    tx: SyncSender<Entry>,
    axis: u16,
    dropped: Arc<AtomicU64>,
}

impl EdgeTrace {
    /// Queue one written level; never blocks or allocates (a full buffer drops it and counts it).
    pub fn record(&self, t_ns: u64, (a, b): (bool, bool), source: TraceSource) {
        let e = Entry {
            t_ns,
            axis: self.axis,
            a,
            b,
            source,
        };
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = self.tx.try_send(e) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The writer thread and the handles the injectors record through.
#[derive(Debug)]
pub struct TraceWriter {
    tx: Option<SyncSender<Entry>>,
    dropped: Arc<AtomicU64>,
    failed: Arc<AtomicBool>,
    join: Option<std::thread::JoinHandle<()>>,
    path: PathBuf,
}

impl TraceWriter {
    /// Rotate an existing trace, create the file and start the writer for `axes` (config order).
    pub fn start(cfg: &TraceConfig, axes: Vec<String>) -> std::io::Result<Self> {
        let mut file = RotatingCsv::open(&cfg.path, cfg.max_bytes)?;
        let (tx, rx) = std::sync::mpsc::sync_channel(cfg.buffer_edges);
        let failed = Arc::new(AtomicBool::new(false));
        let flag = failed.clone();
        let join = std::thread::Builder::new()
            .name("quadrature-trace".into())
            .spawn(move || {
                if let Err(e) = drain(&rx, &mut file, &axes) {
                    flag.store(true, Ordering::Relaxed);
                    tracing::error!(path = %file.path.display(), %e, "quadrature edge trace: write failed, tracing stopped");
                }
            })?;
        Ok(Self {
            tx: Some(tx),
            dropped: Arc::new(AtomicU64::new(0)),
            failed,
            join: Some(join),
            path: cfg.path.clone(),
        })
    }

    /// The handle axis `index` (config order) records through.
    pub fn for_axis(&self, index: usize) -> Option<EdgeTrace> {
        Some(EdgeTrace {
            tx: self.tx.clone()?,
            axis: u16::try_from(index).ok()?,
            dropped: self.dropped.clone(),
        })
    }

    /// Entries lost so far (buffer full, or the writer gone).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// The writer stopped on an I/O error.
    pub fn failed(&self) -> bool {
        self.failed.load(Ordering::Relaxed)
    }

    /// Wait for the writer to write what is queued and close the file. Every [`EdgeTrace`] must
    /// be dropped first (the writer runs until the last sender is gone).
    pub fn finish(&mut self) {
        self.tx = None;
        if let Some(j) = self.join.take() {
            let _ = j.join();
            let dropped = self.dropped();
            if dropped > 0 {
                tracing::warn!(path = %self.path.display(), dropped, "quadrature edge trace closed with entries missing");
            }
        }
    }
}

impl Drop for TraceWriter {
    fn drop(&mut self) {
        self.finish();
    }
}

/// Write what arrives until every sender is gone, flushing whenever the buffer is empty.
fn drain(rx: &Receiver<Entry>, file: &mut RotatingCsv, axes: &[String]) -> std::io::Result<()> {
    loop {
        match rx.try_recv() {
            Ok(e) => {
                let axis = axes.get(usize::from(e.axis)).map_or("?", String::as_str);
                file.row(&format!(
                    "{},{axis},{},{},{}\n",
                    e.t_ns,
                    u8::from(e.a),
                    u8::from(e.b),
                    e.source.name()
                ))?;
            }
            Err(TryRecvError::Empty) => {
                file.flush()?;
                std::thread::sleep(DRAIN_PERIOD);
            }
            Err(TryRecvError::Disconnected) => return file.flush(),
        }
    }
}

/// A CSV file with a header that is renamed to `<path>.1` when it would pass `max_bytes`.
#[derive(Debug)]
struct RotatingCsv {
    path: PathBuf,
    max_bytes: u64,
    out: std::io::BufWriter<std::fs::File>,
    bytes: u64,
}

impl RotatingCsv {
    fn open(path: &Path, max_bytes: u64) -> std::io::Result<Self> {
        if std::fs::metadata(path).is_ok_and(|m| m.len() > 0) {
            std::fs::rename(path, rotated_path(path))?;
        }
        let (out, bytes) = Self::create(path)?;
        Ok(Self {
            path: path.to_path_buf(),
            max_bytes,
            out,
            bytes,
        })
    }

    fn create(path: &Path) -> std::io::Result<(std::io::BufWriter<std::fs::File>, u64)> {
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        writeln!(out, "{HEADER}")?;
        Ok((out, HEADER.len() as u64 + 1))
    }

    fn row(&mut self, row: &str) -> std::io::Result<()> {
        if self.bytes + row.len() as u64 > self.max_bytes {
            self.out.flush()?;
            std::fs::rename(&self.path, rotated_path(&self.path))?;
            (self.out, self.bytes) = Self::create(&self.path)?;
        }
        self.out.write_all(row.as_bytes())?;
        self.bytes += row.len() as u64;
        Ok(())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// `<path>.1`.
pub fn rotated_path(path: &Path) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".1");
    PathBuf::from(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(path: PathBuf, max_bytes: u64, buffer_edges: usize) -> TraceConfig {
        TraceConfig {
            path,
            max_bytes,
            buffer_edges,
        }
    }

    #[test]
    fn rows_carry_time_axis_levels_and_source_and_the_file_rotates_at_its_cap() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("trace.csv");
        std::fs::write(&path, "an earlier run\n").unwrap();
        let mut w = TraceWriter::start(&cfg(path.clone(), 200, 1024), vec!["x".into(), "z".into()])
            .unwrap();
        let (x, z) = (w.for_axis(0).unwrap(), w.for_axis(1).unwrap());
        x.record(0, (false, false), TraceSource::Start);
        z.record(5, (true, false), TraceSource::Native);
        for t in 1..=20 {
            x.record(t * 1000, (t % 2 == 1, false), TraceSource::Injected);
        }
        drop((x, z));
        w.finish();
        assert_eq!(w.dropped(), 0);
        assert!(!w.failed());
        let now = std::fs::read_to_string(&path).unwrap();
        let old = std::fs::read_to_string(rotated_path(&path)).unwrap();
        assert!(now.len() <= 200 && old.len() <= 200, "{now}\n{old}");
        assert!(now.starts_with(HEADER) && old.starts_with(HEADER), "{old}");
        assert!(now.ends_with("20000,x,0,0,injected\n"), "{now}");
        // 22 rows of ≈ 20 bytes do not fit in two 200-byte files: the oldest rows (and the
        // earlier run) were rotated away, never more than the two files kept.
        assert!(
            !old.contains("earlier run") && !old.contains("start"),
            "{old}"
        );
    }

    #[test]
    fn a_full_buffer_drops_and_counts_instead_of_waiting() {
        let (tx, _rx) = std::sync::mpsc::sync_channel(4);
        let dropped = Arc::new(AtomicU64::new(0));
        let t = EdgeTrace {
            tx,
            axis: 0,
            dropped: dropped.clone(),
        };
        for i in 0..10 {
            t.record(i, (true, true), TraceSource::Injected);
        }
        assert_eq!(dropped.load(Ordering::Relaxed), 6);
    }
}
