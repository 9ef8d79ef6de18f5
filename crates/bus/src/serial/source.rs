//! A serial line source: framer + format parser + channel map, sans-IO ([`LineSource`]:
//! `push`/`handle_line(…, now)`, `poll(now)`, `poll_transmit()` for the request, `poll_timeout()`),
//! with a thin async loop over any byte stream ([`run`]: a tokio-serial port or a pty in tests)
//! that sleeps until the source's next deadline. Times are seconds on the caller's clock.
//!
//! Every reading becomes `value = reading · scale + offset` in the channel's unit. Lines that do not
//! parse, overlong lines and readings for no configured key are counted and skipped, never fatal.
//! A channel with no reading for `timeout_s` is reported `Stale` by [`LineSource::poll`] from that
//! moment, and again every `period_s` while it stays silent.

use super::formats::{
    GenericFormat, LineError, Reading, parse_generic, parse_heidenhain, parse_mitutoyo,
    parse_nd522, parse_weighing,
};
use super::framer::{DEFAULT_MAX_LINE, LineFramer};
use crate::deadline::{sleep_for, stale_report_due_s};
use crate::{ChannelId, ChannelTable, Health, Sample};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum LineFormat {
    Heidenhain {
        decimals: u8,
    },
    Nd522,
    Mitutoyo,
    Weighing {
        #[serde(default)]
        unit: Option<String>,
        #[serde(default)]
        accept_unstable: bool,
    },
    Generic {
        #[serde(default)]
        prefix: Option<String>,
        #[serde(default)]
        delimiter: Option<String>,
        #[serde(default)]
        unit: Option<String>,
    },
}

impl LineFormat {
    /// Parse one framed line into readings.
    pub fn parse(&self, line: &[u8]) -> Result<Vec<Reading>, LineError> {
        match self {
            LineFormat::Heidenhain { decimals } => {
                parse_heidenhain(line, *decimals).map(|r| vec![r])
            }
            LineFormat::Nd522 => parse_nd522(line).map(|r| vec![r]),
            LineFormat::Mitutoyo => parse_mitutoyo(line).map(|r| vec![r]),
            LineFormat::Weighing { unit, .. } => {
                parse_weighing(line, unit.as_deref()).map(|r| vec![r])
            }
            LineFormat::Generic {
                prefix,
                delimiter,
                unit,
            } => parse_generic(
                line,
                &GenericFormat {
                    prefix: prefix.clone(),
                    delimiter: delimiter.clone(),
                    unit: unit.clone(),
                },
            ),
        }
    }
}

fn one() -> f64 {
    1.0
}
fn d_baud() -> u32 {
    9600
}
fn d_timeout() -> f64 {
    1.0
}
fn d_period() -> f64 {
    0.1
}
fn d_max_line() -> usize {
    DEFAULT_MAX_LINE
}

/// `[[serial.source.channel]]`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialChannel {
    pub name: String,
    /// Axis letter (nd522), channel number (mitutoyo), `GS`/`NT` (weighing), field index (generic).
    /// Unset: heidenhain assigns by order; other formats take any key.
    #[serde(default)]
    pub key: Option<String>,
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
}

/// `[[serial.source]]` of the field TOML.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialSourceConfig {
    pub name: String,
    #[serde(default)]
    pub device: Option<String>,
    #[serde(default = "d_baud")]
    pub baud: u32,
    pub format: LineFormat,
    /// Bytes sent every `period_s` to request a reading (e.g. "\u0002" for Heidenhain's Ctrl-B).
    #[serde(default)]
    pub request: Option<String>,
    #[serde(default = "d_period")]
    pub period_s: f64,
    #[serde(default = "d_timeout")]
    pub timeout_s: f64,
    #[serde(default = "d_max_line")]
    pub max_line: usize,
    #[serde(default)]
    pub channel: Vec<SerialChannel>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SerialCounters {
    pub lines: u64,
    pub readings: u64,
    pub garbage_lines: u64,
    pub overlong_lines: u64,
    /// Readings whose key matches no channel.
    pub unmatched: u64,
    /// Unsettled weighing readings skipped.
    pub unstable_skipped: u64,
}

#[derive(Debug, Clone)]
pub struct LineSource {
    pub cfg: SerialSourceConfig,
    framer: LineFramer,
    /// Next channel for order-assigned (heidenhain) readings.
    seq: usize,
    /// Each channel's id, resolved at construction.
    ids: Vec<ChannelId>,
    last: Vec<(Option<f64>, f64)>,
    /// When [`LineSource::poll`] last ran (None: never) and when its next period starts.
    last_poll_s: Option<f64>,
    next_period_s: f64,
    /// A period started and the request for it is not sent yet.
    request_due: bool,
    counters: SerialCounters,
}

impl LineSource {
    /// The source of `cfg`, its channels resolved in `channels` (the gateway's table).
    pub fn new(cfg: SerialSourceConfig, channels: &mut ChannelTable) -> Self {
        LineSource {
            framer: LineFramer::new(cfg.max_line),
            seq: 0,
            last: vec![(None, f64::NAN); cfg.channel.len()],
            ids: cfg
                .channel
                .iter()
                .map(|c| channels.resolve(&c.name))
                .collect(),
            cfg,
            last_poll_s: None,
            next_period_s: f64::NEG_INFINITY,
            request_due: false,
            counters: SerialCounters::default(),
        }
    }

    pub fn counters(&self) -> SerialCounters {
        SerialCounters {
            overlong_lines: self.framer.overlong,
            ..self.counters
        }
    }

    /// Call when a request was sent: the reply block starts again at the first axis.
    pub fn handle_request(&mut self) {
        self.seq = 0;
    }

    fn channel_for(&mut self, key: &Option<String>) -> Option<usize> {
        if matches!(self.cfg.format, LineFormat::Heidenhain { .. }) {
            let n = self.cfg.channel.len();
            let i = (n > 0).then(|| self.seq % n);
            self.seq += 1;
            return i;
        }
        self.cfg.channel.iter().position(|c| match (&c.key, key) {
            (None, _) => true,
            (Some(k), Some(r)) => k == r,
            (Some(_), None) => false,
        })
    }

    /// Feed bytes received at `t_s`; samples are appended to `out`.
    pub fn push(&mut self, bytes: &[u8], t_s: f64, out: &mut Vec<Sample>) {
        let mut lines: Vec<Vec<u8>> = Vec::new();
        self.framer.push(bytes, |l| lines.push(l.to_vec()));
        for line in lines {
            self.handle_line(&line, t_s, out);
        }
    }

    /// Handle one already-framed line.
    pub fn handle_line(&mut self, line: &[u8], t_s: f64, out: &mut Vec<Sample>) {
        self.counters.lines += 1;
        let readings = match self.cfg.format.parse(line) {
            Ok(r) => r,
            Err(_) => {
                self.counters.garbage_lines += 1;
                return;
            }
        };
        let accept_unstable = matches!(
            self.cfg.format,
            LineFormat::Weighing {
                accept_unstable: true,
                ..
            }
        );
        for r in readings {
            self.counters.readings += 1;
            if r.unstable && !accept_unstable {
                self.counters.unstable_skipped += 1;
                continue;
            }
            let Some(i) = self.channel_for(&r.key) else {
                self.counters.unmatched += 1;
                continue;
            };
            let c = &self.cfg.channel[i];
            let v = r.value * c.scale + c.offset;
            let ok = !r.overload
                && v.is_finite()
                && c.min.is_none_or(|m| v >= m)
                && c.max.is_none_or(|m| v <= m);
            let health = if ok { Health::Ok } else { Health::OutOfRange };
            self.last[i].0 = Some(t_s);
            if ok {
                self.last[i].1 = v;
            }
            out.push(Sample {
                channel: self.ids[i],
                t_s,
                value: v,
                health,
            });
        }
    }

    /// The request period, s (`period_s`, kept within 1 ms … 1 h).
    fn period_s(&self) -> f64 {
        self.cfg.period_s.clamp(1e-3, 3600.0)
    }

    /// At `t_s`: start the next period if it is due (its request then waits in
    /// [`Self::poll_transmit`]), and a `Stale` sample (last good value) for every channel silent
    /// for `timeout_s` or longer.
    pub fn poll(&mut self, t_s: f64, out: &mut Vec<Sample>) {
        if t_s >= self.next_period_s {
            self.next_period_s = t_s + self.period_s();
            self.request_due = self.cfg.request.is_some();
        }
        self.last_poll_s = Some(self.last_poll_s.map_or(t_s, |p| p.max(t_s)));
        for (&channel, (seen, v)) in self.ids.iter().zip(&self.last) {
            if seen.is_none_or(|t| t_s >= t + self.cfg.timeout_s) {
                out.push(Sample {
                    channel,
                    t_s,
                    value: *v,
                    health: Health::Stale,
                });
            }
        }
    }

    /// The request to send now, once per period (`request` of the config; none without one). The
    /// reply block then starts again at the first axis.
    pub fn poll_transmit(&mut self) -> Option<&[u8]> {
        if !std::mem::take(&mut self.request_due) {
            return None;
        }
        self.handle_request();
        self.cfg.request.as_deref().map(str::as_bytes)
    }

    /// When [`Self::poll`] is next due (s; may be in the past: poll now): the next period, or
    /// earlier the moment a channel falls silent for `timeout_s`. A silent channel is reported
    /// again on every period.
    pub fn poll_timeout(&self) -> f64 {
        self.last
            .iter()
            .map(|(seen, _)| {
                let from = seen.map_or(f64::NEG_INFINITY, |t| t + self.cfg.timeout_s);
                stale_report_due_s(from, self.last_poll_s, self.period_s())
            })
            .fold(self.next_period_s, f64::min)
    }
}

/// Open the configured device with tokio-serial (8N1 at `baud`).
pub fn open(cfg: &SerialSourceConfig) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
    let dev = cfg.device.as_deref().unwrap_or("");
    tokio_serial::SerialStream::open(&tokio_serial::new(dev, cfg.baud))
}

/// Read lines from `io` until EOF, an I/O error, or `out` closing; send `request` every `period_s`
/// if configured; report staleness when [`LineSource::poll_timeout`] says. Returns the final
/// counters.
pub async fn run<S: AsyncRead + AsyncWrite + Unpin>(
    io: S,
    mut src: LineSource,
    clock_s: impl Fn() -> f64,
    out: tokio::sync::mpsc::Sender<Vec<Sample>>,
) -> std::io::Result<SerialCounters> {
    let (mut rd, mut wr) = tokio::io::split(io);
    let mut buf = [0u8; 1024];
    loop {
        let mut batch = Vec::new();
        let wait = sleep_for(Some(src.poll_timeout()), clock_s());
        tokio::select! {
            // Checked first: once the consumer is gone, a hang-up of the line (EIO on a pty) is the
            // expected end, not a failure to report.
            biased;
            _ = out.closed() => return Ok(src.counters()),
            n = rd.read(&mut buf) => {
                let n = n?;
                if n == 0 {
                    return Ok(src.counters());
                }
                src.push(&buf[..n], clock_s(), &mut batch);
            }
            () = tokio::time::sleep(wait) => {
                src.poll(clock_s(), &mut batch);
                if let Some(req) = src.poll_transmit() {
                    wr.write_all(req).await?;
                }
            }
        }
        if !batch.is_empty() && out.send(batch).await.is_err() {
            return Ok(src.counters());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dro() -> SerialSourceConfig {
        SerialSourceConfig {
            name: "dro".into(),
            device: None,
            baud: 9600,
            format: LineFormat::Heidenhain { decimals: 4 },
            request: Some("\u{2}".into()),
            period_s: 0.1,
            timeout_s: 0.5,
            max_line: 64,
            channel: ["x_mm", "y_mm", "z_mm"]
                .iter()
                .map(|n| SerialChannel {
                    name: n.to_string(),
                    key: None,
                    scale: 1.0,
                    offset: 0.0,
                    min: None,
                    max: None,
                })
                .collect(),
        }
    }

    #[test]
    fn heidenhain_block_assigns_axes_in_order_and_skips_garbage() {
        let mut table = ChannelTable::default();
        let mut s = LineSource::new(dro(), &mut table);
        let mut out = Vec::new();
        s.push(
            b"\x02+001234500\r\n\x02-000000100\r\nnoise!!\r\n\x02+000",
            1.0,
            &mut out,
        );
        s.push(b"010000\r\n", 1.01, &mut out);
        let got: Vec<_> = out
            .iter()
            .map(|s| (table.name(s.channel), s.value))
            .collect();
        assert_eq!(got, vec![("x_mm", 123.45), ("y_mm", -0.01), ("z_mm", 1.0)]);
        assert_eq!(s.counters().garbage_lines, 1);
        s.handle_request();
        out.clear();
        s.push(b"\x02+000000000\r\n", 1.2, &mut out);
        assert_eq!(
            table.name(out[0].channel),
            "x_mm",
            "a request restarts at the first axis"
        );
        out.clear();
        s.poll(1.6, &mut out);
        let stale: Vec<_> = out.iter().map(|s| table.name(s.channel)).collect();
        assert_eq!(stale, vec!["y_mm", "z_mm"]);
        assert!(out.iter().all(|s| s.health == Health::Stale));
    }

    /// Driven only at its own deadlines (virtual time): one request per period, a channel that
    /// falls silent reported at that instant (not at the next period), then once per period.
    #[test]
    fn polled_at_its_deadlines_it_requests_each_period_and_reports_silence_on_time() {
        let mut s = LineSource::new(dro(), &mut ChannelTable::default());
        let mut out = Vec::new();
        assert_eq!(
            s.poll_timeout(),
            f64::NEG_INFINITY,
            "the first period starts at once"
        );
        s.poll(0.0, &mut out);
        assert_eq!(s.poll_transmit(), Some(&b"\x02"[..]));
        assert_eq!(s.poll_transmit(), None, "one request per period");
        assert_eq!(out.len(), 3, "nothing read yet: every channel stale");
        assert_eq!(s.poll_timeout(), 0.1, "next period");
        out.clear();
        s.push(
            b"\x02+000000000\r\n\x02+000000000\r\n\x02+000000000\r\n",
            0.05,
            &mut out,
        );
        s.poll(0.1, &mut out);
        assert!(s.poll_transmit().is_some());
        out.clear();
        // Read at 0.05, silent for timeout_s = 0.5: due at 0.55, between periods (0.5, 0.6).
        let mut requests = 1;
        let mut stale_at = None;
        while stale_at.is_none() {
            let now = s.poll_timeout();
            s.poll(now, &mut out);
            requests += usize::from(s.poll_transmit().is_some());
            if !out.is_empty() {
                stale_at = Some(now);
            }
        }
        assert_eq!(requests, 1 + 4, "periods at 0.2, 0.3, 0.4, 0.5");
        assert!((stale_at.unwrap() - 0.55).abs() < 1e-9, "{stale_at:?}");
        assert_eq!(out.len(), 3);
        assert!(
            s.poll_transmit().is_none(),
            "a staleness deadline is not a period"
        );
        assert!(
            (s.poll_timeout() - 0.6).abs() < 1e-9,
            "then the next period"
        );
    }

    #[test]
    fn weighing_skips_unstable_and_flags_overload() {
        let cfg = SerialSourceConfig {
            format: LineFormat::Weighing {
                unit: Some("kg".into()),
                accept_unstable: false,
            },
            channel: vec![SerialChannel {
                name: "F_load_N".into(),
                key: Some("GS".into()),
                scale: 9.80665,
                offset: 0.0,
                min: None,
                max: None,
            }],
            ..dro()
        };
        let mut s = LineSource::new(cfg, &mut ChannelTable::default());
        let mut out = Vec::new();
        s.push(
            b"US,GS,+0001.000kg\r\nST,GS,+0010.000kg\r\nST,NT,+0002.000kg\r\nOL,GS,+9999.999kg\r\n",
            0.0,
            &mut out,
        );
        assert_eq!(out.len(), 2);
        assert!((out[0].value - 98.0665).abs() < 1e-9);
        assert_eq!(out[1].health, Health::OutOfRange);
        let c = s.counters();
        assert_eq!((c.unstable_skipped, c.unmatched, c.readings), (1, 1, 4));
    }

    #[tokio::test]
    async fn run_sends_the_request_and_reads_the_reply_block() {
        // A Heidenhain DRO answers Ctrl-B (0x02) with one line per axis.
        let (ours, mut device) = tokio::io::duplex(256);
        let (tx, mut rx) = tokio::sync::mpsc::channel(16);
        let mut table = ChannelTable::default();
        let task = tokio::spawn(run(ours, LineSource::new(dro(), &mut table), || 0.0, tx));
        let mut req = [0u8; 1];
        device.read_exact(&mut req).await.unwrap();
        assert_eq!(req, [0x02]);
        device
            .write_all(b"\x02+000100000\r\n\x02+000200000\r\n\x02-000300000\r\n")
            .await
            .unwrap();
        let mut got = Vec::new();
        while got.len() < 3 {
            let b = rx.recv().await.unwrap();
            got.extend(b.into_iter().filter(|s| s.health == Health::Ok));
        }
        let v: Vec<_> = got
            .iter()
            .map(|s| (table.name(s.channel), s.value))
            .collect();
        assert_eq!(v, vec![("x_mm", 10.0), ("y_mm", 20.0), ("z_mm", -30.0)]);
        drop(device); // EOF ends the source with its counters
        let c = task.await.unwrap().unwrap();
        assert_eq!((c.lines, c.readings, c.garbage_lines), (3, 3, 0));
    }
}
