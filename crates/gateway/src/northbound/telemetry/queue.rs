//! The store-and-forward queue: data records wait here, in order, until the broker acknowledged
//! them. Bounded by a record count and a byte size; when full, the configured policy drops the
//! oldest or the newest record, and every drop is counted (never silent). With a directory, each
//! record is also a file (`<id>.spb`, written to a temporary name then renamed, so a crash never
//! leaves half a record), so what waits survives a gateway restart; the directory is read back
//! in id order at start. Without one the queue lives in memory only (demo, load bench).
//!
//! A record on disk is a Sparkplug `Payload` whose metrics carry their names (not aliases: the
//! alias table belongs to a session, a record may outlive it) and the source's timestamp.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};

use prost::Message;

use super::metrics::Record;
use super::sparkplug::{Metric, Payload};

pub(crate) use super::config::DropPolicy;

#[derive(Clone, Debug, PartialEq)]
pub(crate) struct QueueLimits {
    pub dir: Option<PathBuf>,
    pub max_records: usize,
    pub max_bytes: u64,
    pub policy: DropPolicy,
}

/// One queued record: its id (increasing, the send order) and its encoded bytes.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    pub id: u64,
    pub bytes: Vec<u8>,
}

#[derive(Debug)]
pub(crate) struct Queue {
    limits: QueueLimits,
    entries: VecDeque<Entry>,
    next_id: u64,
    bytes: u64,
    dropped_total: u64,
    /// In a drop episode (the queue was full at the last push): logs once per episode.
    dropping: bool,
    disk_error_logged: bool,
}

pub(crate) fn encode(rec: &Record) -> Vec<u8> {
    Payload {
        timestamp: Some(rec.t_ms),
        metrics: rec
            .values
            .iter()
            .map(|(n, v)| Metric {
                name: Some(n.clone()),
                value: Some(v.clone()),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    }
    .encode_to_vec()
}

pub(crate) fn decode(bytes: &[u8]) -> Option<Record> {
    let p = Payload::decode(bytes).ok()?;
    let values = p
        .metrics
        .into_iter()
        .filter_map(|m| Some((m.name?, m.value?)))
        .collect();
    Some(Record {
        t_ms: p.timestamp?,
        values,
    })
}

fn file_of(dir: &Path, id: u64) -> PathBuf {
    dir.join(format!("{id:020}.spb"))
}

impl Queue {
    /// Open the queue, reading back what a previous run left in `limits.dir` (oldest first).
    pub(crate) fn open(limits: QueueLimits) -> std::io::Result<Self> {
        let mut q = Queue {
            limits,
            entries: VecDeque::new(),
            next_id: 0,
            bytes: 0,
            dropped_total: 0,
            dropping: false,
            disk_error_logged: false,
        };
        if let Some(dir) = q.limits.dir.clone() {
            std::fs::create_dir_all(&dir)?;
            let mut found: Vec<(u64, PathBuf)> = Vec::new();
            for e in std::fs::read_dir(&dir)? {
                let path = e?.path();
                let id = path
                    .file_name()
                    .and_then(|n| n.to_str())
                    .and_then(|n| n.strip_suffix(".spb"))
                    .and_then(|n| n.parse::<u64>().ok());
                match id {
                    Some(id) => found.push((id, path)),
                    // A temporary file of a write the crash interrupted: incomplete, not a record.
                    None if path.extension().is_some_and(|x| x == "tmp") => {
                        let _ = std::fs::remove_file(&path);
                    }
                    None => {}
                }
            }
            found.sort_unstable();
            for (id, path) in found {
                let bytes = std::fs::read(&path)?;
                q.bytes += bytes.len() as u64;
                q.entries.push_back(Entry { id, bytes });
                q.next_id = id + 1;
            }
            if !q.entries.is_empty() {
                tracing::info!(records = q.entries.len(), dir = %dir.display(), "telemetry queue: records from the last run will be sent first");
            }
        }
        Ok(q)
    }

    pub(crate) fn len(&self) -> usize {
        self.entries.len()
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub(crate) fn bytes(&self) -> u64 {
        self.bytes
    }

    pub(crate) fn dropped_total(&self) -> u64 {
        self.dropped_total
    }

    /// The id the next pushed record gets.
    pub(crate) fn next_id(&self) -> u64 {
        self.next_id
    }

    fn full_with(&self, extra: u64) -> bool {
        self.entries.len() + 1 > self.limits.max_records
            || self.bytes + extra > self.limits.max_bytes
    }

    /// Append a record; when the queue is full, the policy drops a record (counted). Returns
    /// the number of records dropped by this push.
    pub(crate) fn push(&mut self, bytes: Vec<u8>) -> u64 {
        let extra = bytes.len() as u64;
        let mut dropped = 0;
        while self.full_with(extra) {
            match self.limits.policy {
                DropPolicy::DropNewest => {
                    dropped += 1;
                    break;
                }
                DropPolicy::DropOldest => match self.entries.front().map(|e| e.id) {
                    Some(id) => {
                        self.remove(id);
                        dropped += 1;
                    }
                    None => break,
                },
            }
        }
        let refused = self.limits.policy == DropPolicy::DropNewest && dropped > 0;
        self.dropped_total += dropped;
        if dropped > 0 && !self.dropping {
            self.dropping = true;
            tracing::warn!(policy = ?self.limits.policy, max_records = self.limits.max_records, max_bytes = self.limits.max_bytes, "telemetry queue full: dropping records (counted in Telemetry/dropped_total) until it has room");
        } else if dropped == 0 && self.dropping {
            self.dropping = false;
            tracing::info!(
                dropped_total = self.dropped_total,
                "telemetry queue has room again"
            );
        }
        if refused {
            return dropped;
        }
        let id = self.next_id;
        self.next_id += 1;
        if let Some(dir) = &self.limits.dir {
            let tmp = dir.join(format!("{id:020}.tmp"));
            let res =
                std::fs::write(&tmp, &bytes).and_then(|()| std::fs::rename(&tmp, file_of(dir, id)));
            if let Err(e) = res {
                // Kept in memory: the record is still sent; only a restart during the outage
                // would lose it. Logged once (a full disk would otherwise log every record).
                if !self.disk_error_logged {
                    self.disk_error_logged = true;
                    tracing::error!(%e, dir = %dir.display(), "telemetry queue: cannot write to disk; queueing in memory");
                }
            }
        }
        self.bytes += extra;
        self.entries.push_back(Entry { id, bytes });
        dropped
    }

    /// The first entry whose id is at least `from` (the next to send).
    pub(crate) fn first_from(&self, from: u64) -> Option<&Entry> {
        // Ids increase along the deque, so the first match is found by bisection.
        let i = self.entries.partition_point(|e| e.id < from);
        self.entries.get(i)
    }

    /// Forget an entry (acknowledged by the broker, or dropped). Unknown ids are ignored (an
    /// acknowledgement of a record that the drop policy already removed).
    pub(crate) fn remove(&mut self, id: u64) {
        let i = self.entries.partition_point(|e| e.id < id);
        if self.entries.get(i).is_some_and(|e| e.id == id) {
            let e = self.entries.remove(i).expect("index checked");
            self.bytes -= e.bytes.len() as u64;
            if let Some(dir) = &self.limits.dir {
                let _ = std::fs::remove_file(file_of(dir, id));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::northbound::telemetry::sparkplug::Value;

    fn rec(t: u64) -> Vec<u8> {
        encode(&Record {
            t_ms: t,
            values: vec![("Gateway/cycles".into(), Value::Long(t))],
        })
    }

    fn limits(dir: Option<PathBuf>, max: usize, policy: DropPolicy) -> QueueLimits {
        QueueLimits {
            dir,
            max_records: max,
            max_bytes: 1 << 20,
            policy,
        }
    }

    fn times(q: &Queue) -> Vec<u64> {
        q.entries
            .iter()
            .map(|e| decode(&e.bytes).unwrap().t_ms)
            .collect()
    }

    #[test]
    fn drop_oldest_keeps_the_newest_and_counts() {
        let mut q = Queue::open(limits(None, 3, DropPolicy::DropOldest)).unwrap();
        for t in 1..=5 {
            q.push(rec(t));
        }
        assert_eq!(times(&q), [3, 4, 5]);
        assert_eq!(q.dropped_total(), 2);
    }

    #[test]
    fn drop_newest_keeps_the_oldest_and_counts() {
        let mut q = Queue::open(limits(None, 3, DropPolicy::DropNewest)).unwrap();
        for t in 1..=5 {
            q.push(rec(t));
        }
        assert_eq!(times(&q), [1, 2, 3]);
        assert_eq!(q.dropped_total(), 2);
    }

    #[test]
    fn byte_bound_applies_too() {
        let one = rec(1).len() as u64;
        let mut q = Queue::open(QueueLimits {
            max_bytes: 2 * one,
            ..limits(None, 100, DropPolicy::DropOldest)
        })
        .unwrap();
        for t in 1..=4 {
            q.push(rec(t));
        }
        assert_eq!(q.len(), 2);
        assert!(q.bytes() <= 2 * one);
    }

    #[test]
    fn records_survive_a_restart_in_order_and_acked_ones_are_gone() {
        let dir = tempfile::tempdir().unwrap();
        let l = limits(Some(dir.path().join("q")), 10, DropPolicy::DropOldest);
        {
            let mut q = Queue::open(l.clone()).unwrap();
            for t in 1..=4 {
                q.push(rec(t));
            }
            let first = q.first_from(0).unwrap().id;
            q.remove(first);
            std::fs::write(dir.path().join("q/00000000000000000099.tmp"), b"half").unwrap();
        }
        let mut q = Queue::open(l).unwrap();
        assert_eq!(times(&q), [2, 3, 4]);
        assert!(!dir.path().join("q/00000000000000000099.tmp").exists());
        assert_eq!(q.push(rec(5)), 0, "nothing dropped");
        assert_eq!(times(&q), [2, 3, 4, 5]);
        assert_eq!(q.first_from(q.next_id() - 1).map(|e| e.id), Some(4));
    }
}
