//! What `gateway_faults_hil` reads back: hil-sim's log of client writes (`plc_writes.csv`), its
//! recording (applied shift vs the ideal correction), and the gateway's fault log lines. Sans-IO:
//! every function takes the text.

use std::collections::BTreeMap;

use crate::configs::{CAP_UM, CLAMP_UM, CLAMP_Y_UM, LSB_UM};

/// One row of plc_writes.csv.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Write {
    pub t_s: f64,
    pub address: u16,
    pub um: [f64; 3],
    /// The gateway's TCP source port: a new one is a new connection.
    pub port: u16,
}

pub(crate) fn parse_writes(text: &str) -> Vec<Write> {
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("t_s,address,count,x_um,y_um,z_um,client_port")
    );
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 7, "{l}");
            let num = |i: usize| f[i].parse::<f64>().unwrap_or_else(|e| panic!("{l}: {e}"));
            Write {
                t_s: num(0),
                address: f[1].parse().unwrap(),
                um: [num(3), num(4), num(5)],
                port: f[6].parse().unwrap(),
            }
        })
        .collect()
}

/// Asserts every row of the PLC write log: only the shift block (address 0) and the strobe (10) are
/// written, every value is within its axis' clamp, and no change between consecutive values exceeds
/// the dosing cap (the sink doses in µm; encoding adds up to one register LSB of rounding).
/// Returns (max |value| per axis, max change), µm.
pub(crate) fn assert_clamp_and_cap(writes: &[Write]) -> ([f64; 3], f64) {
    let clamp = [CLAMP_UM, CLAMP_Y_UM, CLAMP_UM];
    let mut max_abs = [0.0f64; 3];
    for w in writes {
        assert!(w.address == 0 || w.address == 10, "{w:?}");
        for k in 0..3 {
            assert!(w.um[k].abs() <= clamp[k] + 1e-9, "beyond the clamp: {w:?}");
            max_abs[k] = max_abs[k].max(w.um[k].abs());
        }
    }
    let mut max_step = 0.0f64;
    for p in writes.windows(2) {
        for k in 0..3 {
            let step = (p[1].um[k] - p[0].um[k]).abs();
            max_step = max_step.max(step);
            assert!(
                step <= CAP_UM + LSB_UM + 1e-9,
                "a change beyond the cap between {:?} and {:?}",
                p[0],
                p[1]
            );
        }
    }
    (max_abs, max_step)
}

/// (t_s, deviation of the applied correction from the ideal one per axis, µm). Ideal = −(error
/// without correction), clamped; the recording's error includes the applied shift, so the error
/// without it is `e − shift` (register + moves the slide +).
pub(crate) fn deviations(recording: &str) -> Vec<(f64, [f64; 3])> {
    let mut rdr = csv::Reader::from_reader(recording.as_bytes());
    let h = rdr.headers().unwrap().clone();
    let col = |n: &str| {
        h.iter()
            .position(|c| c == n)
            .unwrap_or_else(|| panic!("no {n}"))
    };
    let t = col("t_s");
    let e = [col("ex_um"), col("ey_um"), col("ez_um")];
    let s = [col("shift_x_um"), col("shift_y_um"), col("shift_z_um")];
    let clamp = [CLAMP_UM, CLAMP_Y_UM, CLAMP_UM];
    rdr.records()
        .map(|r| {
            let r = r.unwrap();
            let v = |i: usize| r[i].parse::<f64>().unwrap();
            let d = std::array::from_fn(|k| {
                let uncorrected = v(e[k]) - v(s[k]);
                v(s[k]) - (-uncorrected).clamp(-clamp[k], clamp[k])
            });
            (v(t), d)
        })
        .collect()
}

/// Share of the distinct values written to the shift registers (in write order, repeats collapsed)
/// that the recording shows as the applied (latched) shift at some row. A value is missed only when
/// it was latched and replaced between two recording rows.
pub(crate) fn applied_share(writes: &[Write], recording: &str) -> f64 {
    let mut rdr = csv::Reader::from_reader(recording.as_bytes());
    let h = rdr.headers().unwrap().clone();
    let cols: Vec<usize> = ["shift_x_um", "shift_y_um", "shift_z_um"]
        .iter()
        .map(|n| h.iter().position(|c| c == *n).unwrap())
        .collect();
    let key = |v: [f64; 3]| v.map(|x| (x * 1000.0).round() as i64);
    let latched: std::collections::HashSet<[i64; 3]> = rdr
        .records()
        .map(|r| {
            let r = r.unwrap();
            key([0, 1, 2].map(|k| r[cols[k]].parse::<f64>().unwrap()))
        })
        .collect();
    let mut written: Vec<[i64; 3]> = writes
        .iter()
        .filter(|w| w.address == 0)
        .map(|w| key(w.um))
        .collect();
    written.dedup();
    let seen = written.iter().filter(|v| latched.contains(*v)).count();
    seen as f64 / written.len().max(1) as f64
}

pub(crate) fn max_dev(devs: &[(f64, [f64; 3])], from_s: f64, to_s: f64, axes: &[usize]) -> f64 {
    let rows: Vec<_> = devs
        .iter()
        .filter(|(t, _)| *t >= from_s && *t < to_s)
        .collect();
    assert!(rows.len() > 10, "no recording in {from_s}..{to_s}");
    rows.iter()
        .flat_map(|(_, d)| axes.iter().map(|k| d[*k].abs()))
        .fold(0.0, f64::max)
}

/// Fault log lines of one gateway process: (source, kind, started, t_s).
pub(crate) fn fault_events(log: &str) -> Vec<(String, String, bool, f64)> {
    let field = |line: &str, key: &str| -> Option<String> {
        let i = line.find(&format!(" {key}="))? + key.len() + 2;
        let rest = &line[i..];
        let v = rest.split_whitespace().next()?;
        Some(v.trim_matches('"').to_string())
    };
    log.lines()
        .filter_map(|l| {
            let started = if l.contains("fault started") {
                true
            } else if l.contains("fault cleared") {
                false
            } else {
                return None;
            };
            Some((
                field(l, "source")?,
                field(l, "kind")?,
                started,
                field(l, "t_s")?.parse().ok()?,
            ))
        })
        .collect()
}

/// Each fault logged once at start and once at clear: per (source, kind) the events alternate,
/// starting with a start. Returns the start times per (source, kind).
pub(crate) fn episodes(
    events: &[(String, String, bool, f64)],
) -> BTreeMap<(String, String), Vec<f64>> {
    let mut last: BTreeMap<(String, String), bool> = BTreeMap::new();
    let mut starts: BTreeMap<(String, String), Vec<f64>> = BTreeMap::new();
    for (s, k, started, t) in events {
        let key = (s.clone(), k.clone());
        let prev = last.insert(key.clone(), *started);
        assert_ne!(
            prev.unwrap_or(false),
            *started,
            "{s} {k} logged {} twice in a row (t = {t})",
            if *started { "started" } else { "cleared" }
        );
        if *started {
            starts.entry(key).or_default().push(*t);
        }
    }
    starts
}
