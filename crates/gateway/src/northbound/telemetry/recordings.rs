//! Recordings of every machine, shipped to the fleet (sans-IO; issue 17 point 3). A box cuts a
//! recording CSV (the docs/recording-csv.md contract, unchanged: header with units in the column names, one
//! sample per row) into **chunks** of whole rows; every chunk repeats the header, so each is itself
//! a valid recording CSV. A chunk travels as a small JSON envelope naming the machine (Sparkplug
//! group + edge node), the recording's file name, its index and whether it is the last one. The
//! shell (`super::shipper`) puts chunks through the same bounded store-and-forward `super::queue`
//! as the telemetry (QoS 1, leave on PUBACK, resent after a reconnect), so they arrive in order and
//! possibly twice; the [`Collector`] on the fleet side writes them per machine as
//! `<dir>/<group>/<edge node>/<name>` (the contract again), appending rows in index order,
//! dropping duplicates and holding early chunks until the gap is filled. Shipping to a directory
//! writes the same layout, so the fleet reads both the same way. Units: whatever the CSV says.

use std::collections::{BTreeMap, HashMap};
use std::io::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::TelemetryError;

/// One piece of a recording on the wire.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chunk {
    pub group: String,
    pub edge_node: String,
    /// File name of the recording (`[A-Za-z0-9._-]`, no path).
    pub name: String,
    /// 0, 1, 2 … in row order.
    pub index: u64,
    pub last: bool,
    /// Header line + whole rows, `\n`-terminated.
    pub csv: String,
}

impl Chunk {
    pub fn encode(&self) -> Vec<u8> {
        serde_json::to_vec(self).expect("a chunk serializes")
    }
    pub fn decode(b: &[u8]) -> Option<Chunk> {
        serde_json::from_slice(b).ok()
    }
}

/// A name that is safe as one path component (no separators, not `.`/`..`, not empty).
pub fn valid_name(s: &str) -> bool {
    !s.is_empty()
        && s != "."
        && s != ".."
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
}

/// A recording's file name: a [`valid_name`] that is not the `.part` name another recording is
/// written under while incomplete (chunk 0 of `r` would truncate a received `r.part`).
pub fn valid_recording_name(s: &str) -> bool {
    valid_name(s) && !s.ends_with(".part")
}

/// Chunks a recording may have waiting for the gap before them. The shipper never drops a chunk
/// and sends in order, so chunks arrive early only when reordered; without a bound, a peer sending
/// far indices would make the collector hold them all in memory.
pub const MAX_HELD_CHUNKS: usize = 1024;

/// Cut a recording's CSV text into chunks of at most `rows_per_chunk` rows (≥ 1), each carrying
/// the header. A recording without rows is one chunk with the header only.
pub fn chunk_csv(
    group: &str,
    edge_node: &str,
    name: &str,
    csv: &str,
    rows_per_chunk: usize,
) -> Result<Vec<Chunk>, TelemetryError> {
    if !valid_recording_name(name) {
        return Err(TelemetryError::Invalid(format!(
            "recording name {name:?}: use [A-Za-z0-9._-], not ending in .part"
        )));
    }
    if !(valid_name(group) && valid_name(edge_node)) {
        return Err(TelemetryError::Invalid(format!(
            "group/edge node {group:?}/{edge_node:?}: use [A-Za-z0-9._-]"
        )));
    }
    let mut lines = csv.lines().filter(|l| !l.trim().is_empty());
    let header = lines
        .next()
        .ok_or_else(|| TelemetryError::Invalid(format!("recording {name}: empty, no header")))?;
    let rows: Vec<&str> = lines.collect();
    let per = rows_per_chunk.max(1);
    let pieces: Vec<&[&str]> = if rows.is_empty() {
        vec![&[]]
    } else {
        rows.chunks(per).collect()
    };
    let n = pieces.len();
    Ok(pieces
        .into_iter()
        .enumerate()
        .map(|(i, rows)| {
            let mut csv = String::with_capacity(header.len() + 1 + rows.len() * 64);
            csv.push_str(header);
            csv.push('\n');
            for r in rows {
                csv.push_str(r);
                csv.push('\n');
            }
            Chunk {
                group: group.into(),
                edge_node: edge_node.into(),
                name: name.into(),
                index: i as u64,
                last: i + 1 == n,
                csv,
            }
        })
        .collect())
}

/// Where a machine's recording lives under a collection directory.
pub fn path_of(dir: &Path, group: &str, edge_node: &str, name: &str) -> PathBuf {
    dir.join(group).join(edge_node).join(name)
}

/// Per recording being received.
#[derive(Debug, Default)]
struct Assembly {
    next: u64,
    header: Option<String>,
    early: BTreeMap<u64, Chunk>,
    complete: bool,
}

/// What the collector did with a chunk.
#[derive(Debug, PartialEq, Eq)]
pub enum Took {
    /// Written (with any held chunks it released); `Some(path)` when the recording is complete.
    Written(Option<PathBuf>),
    /// Already had it (a QoS 1 resend).
    Duplicate,
    /// Held until the chunks before it arrive.
    Held,
    /// Not a chunk, a bad name, or a header that differs from the recording's first chunk.
    Refused(String),
}

/// Collects chunks into `<dir>/<group>/<edge node>/<name>`. A recording is written to
/// `<name>.part` while incomplete and renamed when its last chunk is in, so a complete file is
/// always a whole recording.
#[derive(Debug)]
pub struct Collector {
    pub dir: PathBuf,
    open: HashMap<(String, String, String), Assembly>,
    pub duplicates: u64,
    pub refused: u64,
}

impl Collector {
    pub fn new(dir: PathBuf) -> Self {
        Collector {
            dir,
            open: HashMap::new(),
            duplicates: 0,
            refused: 0,
        }
    }

    pub fn handle_payload(&mut self, payload: &[u8]) -> std::io::Result<Took> {
        let Some(c) = Chunk::decode(payload) else {
            self.refused += 1;
            return Ok(Took::Refused("not a recording chunk".into()));
        };
        if !(valid_name(&c.group) && valid_name(&c.edge_node) && valid_recording_name(&c.name)) {
            self.refused += 1;
            return Ok(Took::Refused(format!("bad names in {c:?}")));
        }
        let key = (c.group.clone(), c.edge_node.clone(), c.name.clone());
        let a = self.open.entry(key.clone()).or_default();
        if c.index == 0 && a.complete {
            // The same name shipped again (a new recording under an old name): start over.
            *a = Assembly::default();
        }
        if c.index < a.next || a.early.contains_key(&c.index) {
            self.duplicates += 1;
            return Ok(Took::Duplicate);
        }
        if a.complete {
            // Beyond its last chunk: the `.part` file is renamed already (a new chunk 0 starts
            // the name over, above).
            self.refused += 1;
            return Ok(Took::Refused(format!(
                "{}: chunk {} after its last chunk",
                c.name, c.index
            )));
        }
        if c.index > a.next {
            if a.early.len() >= MAX_HELD_CHUNKS {
                self.refused += 1;
                return Ok(Took::Refused(format!(
                    "{}: chunk {} while {MAX_HELD_CHUNKS} wait for chunk {}",
                    c.name, c.index, a.next
                )));
            }
            a.early.insert(c.index, c);
            return Ok(Took::Held);
        }
        let final_path = path_of(&self.dir, &key.0, &key.1, &key.2);
        let part = final_path.with_file_name(format!("{}.part", key.2));
        std::fs::create_dir_all(part.parent().expect("has a parent"))?;
        let mut c = c;
        let took = loop {
            let (header, rows) = c.csv.split_once('\n').unwrap_or((c.csv.as_str(), ""));
            let mut f = if c.index == 0 {
                a.header = Some(header.to_string());
                let mut f = std::fs::File::create(&part)?;
                writeln!(f, "{header}")?;
                f
            } else {
                if a.header.as_deref() != Some(header) {
                    break Took::Refused(format!(
                        "{}: chunk {} has another header than chunk 0",
                        key.2, c.index
                    ));
                }
                std::fs::OpenOptions::new().append(true).open(&part)?
            };
            f.write_all(rows.as_bytes())?;
            a.next = c.index + 1;
            if c.last {
                a.complete = true;
                a.early.clear();
                f.sync_all()?;
                std::fs::rename(&part, &final_path)?;
                break Took::Written(Some(final_path));
            }
            match a.early.remove(&a.next) {
                Some(n) => c = n,
                None => break Took::Written(None),
            }
        };
        if matches!(took, Took::Refused(_)) {
            self.refused += 1;
        }
        Ok(took)
    }
}

/// Ship a recording to a directory in the collection layout (written to a temporary name and
/// renamed, so a reader never sees half a file). Returns the path written.
pub fn ship_to_dir(
    dir: &Path,
    group: &str,
    edge_node: &str,
    name: &str,
    csv: &str,
) -> Result<PathBuf, TelemetryError> {
    // Same checks as for MQTT (names, a header).
    chunk_csv(group, edge_node, name, csv, usize::MAX)?;
    let p = path_of(dir, group, edge_node, name);
    let io = |e: std::io::Error| TelemetryError::setup(dir.display().to_string())(e);
    std::fs::create_dir_all(p.parent().expect("has a parent")).map_err(io)?;
    let tmp = p.with_file_name(format!("{name}.part"));
    std::fs::write(&tmp, csv).map_err(io)?;
    std::fs::rename(&tmp, &p).map_err(io)?;
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CSV: &str = "t_s,x_mm,ex_um\n0,0,1\n1,10,2\n2,20,3\n3,30,4\n4,40,5\n";

    #[test]
    fn chunks_in_any_order_with_duplicates_give_back_the_recording() {
        let chunks = chunk_csv("g", "m1", "r.csv", CSV, 2).unwrap();
        assert_eq!(chunks.len(), 3);
        assert!(chunks.iter().all(|c| c.csv.starts_with("t_s,x_mm,ex_um\n")));
        assert!(chunks[2].last && !chunks[1].last);
        let dir = tempfile::tempdir().unwrap();
        let mut col = Collector::new(dir.path().to_path_buf());
        let enc: Vec<Vec<u8>> = chunks.iter().map(Chunk::encode).collect();
        assert_eq!(col.handle_payload(&enc[1]).unwrap(), Took::Held);
        assert_eq!(col.handle_payload(&enc[0]).unwrap(), Took::Written(None));
        assert_eq!(col.handle_payload(&enc[0]).unwrap(), Took::Duplicate);
        let p = path_of(dir.path(), "g", "m1", "r.csv");
        assert_eq!(
            col.handle_payload(&enc[2]).unwrap(),
            Took::Written(Some(p.clone()))
        );
        assert_eq!(std::fs::read_to_string(&p).unwrap(), CSV);
        assert_eq!(col.duplicates, 1);
    }

    #[test]
    fn another_header_and_bad_names_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut col = Collector::new(dir.path().to_path_buf());
        let a = chunk_csv("g", "m", "r.csv", CSV, 3).unwrap();
        let b = chunk_csv("g", "m", "r.csv", "t_s,y_mm\n0,0\n1,1\n2,2\n3,3\n", 3).unwrap();
        col.handle_payload(&a[0].encode()).unwrap();
        assert!(matches!(
            col.handle_payload(&b[1].encode()).unwrap(),
            Took::Refused(_)
        ));
        assert!(chunk_csv("g", "m", "../x", CSV, 3).is_err());
        let mut evil = a[0].clone();
        evil.edge_node = "..".into();
        assert!(matches!(
            col.handle_payload(&evil.encode()).unwrap(),
            Took::Refused(_)
        ));
    }

    #[test]
    fn a_part_name_and_chunks_held_beyond_the_bound_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut col = Collector::new(dir.path().to_path_buf());
        // `r.part` is where `r` is written while incomplete: refused on both sides.
        assert!(chunk_csv("g", "m", "r.part", CSV, 3).is_err());
        let mut part = chunk_csv("g", "m", "r.csv", CSV, 9).unwrap().remove(0);
        part.name = "r.csv.part".into();
        assert!(matches!(
            col.handle_payload(&part.encode()).unwrap(),
            Took::Refused(_)
        ));
        let c0 = chunk_csv("g", "m", "r.csv", CSV, 1).unwrap().remove(0);
        for i in 1..=MAX_HELD_CHUNKS as u64 {
            let c = Chunk {
                index: i,
                last: false,
                ..c0.clone()
            };
            assert_eq!(col.handle_payload(&c.encode()).unwrap(), Took::Held);
        }
        let far = Chunk {
            index: u64::MAX,
            ..c0.clone()
        };
        assert!(matches!(
            col.handle_payload(&far.encode()).unwrap(),
            Took::Refused(_)
        ));
        // The held ones are still released by the chunk they waited for.
        assert_eq!(
            col.handle_payload(&c0.encode()).unwrap(),
            Took::Written(None)
        );
        assert_eq!(col.refused, 2);
        // A chunk after the last one (its part file renamed) is refused, not an I/O error.
        let mut col = Collector::new(dir.path().join("after"));
        let two = chunk_csv("g", "m", "r.csv", CSV, 3).unwrap();
        col.handle_payload(&two[0].encode()).unwrap();
        assert!(matches!(
            col.handle_payload(&two[1].encode()).unwrap(),
            Took::Written(Some(_))
        ));
        let late = Chunk {
            index: 2,
            ..two[1].clone()
        };
        assert!(matches!(
            col.handle_payload(&late.encode()).unwrap(),
            Took::Refused(_)
        ));
        // A chunk 0 still starts the name over.
        assert_eq!(
            col.handle_payload(&two[0].encode()).unwrap(),
            Took::Written(None)
        );
    }
}
